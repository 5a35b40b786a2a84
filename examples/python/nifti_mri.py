#!/usr/bin/python3
"""A NIfTI volume through nibabel into isotrace: the MRI of examples/data (a 4D NIfTI-1 file;
its first frame), placed in world millimetres by its affine, as an iso-surface, path traced.

    examples/python/nifti_mri.py [OUT.png]     (default: nifti_mri.png)
"""
import os
import sys

import nibabel
import numpy as np

import isotrace

here = os.path.dirname(os.path.abspath(__file__))
out = sys.argv[1] if len(sys.argv) > 1 else "nifti_mri.png"
image = nibabel.load(os.path.join(here, "..", "data", "volumes", "example4d.nii.gz"))
# nibabel gives (nx, ny, nz[, t]) in Fortran order: axes="xyz", used in place. The affine maps
# voxel (i, j, k) to world millimetres; it goes to the volume whole (as the scene's transform).
frame0 = np.asfortranarray(np.asarray(image.dataobj[..., 0]))
volume = isotrace.Volume(frame0, axes="xyz", transform=image.affine)

scene = isotrace.Scene()
scene.add_volume(volume, isosurfaces=[{"value": 300, "color": [0.85, 0.7, 0.65]}])
scene.lights.append({"type": "directional", "direction": [0.4, 0.6, -1], "irradiance": 2.6})
scene.lights.append({"type": "environment", "radiance": 0.35})
scene.frame()
frame = isotrace.render(scene, spp=16, integrator="path", resolution=(320, 240))
frame.save(out)
print(out)
