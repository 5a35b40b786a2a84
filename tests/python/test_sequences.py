"""Sequences from Python (isotrace.render_sequence), volumes that change over time (a 4D array, a
list of arrays), a Scene rendered from several threads, and image-parallel MPI from Python."""
import json
import os
import shutil
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest

import isotrace

BINARY = os.environ.get("ISOTRACE_BINARY", "isotrace")
LIGHTS = [{"type": "directional", "direction": [-1, -2, -1], "irradiance": 3}, {"type": "environment", "radiance": 0.3}]
CAMERA = {"position": [30, 25, 60], "look_at": [11.5, 11.5, 11.5]}
OPTIONS = dict(spp=2, resolution=(40, 30), integrator="direct", threads=2)


def balls(radii, n=24):
    """(len(radii), n, n, n) float32: step t is a ball of radius radii[t] (radius minus distance)."""
    z, y, x = np.mgrid[0:n, 0:n, 0:n]
    d = np.sqrt((x - 11.5) ** 2 + (y - 11.5) ** 2 + (z - 11.5) ** 2)
    return np.stack([(r - d).astype(np.float32) for r in radii])


def scene_of(volume):
    s = isotrace.Scene({"camera": CAMERA, "lights": LIGHTS})
    s.add_volume(volume, isosurfaces=[{"value": 0, "color": [0.8, 0.4, 0.3]}])
    return s


def test_a_4d_array_is_a_time_series_each_frame_its_step():
    steps = balls([4, 6, 8, 10])
    volume = isotrace.Volume(steps)
    assert volume.steps == 4 and volume.dims == (24, 24, 24)
    seen = []
    frames = list(isotrace.render_sequence(scene_of(volume), progress=lambda done, total: seen.append((done, total)),
                                           **OPTIONS))
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert seen == [(0, 4), (1, 4), (2, 4), (3, 4), (4, 4)]
    for t, frame in enumerate(frames):
        single = isotrace.render(scene_of(isotrace.Volume(steps[t].copy())), **OPTIONS)
        assert np.array_equal(frame.rgb, single.rgb), "step %d" % t
    assert not np.array_equal(frames[0].rgb, frames[3].rgb)
    # A list of arrays is the same series; more frames than steps hold each step.
    held = list(isotrace.render_sequence(scene_of(isotrace.Volume(list(steps))), frames=8, progress=lambda d, t: None,
                                         **OPTIONS))
    for f, frame in enumerate(held):
        assert np.array_equal(frame.rgb, frames[f // 2].rgb), "frame %d" % f


def test_a_fortran_4d_array_is_used_in_place_and_a_tqdm_like_bar_advances():
    steps = np.asfortranarray(np.moveaxis(balls([5, 7]), 0, -1).transpose(2, 1, 0, 3))  # (nx, ny, nz, nt)
    volume = isotrace.Volume(steps, axes="xyz")
    assert volume.steps == 2
    assert [g.data for g in volume._grids] == [steps[..., t].ctypes.data for t in range(2)], "no copy"

    class Bar:
        n = 0

        def update(self, k):
            self.n += k

    bar = Bar()
    frames = list(isotrace.render_sequence(scene_of(volume), progress=bar, **OPTIONS))
    assert bar.n == 2 and len(frames) == 2


def test_sequences_are_the_command_lines_frames(tmp_path):
    """A file series with an orbit, from Python and from `isotrace render --frames`: the same bits."""
    steps = balls([5, 7, 9])
    for t in range(3):
        steps[t].tofile(tmp_path / ("b%d.raw" % t))
    doc = {"camera": CAMERA, "lights": LIGHTS, "film": {"width": 40, "height": 30},
           "integrator": {"type": "direct", "spp": 2},
           "volumes": [{"file": "b*.raw", "dims": [24, 24, 24], "type": "float32",
                        "isosurfaces": [{"value": 0, "color": [0.8, 0.4, 0.3]}]}]}
    (tmp_path / "s.json").write_text(json.dumps(doc))
    cli = subprocess.run([BINARY, "render", str(tmp_path / "s.json"), "-o", str(tmp_path / "f.exr"), "--orbit", "90",
                          "--quiet"], capture_output=True, text=True)
    assert cli.returncode == 0, cli.stderr
    frames = list(isotrace.render_sequence(tmp_path / "s.json", orbit=90, progress=lambda d, t: None))
    assert len(frames) == 3
    for t, frame in enumerate(frames):
        assert np.array_equal(frame.rgb, isotrace.read_image(tmp_path / ("f.%04d.exr" % t))[:, :, :3]), "frame %d" % t
    sweep = list(isotrace.render_sequence(scene_of(isotrace.Volume(steps[0].copy())), frames=2, iso_sweep=(0, 0, 2),
                                          progress=lambda d, t: None, **OPTIONS))
    assert len(sweep) == 2 and not np.array_equal(sweep[0].rgb, sweep[1].rgb)


@pytest.mark.parametrize("make, message", [
    (lambda: isotrace.Volume([]), "an empty list of time steps"),
    (lambda: isotrace.Volume([balls([3])[0], balls([3], n=20)[0]]), "time step 1 is 20x20x20 float32, step 0 24x24x24"),
    (lambda: isotrace.Volume([balls([3])[0], balls([3])[0].astype(np.uint16)]), "time step 1 is 24x24x24 uint16"),
    (lambda: isotrace.Volume([balls([3])[0], "x"]), "array[1]: expected a numpy array"),
    (lambda: isotrace.Volume(np.zeros((0, 4, 4, 4), np.float32)), "a 4D array with no time step"),
    (lambda: isotrace.Volume(np.full((2, 4, 4, 4), np.nan, np.float32)), "(time step 0)"),
    (lambda: list(isotrace.render_sequence(scene_of(isotrace.Volume(balls([3])[0])), frames=3)),
     "isotrace.render_sequence: frames: a sequence needs iso_sweep, orbit or a volume that changes over time"),
    (lambda: list(isotrace.render_sequence(scene_of(isotrace.Volume(balls([3])[0])), orbit=90)),
     "iso_sweep and orbit make a sequence: give frames=N"),
    (lambda: list(isotrace.render_sequence(scene_of(isotrace.Volume(balls([3])[0])), frames=2, iso_sweep=(4, 0, 1))),
     "iso_sweep: no iso-surface 4"),
    (lambda: list(isotrace.render_sequence(scene_of(isotrace.Volume(balls([3])[0])), frames=2, iso_sweep="0:1:2")),
     "iso_sweep: expected (surface, from, to)"),
    (lambda: list(isotrace.render_sequence(scene_of(isotrace.Volume(balls([3, 4]))), frames=0)),
     "frames: expected 1 to 100000 frames"),
])
def test_bad_series_and_sequences_are_input_errors(make, message):
    with pytest.raises(isotrace.InputError) as e:
        make()
    assert message in str(e.value)


def test_a_scene_in_use_by_another_thread_is_refused_and_copies_render_at_once():
    scene = scene_of(isotrace.Volume(balls([6])[0]))
    attempted = threading.Event()
    refused = []

    def other():
        try:
            isotrace.render(scene, **OPTIONS)
        except isotrace.InputError as e:
            refused.append(str(e))
        attempted.set()

    def first_progress(done, total):
        # Called while this render holds the scene: the other thread tries now, and this waits
        # for its attempt (an event, not a time).
        if not attempted.is_set() and not hasattr(first_progress, "started"):
            first_progress.started = True
            threading.Thread(target=other).start()
            attempted.wait(60)

    frame = isotrace.render(scene, progress=first_progress, **dict(OPTIONS, spp=8))
    assert attempted.is_set()
    assert refused and "isotrace.Scene: is being rendered by another thread" in refused[0], refused
    # Copies render on two threads at once, each the image of a render alone.
    alone = isotrace.render(scene, **OPTIONS).rgb
    results = [None, None]

    def run(k):
        results[k] = isotrace.render(scene.copy(), **OPTIONS).rgb

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(r is not None and np.array_equal(r, alone) for r in results)
    assert frame.rgb.max() > 0


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="Open MPI's mpirun is not installed")
def test_mpirun_renders_one_frame_over_the_ranks_bit_for_bit(tmp_path):
    script = tmp_path / "mpi.py"
    script.write_text(textwrap.dedent("""
        import sys, numpy as np, isotrace
        n = 24
        z, y, x = np.mgrid[0:n, 0:n, 0:n]
        d = np.sqrt((x - 11.5) ** 2 + (y - 11.5) ** 2 + (z - 11.5) ** 2)
        s = isotrace.Scene({"camera": {"position": [30, 25, 60], "look_at": [11.5, 11.5, 11.5]},
                            "lights": [{"type": "point", "position": [30, 40, 30], "intensity": 3000},
                                       {"type": "environment", "radiance": 0.3}]})
        s.add_volume(isotrace.Volume((7 - d).astype(np.float32)), isosurfaces=[{"value": 0, "color": [0.8, 0.4, 0.3]}])
        s.add_mesh(shape="quad", transform={"scale": 40, "translate": [11.5, -1, 11.5]})
        f = isotrace.render(s, spp=4, resolution=(48, 36), integrator="path", progress=lambda a, b: None)
        # (A file per rank: mpirun interleaves the ranks' stdout within lines.)
        with open(sys.argv[1] + ".rank%d" % isotrace.mpi_rank(), "w") as out:
            out.write("%d %d %d %d %s" % (isotrace.mpi_rank(), isotrace.mpi_size(), f.rank, f.ranks, f.rgb is None))
        f.save(sys.argv[1])
        # A sequence: each frame over the ranks too.
        for frame in isotrace.render_sequence(s, frames=2, orbit=30, spp=2, resolution=(32, 24), progress=lambda a, b: None):
            frame.save(sys.argv[1] + ".%d.exr" % frame.index)
    """))
    env = dict(os.environ, OMPI_MCA_btl_vader_single_copy_mechanism="none")
    one = subprocess.run([sys.executable, str(script), str(tmp_path / "one.exr")], capture_output=True, text=True, env=env)
    assert one.returncode == 0, one.stderr
    two = subprocess.run(["timeout", "--foreground", "-k", "10", "180", "mpirun", "--allow-run-as-root", "--oversubscribe",
                          "-np", "2", sys.executable, str(script), str(tmp_path / "two.exr")],
                         capture_output=True, text=True, env=env)
    assert two.returncode == 0, two.stderr
    assert [(tmp_path / ("two.exr.rank%d" % r)).read_text() for r in range(2)] == ["0 2 0 2 False", "1 2 1 2 True"]
    a, b = isotrace.read_image(tmp_path / "one.exr"), isotrace.read_image(tmp_path / "two.exr")
    assert a.max() > 0.05 and np.array_equal(a, b)
    for k in range(2):
        assert np.array_equal(isotrace.read_image(tmp_path / ("one.exr.%d.exr" % k)),
                              isotrace.read_image(tmp_path / ("two.exr.%d.exr" % k))), "sequence frame %d" % k


def test_mesh_is_clipped_capped_and_coloured():
    scene = isotrace.Scene({"lights": LIGHTS})
    scene.add_volume(isotrace.Volume(balls([8])[0]), isosurfaces=[
        {"value": 0, "color_by": {"field": "gradient_magnitude", "map": [[0, [0, 0, 1]], [9, [0, 0, 1]]]},
         "cap_color_by": {"field": "gradient_magnitude", "map": [[0, [1, 0, 0]], [9, [1, 0, 0]]]}}],
        clip=[{"plane": {"point": [11.5, 11.5, 11.5], "normal": [0, 0, 1]}}])
    vertices, triangles, normals, colors = isotrace.mesh(scene, colors=True)
    assert vertices[:, 2].max() <= 11.5 + 1e-3, "nothing beyond the clip plane"
    # (Away from the rim, where the cap's and the surface's normals blend within a cell.)
    on_cap = (np.abs(vertices[:, 2] - 11.5) < 1e-4) & (np.hypot(vertices[:, 0] - 11.5, vertices[:, 1] - 11.5) < 6)
    assert on_cap.sum() > 50 and np.all(colors[on_cap] == [1, 0, 0]) and np.all(normals[on_cap, 2] > 0.99)
    assert np.all(colors[vertices[:, 2] < 10] == [0, 0, 1])
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert np.all(uses == 2), "closed"
    assert len(isotrace.mesh(scene)) == 3


def test_mesh_of_a_time_step():
    scene = scene_of(isotrace.Volume(balls([4, 8])))
    small, large = (isotrace.mesh(scene, time=t)[0] for t in (0, 1))
    assert np.abs(small - 11.5).max() < 5 < np.abs(large - 11.5).max() < 9
    with pytest.raises(isotrace.InputError, match="isotrace.mesh: time: expected a time step from 0 to 1"):
        isotrace.mesh(scene, time=2)
