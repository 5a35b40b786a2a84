#!/usr/bin/env python3
"""The denoiser judged by error at equal time (issue 45).

For every example scene that path traces (examples/*.json but quick_look), at half the scene's
film size: a reference of 2048 samples per pixel (rendered once, cached outside the repository
in $ISOTRACE_CACHE or ~/.cache/isotrace/denoise, keyed on the scene file's bytes, the size,
the spp and the seed), then renders at 4, 16, 64 and 128 spp (and 32), raw and denoised, with
their times. Prints a table of relMSE (mean over pixels and channels of (x - ref)^2 / (ref^2 +
1e-2)), SSIM (of the sRGB luminance after the clamp curve) and the change of the image mean,
and writes it as JSON (--json) for docs/.

    bench/denoise.py [--scenes a,b] [--spp 4,16,64] [--modes quality,fast] [--json FILE]
                     [--references-only] [--threads N]
"""
import argparse
import hashlib
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ISOTRACE = os.environ.get("ISOTRACE_BINARY") or os.path.join(ROOT, "build", "isotrace")
REFERENCE_SPP = 2048
REFERENCE_SEED = 7919  # not a seed the measured renders use: the reference's noise is its own


def cache_dir():
    d = os.environ.get("ISOTRACE_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "isotrace", "denoise")
    os.makedirs(d, exist_ok=True)
    return d


def example_scenes():
    names = []
    for f in sorted(os.listdir(os.path.join(ROOT, "examples"))):
        if not f.endswith(".json"):
            continue
        with open(os.path.join(ROOT, "examples", f)) as fh:
            doc = json.load(fh)
        if doc.get("integrator", {}).get("type") in ("path", "direct", "compare"):
            names.append(f[:-5])
    return names


def scene_size(name):
    with open(os.path.join(ROOT, "examples", name + ".json")) as fh:
        film = json.load(fh).get("film", {})
    return max(1, film.get("width", 640) // 2), max(1, film.get("height", 480) // 2)


def scene_key(path):
    """What the reference depends on: the scene without the keys a reference overrides or that
    do not change the beauty (spp, film.denoise), so that retuning an example's samples keeps it."""
    with open(path) as fh:
        doc = json.load(fh)
    doc.get("integrator", {}).pop("spp", None)
    doc.get("film", {}).pop("denoise", None)
    return hashlib.sha1(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]


def reference(name, threads):
    path = os.path.join(ROOT, "examples", name + ".json")
    key = scene_key(path)
    w, h = scene_size(name)
    out = os.path.join(cache_dir(), "%s-%s-%dx%d-%dspp-s%d.exr" % (name, key, w, h, REFERENCE_SPP, REFERENCE_SEED))
    if not os.path.exists(out):
        print("denoise.py: rendering the reference of %s (%dx%d, %d spp) to %s" % (name, w, h, REFERENCE_SPP, out),
              file=sys.stderr, flush=True)
        subprocess.run([ISOTRACE, "render", path, "--resolution", "%dx%d" % (w, h), "--spp", str(REFERENCE_SPP),
                        "--seed", str(REFERENCE_SEED), "--threads", str(threads), "--quiet", "-o", out + ".tmp.exr"],
                       check=True, stdout=subprocess.DEVNULL)
        os.replace(out + ".tmp.exr", out)
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default="")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--references-only", action="store_true")
    a = p.parse_args()
    scenes = a.scenes.split(",") if a.scenes else example_scenes()
    for s in scenes:
        reference(s, a.threads)
    if a.references_only:
        return


if __name__ == "__main__":
    main()
