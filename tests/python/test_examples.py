"""examples/python: every script runs and writes images that show something; the notebook runs
top to bottom (python3-nbconvert, python3-ipykernel)."""
import os
import subprocess
import sys

import numpy as np
import pytest

import isotrace

SOURCE = os.environ.get("ISOTRACE_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
EXAMPLES = os.path.join(SOURCE, "examples", "python")


def shows_something(path):
    image = isotrace.read_image(path)[:, :, :3]
    # Not one flat colour: the subject stands out from the background.
    return image.shape[0] > 10 and float(image.std()) > 0.02


@pytest.mark.parametrize("script,args,outputs", [
    ("nifti_mri.py", ["mri.png"], ["mri.png"]),
    ("dicom_series.py", [], ["dicom_series.png"]),
    ("gaussians_compare.py", ["g"], ["g.direct.png", "g.global.png", "g.indirect.png"]),
    ("iso_sweep.py", ["sweep", "3"], ["sweep/frame_00.png", "sweep/frame_01.png", "sweep/frame_02.png"]),
])
def test_example_scripts_write_their_images(tmp_path, script, args, outputs):
    run = subprocess.run([sys.executable, os.path.join(EXAMPLES, script)] + args, cwd=tmp_path, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    for name in outputs:
        assert shows_something(tmp_path / name), name


def test_iso_sweep_frames_differ(tmp_path):
    subprocess.run([sys.executable, os.path.join(EXAMPLES, "iso_sweep.py"), "s", "2"], cwd=tmp_path, check=True,
                   capture_output=True)
    a, b = (isotrace.read_image(tmp_path / "s" / ("frame_%02d.png" % i)) for i in (0, 1))
    assert not np.array_equal(a, b)


def run_notebook(tmp_path, name, temp=None):
    """Runs examples/python/NAME top to bottom; the outputs of its code cells (none an error).
    `temp`: the kernel's temporary folder (TMPDIR)."""
    import json
    out = tmp_path / name
    env = dict(os.environ, PYDEVD_DISABLE_FILE_VALIDATION="1")
    if temp:
        env["TMPDIR"] = str(temp)
    run = subprocess.run([sys.executable, "-m", "nbconvert", "--to", "notebook", "--execute",
                          os.path.join(EXAMPLES, name), "--output", str(out)],
                         capture_output=True, text=True, timeout=600, env=env)
    assert run.returncode == 0, run.stderr
    cells = json.loads(out.read_text())["cells"]
    outputs = [o for c in cells if c["cell_type"] == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    return outputs


def images_of(outputs):
    return [o["data"]["image/png"] for o in outputs if "image/png" in o.get("data", {})]


def test_the_notebook_runs_top_to_bottom(tmp_path):
    assert len(images_of(run_notebook(tmp_path, "explore.ipynb"))) == 3


def test_the_time_series_notebook_renders_a_sequence_from_numpy(tmp_path):
    import base64
    temp = tmp_path / "temp"
    temp.mkdir()
    outputs = run_notebook(tmp_path, "time_series.ipynb", temp)
    texts = ["".join(o.get("text", [])) for o in outputs]
    assert any("12 frames" in t for t in texts)
    # The frames were written as numbered images, into a folder the notebook removes again.
    assert any(t.startswith("12 images: 0000.png, 0001.png, 0002.png") for t in texts), texts
    assert not [p for p in temp.iterdir() if p.name.startswith("isotrace-frames-")]
    images = images_of(outputs)
    assert len(images) == 3
    # The blobs move: the frames shown differ.
    assert len(set(images)) == 3
    assert all(len(base64.b64decode(i)) > 1000 for i in images)
