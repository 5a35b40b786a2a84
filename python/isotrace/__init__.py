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

__all__ = ["InputError", "Volume", "Scene", "Frame", "render", "watertight", "bench", "mesh", "read_image"]


class Volume:
    """A 3D numpy array as a volume, used in place (the volume keeps a reference to the array).

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
    """

    def __init__(self, array, spacing=(1, 1, 1), origin=(0, 0, 0), axes="zyx", transform=None):
        import numpy
        if not isinstance(array, numpy.ndarray):
            raise InputError("isotrace.Volume: array: expected a numpy array, got %s" % type(array).__name__)
        self._grid = _core.grid_from_array(array, tuple(float(s) for s in spacing), tuple(float(o) for o in origin), axes)
        if self._grid.copied:
            warnings.warn("isotrace.Volume: the array was copied once (%s to x-fastest %s); pass %s to use it in place"
                          % (array.dtype, self._grid.dtype, "a C-ordered array shaped (nz, ny, nx)" if axes == "zyx"
                             else "a Fortran-ordered array shaped (nx, ny, nz)"), stacklevel=2)
        self.spacing = tuple(float(s) for s in spacing)
        self.origin = tuple(float(o) for o in origin)
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
        return "isotrace.Volume(dims=%s, dtype=%s, spacing=%s, origin=%s)" % (self.dims, self.dtype, self.spacing, self.origin)


class Scene:
    """A scene: the scene file's JSON as a dict (``scene.doc``), with the Volumes it uses.

    Scene(dict) parses as the command line does (isotrace.InputError names the JSON path);
    Scene.load(path) reads a scene file (its relative file names are relative to it). The
    builder: add_volume, add_mesh, ``scene.camera = {...}``, ``scene.lights.append({...})``,
    frame(). Renders of one Scene keep its volumes loaded: changing an iso value
    (``scene.doc["volumes"][0]["isosurfaces"][0]["value"] = 300``) and rendering again
    rebuilds only the surfaces.
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
        return [v._grid for v in self.volumes]

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
        entry = {"array": len(self.volumes), "isosurfaces": list(isosurfaces)}
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
    denoised(mode): the frame denoised from the feature buffers it keeps."""

    def __init__(self, result):
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
        image here; save direct/indirect with isotrace.Frame(...) of your own or numpy."""
        _core.save_image(self.rgb, self._layers, os.fspath(path), float(exposure), str(tonemap), self._signed)
        return path

    def png(self, exposure=0.0, tonemap="clamp"):
        """The image as PNG bytes."""
        return _core.png_bytes(self.rgb, float(exposure), str(tonemap), self._signed)

    def _repr_png_(self):
        return self.png()

    def __repr__(self):
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
           max_depth=None, intersector=None, ray_flow=None, clamp=None, alpha=None, denoise=None, progress=None):
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
    ``isotrace render`` of the same scene with the same options. One render at a time per
    process (the stop request it listens to is the process's).
    """
    if not isinstance(scene, Scene):
        scene = Scene.load(scene) if isinstance(scene, (str, os.PathLike)) else Scene(scene)
    options = {k: v for k, v in dict(spp=spp, integrator=integrator, resolution=resolution, threads=threads, seed=seed,
                                      adaptive=adaptive, aovs=aovs, max_depth=max_depth, intersector=intersector,
                                      ray_flow=ray_flow, clamp=clamp, alpha=alpha, denoise=denoise).items()
               if v is not None}
    result = scene._renderer.render(scene._text(), scene.path, scene._grids(), options, _progress_callback(progress))
    frame = Frame(result)
    if result["keyboard_interrupt"]:
        error = KeyboardInterrupt("isotrace.render: interrupted; the partial frame (%s of %s samples per pixel) is "
                                  "the exception's .frame" % (frame.stats.get("spp"), frame.stats.get("spp_requested")))
        error.frame = frame
        raise error
    return frame


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


def mesh(scene, volume=0, surface=0, path=None):
    """Iso-surface `surface` of volume `volume` as triangles in world space (``isotrace mesh``):
    (vertices float32 N x 3, triangles uint32 M x 3, normals float32 N x 3, out of the solid);
    also written as glTF (.glb / .gltf) if `path` is given."""
    s = _as_scene(scene)
    return _core.mesh(s._text(), s.path, s._grids(), int(volume), int(surface), os.fspath(path) if path else "")


def read_image(path):
    """An image file (EXR, PNG, JPEG, ...) as float32 H x W x C, row 0 at the top (8-bit files
    scaled to [0, 1])."""
    return _core.read_image(os.fspath(path))
