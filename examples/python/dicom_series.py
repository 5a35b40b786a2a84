#!/usr/bin/python3
"""A DICOM series through pydicom into isotrace: slices sorted along their normal, stacked
(z, y, x), scaled to Hounsfield units, spacing from PixelSpacing and the slices' positions.

    examples/python/dicom_series.py [FOLDER] [OUT.png]

Without a folder it makes a small demo series first (copies of pydicom's CT_small.dcm test file
holding a synthetic skull: a shell of 1200 HU in soft tissue), so that it runs anywhere.
"""
import glob
import os
import sys
import tempfile

import numpy as np
import pydicom
from pydicom.uid import generate_uid

import isotrace


def read_series(folder):
    """The slices of `folder` as float32 HU shaped (nz, ny, nx), and the spacing (x, y, z)."""
    slices = [pydicom.dcmread(f) for f in sorted(glob.glob(os.path.join(folder, "*"))) if os.path.isfile(f)]
    if len(slices) < 2:
        raise SystemExit("%s: fewer than 2 DICOM slices" % folder)
    row, col = np.array(slices[0].ImageOrientationPatient[:3]), np.array(slices[0].ImageOrientationPatient[3:])
    normal = np.cross(row, col)
    slices.sort(key=lambda s: float(np.dot(normal, s.ImagePositionPatient)))
    positions = [float(np.dot(normal, s.ImagePositionPatient)) for s in slices]
    dz = np.diff(positions)
    if np.any(dz <= 0) or np.ptp(dz) > 1e-3 * dz.mean():
        raise SystemExit("%s: slices are not evenly spaced" % folder)
    volume = np.stack([s.pixel_array * float(getattr(s, "RescaleSlope", 1)) + float(getattr(s, "RescaleIntercept", 0))
                       for s in slices]).astype(np.float32)
    dy, dx = (float(v) for v in slices[0].PixelSpacing)  # PixelSpacing is (row step, column step)
    return volume, (dx, dy, float(dz.mean()))


def demo_series(folder, n=40):
    """Writes n slices of 64 x 64: a hollow ball of 'bone' in 'soft tissue', from CT_small.dcm."""
    template = pydicom.dcmread(os.path.join(os.path.dirname(pydicom.__file__), "data", "test_files", "CT_small.dcm"))
    series = generate_uid()
    y, x = np.mgrid[0:64, 0:64]
    for k in range(n):
        ds = template.copy()
        r = np.sqrt((x - 31.5) ** 2 + (y - 31.5) ** 2 + ((k - (n - 1) / 2) * 64 / n) ** 2)
        hu = np.where(r < 30, 40.0, -1000.0) + np.where((r > 20) & (r < 26), 1160.0, 0.0)
        ds.Rows, ds.Columns = 64, 64
        ds.RescaleSlope, ds.RescaleIntercept = 1, -1024
        ds.PixelData = (hu + 1024).astype(np.int16).tobytes()
        ds.PixelSpacing = [0.8, 0.8]
        ds.ImageOrientationPatient = [1, 0, 0, 0, 1, 0]
        ds.ImagePositionPatient = [0, 0, k * 1.25]
        ds.SliceThickness = 1.25
        ds.SeriesInstanceUID, ds.SOPInstanceUID = series, generate_uid()
        ds.InstanceNumber = k + 1
        ds.save_as(os.path.join(folder, "slice%03d.dcm" % k))


folder = sys.argv[1] if len(sys.argv) > 1 else None
out = sys.argv[2] if len(sys.argv) > 2 else "dicom_series.png"
with tempfile.TemporaryDirectory() as demo:
    if folder is None:
        demo_series(demo)
        folder = demo
    hu, spacing = read_series(folder)
    scene = isotrace.Scene()
    # Bone (400 HU) as a solid, cut open by a plane through the middle: the cap shows the HU there.
    centre = [s * (n - 1) / 2 for s, n in zip(spacing, hu.shape[::-1])]
    scene.add_volume(isotrace.Volume(hu, spacing=spacing), name="ct",
                     isosurfaces=[{"value": 400, "color": [0.9, 0.85, 0.7],
                                   "cap_color_by": {"field": "ct", "map": "inferno", "range": [0, 1300]}}],
                     clip=[{"plane": {"point": centre, "normal": [0.3, 0.2, 1]}}])
    scene.lights.append({"type": "directional", "direction": [-0.3, -0.5, -1], "irradiance": 2.5})
    scene.lights.append({"type": "environment", "radiance": 0.35})
    scene.frame()
    frame = isotrace.render(scene, spp=16, integrator="path", resolution=(320, 240))
    frame.save(out)
    print(out)
