"""isotrace from Python: exact iso-surfaces of volume data, path traced.

The same renderer library as the ``isotrace`` command line (a pybind11 binding, not a wrapper of
the executable). Volumes come from numpy arrays, used in place; scenes are the scene file's JSON
(docs/scene-format.md) as a dict, or a file; renders come back as numpy images.

    import numpy, isotrace
    field = numpy.fromfile("ct_256x256x128_uint8.raw", numpy.uint8).reshape(128, 256, 256)
    scene = isotrace.Scene()
    scene.add_volume(isotrace.Volume(field, spacing=(0.7, 0.7, 1.25)),
                     isosurfaces=[{"value": 150, "color": [0.9, 0.85, 0.7]}])
    scene.lights.append({"type": "directional", "direction": [0, -1, -0.3], "irradiance": 3})
    frame = isotrace.render(scene, spp=16, integrator="path", resolution=(640, 480))
    frame.save("ct.png")           # frame.rgb: float32 H x W x 3, linear

Every problem with what is given (a bad array, scene key, option) raises isotrace.InputError
naming the place, as the command line reports it.
"""
import copy
import json
import os
import warnings

from . import _core

InputError = _core.InputError

__all__ = ["InputError", "Volume", "Scene", "Frame", "render", "render_sequence", "watertight", "bench", "mesh",
           "read_image", "mpi_rank", "mpi_size"]


class Volume:
    """A 3D numpy array as a volume, used in place (the volume keeps a reference to the array);
    or a volume that changes over time: a 4D array or a list of 3D arrays, one per time step.

    array: uint8, uint16, int16 or float32 (held as they are); float64 is held as float32 (a
        copy). Other dtypes are refused.
    axes: "zyx" (default) for a C-ordered array shaped (nz, ny, nx), as
        ``numpy.fromfile(...).reshape(nz, ny, nx)`` gives: ``array[k, j, i]`` is sample (i, j, k);
        "xyz" for a Fortran-ordered array shaped (nx, ny, nz), as nibabel's ``get_fdata()`` /
        ``dataobj`` and stacked pydicom slices give: ``array[i, j, k]`` is sample (i, j, k).
        Either way x varies fastest in memory, as in isotrace's grids, so nothing is copied. An
        array in the other memory order (or not contiguous) is copied once, with a warning.
    spacing, origin: sample (i, j, k) lies at origin + (i, j, k) * spacing, before `transform`.
    transform: an optional 4 x 4 matrix (row-major, nested lists or a numpy array) placing the
        grid in the world (e.g. a NIfTI affine's rotation), as the scene file's "transform".
    NaN or infinity anywhere is refused, naming the index (in the array's own axis order).
    Time steps: a 4D array holds them along its slowest axis, so that each step is used in place:
        (nt, nz, ny, nx) in C order with axes "zyx" (``array[t]`` is step t), (nx, ny, nz, nt) in
        Fortran order with axes "xyz" (``array[..., t]``: nibabel's 4D ``get_fdata()``). A list of
        3D arrays is a step each. Every step must have the same shape and dtype. A sequence
        (isotrace.render_sequence) steps through them; a single render shows step 0.
    """

    def __init__(self, array, spacing=(1, 1, 1), origin=(0, 0, 0), axes="zyx", transform=None):
        import numpy
        spacing = tuple(float(s) for s in spacing)
        origin = tuple(float(o) for o in origin)
        if isinstance(array, (list, tuple)):
            steps = list(array)
            if not steps:
                raise InputError("isotrace.Volume: array: an empty list of time steps")
        elif isinstance(array, numpy.ndarray) and array.ndim == 4:
            if axes not in ("zyx", "xyz"):
                raise InputError('isotrace.Volume: axes: expected "zyx" or "xyz", got "%s"' % axes)
            steps = [array[t] for t in range(array.shape[0])] if axes == "zyx" else \
                [array[..., t] for t in range(array.shape[3])]
            if not steps:
                raise InputError("isotrace.Volume: array: a 4D array with no time step")
        else:
            steps = [array]
        for k, a in enumerate(steps):
            if not isinstance(a, numpy.ndarray):
                raise InputError("isotrace.Volume: array%s: expected a numpy array, got %s"
                                 % ("" if len(steps) == 1 and a is array else "[%d]" % k, type(a).__name__))
        self._grids = []
        for k, a in enumerate(steps):
            try:
                grid = _core.grid_from_array(a, spacing, origin, axes)
            except InputError as e:
                if len(steps) == 1:
                    raise
                raise InputError("%s (time step %d)" % (e, k)) from None
            if self._grids and (grid.dims != self._grids[0].dims or grid.dtype != self._grids[0].dtype):
                raise InputError("isotrace.Volume: array: time step %d is %s %s, step 0 %s %s: the steps must agree"
                                 % (k, "x".join(map(str, grid.dims)), grid.dtype,
                                    "x".join(map(str, self._grids[0].dims)), self._grids[0].dtype))
            self._grids.append(grid)
        self._grid = self._grids[0]
        if any(g.copied for g in self._grids):
            warnings.warn("isotrace.Volume: the array was copied once (%s to x-fastest %s); pass %s to use it in place"
                          % (array.dtype, self._grid.dtype, "a C-ordered array shaped (nz, ny, nx)" if axes == "zyx"
                             else "a Fortran-ordered array shaped (nx, ny, nz)"), stacklevel=2)
        self.spacing = spacing
        self.origin = origin
        self.axes = axes
        self.transform = None
        if transform is not None:
            m = numpy.asarray(transform, dtype=float)
            if m.shape != (4, 4) or not numpy.all(numpy.isfinite(m)):
                raise InputError("isotrace.Volume: transform: expected a finite 4 x 4 matrix")
            self.transform = m.tolist()

    @property
    def dims(self):
        """Samples per axis, (nx, ny, nz)."""
        return self._grid.dims

    @property
    def steps(self):
        """Time steps (1: a volume that does not change)."""
        return len(self._grids)

    @property
    def dtype(self):
        """The sample type held: uint8, uint16, int16 or float32."""
        return self._grid.dtype

    @property
    def data_pointer(self):
        """The address of the samples the renderer reads: the array's own unless it was copied."""
        return self._grid.data

    @property
    def value_range(self):
        return self._grid.range

    def __repr__(self):
        steps = ", steps=%d" % self.steps if self.steps > 1 else ""
        return "isotrace.Volume(dims=%s, dtype=%s, spacing=%s, origin=%s%s)" % (self.dims, self.dtype, self.spacing,
                                                                                self.origin, steps)


class Scene:
    """A scene: the scene file's JSON as a dict (``scene.doc``), with the Volumes it uses.

    Scene(dict) parses as the command line does (isotrace.InputError names the JSON path);
    Scene.load(path) reads a scene file (its relative file names are relative to it). The
    builder: add_volume, add_mesh, ``scene.camera = {...}``, ``scene.lights.append({...})``,
    frame(). Renders of one Scene keep its volumes loaded: changing an iso value
    (``scene.doc["volumes"][0]["isosurfaces"][0]["value"] = 300``) and rendering again
    rebuilds only the surfaces.
    Threads: one render of a Scene at a time. A second thread rendering the same Scene meanwhile
    gets isotrace.InputError ("is being rendered by another thread"); give each thread its own
    (``scene.copy()``: the same doc and arrays, its own loaded state). Different Scenes render
    at once from several threads (Ctrl-C stops them all).
    """

    def __init__(self, doc=None, path=None):
        self.doc = copy.deepcopy(doc) if doc is not None else {}
        if not isinstance(self.doc, dict):
            raise InputError("isotrace.Scene: expected a dict (the scene file's JSON)")
        # Relative file names in the scene resolve against this file's folder.
        self.path = os.path.abspath(path) if path else os.path.join(os.getcwd(), "<scene>")
        self.volumes = []  # the Volumes that "array": K entries name
        self._renderer = _core.Renderer()
        if doc is not None:
            self.check()

    @classmethod
    def load(cls, path):
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except OSError as e:
            raise InputError("%s: cannot read the scene file (%s)" % (path, e.strerror)) from None
        try:
            doc = json.loads(text)
        except ValueError as e:
            raise InputError("%s: JSON: %s" % (path, e)) from None
        scene = cls.__new__(cls)
        scene.doc = doc if isinstance(doc, dict) else {}
        scene.path = os.path.abspath(path)
        scene.volumes = []
        scene._renderer = _core.Renderer()
        if not isinstance(doc, dict):
            raise InputError("%s: expected a JSON object" % path)
        scene.check()
        return scene

    def _text(self):
        try:
            return json.dumps(self.doc, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise InputError("%s: the scene is not JSON: %s" % (self.path, e)) from None

    def _grids(self):
        return [g for v in self.volumes for g in v._grids]

    def copy(self):
        """A Scene with a copy of this one's doc and the same Volumes (arrays shared, not copied),
        and its own loaded state: for another thread to render."""
        other = Scene.__new__(Scene)
        other.doc = copy.deepcopy(self.doc)
        other.path = self.path
        other.volumes = list(self.volumes)
        other._renderer = _core.Renderer()
        return other

    def check(self):
        """Parses the scene as the renderer will (isotrace.InputError if anything is wrong)."""
        _core.check_scene(self._text(), self.path, self._grids())
        return self

    def add_volume(self, volume, isosurfaces=(), **keys):
        """Adds a Volume with its iso-surfaces (the scene file's "isosurfaces" entries, e.g.
        ``[{"value": 150, "color": [0.9, 0.8, 0.7]}]``) and any other volume keys ("name",
        "slices", "clip", ...); returns the volume's index in the scene."""
        if not isinstance(volume, Volume):
            raise InputError("isotrace.Scene.add_volume: expected an isotrace.Volume, got %s" % type(volume).__name__)
        first = sum(v.steps for v in self.volumes)  # (the arrays' index: every step of every Volume)
        entry = {"array": first if volume.steps == 1 else list(range(first, first + volume.steps)),
                 "isosurfaces": list(isosurfaces)}
        entry.update(keys)
        if volume.transform is not None and "transform" not in keys:
            entry["transform"] = {"matrix": [x for row in volume.transform for x in row]}
        self.volumes.append(volume)
        self.doc.setdefault("volumes", []).append(entry)
        try:
            self.check()
        except InputError:
            self.doc["volumes"].pop()
            self.volumes.pop()
            raise
        return len(self.doc["volumes"]) - 1

    def add_mesh(self, file=None, shape=None, **keys):
        """Adds a glTF/OBJ file (or a built-in shape: "sphere", "quad") with any mesh keys
        ("transform", "material"); returns its index."""
        entry = {}
        if file is not None:
            entry["file"] = os.path.abspath(file)
        if shape is not None:
            entry["shape"] = shape
        entry.update(keys)
        self.doc.setdefault("meshes", []).append(entry)
        try:
            self.check()
        except InputError:
            self.doc["meshes"].pop()
            raise
        return len(self.doc["meshes"]) - 1

    @property
    def camera(self):
        return self.doc.get("camera")

    @camera.setter
    def camera(self, value):
        self.doc["camera"] = dict(value)

    @property
    def lights(self):
        """The scene's light list (append to it)."""
        return self.doc.setdefault("lights", [])

    @property
    def materials(self):
        """The scene's named materials (a dict)."""
        return self.doc.setdefault("materials", {})

    def frame(self):
        """Sets the camera that frames everything the scene holds (the one the scene gets
        without a camera) and returns it."""
        self.doc.pop("camera", None)
        camera = self._renderer.auto_camera(self._text(), self.path, self._grids())
        self.doc["camera"] = camera
        return camera

    def to_json(self, path=None):
        """The scene as JSON text (written to `path` if given). Volumes from arrays appear as
        {"array": K}: such a file renders only from Python, with the same Volumes."""
        text = json.dumps(self.doc, indent=2)
        if path:
            with open(path, "w", encoding="utf-8") as f:
                f.write(text + "\n")
        return text


class Frame:
    """A rendered image. rgb: float32 H x W x 3, linear radiance, row 0 at the top (as in the
    image files). aov(name): an extra layer asked for in render(aovs=[...]) (albedo, normal,
    depth, variance, samples). stats: what ``isotrace render --stats`` writes. For the
    `compare` integrator, direct and indirect (rgb is the global image); else None.
    raw: the image as rendered when rgb is denoised (render(denoise=...), denoised()), else None.
    denoised(mode): the frame denoised from the feature buffers it keeps.
    index: the frame's place in a sequence (render_sequence), else 0.
    Under mpirun (more than one rank) rank 0's frame holds the image; on the other ranks rgb is
    None and save() writes nothing (rank and ranks say which is which)."""

    def __init__(self, result):
        self.index = int(result.get("frame", 0))
        self.rank = int(result.get("rank", 0))
        self.ranks = int(result.get("ranks", 1))
        self.rgb = result["rgb"]
        self.direct = result.get("direct")
        self.indirect = result.get("indirect")
        self.raw = result.get("raw")
        self._raw_parts = (result.get("raw_direct"), result.get("raw_indirect"))
        self._layers = dict(result["layers"])
        self._signed = bool(result["signed"])
        self._buffers = result.get("denoise_input")
        self.stats = json.loads(result["stats"])
        self.interrupted = bool(self.stats.get("interrupted"))

    def denoised(self, mode="quality", threads=0):
        """A copy of this frame denoised in `mode` ("quality": feature regression, the best image;
        "fast": a-trous, for previews), from the albedo, normal, depth, variance and half images
        the render kept (so the same as render(..., denoise=mode), bit for bit). Its `raw` is this
        frame's image; stats["seconds"]["denoise"] its time. `normals` and `eyelight` frames
        have nothing to denoise (InputError)."""
        if self._buffers is None:
            raise InputError("isotrace.Frame.denoised: a %s frame has no noise to remove"
                             % self.stats.get("integrator"))
        d = _core.denoise(self._buffers, str(mode), int(threads))
        frame = copy.copy(self)
        frame.stats = copy.deepcopy(self.stats)
        frame.raw = self.raw if self.raw is not None else self.rgb
        if self.direct is not None and self._raw_parts[0] is None:
            frame._raw_parts = (self.direct, self.indirect)
        frame.rgb = d["rgb"]
        frame.direct = d.get("direct")
        frame.indirect = d.get("indirect")
        frame.stats["denoise"] = str(mode)
        frame.stats.setdefault("seconds", {})["denoise"] = d["seconds"]
        return frame

    @property
    def images(self):
        """The `compare` integrator's three images: {"direct", "global", "indirect"}; else {"rgb"}."""
        if self.direct is None:
            return {"rgb": self.rgb}
        return {"direct": self.direct, "global": self.rgb, "indirect": self.indirect}

    @property
    def aovs(self):
        return sorted(self._layers)

    def aov(self, name):
        if name not in self._layers:
            raise InputError("isotrace.Frame.aov: no layer '%s' (this frame has: %s; ask render(aovs=[...]))"
                             % (name, ", ".join(sorted(self._layers)) or "none"))
        return self._layers[name]

    def save(self, path, exposure=0.0, tonemap="clamp"):
        """Writes the image: EXR (linear, with the extra layers), PNG or JPEG (8-bit sRGB after
        `exposure` EV and `tonemap`: clamp, aces, filmic). `compare` frames write the global
        image here; save direct/indirect with isotrace.Frame(...) of your own or numpy. On an MPI
        rank other than 0 (no image) nothing is written and None returned."""
        if self.rgb is None:
            return None
        _core.save_image(self.rgb, self._layers, os.fspath(path), float(exposure), str(tonemap), self._signed)
        return path

    def png(self, exposure=0.0, tonemap="clamp"):
        """The image as PNG bytes (None on an MPI rank other than 0)."""
        if self.rgb is None:
            return None
        return _core.png_bytes(self.rgb, float(exposure), str(tonemap), self._signed)

    def _repr_png_(self):
        return self.png()

    def __repr__(self):
        if self.rgb is None:
            return "isotrace.Frame(rank %d of %d: the image is rank 0's)" % (self.rank, self.ranks)
        h, w = self.rgb.shape[:2]
        return "isotrace.Frame(%dx%d, %s spp, %s)" % (w, h, self.stats.get("spp"), self.stats.get("integrator"))


def _progress_callback(progress):
    if progress is not None:
        return progress
    try:
        import tqdm  # optional: a bar when tqdm is installed and no callback is given
    except ImportError:
        return None
    bar = {}

    def update(done, total):
        if "bar" not in bar:
            bar["bar"] = tqdm.tqdm(total=total, unit="samples", unit_scale=True, leave=False)
        b = bar["bar"]
        b.update(done - b.n)
        if done >= total:
            b.close()

    return update


def render(scene, spp=None, integrator=None, resolution=None, threads=None, seed=None, adaptive=None, aovs=None,
           max_depth=None, intersector=None, ray_flow=None, clamp=None, alpha=None, denoise=None, progress=None,
           sequence=None, frame=None):
    """Renders `scene` (a Scene, a dict, or a scene file's path) and returns a Frame.

    Options left None keep the scene's own (its "film", "integrator", "intersector"): spp,
    integrator (normals, eyelight, ao, direct, path, compare), resolution=(width, height),
    threads (0: all cores), seed, adaptive (noise threshold), aovs (["albedo", "normal",
    "depth", "variance", "samples"]), max_depth, intersector, ray_flow, clamp, alpha,
    denoise ("quality", "fast", "off" or True; the scene's "film": {"denoise"} otherwise): rgb
    is then the denoised image and frame.raw the rendered one (frame.denoised(mode) denoises any
    frame afterwards).
    progress: fn(done, total) called about every 50 ms with the pixel samples done (a tqdm bar
    if tqdm is installed and no callback is given). The GIL is released while rendering.
    Ctrl-C (KeyboardInterrupt) stops the render at the next tile and raises with the partial
    frame as the exception's ``frame`` attribute. The image is the same, bit for bit, as
    ``isotrace render`` of the same scene with the same options. One render of a Scene at a time
    (another thread's meanwhile is refused: scene.copy() for each thread); Ctrl-C stops every
    render of the process. Under mpirun (mpi_size() > 1) the frame is rendered over all ranks
    (no progress reports; call it from the thread that first did, MPI's): rank 0's frame holds
    the image, bit for bit one process's.
    """
    if not isinstance(scene, Scene):
        scene = Scene.load(scene) if isinstance(scene, (str, os.PathLike)) else Scene(scene)
    options = {k: v for k, v in dict(spp=spp, integrator=integrator, resolution=resolution, threads=threads, seed=seed,
                                      adaptive=adaptive, aovs=aovs, max_depth=max_depth, intersector=intersector,
                                      ray_flow=ray_flow, clamp=clamp, alpha=alpha, denoise=denoise,
                                      sequence=sequence, frame=frame).items()
               if v is not None}
    result = scene._renderer.render(scene._text(), scene.path, scene._grids(), options, _progress_callback(progress))
    frame = Frame(result)
    if result["keyboard_interrupt"]:
        error = KeyboardInterrupt("isotrace.render: interrupted; the partial frame (%s of %s samples per pixel) is "
                                  "the exception's .frame" % (frame.stats.get("spp"), frame.stats.get("spp_requested")))
        error.frame = frame
        raise error
    return frame


def render_sequence(scene, frames=None, orbit=None, iso_sweep=None, progress=None, **options):
    """Renders a sequence of frames of `scene` (as ``isotrace render --frames``), yielding a Frame
    each as it is done (a generator: ``for frame in isotrace.render_sequence(...)``).

    frames: how many (default: one per time step of the scene's volumes that change over time, a
        4D or list Volume, or a "file" list or pattern); orbit: degrees the camera turns about its
        look-at point over the frames (360: a turntable); iso_sweep: (surface, from, to) sweeps
        iso-surface `surface` (counted over all volumes) from `from` to `to`. Frame f shows each
        time series at step f * steps // frames; frame.index is f. The frames are the command
        line's, bit for bit. A time series' next step is read on a second thread while a frame
        renders.
    progress: called with (frames done, frames) after each frame, and before the first; or a
        tqdm-like bar (an object with update(n)) advanced by one per frame. None: a tqdm bar when
        tqdm is installed.
    options: as render()'s (spp, resolution, integrator, denoise, ...).
    """
    s = _as_scene(scene)
    request = {"frames": frames, "orbit": orbit, "iso_sweep": iso_sweep}
    count = s._renderer.sequence_length(s._text(), s.path, s._grids(), request)
    bar = None
    if progress is None:
        try:
            import tqdm
            bar = tqdm.tqdm(total=count, unit="frame", leave=False)
        except ImportError:
            pass
    elif hasattr(progress, "update") and not callable(progress):
        bar = progress
    report = progress if callable(progress) and bar is None else None
    if report:
        report(0, count)
    try:
        for f in range(count):
            opts = dict(options)
            opts["sequence"] = request
            opts["frame"] = f
            yield render(s, **opts)
            if bar is not None:
                bar.update(1)
            if report:
                report(f + 1, count)
    finally:
        if bar is not None and progress is None:
            bar.close()


def mpi_rank():
    """This process's rank when mpirun started it (else 0), read from the launcher's environment."""
    return _core.mpi_rank()


def mpi_size():
    """The ranks mpirun started (else 1). With more than one, render() spreads each frame over all
    ranks by tiles (every rank must render the same scenes in the same order); rank 0's frame holds
    the image, the same bits as one process's."""
    return _core.mpi_size()


def _as_scene(scene):
    if isinstance(scene, Scene):
        return scene
    return Scene.load(scene) if isinstance(scene, (str, os.PathLike)) else Scene(scene)


def watertight(scene, rays=100000, offset=(0, 0, 0), seed=1, threads=0, ray_flow="wavefront", intersector=None):
    """``isotrace watertight``: every iso-surface alone under secondary rays; its JSON report as
    a dict: {"total": counts, "surfaces": [counts + volume, iso, intersector]}, counts being
    rays, crossings, reference_crossings, lost_crossings, extra_crossings (per parity ray, the
    reference's crossings the walk did not find, and the walk's the reference did not),
    parity_errors, self_hits, inside_escapes, shadow_mismatches."""
    s = _as_scene(scene)
    return _core.watertight(s._text(), s.path, s._grids(), int(rays), tuple(float(o) for o in offset), int(seed), int(threads),
                            str(ray_flow), intersector or "")


def bench(scene, rays=10000, intersectors=None, seed=1, ray_flow=None):
    """``isotrace bench``: run time against error of intersectors (default: the scene's) on each
    iso-surface, camera and secondary rays; {"ray_flow", "results": [...]} as the JSON report."""
    s = _as_scene(scene)
    return _core.bench(s._text(), s.path, s._grids(), int(rays), list(intersectors or []), int(seed), ray_flow or "")


def mesh(scene, volume=0, surface=0, path=None, colors=False, time=0):
    """Iso-surface `surface` of volume `volume` as triangles in world space (``isotrace mesh``):
    (vertices float32 N x 3, triangles uint32 M x 3, normals float32 N x 3, out of the solid);
    also written as glTF (.glb / .gltf) if `path` is given. The scene's and the volume's "clip"
    cut it as the render does, capped (a closed surface stays closed). colors=True adds a fourth
    item: the vertices' linear RGB (N x 3) from "color_by" ("cap_color_by" on the caps), or None
    when the surface is not coloured by data. time: the time step of volumes that change over time."""
    s = _as_scene(scene)
    v, t, n, c = _core.mesh(s._text(), s.path, s._grids(), int(volume), int(surface), os.fspath(path) if path else "",
                            int(time))
    return (v, t, n, c) if colors else (v, t, n)


def read_image(path):
    """An image file (EXR, PNG, JPEG, ...) as float32 H x W x C, row 0 at the top (8-bit files
    scaled to [0, 1])."""
    return _core.read_image(os.fspath(path))
