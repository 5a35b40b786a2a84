#!/usr/bin/python3
"""An iso sweep: one frame per iso value of a volume from a raw file (numpy.fromfile, used in
place), the volume loaded once for all frames.

    examples/python/iso_sweep.py [OUT_FOLDER] [FRAMES]     (default: iso_sweep, 6 frames)
"""
import os
import sys

import numpy as np

import isotrace

here = os.path.dirname(os.path.abspath(__file__))
folder = sys.argv[1] if len(sys.argv) > 1 else "iso_sweep"
frames = int(sys.argv[2]) if len(sys.argv) > 2 else 6
os.makedirs(folder, exist_ok=True)
# The Open SciVis name says it: 64 x 64 x 64 uint8, x fastest, i.e. shaped (z, y, x).
neghip = np.fromfile(os.path.join(here, "..", "data", "volumes", "neghip_64x64x64_uint8.raw"), np.uint8).reshape(64, 64, 64)
scene = isotrace.Scene()
scene.add_volume(isotrace.Volume(neghip), isosurfaces=[{"value": 30, "color": [0.3, 0.55, 0.9]}])
scene.lights.append({"type": "directional", "direction": [-0.3, -1, -0.6], "irradiance": 2.5})
scene.lights.append({"type": "environment", "radiance": 0.4})
scene.frame()
for i, value in enumerate(np.linspace(30, 150, frames)):
    scene.doc["volumes"][0]["isosurfaces"][0]["value"] = float(value)
    frame = isotrace.render(scene, spp=8, integrator="direct", resolution=(200, 150))
    path = os.path.join(folder, "frame_%02d.png" % i)
    frame.save(path)
    print("%s  iso %.0f  %.2f s" % (path, value, frame.stats["seconds"]["total"]))
