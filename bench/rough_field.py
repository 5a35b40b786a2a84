#!/usr/bin/python3
"""A rough float32 field for hunting exactness errors: random Gaussian blobs plus a
high-frequency ripple, on an anisotropic grid placed anywhere (far from the origin, say).

Writes OUT_DIR/rough_SEED.raw (float32, x fastest) and OUT_DIR/rough_SEED.json, a scene with
the three iso values given. Then, for example:
  build/isotrace watertight OUT_DIR/rough_SEED.json --rays 10000000 --dump failures.txt

Usage: bench/rough_field.py OUT_DIR [--seed N] [--dims NX,NY,NZ] [--spacing SX,SY,SZ]
                            [--origin X,Y,Z] [--blobs N] [--ripple AMPLITUDE,WAVELENGTH]
                            [--iso A,B,C]
Defaults: seed 1, dims 48,40,36, spacing 0.41,0.37,0.43, origin 1e5,1e5,1e5, 24 blobs,
ripple 0.15 over 1.5 cells, iso 0.11,0.42,0.97 (the field spans about 0 to 1.3).
"""
import argparse
import array
import json
import math
import os
import random
import sys


def triple(text, kind, name):
    try:
        values = [kind(v) for v in text.split(",")]
    except ValueError:
        sys.exit("rough_field: %s: expected three comma-separated numbers, got %r" % (name, text))
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        sys.exit("rough_field: %s: expected three finite numbers, got %r" % (name, text))
    return values


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("out_dir")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--dims", default="48,40,36")
    p.add_argument("--spacing", default="0.41,0.37,0.43")
    p.add_argument("--origin", default="1e5,1e5,1e5")
    p.add_argument("--blobs", type=int, default=24)
    p.add_argument("--ripple", default="0.15,1.5")
    p.add_argument("--iso", default="0.11,0.42,0.97")
    a = p.parse_args()
    dims = triple(a.dims, int, "--dims")
    spacing = triple(a.spacing, float, "--spacing")
    origin = triple(a.origin, float, "--origin")
    iso = triple(a.iso, float, "--iso")
    ripple = [float(v) for v in a.ripple.split(",")]
    if any(d < 2 or d > 1024 for d in dims) or dims[0] * dims[1] * dims[2] > 1 << 27:
        sys.exit("rough_field: --dims: each from 2 to 1024, at most 2^27 samples")
    if any(s <= 0 for s in spacing):
        sys.exit("rough_field: --spacing: must be positive")
    if not 0 <= a.blobs <= 1000:
        sys.exit("rough_field: --blobs: 0 to 1000")
    if len(ripple) != 2 or ripple[1] <= 0:
        sys.exit("rough_field: --ripple: AMPLITUDE,WAVELENGTH (in cells, > 0)")
    os.makedirs(a.out_dir, exist_ok=True)

    rng = random.Random(a.seed)
    nx, ny, nz = dims
    blobs = []
    for _ in range(a.blobs):
        centre = (rng.uniform(0, nx - 1), rng.uniform(0, ny - 1), rng.uniform(0, nz - 1))
        width = rng.uniform(2.0, 0.25 * min(dims))  # in cells
        blobs.append((centre, 1.0 / (2 * width * width), rng.uniform(0.3, 1.0)))
    k = 2 * math.pi / ripple[1]
    phase = [rng.uniform(0, 2 * math.pi) for _ in range(3)]
    samples = array.array("f", [0.0]) * (nx * ny * nz)
    i = 0
    for z in range(nz):
        for y in range(ny):
            for x in range(nx):
                v = ripple[0] * math.sin(k * x + phase[0]) * math.sin(k * y + phase[1]) * math.sin(k * z + phase[2])
                for (cx, cy, cz), inv, amp in blobs:
                    r2 = (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2
                    if r2 * inv < 30:
                        v += amp * math.exp(-r2 * inv)
                samples[i] = v
                i += 1
    if sys.byteorder != "little":
        samples.byteswap()
    stem = os.path.join(a.out_dir, "rough_%d" % a.seed)
    with open(stem + ".raw", "wb") as f:
        samples.tofile(f)
    scene = {
        "volumes": [{
            "file": os.path.basename(stem) + ".raw", "dims": dims, "type": "float32",
            "spacing": spacing, "origin": origin,
            "isosurfaces": [{"value": v} for v in iso],
        }],
    }
    with open(stem + ".json", "w") as f:
        json.dump(scene, f, indent=1)
    print(stem + ".json")


if __name__ == "__main__":
    main()
