"""The isotrace Python module (python/): run by ctest as Python.Module with Debian's python3 and
python3-pytest, on the build's module (PYTHONPATH set by ctest)."""
import gc
import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import isotrace

BINARY = os.environ.get("ISOTRACE_BINARY", "isotrace")
DATA = os.environ.get("ISOTRACE_DATA_DIR", os.path.join(os.path.dirname(__file__), "..", "..", "examples", "data"))
SOURCE = os.environ.get("ISOTRACE_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))


def blobs(shape=(36, 40, 44), seed=3):
    """A float32 field shaped (nz, ny, nx): a sum of Gaussian blobs (values 0 to ~1.5)."""
    rng = np.random.default_rng(seed)
    z, y, x = np.meshgrid(*[np.linspace(-1, 1, n) for n in shape], indexing="ij")
    f = np.zeros(shape)
    for _ in range(6):
        c = rng.uniform(-0.5, 0.5, 3)
        f += np.exp(-((z - c[0]) ** 2 + (y - c[1]) ** 2 + (x - c[2]) ** 2) / 0.08)
    return f.astype(np.float32)


LIGHTS = [{"type": "directional", "direction": [-0.4, -1, -0.3], "irradiance": 3}, {"type": "environment", "radiance": 0.3}]
CAMERA = {"position": [40, 50, 130], "look_at": [20, 20, 20], "fov": 35}


def test_render_equals_the_command_line_bit_for_bit(tmp_path):
    field = blobs()
    nz, ny, nx = field.shape
    field.tofile(tmp_path / "blobs.raw")
    volume = {"isosurfaces": [{"value": 0.5, "color": [0.8, 0.5, 0.3]}], "spacing": [1.2, 1.0, 0.8], "origin": [-2, 1, 3]}
    scene_file = {"camera": CAMERA, "lights": LIGHTS,
                  "volumes": [dict(volume, file="blobs.raw", dims=[nx, ny, nz], type="float32")]}
    (tmp_path / "s.json").write_text(json.dumps(scene_file))
    cli = subprocess.run([BINARY, "render", str(tmp_path / "s.json"), "-o", str(tmp_path / "cli.exr"), "--spp", "4",
                          "--integrator", "path", "--resolution", "64x48", "--threads", "2", "--seed", "5", "--quiet"],
                         capture_output=True, text=True)
    assert cli.returncode == 0, cli.stderr
    scene = isotrace.Scene({"camera": CAMERA, "lights": LIGHTS})
    scene.add_volume(isotrace.Volume(field, spacing=(1.2, 1.0, 0.8), origin=(-2, 1, 3)), isosurfaces=volume["isosurfaces"])
    frame = isotrace.render(scene, spp=4, integrator="path", resolution=(64, 48), threads=2, seed=5)
    expected = isotrace.read_image(tmp_path / "cli.exr")[:, :, :3]
    assert frame.rgb.shape == (48, 64, 3) and frame.rgb.dtype == np.float32
    assert frame.rgb.max() > 0.05, "the surface is in the picture"
    assert np.array_equal(frame.rgb, expected)
    assert frame.stats["spp"] == 4 and frame.stats["integrator"] == "path"


@pytest.mark.parametrize("scene, integrator", [("bench/scenes/neghip_glass.json", "path"),
                                               ("examples/cornell_torus.json", "path"),
                                               ("examples/color_by.json", "eyelight")])
def test_the_command_line_and_the_module_render_scene_files_bit_for_bit(tmp_path, scene, integrator):
    """The `isotrace` executable is linked with link-time optimisation (functions inlined across files), the
    module from the libraries' own machine code (CMakeLists.txt): both give the same bits, on scenes with meshes,
    glass, area lights, textures and colour by data as well as iso-surfaces."""
    path = os.path.join(SOURCE, scene)
    flags = dict(spp=3, integrator=integrator, resolution=(48, 32), threads=2, seed=11, denoise="off")
    cli = subprocess.run([BINARY, "render", path, "-o", str(tmp_path / "cli.exr"), "--spp", "3", "--integrator", integrator,
                          "--resolution", "48x32", "--threads", "2", "--seed", "11", "--denoise", "off", "--quiet"],
                         capture_output=True, text=True)
    assert cli.returncode == 0, cli.stderr
    frame = isotrace.render(path, **flags)
    expected = isotrace.read_image(tmp_path / "cli.exr")[:, :, :3]
    assert frame.rgb.max() > 0.05, "something lit is in the picture"
    assert np.array_equal(frame.rgb, expected)


def test_axis_orders_put_the_bright_corner_where_the_docstring_says():
    # A bright blob around index [z0, y0, x0] of a (nz, ny, nx) array: with spacing s and origin
    # o, world point o + (x0, y0, z0) * s. The same data as an (nx, ny, nz) Fortran array with
    # axes="xyz" is the same volume.
    nz, ny, nx = 20, 24, 28
    z0, y0, x0 = 15, 5, 20
    zz, yy, xx = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    zyx = np.exp(-((zz - z0) ** 2 + (yy - y0) ** 2 + (xx - x0) ** 2) / 8.0).astype(np.float32)
    xyz = np.asfortranarray(zyx.transpose(2, 1, 0))
    spacing, origin = (0.5, 2.0, 1.0), (10.0, -4.0, 7.0)
    centre = np.array(origin) + np.array([x0, y0, z0]) * np.array(spacing)
    for array, axes in ((zyx, "zyx"), (xyz, "xyz")):
        volume = isotrace.Volume(array, spacing=spacing, origin=origin, axes=axes)
        assert volume.dims == (nx, ny, nz)
        assert volume.data_pointer == array.ctypes.data, "used in place"
        scene = isotrace.Scene()
        scene.add_volume(volume, isosurfaces=[{"value": 0.5}])
        vertices, triangles, normals = isotrace.mesh(scene)
        assert len(triangles) > 20
        assert np.allclose(vertices.mean(axis=0), centre, atol=0.3), (axes, vertices.mean(axis=0), centre)


def test_the_array_is_used_in_place_and_outlives_every_python_reference():
    field = blobs((24, 24, 24))
    pointer = field.ctypes.data
    volume = isotrace.Volume(field)
    assert volume.data_pointer == pointer
    scene = isotrace.Scene({"camera": {"position": [40, 40, 60], "look_at": [12, 12, 12]}})
    scene.add_volume(volume, isosurfaces=[{"value": 0.4}])
    first = isotrace.render(scene, spp=1, resolution=(32, 24), integrator="normals").rgb
    del field, volume
    gc.collect()
    # Only the scene holds the array now; rendering again reads the same samples.
    again = isotrace.render(scene, spp=1, resolution=(32, 24), integrator="normals").rgb
    assert np.array_equal(first, again)
    assert np.abs(first).max() > 0


def test_rss_grows_by_less_than_a_third_of_a_512_cubed_array():
    # Run alone so that nothing else's allocations count: a 512^3 float32 array (512 MiB) and
    # a render of its surface; the process's peak may grow by no more than 0.3 x the array over
    # what it held with the array made (the brick ranges, the surface's tables, the film).
    script = textwrap.dedent("""
        import numpy as np, isotrace, resource
        def peak():
            return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        n = 512
        x = np.linspace(-1, 1, n, dtype=np.float32)
        a = np.empty((n, n, n), np.float32)
        for k in range(n):  # slice by slice: no temporary the size of the array
            a[k] = np.sqrt(x[None, :] ** 2 + x[:, None] ** 2 + x[k] ** 2)
        s = isotrace.Scene({"camera": {"position": [0, 0, 3], "look_at": [0, 0, 0]}})
        isotrace.render(s, spp=1, resolution=(8, 8))  # the renderer's own start-up, before measuring
        before = peak()
        v = isotrace.Volume(a, spacing=(2 / (n - 1),) * 3, origin=(-1, -1, -1))
        s.add_volume(v, isosurfaces=[{"value": 0.6, "inside": "below"}])
        f = isotrace.render(s, spp=1, resolution=(64, 48), integrator="eyelight")
        print(before, peak(), a.nbytes, float(f.rgb.max()))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    before, peak, nbytes, brightest = [float(v) for v in out.stdout.split()]
    assert brightest > 0
    assert peak - before < 0.3 * nbytes, "grew by %.0f MiB for a %.0f MiB array" % ((peak - before) / 2**20, nbytes / 2**20)


def test_changing_an_iso_value_keeps_the_volume_loaded(tmp_path):
    # The volume's file is gone before the second render: only a volume kept loaded renders.
    raw = tmp_path / "neghip_64x64x64_uint8.raw"
    with open(os.path.join(DATA, "volumes", "neghip_64x64x64_uint8.raw"), "rb") as f:
        raw.write_bytes(f.read())
    scene = isotrace.Scene({"volumes": [{"file": str(raw), "isosurfaces": [{"value": 40}]}]})
    a = isotrace.render(scene, spp=1, resolution=(48, 36))
    raw.unlink()
    scene.doc["volumes"][0]["isosurfaces"][0]["value"] = 90
    b = isotrace.render(scene, spp=1, resolution=(48, 36))
    assert not np.array_equal(a.rgb, b.rgb)
    # Moving the volume is another load: now the missing file is an error naming it.
    scene.doc["volumes"][0]["origin"] = [1, 0, 0]
    with pytest.raises(isotrace.InputError, match="neghip_64x64x64_uint8.raw"):
        isotrace.render(scene, spp=1, resolution=(48, 36))


def test_aovs_compare_save_and_png(tmp_path):
    scene = isotrace.Scene.load(os.path.join(SOURCE, "examples", "quick_look.json"))
    frame = isotrace.render(scene, spp=2, resolution=(40, 30), aovs=["albedo", "normal", "depth"])
    assert frame.aov("albedo").shape == (30, 40, 3)
    assert frame.aov("depth").shape == (30, 40)
    with pytest.raises(isotrace.InputError, match="no layer 'variance'"):
        frame.aov("variance")
    path = frame.save(tmp_path / "f.exr")
    back = isotrace.read_image(path)
    assert np.array_equal(back[:, :, :3], frame.rgb)
    assert frame._repr_png_().startswith(b"\x89PNG")
    frame.save(tmp_path / "f.png", exposure=1, tonemap="aces")
    with pytest.raises(isotrace.InputError, match="tonemap"):
        frame.save(tmp_path / "g.png", tonemap="magic")
    compare = isotrace.render(scene, spp=2, resolution=(40, 30), integrator="path").rgb
    three = isotrace.render(scene, spp=2, resolution=(40, 30), integrator="compare")
    assert set(three.images) == {"direct", "global", "indirect"}
    assert np.allclose(three.images["global"] - three.images["direct"], three.images["indirect"], atol=1e-6)
    assert compare.shape == three.rgb.shape


def test_watertight_bench_and_mesh_reports():
    scene = isotrace.Scene()
    scene.add_volume(isotrace.Volume(blobs((30, 30, 30))), isosurfaces=[{"value": 0.5}],
                     clip=[{"plane": {"point": [15, 15, 15], "normal": [1, 1, 0]}}])
    report = isotrace.watertight(scene, rays=20000, offset=(1e5, 0, 0))
    total = report["total"]
    assert total["rays"] == 20000 and total["crossings"] > 2000
    assert total["parity_errors"] == total["self_hits"] == total["inside_escapes"] == total["shadow_mismatches"] == 0
    bench = isotrace.bench(scene, rays=500, intersectors=["isolation", "linear"])
    assert {r["intersector"] for r in bench["results"]} == {"isolation:8", "linear"}
    vertices, triangles, normals = isotrace.mesh(scene)
    assert vertices.shape == normals.shape and triangles.max() < len(vertices)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-5)


def test_mesh_saves_gltf_that_the_command_line_reads(tmp_path):
    scene = isotrace.Scene()
    scene.add_volume(isotrace.Volume(blobs((24, 24, 24))), isosurfaces=[{"value": 0.5, "color": [0.2, 0.6, 0.3]}])
    vertices, triangles, _ = isotrace.mesh(scene, path=tmp_path / "blobs.glb")
    (tmp_path / "m.json").write_text(json.dumps({"meshes": [{"file": str(tmp_path / "blobs.glb")}]}))
    info = subprocess.run([BINARY, "info", str(tmp_path / "m.json")], capture_output=True, text=True)
    assert info.returncode == 0, info.stderr
    assert "%d triangles" % len(triangles) in info.stdout, info.stdout
    with pytest.raises(isotrace.InputError, match="must be .glb or .gltf"):
        isotrace.mesh(scene, path=tmp_path / "blobs.obj")


def test_progress_is_reported_up_to_the_whole_frame():
    seen = []
    scene = isotrace.Scene.load(os.path.join(SOURCE, "examples", "quick_look.json"))
    isotrace.render(scene, spp=4, resolution=(64, 48), progress=lambda done, total: seen.append((done, total)))
    assert seen and seen[-1][0] == seen[-1][1] == 64 * 48 * 4
    assert all(a[0] <= b[0] for a, b in zip(seen, seen[1:]))


BAD = [
    ("import numpy as np, isotrace; isotrace.Volume(np.zeros((4, 4), np.float32))", "expected a 3D array"),
    ("import numpy as np, isotrace; isotrace.Volume(np.zeros((4, 4, 4), np.int32))", "unsupported dtype int32"),
    ("import numpy as np, isotrace; a = np.zeros((4, 5, 6), np.float32); a[1, 2, 3] = np.nan; isotrace.Volume(a)",
     "index [1, 2, 3] is not finite"),
    ("import numpy as np, isotrace; isotrace.Volume(np.zeros((4, 4, 1), np.uint8))", "2 to 2^20 samples"),
    ("import numpy as np, isotrace; isotrace.Volume(np.zeros((4, 4, 4), np.uint8), spacing=(1, 0, 1))", "spacing must be positive"),
    ("import numpy as np, isotrace; isotrace.Volume(np.zeros((4, 4, 4), np.uint8), axes='yxz')", "axes"),
    ("import isotrace; isotrace.Scene({'volumes': [{'procedural': {'field': 'sphere'}, 'isosurfaces': [{'valeu': 1}]}]})",
     "/volumes/0/isosurfaces/0/valeu: unknown key"),
    ("import isotrace; isotrace.Scene({'volumes': [{'array': 0, 'isosurfaces': []}]})", "/volumes/0/array: no arrays here"),
    ("import isotrace; isotrace.render({'film': {'width': 8, 'height': 8}}, spp=0)", "spp: value 0 is out of range"),
    ("import isotrace; isotrace.render({}, integrator='raytrace')", "unknown integrator 'raytrace'"),
    ("import isotrace; isotrace.render({}, resolution=(0, 5))", "resolution"),
    ("import isotrace; isotrace.render({}, aovs=['glow'])", "unknown layer 'glow'"),
    ("import isotrace; isotrace.Scene.load('/nonexistent/scene.json')", "cannot read the scene file"),
    ("import isotrace; isotrace.watertight({'volumes': []}, rays=10)", "no volume"),
    ("import isotrace; isotrace.mesh({'volumes': [{'procedural': {'field': 'sphere'}, 'isosurfaces': [{'value': 0.5}]}]}, surface=3)",
     "no iso-surface 3"),
]


@pytest.mark.parametrize("code,message", BAD)
def test_bad_input_is_an_input_error_naming_the_place(code, message):
    # Each in its own interpreter: whatever happens, this one survives.
    run = subprocess.run([sys.executable, "-c", code + "\n"], capture_output=True, text=True)
    assert run.returncode == 1, run.stderr  # an uncaught exception, not a crash
    assert "isotrace._core.InputError" in run.stderr or "InputError" in run.stderr, run.stderr
    assert message in run.stderr, run.stderr


def test_a_non_contiguous_array_is_copied_once_with_a_warning():
    field = blobs((20, 20, 40))[:, :, ::2]  # a strided view
    with pytest.warns(UserWarning, match="copied once"):
        volume = isotrace.Volume(field)
    assert volume.data_pointer != field.ctypes.data
    scene = isotrace.Scene()
    scene.add_volume(volume, isosurfaces=[{"value": 0.5}])
    assert len(isotrace.mesh(scene)[1]) > 0


def test_keyboard_interrupt_stops_a_render_within_a_second():
    # A render far longer than the test waits; SIGINT once it has begun (the first progress
    # report is the event), and the interpreter must be back with KeyboardInterrupt and the
    # partial frame within a second.
    script = textwrap.dedent("""
        import os, signal, sys, time, isotrace
        scene = isotrace.Scene.load(sys.argv[1])
        started = []
        def progress(done, total):
            if done > 0 and not started:
                started.append(time.monotonic())
                os.kill(os.getpid(), signal.SIGINT)
        try:
            isotrace.render(scene, spp=100000, resolution=(64, 48), integrator="path", progress=progress)
            print("finished")
        except KeyboardInterrupt as e:
            print("interrupted", time.monotonic() - started[0], e.frame.stats["spp"], e.frame.rgb.shape)
    """)
    run = subprocess.run([sys.executable, "-c", script, os.path.join(SOURCE, "examples", "quick_look.json")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    words = run.stdout.split()
    assert words[0] == "interrupted", run.stdout
    assert float(words[1]) < 1.0, "took %s s to return" % words[1]
    assert int(words[2]) >= 1


def test_import_needs_no_environment_variable():
    # ./run.sh and ./test.sh install a .pth for Debian's python3: import works from anywhere.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    run = subprocess.run(["/usr/bin/python3", "-c", "import isotrace; print(isotrace.__file__)"], cwd="/", env=env,
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().endswith("isotrace/__init__.py")


def test_denoise_matches_the_command_line_and_frame_denoised(tmp_path):
    field = blobs()
    nz, ny, nx = field.shape
    field.tofile(tmp_path / "blobs.raw")
    iso = [{"value": 0.5, "color": [0.8, 0.5, 0.3]}]
    scene_file = {"camera": CAMERA, "lights": LIGHTS,
                  "volumes": [{"file": "blobs.raw", "dims": [nx, ny, nz], "type": "float32", "isosurfaces": iso}]}
    (tmp_path / "s.json").write_text(json.dumps(scene_file))
    cli = subprocess.run([BINARY, "render", str(tmp_path / "s.json"), "-o", str(tmp_path / "cli.exr"), "--spp", "4",
                          "--integrator", "path", "--resolution", "64x48", "--threads", "2", "--seed", "5", "--quiet",
                          "--denoise", "quality"], capture_output=True, text=True)
    assert cli.returncode == 0, cli.stderr
    scene = isotrace.Scene({"camera": CAMERA, "lights": LIGHTS})
    scene.add_volume(isotrace.Volume(field), isosurfaces=iso)
    frame = isotrace.render(scene, spp=4, integrator="path", resolution=(64, 48), threads=1, seed=5, denoise="quality")
    assert np.array_equal(frame.rgb, isotrace.read_image(tmp_path / "cli.exr")[:, :, :3])
    assert frame.raw is not None and not np.array_equal(frame.raw, frame.rgb)
    assert frame.stats["denoise"] == "quality" and frame.stats["seconds"]["denoise"] > 0
    raw = isotrace.render(scene, spp=4, integrator="path", resolution=(64, 48), threads=2, seed=5)
    assert raw.raw is None and np.array_equal(raw.rgb, frame.raw)
    later = raw.denoised("quality")
    assert np.array_equal(later.rgb, frame.rgb), "denoised afterwards: the same bits"
    assert np.array_equal(later.raw, raw.rgb) and np.array_equal(raw.rgb, frame.raw), "the frame itself is untouched"
    fast = raw.denoised("fast")
    assert fast.stats["denoise"] == "fast" and not np.array_equal(fast.rgb, later.rgb)
    compare = isotrace.render(scene, spp=4, integrator="compare", resolution=(64, 48), seed=5).denoised()
    assert np.allclose(compare.rgb, compare.direct + compare.indirect, rtol=1e-6, atol=1e-7)
    with pytest.raises(isotrace.InputError, match="unknown mode 'sharp'"):
        raw.denoised("sharp")
    with pytest.raises(isotrace.InputError, match="denoise: unknown mode 'sharp'"):
        isotrace.render(scene, spp=1, resolution=(8, 8), denoise="sharp")
    with pytest.raises(isotrace.InputError, match="no noise to remove"):
        isotrace.render(scene, spp=1, resolution=(8, 8), integrator="normals").denoised()
