#!/usr/bin/python3
"""A field made in numpy (a sum of Gaussian blobs) with two nested iso-surfaces, rendered with
the `compare` integrator: direct light, global illumination and their difference, side by side.

    examples/python/gaussians_compare.py [OUT_PREFIX]     (default: gaussians; writes
    OUT_PREFIX.direct.png, .global.png, .indirect.png)
"""
import sys

import numpy as np

import isotrace

prefix = sys.argv[1] if len(sys.argv) > 1 else "gaussians"
rng = np.random.default_rng(7)
n = 80
z, y, x = np.meshgrid(*(np.linspace(-1, 1, n, dtype=np.float32),) * 3, indexing="ij")
field = np.zeros((n, n, n), np.float32)
for centre, width in zip(rng.uniform(-0.45, 0.45, (8, 3)), rng.uniform(0.05, 0.12, 8)):
    field += np.exp(-((z - centre[0]) ** 2 + (y - centre[1]) ** 2 + (x - centre[2]) ** 2) / width)

scene = isotrace.Scene({"materials": {"glass": {"type": "dielectric", "ior": 1.3, "color": [0.9, 0.95, 1], "thin": True},
                                      "core": {"type": "diffuse", "color": [0.85, 0.35, 0.2]},
                                      "floor": {"type": "diffuse", "color": 0.6}}})
scene.add_volume(isotrace.Volume(field, spacing=(2 / (n - 1),) * 3, origin=(-1, -1, -1)),
                 isosurfaces=[{"value": 0.3, "material": "glass"}, {"value": 0.9, "material": "core"}])
scene.add_mesh(shape="quad", transform={"scale": 6, "translate": [0, -1, 0]}, material="floor")
scene.lights.append({"type": "directional", "direction": [-0.4, -1, -0.5], "irradiance": 3})
scene.lights.append({"type": "environment", "radiance": 0.25})
scene.camera = {"position": [1.8, 1.3, 2.6], "look_at": [0, -0.2, 0], "fov": 40}
frame = isotrace.render(scene, spp=32, integrator="compare", resolution=(256, 192), max_depth=5)
for name, image in frame.images.items():
    path = "%s.%s.png" % (prefix, name)
    isotrace.Frame({"rgb": image, "layers": {}, "signed": False, "stats": "{}"}).save(path)
    print(path)
share = frame.images["indirect"].mean() / max(frame.images["global"].mean(), 1e-9)
print("indirect light: %.0f%% of the image" % (100 * share))
