// isotrace._core: the renderer library for Python (pybind11). The package (isotrace/__init__.py)
// builds the user's API on these: numpy arrays become grids used in place, a scene is its JSON
// text with the arrays it names ({"array": K}), and render / watertight / bench / mesh run the
// same code as the command line. Every problem with what the caller gave is an InputError (the
// package's isotrace.InputError) naming the place, as the command line reports it.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <tbb/task_arena.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <sstream>
#include <thread>

#include "accuracy/accuracy.h"
#include "accuracy/watertight.h"
#include "renderer/commands.h"
#include "renderer/distributed.h"
#include "renderer/film.h"
#include "renderer/render.h"
#include "renderer/sequence.h"
#include "scene/gltf.h"
#include "scene/image_plugin.h"
#include "scene/world.h"
#include "volume/input_error.h"

namespace py = pybind11;

namespace iso {
namespace {

// ---- Volumes from numpy arrays -------------------------------------------------------------

// A grid over a numpy array's buffer: the grid's shared samples hold a reference to the array
// (released under the GIL), so the buffer lives as long as any grid, World or scene using it.
struct ArrayGrid {
  std::shared_ptr<const Grid> grid;
  bool copied = false;   // the array was not in x-fastest order or not one of the held types
  std::string dtype;     // as held
  uintptr_t data = 0;    // the samples' address (the array's own, unless copied)
};

template <typename T>
std::optional<size_t> firstNonFinite(const T* v, size_t n) {
  if constexpr (std::is_floating_point_v<T>)
    for (size_t i = 0; i < n; ++i)
      if (!std::isfinite(v[i])) return i;
  return std::nullopt;
}

ArrayGrid gridFromArray(py::array array, std::array<double, 3> spacing, std::array<double, 3> origin,
                        const std::string& axes) {
  const std::string where = "isotrace.Volume";
  if (axes != "zyx" && axes != "xyz") throw InputError(where, "axes", "expected \"zyx\" or \"xyz\", got \"" + axes + "\"");
  if (array.ndim() != 3)
    throw InputError(where, "array", "expected a 3D array, got " + std::to_string(array.ndim()) + " dimensions");
  for (int a = 0; a < 3; ++a) {
    if (!(spacing[size_t(a)] > 0 && std::isfinite(spacing[size_t(a)])))
      throw InputError(where, "spacing", "spacing must be positive and finite");
    if (!std::isfinite(origin[size_t(a)])) throw InputError(where, "origin", "the origin is not finite");
  }
  const py::dtype dt = array.dtype();
  ArrayGrid out;
  ScalarType type;
  const char kind = dt.kind();
  const py::ssize_t size = dt.itemsize();
  const bool nativeOrder = dt.byteorder() != '>';  // '=' native, '<' little (this machine), '|' bytes
  if (kind == 'u' && size == 1) type = ScalarType::UInt8, out.dtype = "uint8";
  else if (kind == 'u' && size == 2) type = ScalarType::UInt16, out.dtype = "uint16";
  else if (kind == 'i' && size == 2) type = ScalarType::Int16, out.dtype = "int16";
  else if (kind == 'f' && size == 4) type = ScalarType::Float32, out.dtype = "float32";
  else if (kind == 'f' && size == 8) type = ScalarType::Float32, out.dtype = "float32", out.copied = true;
  else
    throw InputError(where, "array", "unsupported dtype " + dt.attr("name").cast<std::string>() +
                                         " (uint8, uint16, int16, float32; float64 is held as float32)");
  if (!nativeOrder) out.copied = true;  // big-endian samples: converted to this machine's order
  // x fastest in memory: C order for (nz, ny, nx), Fortran order for (nx, ny, nz).
  const bool zyx = axes == "zyx";
  const int flag = zyx ? py::array::c_style : py::array::f_style;
  const bool inPlace = !out.copied && (array.flags() & flag) != 0;
  py::array held = array;
  if (!inPlace) {
    out.copied = true;
    const py::module_ np = py::module_::import("numpy");
    static const char* names[] = {"uint8", "uint16", "int16", "float32"};
    held = np.attr(zyx ? "ascontiguousarray" : "asfortranarray")(array, py::arg("dtype") = names[int(type)]);
  }
  Vec3i dims;
  for (int a = 0; a < 3; ++a) {
    const py::ssize_t n = held.shape(zyx ? 2 - a : a);
    if (n < 2 || n > (1 << 20)) throw InputError(where, "array", "each side must hold 2 to 2^20 samples");
    dims[a] = int(n);
  }
  if (double(dims.x) * dims.y * dims.z > double(1ull << 34)) throw InputError(where, "array", "more than 2^34 samples");
  const void* data = held.data();
  const size_t count = size_t(dims.x) * dims.y * dims.z;
  std::optional<size_t> bad;
  if (type == ScalarType::Float32) bad = firstNonFinite(static_cast<const float*>(data), count);
  if (bad) {
    const size_t i = *bad, x = i % size_t(dims.x), y = (i / size_t(dims.x)) % size_t(dims.y), z = i / (size_t(dims.x) * dims.y);
    const std::string index = zyx ? "[" + std::to_string(z) + ", " + std::to_string(y) + ", " + std::to_string(x) + "]"
                                  : "[" + std::to_string(x) + ", " + std::to_string(y) + ", " + std::to_string(z) + "]";
    throw InputError(where, "array", "value at index " + index + " is not finite (NaN or infinity)");
  }
  // The samples keep the array alive; the last owner (a grid, possibly freed on a render thread
  // or at exit) lets it go under the GIL.
  auto* keep = new py::object(held);
  std::shared_ptr<const void> samples(data, [keep](const void*) {
    if (!Py_IsInitialized()) return;  // the interpreter is gone: nothing to release into
    py::gil_scoped_acquire gil;
    delete keep;
  });
  out.grid = std::make_shared<const Grid>(dims, type, std::move(samples), Vec3d{origin[0], origin[1], origin[2]},
                                          Vec3d{spacing[0], spacing[1], spacing[2]});
  out.data = reinterpret_cast<uintptr_t>(data);
  return out;
}

// ---- Scenes --------------------------------------------------------------------------------

SceneDesc parseScene(const std::string& text, const std::string& path, const std::vector<std::shared_ptr<const Grid>>& grids) {
  return parseSceneText(text, path, {}, &grids);
}

py::array_t<float> imageOf(const Film& film) {
  py::array_t<float> out({py::ssize_t(film.height()), py::ssize_t(film.width()), py::ssize_t(3)});
  auto v = out.mutable_unchecked<3>();
  for (int y = 0; y < film.height(); ++y)
    for (int x = 0; x < film.width(); ++x)
      for (int c = 0; c < 3; ++c) v(y, x, c) = film.at(x, y)[c];
  return out;
}

py::dict layersOf(const Film& film) {
  py::dict layers;
  for (const Film::Layer& layer : film.layers()) {
    const py::ssize_t channels = py::ssize_t(layer.channels.size());
    py::array_t<float> a = channels == 1
                               ? py::array_t<float>({py::ssize_t(film.height()), py::ssize_t(film.width())})
                               : py::array_t<float>({py::ssize_t(film.height()), py::ssize_t(film.width()), channels});
    std::copy(layer.data.begin(), layer.data.end(), a.mutable_data());
    layers[py::str(layer.name)] = a;
  }
  if (!film.alpha().empty()) {
    py::array_t<float> a({py::ssize_t(film.height()), py::ssize_t(film.width())});
    std::copy(film.alpha().begin(), film.alpha().end(), a.mutable_data());
    layers["alpha"] = a;
  }
  return layers;
}

// A float32 H x W x 3 array (and optional layers) as a Film, for writing.
Film filmOf(py::array_t<float, py::array::c_style | py::array::forcecast> rgb, const py::dict& layers) {
  if (rgb.ndim() != 3 || rgb.shape(2) != 3) throw InputError("Frame.save", "rgb", "expected an H x W x 3 image");
  const int h = int(rgb.shape(0)), w = int(rgb.shape(1));
  Film film(w, h);
  auto v = rgb.unchecked<3>();
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) film.at(x, y) = {v(y, x, 0), v(y, x, 1), v(y, x, 2)};
  for (const auto& [key, value] : layers) {
    const std::string name = py::str(key);
    auto a = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(value);
    if (!a || a.shape(0) != h || a.shape(1) != w) continue;
    if (name == "alpha") {
      film.alpha().assign(a.data(), a.data() + a.size());
      continue;
    }
    const bool three = a.ndim() == 3 && a.shape(2) == 3;
    Film::Layer& layer = film.addLayer(name, three ? std::vector<std::string>{"R", "G", "B"} : std::vector<std::string>{"Z"});
    if (size_t(a.size()) == layer.data.size()) std::copy(a.data(), a.data() + a.size(), layer.data.begin());
  }
  return film;
}

DisplaySettings displayOf(double exposure, const std::string& tonemap) {
  DisplaySettings d;
  if (!std::isfinite(exposure) || std::fabs(exposure) > 64) throw InputError("Frame.save", "exposure", "expected a finite EV within +-64");
  d.exposure = exposure;
  if (!parseTonemap(tonemap, d.tonemap)) throw InputError("Frame.save", "tonemap", "unknown tonemap '" + tonemap + "' (clamp, aces, filmic)");
  return d;
}

void saveImage(py::array_t<float, py::array::c_style | py::array::forcecast> rgb, const py::dict& layers,
               const std::string& path, double exposure, const std::string& tonemap, bool signedData) {
  const DisplaySettings display = displayOf(exposure, tonemap);
  imageFormatFor(path);  // an unknown extension is an InputError before any work
  checkWritable(path);
  const Film film = filmOf(rgb, layers);
  writeImage(path, film, signedData, {{"Software", "isotrace (Python)"}}, display);
}

py::bytes pngBytes(py::array_t<float, py::array::c_style | py::array::forcecast> rgb, double exposure,
                   const std::string& tonemap, bool signedData) {
  const DisplaySettings display = displayOf(exposure, tonemap);
  const Film film = filmOf(rgb, py::dict());
  const std::filesystem::path dir = std::filesystem::temp_directory_path();
  const std::string path = (dir / ("isotrace-" + std::to_string(::getpid()) + "-" +
                                   std::to_string(reinterpret_cast<uintptr_t>(&film)) + ".png")).string();
  writeImage(path, film, signedData, {}, display);
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::filesystem::remove(path);
  return py::bytes(bytes);
}

// An image file's pixels as float32 H x W x C (row 0 at the top): to compare with what the
// command line wrote, and to read back what a frame saved.
py::array_t<float> readImage(const std::string& path) {
  std::string error;
  std::unique_ptr<ImageReader> in = imagePlugin().open(path, nullptr, 0, error);
  if (!in) throw InputError(path, "", "cannot read the image (" + error + ")");
  if (in->width < 1 || in->height < 1 || in->channels < 1 || double(in->width) * in->height * in->channels > double(1ull << 32))
    throw InputError(path, "", "unsupported image size");
  py::array_t<float> out({py::ssize_t(in->height), py::ssize_t(in->width), py::ssize_t(in->channels)});
  error = in->readFloats(out.mutable_data());
  if (!error.empty()) throw InputError(path, "", "cannot read the image (" + error + ")");
  return out;
}

// ---- Rendering -------------------------------------------------------------------------------

// A scene's render state kept between calls (isotrace.Scene holds one): the last World, whose
// grids and bricks the next render reuses when its volumes load alike.
// What a frame keeps for Frame.denoised(): the denoiser's input (renderer/denoise.h), gathered
// with the render (about 80 bytes per pixel; 200 for `compare`).
struct DenoiseBuffers {
  DenoiseInput input;
  int threads = 0;
};

// The denoised images of a frame: {"rgb", and for compare "direct", "indirect"; "seconds",
// "non_finite_pixels"}.
py::dict denoiseBuffers(const DenoiseBuffers& b, const std::string& modeName, int threads) {
  DenoiseMode mode;
  if (!parseDenoiseMode(modeName, mode) || mode == DenoiseMode::Off)
    throw InputError("isotrace.Frame.denoised", "mode", "unknown mode '" + modeName + "' (known: quality, fast)");
  if (threads < 0 || threads > 4096) throw InputError("isotrace.Frame.denoised", "threads", "expected 0 to 4096");
  const DenoiseInput& in = b.input;
  Film film(in.width, in.height), direct(in.width, in.height), indirect(0, 0);
  RenderResult result;
  DenoiseReport report;
  {
    py::gil_scoped_release release;
    film.pixels() = in.color.mean;
    if (!in.direct.empty()) direct.pixels() = in.direct.mean;
    report = denoiseFrame(in, mode, threads, false, film, in.direct.empty() ? nullptr : &direct,
                          in.direct.empty() ? nullptr : &indirect, result);
  }
  py::dict out;
  out["rgb"] = imageOf(film);
  if (!in.direct.empty()) {
    out["direct"] = imageOf(direct);
    out["indirect"] = imageOf(indirect);
  }
  out["seconds"] = report.seconds;
  out["non_finite_pixels"] = report.nonFinitePixels;
  return out;
}

// Under mpirun (more than one rank) the process's place in the MPI job: created by the first
// render (MPI_Init, on the thread that renders: MPI is used from that thread only), finalised at
// interpreter exit. Null otherwise: MPI is never touched.
std::unique_ptr<MpiJob> g_mpiJob;
std::unique_ptr<MpiJob>& pythonMpiJob() {
  if (!g_mpiJob && launchedRanks().size > 1) g_mpiJob = std::make_unique<MpiJob>();
  return g_mpiJob;
}

// Renders that run at once in this process (several Scenes on several threads): the stop request
// that Ctrl-C makes is the process's, cleared when the first begins and the last ends.
std::mutex g_rendersMutex;
int g_renders = 0;
struct RenderRunning {
  RenderRunning() {
    std::lock_guard<std::mutex> lock(g_rendersMutex);
    if (g_renders++ == 0) clearStopRequest();
  }
  ~RenderRunning() {
    std::lock_guard<std::mutex> lock(g_rendersMutex);
    if (--g_renders == 0) clearStopRequest();
  }
};

// A sequence's request from Python: {"frames": N or None, "iso_sweep": (surface, from, to) or
// None, "orbit": degrees or None}.
SequenceRequest sequenceRequest(const py::dict& d) {
  SequenceRequest r;
  r.where = "isotrace.render_sequence";
  if (d.contains("frames") && !d["frames"].is_none()) {
    if (!py::isinstance<py::int_>(d["frames"]) || py::isinstance<py::bool_>(d["frames"]))
      throw InputError(r.where, "frames", "expected a whole number of frames");
    r.frames = int(std::clamp<long long>(d["frames"].cast<long long>(), -1, 1 << 30));
  }
  if (d.contains("orbit") && !d["orbit"].is_none()) r.orbit = d["orbit"].cast<double>();
  if (d.contains("iso_sweep") && !d["iso_sweep"].is_none()) {
    const py::object sweep = d["iso_sweep"];
    if (!py::isinstance<py::sequence>(sweep) || py::isinstance<py::str>(sweep) || py::len(sweep) != 3)
      throw InputError(r.where, "iso_sweep", "expected (surface, from, to), e.g. (0, 40, 120)");
    const py::sequence s = sweep;
    if (!py::isinstance<py::int_>(s[0]) || s[0].cast<long long>() < 0 || s[0].cast<long long>() > 999999)
      throw InputError(r.where, "iso_sweep", "the surface is a whole number from 0 (counted over all volumes)");
    std::ostringstream text;
    text.precision(17);
    text << s[0].cast<long long>() << ':' << s[1].cast<double>() << ':' << s[2].cast<double>();
    r.isoSweep = text.str();
  }
  return r;
}

class Renderer {
 public:
  py::dict render(const std::string& text, const std::string& path, const std::vector<std::shared_ptr<const Grid>>& grids,
                  const py::dict& options, py::object progress);
  py::dict autoCamera(const std::string& text, const std::string& path, const std::vector<std::shared_ptr<const Grid>>& grids);
  // The frames of a sequence of this scene (isotrace.render_sequence), checked.
  int sequenceLength(const std::string& text, const std::string& path, const std::vector<std::shared_ptr<const Grid>>& grids,
                     const py::dict& request);

 private:
  const World& worldFor(const SceneDesc& scene, double& loadSeconds, double& buildSeconds);
  // One render of this Scene at a time: a second thread's is refused (InputError), not queued.
  class Busy {
   public:
    explicit Busy(Renderer& r) : m_lock(r.m_busy, std::try_to_lock) {
      if (!m_lock.owns_lock())
        throw InputError("isotrace.Scene", "", "is being rendered by another thread; give each thread its own Scene "
                                               "(scene.copy() shares the arrays) or wait for that render");
    }

   private:
    std::unique_lock<std::mutex> m_lock;
  };
  std::mutex m_busy;
  // The last World: the next one reuses each volume that loads alike (the same source: only iso
  // values, materials, camera and the like changed), and takes a sequence's next step read ahead.
  std::unique_ptr<World> m_world;
  TimeStepsAhead m_ahead;
};

const World& Renderer::worldFor(const SceneDesc& scene, double& loadSeconds, double& buildSeconds) {
  std::unique_ptr<World> world = std::make_unique<World>(scene, scene.settings.intersector, m_world.get(), m_ahead.loader());
  loadSeconds = world->loadSeconds();
  buildSeconds = world->buildSeconds();
  m_world = std::move(world);
  return *m_world;
}

int Renderer::sequenceLength(const std::string& text, const std::string& path,
                             const std::vector<std::shared_ptr<const Grid>>& grids, const py::dict& request) {
  SceneDesc scene = parseScene(text, path, grids);
  return frameSequence(sequenceRequest(request), scene).frames;
}

// The render options a Python call may set, checked like the command line's flags.
void applyOptions(const py::dict& o, SceneDesc& scene, RenderOptions& options) {
  RenderSettings& s = scene.settings;
  auto get = [&](const char* key) -> py::object { return o.contains(key) ? py::object(o[key]) : py::none(); };
  auto whole = [&](const char* key, long long lo, long long hi) -> std::optional<long long> {
    const py::object v = get(key);
    if (v.is_none()) return std::nullopt;
    if (!py::isinstance<py::int_>(v) || py::isinstance<py::bool_>(v))
      throw InputError("isotrace.render", key, "expected a whole number");
    const long long n = v.cast<long long>();
    if (n < lo || n > hi)
      throw InputError("isotrace.render", key, "value " + std::to_string(n) + " is out of range [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return n;
  };
  if (auto n = whole("spp", 1, 1 << 20)) s.spp = int(*n);
  if (auto n = whole("max_depth", 1, 1000)) s.maxDepth = int(*n);
  if (auto n = whole("threads", 0, 4096)) s.threads = int(*n);
  if (auto n = whole("seed", 0, (1ll << 62))) s.seed = uint64_t(*n);
  if (py::object v = get("integrator"); !v.is_none()) {
    const std::string name = py::str(v);
    if (!isKnownIntegrator(name))
      throw InputError("isotrace.render", "integrator", "unknown integrator '" + name + "' (known: " + integratorList() + ")");
    s.integrator = name;
  }
  if (py::object v = get("intersector"); !v.is_none()) {
    std::string error;
    if (!parseIntersector(py::str(v), s.intersector, error)) throw InputError("isotrace.render", "intersector", error);
  }
  if (py::object v = get("ray_flow"); !v.is_none())
    if (!parseRayFlow(py::str(v), s.rayFlow))
      throw InputError("isotrace.render", "ray_flow", "unknown ray flow (known: wavefront, scalar)");
  if (py::object v = get("resolution"); !v.is_none()) {
    if (!py::isinstance<py::sequence>(v) || py::len(v) != 2) throw InputError("isotrace.render", "resolution", "expected (width, height)");
    const py::sequence seq = v;
    for (int i = 0; i < 2; ++i)
      if (!py::isinstance<py::int_>(seq[size_t(i)])) throw InputError("isotrace.render", "resolution", "expected two whole numbers");
    const long long w = seq[0].cast<long long>(), h = seq[1].cast<long long>();
    if (w < 1 || h < 1 || w > kMaxFilmSide || h > kMaxFilmSide)
      throw InputError("isotrace.render", "resolution", "each side 1 to " + std::to_string(kMaxFilmSide));
    s.width = int(w), s.height = int(h);
  }
  if (double(s.width) * s.height > double(kMaxFilmPixels))
    throw InputError("isotrace.render", "resolution", "more than " + std::to_string(kMaxFilmPixels) + " pixels");
  if (py::object v = get("adaptive"); !v.is_none()) {
    const double t = v.cast<double>();
    if (!(t >= 0 && t <= 1)) throw InputError("isotrace.render", "adaptive", "expected a noise threshold in [0, 1]");
    s.noiseThreshold = t;
  }
  if (py::object v = get("clamp"); !v.is_none()) {
    const double c = v.cast<double>();
    if (!(c >= 0 && c <= 1e30)) throw InputError("isotrace.render", "clamp", "expected a radiance >= 0 (0: off)");
    s.clampIndirect = c;
  }
  options = renderOptions(s);
  if (py::object v = get("aovs"); !v.is_none()) {
    for (const py::handle item : v) {
      const std::string name = py::str(item);
      if (name != "albedo" && name != "normal" && name != "depth" && name != "variance" && name != "samples")
        throw InputError("isotrace.render", "aovs", "unknown layer '" + name + "' (known: albedo, normal, depth, variance, samples)");
      if (std::find(options.aovs.begin(), options.aovs.end(), name) == options.aovs.end()) options.aovs.push_back(name);
    }
  }
  if (py::object v = get("alpha"); !v.is_none()) options.alpha = v.cast<bool>();
  if (py::object v = get("denoise"); !v.is_none()) {
    const std::string name = py::isinstance<py::bool_>(v) ? (v.cast<bool>() ? "quality" : "off") : std::string(py::str(v));
    if (!parseDenoiseMode(name, s.denoise))
      throw InputError("isotrace.render", "denoise", "unknown mode '" + name + "' (known: " + denoiseModeList() + ")");
  }
}

py::dict Renderer::render(const std::string& text, const std::string& path,
                          const std::vector<std::shared_ptr<const Grid>>& grids, const py::dict& opts, py::object progress) {
  const auto start = std::chrono::steady_clock::now();
  const Busy busy(*this);
  SceneDesc scene = parseScene(text, path, grids);
  RenderOptions options;
  applyOptions(opts, scene, options);
  // Frame f of a sequence (isotrace.render_sequence): its iso value, time steps and camera.
  std::optional<FrameSequence> seq;
  int frameIndex = 0;
  if (opts.contains("sequence")) {
    seq = frameSequence(sequenceRequest(opts["sequence"]), scene);
    frameIndex = opts["frame"].cast<int>();
    if (frameIndex < 0 || frameIndex >= seq->frames) throw InputError("isotrace.render_sequence", "frame", "out of range");
    seq->apply(scene, frameIndex);
  }
  std::unique_ptr<MpiJob>& job = pythonMpiJob();
  double loadSeconds = 0, buildSeconds = 0;
  const World* world = nullptr;
  {
    py::gil_scoped_release release;
    if (!job) {
      world = &worldFor(scene, loadSeconds, buildSeconds);
    } else {
      // Every rank loads for itself; they agree on the first failure before any talks (a rank
      // that raised alone would leave the others waiting for it for ever).
      std::string error;
      try {
        world = &worldFor(scene, loadSeconds, buildSeconds);
      } catch (const std::exception& e) {
        error = e.what();
      }
      error = job->firstError(error);
      if (!error.empty()) throw InputError(error);
    }
    if (seq && frameIndex + 1 < seq->frames && !job) m_ahead.startFrame(*seq, scene, frameIndex + 1);
  }
  const RenderSettings& s = scene.settings;
  const Camera camera(seq ? seq->camera(world->camera(), frameIndex) : world->camera(), s.width, s.height);
  const std::unique_ptr<Integrator> integrator = makeIntegrator(s.integrator, *world, s);
  Film film(s.width, s.height);
  std::unique_ptr<Film> direct;
  if (integrator->splitsDirect()) direct = std::make_unique<Film>(s.width, s.height);
  std::atomic<uint64_t> done{0};
  options.workDone = &done;
  const double total = double(s.width) * s.height * s.spp;
  // Every frame keeps the denoiser's input (Frame.denoised()), where its integrator has noise.
  std::shared_ptr<DenoiseBuffers> buffers;
  if (integratorDenoises(s.integrator)) {
    buffers = std::make_shared<DenoiseBuffers>();
    options.denoiseInput = &buffers->input;
  }

  // The render runs on its own thread without the GIL; this one wakes every 50 ms to report
  // progress and to let Python look at its signals: Ctrl-C asks the render to stop at the next
  // tile (once the first pass is done), and the partial frame comes back with the interrupt.
  // Under mpirun the frame is rendered over all ranks by tiles (renderer/distributed.h), on this
  // thread (MPI's): no progress reports, and rank 0 alone gets the image.
  const RenderRunning running;
  RenderResult result;
  std::exception_ptr failure;
  std::mutex mutex;
  std::condition_variable finished;
  bool over = false;
  auto renderIt = [&] {
    try {
      result = job ? renderFrameDistributed(*job, camera, *integrator, options, film, direct.get(), nullptr)
                   : renderFrame(camera, *integrator, options, film, direct.get());
    } catch (...) {
      failure = std::current_exception();
    }
    std::lock_guard<std::mutex> lock(mutex);
    over = true;
    finished.notify_all();
  };
  std::thread worker;
  if (job) {
    py::gil_scoped_release release;
    renderIt();
  } else {
    worker = std::thread(renderIt);
  }
  bool interrupted = false;
  std::optional<py::error_already_set> raised;  // by a signal handler or the progress callback
  for (;;) {
    bool ended;
    {
      py::gil_scoped_release release;
      std::unique_lock<std::mutex> lock(mutex);
      finished.wait_for(lock, std::chrono::milliseconds(50), [&] { return over; });
      ended = over;
    }
    if (!interrupted && !raised && PyErr_CheckSignals() != 0) {
      if (PyErr_ExceptionMatches(PyExc_KeyboardInterrupt)) {
        PyErr_Clear();
        interrupted = true;
      } else {
        raised.emplace();  // takes the error that is set
      }
      requestStop();
    }
    if (!progress.is_none() && !raised && !interrupted) {
      try {
        progress(std::min<double>(double(done.load()), total), total);
      } catch (py::error_already_set& e) {
        if (e.matches(PyExc_KeyboardInterrupt)) interrupted = true;
        else raised.emplace(std::move(e));
        requestStop();
      }
    }
    if (ended) break;
  }
  if (worker.joinable()) worker.join();
  if (failure) std::rethrow_exception(failure);
  if (raised) throw std::move(*raised);

  py::dict out;
  const int threads = s.threads > 0 ? s.threads : tbb::this_task_arena::max_concurrency();
  const int rank = job ? job->rank() : 0, ranks = job ? job->size() : 1;
  out["rank"] = rank;
  out["ranks"] = ranks;
  out["frame"] = frameIndex;
  if (rank != 0) {  // (rank 0 holds the image)
    out["rgb"] = py::none();
    out["layers"] = py::dict();
    out["signed"] = integrator->signedOutput();
    out["stats"] = statsJson(scene, loadSeconds, buildSeconds, result, 1, threads, 0, ranks, nullptr);
    out["keyboard_interrupt"] = false;
    return out;
  }
  if (interrupted) result.interrupted = true;
  Film indirect(0, 0);
  if (direct) indirect = indirectOf(film, *direct);
  if (buffers && s.denoise != DenoiseMode::Off) {
    out["raw"] = imageOf(film);
    if (direct) {
      out["raw_direct"] = imageOf(*direct);
      out["raw_indirect"] = imageOf(indirect);
    }
    py::gil_scoped_release release;
    denoiseFrame(buffers->input, s.denoise, s.threads, false, film, direct.get(), &indirect, result);
  }
  if (buffers) out["denoise_input"] = buffers;
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  out["stats"] = statsJson(scene, loadSeconds, buildSeconds, result, 1, threads, seconds, ranks, nullptr);
  out["signed"] = integrator->signedOutput();
  if (direct) {
    out["rgb"] = imageOf(film);
    out["direct"] = imageOf(*direct);
    out["indirect"] = imageOf(indirect);
  } else {
    out["rgb"] = imageOf(film);
  }
  out["layers"] = layersOf(film);
  out["keyboard_interrupt"] = interrupted;
  return out;
}

py::dict Renderer::autoCamera(const std::string& text, const std::string& path,
                              const std::vector<std::shared_ptr<const Grid>>& grids) {
  const Busy busy(*this);
  SceneDesc scene = parseScene(text, path, grids);
  scene.camera.frameScene = true;
  scene.camera.gltfCamera.clear();
  double load, build;
  const CameraDesc c = worldFor(scene, load, build).camera();
  py::dict d;
  d["position"] = std::vector<double>{c.position.x, c.position.y, c.position.z};
  d["look_at"] = std::vector<double>{c.lookAt.x, c.lookAt.y, c.lookAt.z};
  d["up"] = std::vector<double>{c.up.x, c.up.y, c.up.z};
  d["fov"] = c.fov;
  return d;
}

// ---- Accuracy tools --------------------------------------------------------------------------

py::dict countsOf(const WatertightCounts& c) {
  py::dict d;
  d["rays"] = c.rays;
  d["crossings"] = c.crossings;
  d["reference_crossings"] = c.referenceCrossings;
  d["lost_crossings"] = c.lostCrossings;
  d["extra_crossings"] = c.extraCrossings;
  d["parity_errors"] = c.parityErrors;
  d["self_hits"] = c.selfHits;
  d["inside_escapes"] = c.insideEscapes;
  d["shadow_mismatches"] = c.shadowMismatches;
  return d;
}

py::dict watertight(const std::string& text, const std::string& path, const std::vector<std::shared_ptr<const Grid>>& grids,
                    int rays, std::array<double, 3> offset, long long seed, int threads, const std::string& rayFlow,
                    const std::string& intersector) {
  const SceneDesc scene = parseScene(text, path, grids);
  if (rays < 1 || rays > 1000000000) throw InputError("isotrace.watertight", "rays", "expected 1 to 1e9 rays");
  if (seed < 0) throw InputError("isotrace.watertight", "seed", "expected a seed >= 0");
  if (threads < 0) throw InputError("isotrace.watertight", "threads", "expected 0 (all cores) or more");
  WatertightOptions options;
  options.rays = rays;
  options.seed = uint64_t(seed);
  options.threads = threads;
  for (int a = 0; a < 3; ++a) {
    if (!(std::fabs(offset[size_t(a)]) <= 1e12)) throw InputError("isotrace.watertight", "offset", "expected finite coordinates within 1e12");
    options.offset[a] = offset[size_t(a)];
  }
  if (!parseRayFlow(rayFlow, options.rayFlow)) throw InputError("isotrace.watertight", "ray_flow", "unknown ray flow (known: wavefront, scalar)");
  IntersectorSpec spec = scene.settings.intersector;
  std::string error;
  if (!intersector.empty() && !parseIntersector(intersector, spec, error)) throw InputError("isotrace.watertight", "intersector", error);
  if (scene.volumes.empty()) throw InputError(path, "/volumes", "the scene has no volume to check");
  std::vector<WatertightReport> reports;
  {
    py::gil_scoped_release release;
    reports = checkWatertight(scene, spec, options);
  }
  WatertightCounts total;
  py::list surfaces;
  for (const WatertightReport& r : reports) {
    py::dict d = countsOf(r.counts);
    d["volume"] = r.volume;
    d["iso"] = r.iso;
    d["intersector"] = r.intersector;
    surfaces.append(d);
    total.add(r.counts);
  }
  py::dict out;
  out["total"] = countsOf(total);
  out["surfaces"] = surfaces;
  out["ray_flow"] = rayFlowName(options.rayFlow);
  return out;
}

py::dict bench(const std::string& text, const std::string& path, const std::vector<std::shared_ptr<const Grid>>& grids,
               int rays, const std::vector<std::string>& intersectors, long long seed, const std::string& rayFlow) {
  const SceneDesc scene = parseScene(text, path, grids);
  if (rays < 1 || rays > 100000000) throw InputError("isotrace.bench", "rays", "expected 1 to 1e8 rays");
  if (seed < 0) throw InputError("isotrace.bench", "seed", "expected a seed >= 0");
  RayFlow flow = scene.settings.rayFlow;
  if (!rayFlow.empty() && !parseRayFlow(rayFlow, flow)) throw InputError("isotrace.bench", "ray_flow", "unknown ray flow (known: wavefront, scalar)");
  std::vector<IntersectorSpec> specs;
  for (const std::string& name : intersectors) {
    IntersectorSpec spec;
    std::string error;
    if (!parseIntersector(name, spec, error)) throw InputError("isotrace.bench", "intersectors", error);
    specs.push_back(spec);
  }
  if (specs.empty()) specs.push_back(scene.settings.intersector);
  if (scene.volumes.empty()) throw InputError(path, "/volumes", "the scene has no volume to measure");
  py::list results;
  for (size_t v = 0; v < scene.volumes.size(); ++v) {
    Grid grid;
    {
      py::gil_scoped_release release;
      grid = loadVolume(scene.volumes[v]).grid;
    }
    for (const IsoSurfaceDesc& iso : scene.volumes[v].isosurfaces)
      for (RayKind kind : {RayKind::Camera, RayKind::Secondary})
        for (const IntersectorSpec& spec : specs) {
          AccuracyReport r;
          {
            py::gil_scoped_release release;
            r = measureAccuracy(grid, iso.value, spec, kind, rays, uint64_t(seed), flow == RayFlow::Wavefront);
          }
          py::dict d;
          d["volume"] = v;
          d["iso"] = iso.value;
          d["rays"] = kind == RayKind::Camera ? "camera" : "secondary";
          d["intersector"] = intersectorName(spec);
          d["count"] = r.rays;
          d["reference_hits"] = r.referenceHits;
          d["tangent"] = r.tangentOnly;
          d["misses"] = r.misses;
          d["false_hits"] = r.falseHits;
          d["median_dt"] = r.medianDt;
          d["p99_dt"] = r.p99Dt;
          d["max_dt"] = r.maxDt;
          d["ns_per_ray"] = r.nsPerRay;
          results.append(d);
        }
  }
  py::dict out;
  out["ray_flow"] = rayFlowName(flow);
  out["results"] = results;
  return out;
}

py::tuple mesh(const std::string& text, const std::string& path, const std::vector<std::shared_ptr<const Grid>>& grids,
               int volume, int surface, const std::string& output, int time) {
  SceneDesc scene = parseScene(text, path, grids);
  selectMeshTimeStep(scene, time, "isotrace.mesh: time");
  if (!output.empty()) {
    const std::string ext = std::filesystem::path(output).extension().string();
    if (ext != ".glb" && ext != ".gltf") throw InputError(output, "", "the mesh output must be .glb or .gltf");
    checkWritable(output);
  }
  GltfMeshOut m;
  {
    py::gil_scoped_release release;
    m = surfaceMesh(scene, volume, surface, "volume", "surface");
  }
  if (!output.empty()) saveGltfMesh(output, m);
  const py::ssize_t nv = py::ssize_t(m.positions.size()), nt = py::ssize_t(m.indices.size() / 3);
  py::array_t<float> vertices({nv, py::ssize_t(3)}), normals({nv, py::ssize_t(3)});
  py::array_t<uint32_t> triangles({nt, py::ssize_t(3)});
  for (py::ssize_t i = 0; i < nv; ++i)
    for (int c = 0; c < 3; ++c) {
      vertices.mutable_at(i, c) = m.positions[size_t(i)][c];
      normals.mutable_at(i, c) = m.normals[size_t(i)][c];
    }
  std::copy(m.indices.begin(), m.indices.end(), triangles.mutable_data());
  py::object colors = py::none();
  if (!m.colors.empty()) {
    py::array_t<float> c({nv, py::ssize_t(3)});
    for (py::ssize_t i = 0; i < nv; ++i)
      for (int k = 0; k < 3; ++k) c.mutable_at(i, k) = m.colors[size_t(i)][k];
    colors = c;
  }
  return py::make_tuple(vertices, triangles, normals, colors);
}

}  // namespace
}  // namespace iso

PYBIND11_MODULE(_core, m) {
  using namespace iso;
  m.doc() = "isotrace's renderer library (use the isotrace package, not this module)";
  static py::exception<InputError> inputError(m, "InputError", PyExc_ValueError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const InputError& e) {
      inputError(e.what());
    }
  });
  py::class_<ArrayGrid>(m, "Grid")
      .def_readonly("copied", &ArrayGrid::copied)
      .def_readonly("dtype", &ArrayGrid::dtype)
      .def_readonly("data", &ArrayGrid::data)
      .def_property_readonly("dims", [](const ArrayGrid& g) { const Vec3i d = g.grid->dims(); return py::make_tuple(d.x, d.y, d.z); })
      .def_property_readonly("range", [](const ArrayGrid& g) { float lo, hi; g.grid->range(lo, hi); return py::make_tuple(lo, hi); });
  m.def("grid_from_array", &gridFromArray, py::arg("array"), py::arg("spacing"), py::arg("origin"), py::arg("axes"));
  auto gridsOf = [](const std::vector<ArrayGrid>& grids) {
    std::vector<std::shared_ptr<const Grid>> g;
    for (const ArrayGrid& a : grids) g.push_back(a.grid);
    return g;
  };
  m.def("check_scene", [gridsOf](const std::string& text, const std::string& path, const std::vector<ArrayGrid>& grids) {
    parseScene(text, path, gridsOf(grids));
  });
  py::class_<DenoiseBuffers, std::shared_ptr<DenoiseBuffers>>(m, "DenoiseBuffers")
      .def_property_readonly("width", [](const DenoiseBuffers& b) { return b.input.width; })
      .def_property_readonly("height", [](const DenoiseBuffers& b) { return b.input.height; });
  m.def("denoise", &denoiseBuffers, py::arg("buffers"), py::arg("mode"), py::arg("threads"));
  py::class_<Renderer>(m, "Renderer")
      .def(py::init<>())
      .def("render", [gridsOf](Renderer& r, const std::string& text, const std::string& path, const std::vector<ArrayGrid>& grids,
                               const py::dict& options, py::object progress) {
        return r.render(text, path, gridsOf(grids), options, std::move(progress));
      })
      .def("auto_camera", [gridsOf](Renderer& r, const std::string& text, const std::string& path, const std::vector<ArrayGrid>& grids) {
        return r.autoCamera(text, path, gridsOf(grids));
      })
      .def("sequence_length", [gridsOf](Renderer& r, const std::string& text, const std::string& path,
                                        const std::vector<ArrayGrid>& grids, const py::dict& request) {
        return r.sequenceLength(text, path, gridsOf(grids), request);
      });
  m.def("mpi_rank", [] { return launchedRanks().rank; });
  m.def("mpi_size", [] { return launchedRanks().size; });
  // MPI ends with the interpreter (on its main thread, before the module goes).
  py::module_::import("atexit").attr("register")(py::cpp_function([] { g_mpiJob.reset(); }));
  m.def("save_image", &saveImage, py::arg("rgb"), py::arg("layers"), py::arg("path"), py::arg("exposure"), py::arg("tonemap"),
        py::arg("signed_data"));
  m.def("read_image", &readImage, py::arg("path"));
  m.def("png_bytes", &pngBytes, py::arg("rgb"), py::arg("exposure"), py::arg("tonemap"), py::arg("signed_data"));
  m.def("watertight", [gridsOf](const std::string& text, const std::string& path, const std::vector<ArrayGrid>& grids, int rays,
                                std::array<double, 3> offset, long long seed, int threads, const std::string& rayFlow,
                                const std::string& intersector) {
    return watertight(text, path, gridsOf(grids), rays, offset, seed, threads, rayFlow, intersector);
  });
  m.def("bench", [gridsOf](const std::string& text, const std::string& path, const std::vector<ArrayGrid>& grids, int rays,
                           const std::vector<std::string>& intersectors, long long seed, const std::string& rayFlow) {
    return bench(text, path, gridsOf(grids), rays, intersectors, seed, rayFlow);
  });
  m.def("mesh", [gridsOf](const std::string& text, const std::string& path, const std::vector<ArrayGrid>& grids, int volume,
                          int surface, const std::string& output, int time) {
    return mesh(text, path, gridsOf(grids), volume, surface, output, time);
  });
}
