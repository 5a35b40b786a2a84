#include "renderer/cli.h"

#include <CLI/CLI.hpp>
#include <OpenImageIO/oiioversion.h>
#include <embree3/rtcore_config.h>
#include <oneapi/tbb/version.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <chrono>
#include <signal.h>

#include <csignal>
#include <unistd.h>
#include <tbb/task_arena.h>
#include <map>
#include <optional>
#include <cmath>
#include <regex>
#include <sstream>

#include "bench/accuracy.h"
#include "bench/watertight.h"
#include "renderer/distributed.h"
#include "renderer/render.h"
#include "renderer/view.h"
#include "scene/gltf.h"
#include "volume/iso_mesh.h"
#include "volume/input_error.h"

namespace iso {
namespace {

struct RenderFlags {
  std::string scene, output, integrator, intersector, resolution, aov, stats, tonemap, isoSweep;
  int spp = 0, threads = -1, maxDepth = 0, frames = 1;
  std::optional<double> orbit;
  long long seed = -1;
  bool quiet = false, alpha = false, allowLarge = false;
  std::optional<double> exposure, clamp, adaptive;
};

// --exposure and --tonemap, checked; a warning when the output is EXR (which stays linear).
DisplaySettings displayFlags(const RenderFlags& f, const std::string& output) {
  DisplaySettings d;
  if (f.exposure) {
    if (!(*f.exposure >= -30 && *f.exposure <= 30)) throw InputError("--exposure", "", "expected EV in [-30, 30]");
    d.exposure = *f.exposure;
  }
  if (!f.tonemap.empty() && !parseTonemap(f.tonemap, d.tonemap))
    throw InputError("--tonemap", "", "unknown curve '" + f.tonemap + "' (known: clamp, aces, filmic)");
  if (imageFormatFor(output) == ImageFormat::Exr && (f.exposure || !f.tonemap.empty()))
    std::fprintf(stderr, "isotrace: warning: --exposure and --tonemap shape PNG and JPEG output; %s stays linear\n",
                 output.c_str());
  if (f.alpha && imageFormatFor(output) == ImageFormat::Jpeg)
    throw InputError("--alpha", "", "JPEG has no alpha channel: write .png or .exr");
  return d;
}

// Images above this many pixels need --allow-large; no side may exceed kMaxFilmSide.
constexpr long long kMaxFilmPixels = 1LL << 25;
constexpr int kMaxFilmSide = 16384;

// --resolution WIDTHxHEIGHT, each side 1 to kMaxFilmSide.
void parseResolution(const std::string& text, int& width, int& height) {
  std::smatch m;
  static const std::regex wxh(R"((\d{1,5})x(\d{1,5}))");
  if (!std::regex_match(text, m, wxh) || std::stoi(m[1]) < 1 || std::stoi(m[2]) < 1)
    throw InputError("--resolution", "", "expected WIDTHxHEIGHT, e.g. 640x480, got '" + text + "'");
  width = std::stoi(m[1]);
  height = std::stoi(m[2]);
  if (width > kMaxFilmSide || height > kMaxFilmSide)
    throw InputError("--resolution", "", "each side must be at most " + std::to_string(kMaxFilmSide) + " pixels");
}

// Flags override the scene file; each is checked here so that a bad one is an InputError.
void applyFlags(const RenderFlags& f, SceneDesc& scene) {
  RenderSettings& s = scene.settings;
  if (!f.integrator.empty()) {
    if (!isKnownIntegrator(f.integrator))
      throw InputError("--integrator", "", "unknown integrator '" + f.integrator + "' (known: " +
                                               integratorList() + ")");
    s.integrator = f.integrator;
  }
  if (!f.intersector.empty()) {
    std::string error;
    if (!parseIntersector(f.intersector, s.intersector, error))
      throw InputError("--intersector", "", error);
  }
  if (!f.resolution.empty()) parseResolution(f.resolution, s.width, s.height);
  // The film costs ~170 bytes per pixel while rendering (the sums of every layer, in double).
  if (double(s.width) * s.height > double(kMaxFilmPixels) && !f.allowLarge)
    throw InputError(f.resolution.empty() ? scene.path : "--resolution", f.resolution.empty() ? "/film" : "",
                     std::to_string(s.width) + "x" + std::to_string(s.height) + " is more than " +
                         std::to_string(kMaxFilmPixels) + " pixels (~" +
                         std::to_string(kMaxFilmPixels * 170 >> 30) + " GiB to render); --allow-large renders it anyway");
  if (f.spp != 0) s.spp = f.spp;  // CLI11 checked the range; 0 is "not given"
  if (f.maxDepth != 0) s.maxDepth = f.maxDepth;
  if (f.threads >= 0) s.threads = f.threads;
  if (f.seed >= 0) s.seed = uint64_t(f.seed);
  if (f.clamp) {
    if (!(*f.clamp >= 0 && *f.clamp <= 1e30)) throw InputError("--clamp", "", "expected a radiance >= 0 (0: off)");
    s.clampIndirect = *f.clamp;
  }
  if (f.adaptive) {
    if (!(*f.adaptive >= 0 && *f.adaptive <= 1))
      throw InputError("--adaptive", "", "expected a noise threshold in [0, 1], e.g. 0.02 (0: off)");
    s.noiseThreshold = *f.adaptive;
  }
}

std::vector<std::string> parseAovs(const std::string& list, const std::string& output) {
  std::vector<std::string> aovs;
  if (list.empty()) return aovs;
  size_t start = 0;
  while (start <= list.size()) {
    const size_t comma = std::min(list.find(',', start), list.size());
    const std::string name = list.substr(start, comma - start);
    if (name != "albedo" && name != "normal" && name != "depth" && name != "variance" && name != "samples")
      throw InputError("--aov", "", "unknown layer '" + name + "' (known: albedo, normal, depth, variance, samples)");
    if (std::find(aovs.begin(), aovs.end(), name) == aovs.end()) aovs.push_back(name);
    start = comma + 1;
  }
  if (imageFormatFor(output) != ImageFormat::Exr)
    throw InputError("--aov", "", "extra layers need an EXR output (-o NAME.exr), not " + output);
  return aovs;
}

// "out/x.png" -> "out/x.direct.png".
std::string withSuffix(const std::string& path, const std::string& suffix) {
  const std::filesystem::path p(path);
  return (p.parent_path() / (p.stem().string() + "." + suffix + p.extension().string())).string();
}

// SIGINT and SIGTERM: the first asks the render to stop (the image of the samples so far is
// still written, and nothing partial is left); a second SIGINT ends the process at once.
volatile std::sig_atomic_t g_stopSignal = 0;  // the first stop signal, named in the message
void onStopSignal(int signal) {
  if (g_stopSignal == 0) g_stopSignal = signal;
  requestStop();
  if (signal == SIGINT) std::signal(SIGINT, SIG_DFL);
}

// A temporary name beside `path`, unique to this process: ".NAME.partial-PID".
std::string temporaryBeside(const std::string& path) {
  const std::filesystem::path p(path);
  return (p.parent_path() / ("." + p.filename().string() + ".partial-" + std::to_string(getpid()))).string();
}

// An output must be writable before any work is done: its directory exists and takes a file,
// and the name is no directory.
void checkWritable(const std::string& path) {
  namespace fs = std::filesystem;
  const fs::path p(path);
  std::error_code ec;
  if (fs::is_directory(p, ec)) throw InputError(path, "", "is a directory; name the output file");
  if (p.has_parent_path() && !fs::is_directory(p.parent_path(), ec))
    throw InputError(path, "", "output directory does not exist");
  const std::string probe = temporaryBeside(path);
  FILE* f = std::fopen(probe.c_str(), "w");
  if (!f) throw InputError(path, "", std::string("cannot write in its directory: ") + std::strerror(errno));
  std::fclose(f);
  std::remove(probe.c_str());
}

// The shortest decimal that reads back as the same double (0.28, not 0.28000000000000003).
std::string jsonNumber(double v) {
  char buf[32];
  for (int digits = 15; digits <= 17; ++digits) {
    std::snprintf(buf, sizeof buf, "%.*g", digits, v);
    if (std::strtod(buf, nullptr) == v) break;
  }
  return buf;
}

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      out += buf;
      continue;
    }
    out += c;
  }
  return out + "\"";
}

// Under MPI, one frame: tiles and busy seconds per rank, and busiest over idlest rank.
std::string rankFigures(const RankFigures* f) {
  if (!f || f->tiles.empty()) return "";
  std::string tiles, busy;
  double most = 0, least = INFINITY;
  for (size_t r = 0; r < f->tiles.size(); ++r) {
    tiles += (r ? ", " : "") + std::to_string(f->tiles[r]);
    busy += (r ? ", " : "") + jsonNumber(f->busySeconds[r]);
    most = std::max(most, f->busySeconds[r]);
    least = std::min(least, f->busySeconds[r]);
  }
  return "  \"tiles_per_rank\": [" + tiles + "],\n  \"busy_seconds_per_rank\": [" + busy + "],\n  \"balance\": " +
         jsonNumber(least > 0 ? most / least : 0) + ",\n";
}

void writeStats(const std::string& path, const SceneDesc& scene, double loadSeconds, double buildSeconds,
                const RenderResult& r, int frames, int threads, double totalSeconds, int ranks,
                const RankFigures* perRank) {
  const RenderSettings& s = scene.settings;
  const RayCounters& c = r.counters;
  const uint64_t rays = c.camera + c.shadow + c.indirect;
  const std::string temp = temporaryBeside(path);
  FILE* f = std::fopen(temp.c_str(), "w");
  if (!f) throw InputError(path, "", "cannot write statistics");
  std::fprintf(f,
               "{\n  \"scene\": %s,\n  \"width\": %d,\n  \"height\": %d,\n  \"spp\": %d,\n  \"spp_requested\": %d,\n"
               "  \"spp_mean\": %.4f,\n  \"spp_max\": %d,\n  \"noise_threshold\": %s,\n  \"clamp\": %s,\n"
               "  \"interrupted\": %s,\n  \"threads\": %d,\n  \"integrator\": %s,\n  \"intersector\": %s,\n"
               "  \"max_depth\": %d,\n  \"frames\": %d,\n  \"ranks\": %d,\n%s"
               "  \"seconds\": {\"load\": %.6f, \"build\": %.6f, \"render\": %.6f, \"total\": %.6f},\n"
               "  \"rays\": {\"camera\": %llu, \"shadow\": %llu, \"indirect\": %llu, \"total\": %llu},\n"
               "  \"rays_per_second\": %.1f,\n"
               "  \"counters\": {\"Iso/CellsVisited\": %llu, \"Iso/CellsSolved\": %llu, \"Iso/RootsRefined\": %llu}\n}\n",
               jsonString(scene.path).c_str(), s.width, s.height, r.minSamples, s.spp, r.meanSamples, r.maxSamples,
               jsonNumber(s.noiseThreshold).c_str(), jsonNumber(s.clampIndirect).c_str(), r.interrupted ? "true" : "false",
               threads, jsonString(s.integrator).c_str(), jsonString(intersectorName(s.intersector)).c_str(), s.maxDepth,
               frames, ranks, rankFigures(perRank).c_str(), loadSeconds, buildSeconds, r.seconds, totalSeconds, (unsigned long long)c.camera,
               (unsigned long long)c.shadow, (unsigned long long)c.indirect, (unsigned long long)rays,
               r.seconds > 0 ? rays / r.seconds : 0.0, (unsigned long long)c.traversal.cellsVisited,
               (unsigned long long)c.traversal.cellsSolved, (unsigned long long)c.traversal.rootsRefined);
  const bool ok = std::fclose(f) == 0;
  if (!ok || std::rename(temp.c_str(), path.c_str()) != 0) {
    std::remove(temp.c_str());
    throw InputError(path, "", "cannot write statistics");
  }
}

// A frame sequence (--frames, --iso-sweep, --orbit): frame f of N has iso-surface `surface`
// (counted over all volumes in scene order) at from + (to - from) f / (N - 1), and the camera
// turned about its look-at point, around its up vector, by orbit f / N degrees (a full 360
// turn does not repeat the first frame).
struct FrameSequence {
  int frames = 1;
  int surface = -1;  // swept surface, or -1
  double from = 0, to = 0;
  double orbit = 0;
  IsoSurfaceDesc* iso(SceneDesc& scene) const {
    int k = 0;
    for (VolumeDesc& v : scene.volumes)
      for (IsoSurfaceDesc& d : v.isosurfaces)
        if (k++ == surface) return &d;
    return nullptr;
  }
  double isoValue(int f) const { return frames == 1 ? from : from + (to - from) * double(f) / double(frames - 1); }
  // OUT.png -> OUT.0007.png (at least 4 digits, more for longer sequences).
  std::string name(const std::string& output, int f) const {
    if (frames == 1) return output;
    const int digits = std::max<int>(4, int(std::to_string(frames - 1).size()));
    std::string number = std::to_string(f);
    return withSuffix(output, std::string(size_t(digits) - number.size(), '0') + number);
  }
};

FrameSequence frameSequence(const RenderFlags& f, SceneDesc& scene) {
  FrameSequence seq;
  seq.frames = f.frames;
  if (!f.isoSweep.empty()) {
    std::istringstream in(f.isoSweep);
    std::string index, from, to;
    if (!std::getline(in, index, ':') || !std::getline(in, from, ':') || !std::getline(in, to) ||
        index.find_first_not_of("0123456789") != std::string::npos || index.empty() || index.size() > 6)
      throw InputError("--iso-sweep", "", "expected SURFACE:FROM:TO, e.g. 0:40:120 (SURFACE counts all iso-surfaces from 0)");
    seq.surface = std::stoi(index);
    try {
      size_t used = 0;
      seq.from = std::stod(from, &used);
      if (used != from.size()) throw std::invalid_argument(from);
      seq.to = std::stod(to, &used);
      if (used != to.size()) throw std::invalid_argument(to);
    } catch (const std::exception&) {
      throw InputError("--iso-sweep", "", "'" + from + "' and '" + to + "' must be numbers");
    }
    if (!std::isfinite(seq.from) || !std::isfinite(seq.to))
      throw InputError("--iso-sweep", "", "the iso values must be finite");
    if (!seq.iso(scene)) {
      size_t count = 0;
      for (const VolumeDesc& v : scene.volumes) count += v.isosurfaces.size();
      throw InputError("--iso-sweep", "", "no iso-surface " + index + " (the scene has " + std::to_string(count) +
                                              ", counted from 0 over all volumes)");
    }
  }
  if (f.orbit) {
    if (!std::isfinite(*f.orbit) || std::fabs(*f.orbit) > 36000) throw InputError("--orbit", "", "expected degrees in [-36000, 36000]");
    seq.orbit = *f.orbit;
  }
  if (seq.frames > 1 && seq.surface < 0 && !f.orbit)
    throw InputError("--frames", "", "a sequence needs --iso-sweep and/or --orbit (else every frame is the same)");
  if (seq.frames == 1 && (seq.surface >= 0 || f.orbit))
    throw InputError("--frames", "", "--iso-sweep and --orbit make a sequence: give --frames N (N >= 2)");
  return seq;
}

// The camera turned about its look-at point, around its up vector, by `degrees`.
CameraDesc orbitCamera(CameraDesc c, double degrees) {
  if (degrees == 0) return c;
  const Transform r = Transform::rotate(degrees, c.up);
  c.position = c.lookAt + r.vector(c.position - c.lookAt);
  return c;
}

// Loads the scene and checks every flag and output before any work: the part of a render
// that every rank of an MPI job does alike.
struct RenderSetup {
  SceneDesc scene;
  FrameSequence seq;
  std::string output;
  DisplaySettings display;
  RenderOptions options;
};

RenderSetup prepareRender(const RenderFlags& flags) {
  RenderSetup r;
  r.scene = parseSceneFile(flags.scene);
  applyFlags(flags, r.scene);
  r.seq = frameSequence(flags, r.scene);
  r.output = flags.output.empty() ? std::filesystem::path(flags.scene).stem().string() + ".png" : flags.output;
  std::error_code ec;
  if (std::filesystem::is_directory(r.output, ec)) throw InputError(r.output, "", "is a directory; name the output file");
  r.display = displayFlags(flags, r.output);  // bad names and values before any work
  const RenderSettings& s = r.scene.settings;
  r.options.spp = s.spp;
  r.options.seed = s.seed;
  r.options.threads = s.threads;
  r.options.aovs = parseAovs(flags.aov, r.output);
  r.options.alpha = flags.alpha;
  r.options.noiseThreshold = s.noiseThreshold;
  r.options.progress = !flags.quiet && isatty(2);
  for (int f : {0, r.seq.frames - 1}) {  // the first and last names: the same folder, other digits
    const std::string name = r.seq.name(r.output, f);
    if (s.integrator == "compare") {
      for (const char* part : {"direct", "global", "indirect"}) checkWritable(withSuffix(name, part));
    } else {
      checkWritable(name);
    }
  }
  if (!flags.stats.empty()) checkWritable(flags.stats);
  return r;
}

// The frames this rank renders, written and reported (rank 0 reports for all).
template <typename Mine, typename Build>
int renderFrames(const RenderFlags& flags, MpiJob& job, RenderSetup& setup, bool byTiles, Mine mine,
                 std::unique_ptr<World>& world, int& worldFrame, Build buildWorld, double& loadSeconds,
                 double& buildSeconds, std::chrono::steady_clock::time_point start) {
  const SceneDesc& scene = setup.scene;
  const FrameSequence& seq = setup.seq;
  const RenderSettings& s = scene.settings;
  const std::string& output = setup.output;
  const DisplaySettings& display = setup.display;
  RenderOptions options = setup.options;
  options.progress = options.progress && job.rank() == 0;
  RenderResult total;
  RankFigures figures;
  int framesDone = 0;
  bool warned = false;
  for (int frame = 0; frame < seq.frames; ++frame) {
    if (!mine(frame)) continue;
    if (worldFrame != frame) buildWorld(frame);
    if (stopRequested()) {
      std::fprintf(stderr, "isotrace: %sinterrupted while loading: no image written for frame %d\n", job.where().c_str(), frame);
      if (job.distributed()) job.abort(130);
      return 130;
    }
    if (!warned && job.rank() == 0)
      for (const std::string& w : world->warnings()) std::fprintf(stderr, "isotrace: warning: %s\n", w.c_str());
    warned = true;
    const double degrees = seq.orbit * double(frame) / double(seq.frames);
    Camera camera(orbitCamera(world->camera(), degrees), s.width, s.height);
    auto integrator = makeIntegrator(s.integrator, *world, s);
    Film film(s.width, s.height);
    std::unique_ptr<Film> direct;
    if (integrator->splitsDirect()) direct = std::make_unique<Film>(s.width, s.height);

    // Said before the first sample, so that a log (or a test) knows the render has begun.
    if (!flags.quiet && job.rank() == 0) {
      const std::string which = seq.frames > 1 ? " (frame " + std::to_string(frame + 1) + " of " + std::to_string(seq.frames) + ")" : "";
      std::fprintf(stderr, "isotrace: rendering %dx%d, %d spp, %s%s\n", s.width, s.height, s.spp, s.integrator.c_str(), which.c_str());
      std::fflush(stderr);
    }
    const RenderResult result = byTiles ? renderFrameDistributed(job, camera, *integrator, options, film, direct.get(), &figures)
                                        : renderFrame(camera, *integrator, options, film, direct.get());
    if (byTiles && job.rank() != 0) return result.interrupted ? 130 : 0;  // rank 0 writes the image

    std::map<std::string, std::string> metadata = {
        {"Software", "isotrace"},
        {"isotrace:spp", std::to_string(result.minSamples)},
        {"isotrace:spp_requested", std::to_string(s.spp)},
        {"isotrace:integrator", s.integrator},
        {"isotrace:max_depth", std::to_string(s.maxDepth)},
        {"isotrace:intersector", intersectorName(s.intersector)},
        {"isotrace:seed", std::to_string(s.seed)}};
    if (s.noiseThreshold > 0) {
      metadata["isotrace:noise_threshold"] = jsonNumber(s.noiseThreshold);
      metadata["isotrace:spp_mean"] = jsonNumber(result.meanSamples);
      metadata["isotrace:spp_max"] = std::to_string(result.maxSamples);
    }
    if (s.clampIndirect > 0) metadata["isotrace:clamp"] = jsonNumber(s.clampIndirect);
    if (result.interrupted) metadata["isotrace:interrupted"] = "1";
    if (seq.frames > 1) {
      metadata["isotrace:frame"] = std::to_string(frame) + "/" + std::to_string(seq.frames);
      if (seq.surface >= 0) metadata["isotrace:iso_value"] = jsonNumber(seq.isoValue(frame));
      if (seq.orbit != 0) metadata["isotrace:orbit_degrees"] = jsonNumber(degrees);
    }
    if (imageFormatFor(output) != ImageFormat::Exr) {
      metadata["isotrace:exposure"] = jsonNumber(display.exposure);
      metadata["isotrace:tonemap"] = tonemapName(display.tonemap);
    }
    const std::string frameOutput = seq.name(output, frame);
    std::vector<std::string> written;
    if (direct) {
      // global = everything, direct = paths of depth 1, indirect = global - direct.
      Film indirect = indirectOf(film, *direct);
      const std::string global = withSuffix(frameOutput, "global");
      direct->alpha() = indirect.alpha() = film.alpha();
      writeImage(withSuffix(frameOutput, "direct"), *direct, false, metadata, display);
      writeImage(global, film, false, metadata, display);
      writeImage(withSuffix(frameOutput, "indirect"), indirect, false, metadata, display);
      written = {withSuffix(frameOutput, "direct"), global, withSuffix(frameOutput, "indirect")};
      const double ld = direct->meanLuminance(), lg = film.meanLuminance(), li = indirect.meanLuminance();
      std::fprintf(stderr, "isotrace: compare: mean luminance direct %.6g, global %.6g, indirect %.6g; "
                   "%.1f%% of the light is indirect\n", ld, lg, li, lg > 0 ? 100 * li / lg : 0.0);
    } else {
      writeImage(frameOutput, film, integrator->signedOutput(), metadata, display);
      written = {frameOutput};
    }
    for (const std::string& path : written) std::printf("%s\n", path.c_str());
    std::fflush(stdout);
    total.counters.add(result.counters);
    total.seconds += result.seconds;
    total.minSamples = framesDone == 0 ? result.minSamples : std::min(total.minSamples, result.minSamples);
    total.maxSamples = std::max(total.maxSamples, result.maxSamples);
    total.meanSamples += result.meanSamples;  // averaged over the frames below
    total.interrupted = result.interrupted;
    ++framesDone;
    if (result.interrupted) break;
  }
  if (framesDone > 0) total.meanSamples /= framesDone;
  if (job.distributed() && !byTiles) {
    // The frames of all ranks: counters and samples on rank 0, which alone reports them.
    const int framesAll = job.sum(framesDone);
    total = job.combine(total, framesDone, framesAll);
    framesDone = framesAll;
    if (job.rank() != 0) return total.interrupted ? 130 : 0;
  }

  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const int threads = s.threads > 0 ? s.threads : tbb::this_task_arena::max_concurrency();
  if (!flags.stats.empty())
    writeStats(flags.stats, scene, loadSeconds, buildSeconds, total, framesDone, threads, seconds, job.size(),
               byTiles ? &figures : nullptr);
  if (!flags.quiet) {
    const RayCounters& c = total.counters;
    char buf[96];
    if (s.noiseThreshold > 0)
      std::snprintf(buf, sizeof buf, "%d-%d (mean %.1f, adaptive %g)", total.minSamples, total.maxSamples,
                    total.meanSamples, s.noiseThreshold);
    else
      std::snprintf(buf, sizeof buf, "%d", total.minSamples);
    const std::string sppSummary = buf;
    const std::string frameSummary = seq.frames > 1 ? ", " + std::to_string(framesDone) + " frames" : "";
    const double rays = double(c.camera + c.shadow + c.indirect);
    std::fprintf(stderr,
                 "isotrace: %dx%d%s, %s spp, %s, %s, %d threads%s: load %.2fs, build %.2fs, render %.2fs, total %.2fs\n"
                 "isotrace: rays: %llu camera, %llu shadow, %llu indirect; %.2f Mrays/s; "
                 "iso-surface cells visited %llu, solved %llu, roots refined %llu\n",
                 s.width, s.height, frameSummary.c_str(), sppSummary.c_str(), s.integrator.c_str(),
                 intersectorName(s.intersector).c_str(), threads,
                 job.distributed() ? (" x " + std::to_string(job.size()) + " ranks").c_str() : "", loadSeconds, buildSeconds, total.seconds, seconds,
                 (unsigned long long)c.camera, (unsigned long long)c.shadow, (unsigned long long)c.indirect,
                 total.seconds > 0 ? rays / total.seconds * 1e-6 : 0.0,
                 (unsigned long long)c.traversal.cellsVisited, (unsigned long long)c.traversal.cellsSolved,
                 (unsigned long long)c.traversal.rootsRefined);
  }
  if (total.interrupted) {
    std::fprintf(stderr, "isotrace: interrupted by %s: wrote the image of %d of %d samples per pixel%s\n",
                 g_stopSignal == SIGTERM ? "SIGTERM" : "SIGINT", total.minSamples,
                 s.spp, seq.frames > 1 ? (" (frame " + std::to_string(framesDone - 1) + "; the rest not rendered)").c_str() : "");
    return 130;
  }
  return 0;
}


int render(const RenderFlags& flags) {
  const auto start = std::chrono::steady_clock::now();
  MpiJob job;  // one rank of many under mpirun; otherwise MPI is not touched
  // A stop signal is a request from here on: loading ends first (then nothing is written), a
  // render ends at the next tile (the next pixel under MPI) and its image is written whole (a
  // sequence then stops).
  // A job that a non-interactive shell starts with `&` begins with SIGINT ignored, so that a
  // Ctrl-C at the terminal reaches only the foreground job: that ignore is kept, as shells and
  // the GNU tools keep it. SIGTERM always asks the render to stop.
  clearStopRequest();
  g_stopSignal = 0;
  struct sigaction inherited {};
  sigaction(SIGINT, nullptr, &inherited);
  auto previousInt = inherited.sa_handler == SIG_IGN ? SIG_IGN : std::signal(SIGINT, onStopSignal);
  auto previousTerm = std::signal(SIGTERM, onStopSignal);
  struct RestoreSignals {
    decltype(previousInt) i, t;
    ~RestoreSignals() {
      std::signal(SIGINT, i == SIG_ERR ? SIG_DFL : i);
      std::signal(SIGTERM, t == SIG_ERR ? SIG_DFL : t);
    }
  } restore{previousInt, previousTerm};

  // Under MPI one frame is spread over the ranks by tiles; a sequence by whole frames (frame f
  // on rank f mod N, which writes it).
  RenderSetup setup;
  const bool byTiles = job.distributed() && flags.frames == 1;
  auto mine = [&](int frame) { return byTiles || frame % job.size() == job.rank(); };
  std::unique_ptr<World> world;
  int worldFrame = -1;
  double loadSeconds = 0, buildSeconds = 0;
  auto buildWorld = [&](int frame) {
    // A new iso value is a new World (its bricks and BVH for that value); a camera move is not.
    if (world && setup.seq.surface < 0) return;
    if (setup.seq.surface >= 0) setup.seq.iso(setup.scene)->value = setup.seq.isoValue(frame);
    // A sweep changes iso values only: the volumes stay loaded from the previous frame's World.
    world = std::make_unique<World>(setup.scene, setup.scene.settings.intersector, world.get());
    worldFrame = frame;
    loadSeconds += world->loadSeconds();
    buildSeconds += world->buildSeconds();
  };
  auto firstFrame = [&] {
    for (int f = 0; f < setup.seq.frames; ++f)
      if (mine(f)) return f;
    return -1;
  };
  if (!job.distributed()) {
    setup = prepareRender(flags);
  } else {
    // Every rank loads for itself; before the ranks talk, they agree on the first failure, which
    // rank 0 reports in one line (naming the rank that saw it), and all end with status 2.
    std::string error;
    try {
      setup = prepareRender(flags);
      if (const int f = firstFrame(); f >= 0) buildWorld(f);
      if (stopRequested()) error = "interrupted while loading: no image written";
    } catch (const InputError& e) {
      error = e.what();
    } catch (const std::bad_alloc&) {
      error = "out of memory";
    } catch (const std::exception& e) {
      error = std::string("internal error: ") + e.what();
    }
    error = job.firstError(error);
    if (!error.empty()) {
      if (job.rank() == 0) std::fprintf(stderr, "isotrace: %s\n", error.c_str());
      return stopRequested() ? 130 : 2;
    }
  }
  try {
    return renderFrames(flags, job, setup, byTiles, mine, world, worldFrame, buildWorld, loadSeconds, buildSeconds, start);
  } catch (const std::exception& e) {
    if (!job.distributed()) throw;
    // The other ranks would wait for this one forever: say which rank failed, end them all.
    const InputError* input = dynamic_cast<const InputError*>(&e);
    std::fprintf(stderr, "isotrace: %s%s%s\n", job.where().c_str(), input ? "" : "internal error: ", e.what());
    job.abort(input ? 2 : 1);
  }
}

const char* materialTypeName(MaterialType t) {
  switch (t) {
    case MaterialType::Diffuse: return "diffuse";
    case MaterialType::MetallicRoughness: return "metallic_roughness";
    case MaterialType::Conductor: return "conductor";
    case MaterialType::Dielectric: return "dielectric";
    case MaterialType::Emissive: return "emissive";
  }
  return "?";
}

const char* lightKindName(Light::Kind k) {
  switch (k) {
    case Light::Kind::Point: return "point";
    case Light::Kind::Spot: return "spot";
    case Light::Kind::Directional: return "directional";
    case Light::Kind::Environment: return "environment";
    case Light::Kind::Area: return "area (emissive triangles)";
    case Light::Kind::IsoSurface: return "emissive iso-surface";
  }
  return "?";
}

int info(const std::string& path) {
  const SceneDesc scene = parseSceneFile(path);
  World world(scene, scene.settings.intersector);
  for (const std::string& w : world.warnings()) std::fprintf(stderr, "isotrace: warning: %s\n", w.c_str());
  const RenderSettings& s = scene.settings;
  std::printf("scene %s\n", path.c_str());
  std::printf("  film %dx%d, %d spp, integrator %s (max depth %d), intersector %s\n", s.width, s.height, s.spp,
              s.integrator.c_str(), s.maxDepth, intersectorName(s.intersector).c_str());
  const CameraDesc& c = world.camera();
  std::printf("  camera%s%s: position (%g, %g, %g), looking at (%g, %g, %g), fov %g degrees\n",
              scene.camera.gltfCamera.empty() ? "" : (" (glTF camera " + scene.camera.gltfCamera + ")").c_str(),
              scene.camera.frameScene ? " (none in the scene: framing its bounds)" : "", c.position.x, c.position.y, c.position.z, c.lookAt.x, c.lookAt.y, c.lookAt.z, c.fov);
  std::vector<std::string> skipped;
  if (world.meshes().empty()) skipped.push_back("no meshes: no triangle geometry is built");
  size_t images = 0;
  for (size_t m = 0; m < world.meshes().size(); ++m) {
    const MeshInfo& mi = world.meshes()[m];
    images += mi.images;
    std::printf("  mesh %zu: %s\n    %zu triangles in the world (%zu stored), %zu meshes, %zu placements "
                "(%zu as Embree instances); %zu materials, %zu textures, %zu cameras, %zu lights in the file\n",
                m, mi.name.c_str(), mi.triangles, mi.uniqueTriangles, mi.meshes, mi.instances, mi.embreeInstances,
                mi.materials, mi.textures, mi.cameras, mi.lights);
    if (mi.triangles)
      std::printf("    bounds (%g, %g, %g) to (%g, %g, %g)\n", mi.lower.x, mi.lower.y, mi.lower.z, mi.upper.x,
                  mi.upper.y, mi.upper.z);
  }
  if (world.volumes().empty()) skipped.push_back("no volumes: no grid, brick or iso-surface work is done");
  for (size_t v = 0; v < world.volumes().size(); ++v) {
    const VolumeInfo& vi = world.volumes()[v];
    const Grid& g = *vi.grid;
    std::printf("  volume %zu: %s (%s)\n    %dx%dx%d %s, %.2f MiB samples + %.2f MiB brick ranges; "
                "origin (%g, %g, %g), spacing (%g, %g, %g)%s\n",
                v, vi.name.c_str(), vi.format.c_str(), g.dims().x, g.dims().y, g.dims().z, scalarTypeName(g.type()),
                g.bytes() / 1048576.0, vi.bricks->bytes() / 1048576.0, g.origin().x, g.origin().y,
                g.origin().z, g.spacing().x, g.spacing().y, g.spacing().z,
                vi.transform.isIdentity() ? "" : ", transformed (Embree instance)");
    for (const std::string& note : vi.notes) std::printf("    %s\n", note.c_str());
    // Where the values lie, to choose iso values by: the range and a few quantiles.
    const std::vector<double> shares{0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99};
    const std::vector<double> q = g.quantiles(shares);
    std::printf("    values %g to %g; quantiles", double(vi.bricks->minValue()), double(vi.bricks->maxValue()));
    for (size_t i = 0; i < shares.size(); ++i) std::printf("%s %g%%: %.6g", i ? "," : "", shares[i] * 100, q[i]);
    std::printf("%s\n", g.type() == ScalarType::Float32 ? " (float32: within 1/65536 of the range)" : "");
    for (const SurfaceInfo& si : world.surfaces())
      if (si.volume == int(v))
        std::printf("    iso-surface %g: %zu of %zu bricks active (%.1f%%; %.1f MiB of tight boxes and cell classes), "
                    "material %s%s\n", si.iso, si.surface->activeBricks().size(), si.surface->totalBricks(),
                    100.0 * double(si.surface->activeBricks().size()) / double(std::max<size_t>(1, si.surface->totalBricks())),
                    si.surface->bytes() / 1048576.0, world.materials()[si.material].name.c_str(),
                    si.surface->activeBricks().empty() ? " (empty: not built)" : "");
  }
  std::printf("  materials in use: %zu\n", world.materials().size());
  const size_t shown = std::min<size_t>(world.materials().size(), 12);
  for (size_t i = 0; i < shown; ++i) {
    const Material& m = world.materials()[i];
    std::printf("    %s: %s%s\n", m.name.c_str(), materialTypeName(m.type), m.emits() ? ", emissive" : "");
  }
  if (shown < world.materials().size()) std::printf("    ... and %zu more\n", world.materials().size() - shown);
  std::printf("  textures decoded: %zu", world.textures().size());
  if (images > world.textures().size()) std::printf(" (images in glTF files: %zu; unused ones are not decoded)", images);
  std::printf("\n");
  std::map<std::string, int> lightCounts;
  size_t areaTriangles = 0;
  for (const Light& l : world.lights()) {
    ++lightCounts[lightKindName(l.kind())];
    areaTriangles += l.triangleCount();
  }
  std::printf("  lights: %zu%s\n", world.lights().size(), world.lights().empty() ? " (direct lighting sees none)" : "");
  for (const auto& [kind, count] : lightCounts)
    std::printf("    %d %s%s\n", count, kind.c_str(),
                kind.rfind("area", 0) == 0 ? (", " + std::to_string(areaTriangles) + " triangles").c_str() : "");
  if (world.environmentLights().empty()) skipped.push_back("no environment light: escaped rays are black");
  for (const std::string& line : skipped) std::printf("  skipped: %s\n", line.c_str());
  std::printf("  time: load %.2fs, build %.2fs\n", world.loadSeconds(), world.buildSeconds());
  return 0;
}

struct CheckFlags {
  std::string scene, intersector, json, offset;
  int rays = 100000, threads = 0;
  long long seed = 1;
};

Vec3d parseOffset(const std::string& text) {
  Vec3d v{0, 0, 0};
  if (text.empty()) return v;
  std::smatch m;
  static const std::regex three(R"(\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*)");
  try {
    if (!std::regex_match(text, m, three)) throw std::invalid_argument("format");
    v = {std::stod(m[1]), std::stod(m[2]), std::stod(m[3])};
  } catch (const std::exception&) {
    throw InputError("--offset", "", "expected X,Y,Z, e.g. 1e5,1e5,1e5, got '" + text + "'");
  }
  if (!isFinite(v)) throw InputError("--offset", "", "offset must be finite");
  return v;
}

void writeJsonFile(const std::string& path, const std::string& text) {
  const std::filesystem::path p(path);
  if (p.has_parent_path() && !std::filesystem::is_directory(p.parent_path()))
    throw InputError(path, "", "output directory does not exist");
  const std::string temp = temporaryBeside(path);
  FILE* f = std::fopen(temp.c_str(), "w");
  const bool ok = f && std::fputs(text.c_str(), f) >= 0;
  if (f && std::fclose(f) != 0) throw InputError(path, "", "cannot write");
  if (!ok || std::rename(temp.c_str(), path.c_str()) != 0) {
    std::remove(temp.c_str());
    throw InputError(path, "", "cannot write");
  }
}

int watertight(const CheckFlags& flags) {
  SceneDesc scene = parseSceneFile(flags.scene);
  IntersectorSpec spec = scene.settings.intersector;
  if (!flags.intersector.empty()) {
    std::string error;
    if (!parseIntersector(flags.intersector, spec, error)) throw InputError("--intersector", "", error);
  }
  if (flags.rays < 1) throw InputError("--rays", "", "must be at least 1");
  if (flags.seed < 0) throw InputError("--seed", "", "must be at least 0");
  if (scene.volumes.empty()) throw InputError(flags.scene, "/volumes", "the scene has no volume to check");
  WatertightOptions options;
  options.rays = flags.rays;
  options.seed = uint64_t(flags.seed);
  options.offset = parseOffset(flags.offset);
  options.threads = flags.threads;
  const auto start = std::chrono::steady_clock::now();
  const std::vector<WatertightReport> reports = checkWatertight(scene, spec, options);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("watertight %s: intersector %s, %d rays per test and iso-surface, seed %lld, offset (%g, %g, %g)\n",
              flags.scene.c_str(), intersectorName(spec).c_str(), flags.rays, flags.seed, options.offset.x,
              options.offset.y, options.offset.z);
  std::printf("%-7s %-10s %9s %10s %10s %14s %10s %15s %18s\n", "volume", "iso", "rays", "crossings", "reference",
              "parity_errors", "self_hits", "inside_escapes", "shadow_mismatches");
  WatertightCounts total;
  auto row = [](const char* v, const std::string& iso, const WatertightCounts& c) {
    std::printf("%-7s %-10s %9llu %10llu %10llu %14llu %10llu %15llu %18llu\n", v, iso.c_str(), (unsigned long long)c.rays,
                (unsigned long long)c.crossings, (unsigned long long)c.referenceCrossings,
                (unsigned long long)c.parityErrors, (unsigned long long)c.selfHits,
                (unsigned long long)c.insideEscapes, (unsigned long long)c.shadowMismatches);
  };
  auto counts = [](const WatertightCounts& c) {
    char buf[400];
    std::snprintf(buf, sizeof buf,
                  "\"rays\": %llu, \"crossings\": %llu, \"reference_crossings\": %llu, \"parity_errors\": %llu, "
                  "\"self_hits\": %llu, \"inside_escapes\": %llu, \"shadow_mismatches\": %llu",
                  (unsigned long long)c.rays, (unsigned long long)c.crossings,
                  (unsigned long long)c.referenceCrossings, (unsigned long long)c.parityErrors,
                  (unsigned long long)c.selfHits, (unsigned long long)c.insideEscapes,
                  (unsigned long long)c.shadowMismatches);
    return std::string(buf);
  };
  std::string surfaces;
  for (const WatertightReport& r : reports) {
    char iso[32];
    std::snprintf(iso, sizeof iso, "%g", r.iso);
    row(std::to_string(r.volume).c_str(), iso, r.counts);
    total.add(r.counts);
    char head[200];
    std::snprintf(head, sizeof head, "    {\"volume\": %d, \"iso\": %s, \"intersector\": %s, ", r.volume, jsonNumber(r.iso).c_str(),
                  jsonString(r.intersector).c_str());
    surfaces += (surfaces.empty() ? "" : ",\n") + std::string(head) + counts(r.counts) + "}";
  }
  row("total", "", total);
  std::printf("%.2f s; %llu errors\n", seconds, (unsigned long long)total.errors());
  if (!flags.json.empty())
    writeJsonFile(flags.json, "{\n  \"total\": {" + counts(total) + "},\n  \"surfaces\": [\n" + surfaces + "\n  ]\n}\n");
  return 0;
}

int bench(const CheckFlags& flags) {
  const SceneDesc scene = parseSceneFile(flags.scene);
  std::vector<IntersectorSpec> specs;
  const std::string list = flags.intersector.empty()
                               ? "linear,neubauer:1,neubauer:2,neubauer:3,neubauer:5,neubauer:8,schwarze,"
                                 "isolation:1,isolation:2,isolation:3,isolation:5,isolation:8,reference"
                               : flags.intersector;
  for (size_t start = 0; start <= list.size();) {
    const size_t comma = std::min(list.find(',', start), list.size());
    IntersectorSpec spec;
    std::string error;
    if (!parseIntersector(list.substr(start, comma - start), spec, error)) throw InputError("--intersector", "", error);
    specs.push_back(spec);
    start = comma + 1;
  }
  if (flags.rays < 1) throw InputError("--rays", "", "must be at least 1");
  if (scene.volumes.empty()) throw InputError(flags.scene, "/volumes", "the scene has no volume to measure");
  std::printf("bench %s: %d rays of each kind per iso-surface and intersector, single thread, seed %lld;\n"
              "error against `reference` in cell units (misses/false hits judged by each hit's own bound)\n",
              flags.scene.c_str(), flags.rays, flags.seed);
  std::printf("%-7s %-9s %-10s %-12s %8s %8s %8s %10s %10s %10s %8s\n", "volume", "iso", "rays", "intersector",
              "refHits", "misses", "false", "median|dt|", "p99|dt|", "max|dt|", "ns/ray");
  std::string rows;
  for (size_t v = 0; v < scene.volumes.size(); ++v) {
    const Grid grid = loadVolume(scene.volumes[v]).grid;
    for (const IsoSurfaceDesc& iso : scene.volumes[v].isosurfaces)
      for (RayKind kind : {RayKind::Camera, RayKind::Secondary})
        for (const IntersectorSpec& spec : specs) {
          const AccuracyReport r = measureAccuracy(grid, iso.value, spec, kind, flags.rays, uint64_t(flags.seed));
          const char* kindName = kind == RayKind::Camera ? "camera" : "secondary";
          std::printf("%-7zu %-9g %-10s %-12s %8llu %8llu %8llu %10.2e %10.2e %10.2e %8.0f\n", v, iso.value, kindName,
                      intersectorName(spec).c_str(), (unsigned long long)r.referenceHits,
                      (unsigned long long)r.misses, (unsigned long long)r.falseHits, r.medianDt, r.p99Dt, r.maxDt,
                      r.nsPerRay);
          std::fflush(stdout);
          char buf[600];
          std::snprintf(buf, sizeof buf,
                        "    {\"volume\": %zu, \"iso\": %s, \"rays\": %s, \"intersector\": %s, \"count\": %llu, "
                        "\"reference_hits\": %llu, \"tangent\": %llu, \"misses\": %llu, \"false_hits\": %llu, "
                        "\"miss_rate\": %.6g, \"false_hit_rate\": %.6g, \"median_dt\": %.6g, \"p99_dt\": %.6g, "
                        "\"max_dt\": %.6g, \"ns_per_ray\": %.2f}",
                        v, jsonNumber(iso.value).c_str(), jsonString(kindName).c_str(), jsonString(intersectorName(spec)).c_str(),
                        (unsigned long long)r.rays, (unsigned long long)r.referenceHits,
                        (unsigned long long)r.tangentOnly, (unsigned long long)r.misses,
                        (unsigned long long)r.falseHits, r.referenceHits ? double(r.misses) / r.referenceHits : 0.0,
                        r.rays ? double(r.falseHits) / r.rays : 0.0, r.medianDt, r.p99Dt, r.maxDt, r.nsPerRay);
          rows += (rows.empty() ? "" : ",\n") + std::string(buf);
        }
  }
  if (!flags.json.empty()) writeJsonFile(flags.json, "{\n  \"scene\": " + jsonString(flags.scene) + ",\n  \"results\": [\n" + rows + "\n  ]\n}\n");
  return 0;
}

struct MeshFlags {
  std::string scene, output;
  int volume = 0, surface = 0;
};

// `isotrace mesh`: one iso-surface as triangles in world space, with the surface's material.
int exportMesh(const MeshFlags& flags) {
  const SceneDesc scene = parseSceneFile(flags.scene);
  if (flags.output.empty()) throw InputError("-o", "", "an output file is needed (-o NAME.glb or NAME.gltf)");
  const std::string ext = std::filesystem::path(flags.output).extension().string();
  if (ext != ".glb" && ext != ".gltf") throw InputError(flags.output, "", "the mesh output must be .glb or .gltf");
  if (scene.volumes.empty()) throw InputError(flags.scene, "/volumes", "the scene has no volume");
  if (flags.volume < 0 || size_t(flags.volume) >= scene.volumes.size())
    throw InputError("--volume", "", "no volume " + std::to_string(flags.volume) + " (the scene has " +
                                         std::to_string(scene.volumes.size()) + ", counted from 0)");
  const VolumeDesc& desc = scene.volumes[flags.volume];
  if (flags.surface < 0 || size_t(flags.surface) >= desc.isosurfaces.size())
    throw InputError("--surface", "", "no iso-surface " + std::to_string(flags.surface) + " in " + desc.where +
                                          " (it has " + std::to_string(desc.isosurfaces.size()) + ", counted from 0)");
  const IsoSurfaceDesc& surface = desc.isosurfaces[flags.surface];
  const VolumeFile volume = loadVolume(desc);
  const Grid& grid = volume.grid;
  const Transform& toWorld = volume.toWorld;
  const IsoMesh mesh = extractIsoMesh(grid, surface.value);
  const std::string where = desc.where + "/isosurfaces/" + std::to_string(flags.surface);
  if (mesh.indices.empty()) {
    float lo, hi;
    grid.range(lo, hi);
    throw InputError(flags.scene, where + "/value",
                     "iso value " + jsonNumber(surface.value) + " gives no surface (the volume's values span " +
                         jsonNumber(lo) + " to " + jsonNumber(hi) + ")");
  }
  GltfMeshOut out;
  out.name = std::filesystem::path(flags.scene).stem().string() + where;
  // Grid coordinates -> the volume's space -> world; normals out of the solid.
  const Vec3d origin = grid.origin(), spacing = grid.spacing();
  const double side = surface.solidAbove ? -1 : 1;
  out.positions.reserve(mesh.positions.size());
  out.normals.reserve(mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    out.positions.push_back(Vec3f(toWorld.point(origin + mesh.positions[i] * spacing)));
    const Vec3d n = toWorld.normal(mesh.gradients[i] / spacing) * side;
    const double len = length(n);
    out.normals.push_back(len > 0 && std::isfinite(len) ? Vec3f(n / len) : Vec3f{0, 0, 1});
  }
  out.indices = mesh.indices;
  // The mesh is wound counter-clockwise seen from lower values; glTF's front is the solid's
  // outside, which is the higher side for a solid below the iso value; a mirroring transform
  // flips the winding once more.
  if (!surface.solidAbove != (toWorld.determinant() < 0))
    for (size_t t = 0; t < out.indices.size(); t += 3) std::swap(out.indices[t + 1], out.indices[t + 2]);
  if (!surface.material.empty()) {
    const MaterialDesc& m = scene.materials.at(surface.material);
    out.color = Vec3f(m.color);
    out.metallic = m.type == MaterialType::Conductor ? 1.f : float(m.metallic);
    out.roughness = float(m.roughness);
  } else if (surface.color) {
    out.color = Vec3f(*surface.color);
    out.roughness = 1;
  }
  saveGltfMesh(flags.output, out);
  std::printf("%s\n", flags.output.c_str());
  std::fprintf(stderr, "isotrace: %s iso %s: %zu triangles, %zu vertices\n", where.c_str(),
               jsonNumber(surface.value).c_str(), out.indices.size() / 3, out.positions.size());
  return 0;
}

}  // namespace

std::string versionText() {
  return std::string("isotrace ") + ISOTRACE_VERSION + "\nEmbree " + RTC_VERSION_STRING + ", OpenVDB " +
         openVdbVersion() + ", OpenImageIO " + OIIO_VERSION_STRING + ", oneTBB " + TBB_VERSION_STRING;
}

int runCommandLine(int argc, char** argv) {
  CLI::App app{"isotrace: a path tracer for glTF meshes and exact iso-surfaces of volume data"};
  app.require_subcommand(1);
  app.set_version_flag("--version", versionText(), "print the version of isotrace and of its libraries");
  // A first word that is no command and no option: say so, with the commands.
  const char* commands[] = {"render", "view", "info", "watertight", "bench", "mesh"};
  if (argc >= 2 && argv[1][0] != '-' &&
      std::none_of(std::begin(commands), std::end(commands), [&](const char* c) { return std::strcmp(argv[1], c) == 0; })) {
    std::fprintf(stderr, "isotrace: unknown command '%s' (commands: render, view, info, watertight, bench, mesh; see isotrace --help)\n", argv[1]);
    return 2;
  }
  RenderFlags flags;
  CLI::App* renderCmd = app.add_subcommand("render", "render a scene to an EXR or PNG image");
  renderCmd->add_option("scene", flags.scene, "scene file (JSON)")->required();
  renderCmd->add_option("-o,--output", flags.output, "output image, .exr (linear), .png or .jpg (sRGB); default <scene>.png");
  renderCmd->add_option("--spp", flags.spp, "samples per pixel")->check(CLI::Range(1, 1 << 20));
  renderCmd->add_option("--integrator", flags.integrator, std::string("integrator: ") + integratorList());
  renderCmd->add_option("--max-depth", flags.maxDepth, "longest path for direct/path/compare (1: direct light only)")
      ->check(CLI::Range(1, 1000));
  renderCmd->add_option("--aov", flags.aov, "extra EXR layers, comma-separated: albedo, normal, depth, variance, samples");
  renderCmd->add_option("--stats", flags.stats, "write times, ray counts and counters as JSON to this file");
  renderCmd->add_option("--intersector", flags.intersector, std::string("intersector: ") + intersectorList());
  renderCmd->add_option("--resolution", flags.resolution, "image size WIDTHxHEIGHT");
  renderCmd->add_option("--threads", flags.threads, "worker threads (0: all cores, at most 1024)")->check(CLI::Range(0, 1024));
  renderCmd->add_option("--seed", flags.seed, "random seed (0 to 2^62)")->check(CLI::Range(0LL, 1LL << 62));
  renderCmd->add_flag("--allow-large", flags.allowLarge, "allow images above 2^25 pixels (each side stays <= 16384)");
  renderCmd->add_flag("--quiet", flags.quiet, "print only the output path");
  renderCmd->add_option("--exposure", flags.exposure, "PNG/JPEG: scale radiance by 2^EV before tone mapping (default 0)");
  renderCmd->add_option("--tonemap", flags.tonemap, "PNG/JPEG: clamp (default), aces or filmic");
  renderCmd->add_flag("--alpha", flags.alpha, "transparent background: an alpha channel of coverage (PNG, EXR)");
  renderCmd->add_option("--clamp", flags.clamp, "clip each sample's indirect radiance to X (biased; 0: off, the default)");
  renderCmd->add_option("--adaptive", flags.adaptive, "stop pixels whose relative standard error is below T (e.g. 0.02)");
  renderCmd->add_option("--frames", flags.frames, "render a sequence of N frames, OUT.0000.png ... (with --iso-sweep and/or --orbit)")
      ->check(CLI::Range(1, 100000));
  renderCmd->add_option("--iso-sweep", flags.isoSweep, "SURFACE:FROM:TO: sweep iso-surface SURFACE (from 0, over all volumes) from FROM to TO over the frames");
  renderCmd->add_option("--orbit", flags.orbit, "turn the camera about its look-at point by DEGREES over the frames (360: a turntable)");
  std::string viewScene, viewResolution;
  ViewOptions viewOptions;
  CLI::App* viewCmd = app.add_subcommand("view", "explore a scene live in the browser: iso values, colours, integrator, camera");
  viewCmd->add_option("scene", viewScene, "scene file (JSON)")->required();
  viewCmd->add_option("--port", viewOptions.port, "port to listen on (default 8765; 0: any free port)")->check(CLI::Range(0, 65535));
  viewCmd->add_option("--host", viewOptions.host, "address to listen on (default 127.0.0.1: this machine only)");
  viewCmd->add_option("--resolution", viewResolution, "image size WIDTHxHEIGHT (default 480 wide, the scene's aspect)");
  viewCmd->add_option("--threads", viewOptions.threads, "worker threads (0: all cores, at most 1024)")->check(CLI::Range(0, 1024));
  std::string infoScene;
  CLI::App* infoCmd = app.add_subcommand("info", "what the scene holds and what will be built");
  infoCmd->add_option("scene", infoScene, "scene file (JSON)")->required();
  CheckFlags check, benchFlags;
  CLI::App* watertightCmd = app.add_subcommand("watertight", "count holes and double hits of every iso-surface under secondary rays");
  watertightCmd->add_option("scene", check.scene, "scene file (JSON)")->required();
  watertightCmd->add_option("--rays", check.rays, "rays per test and iso-surface (default 100000)")->check(CLI::Range(1, 1 << 30));
  watertightCmd->add_option("--intersector", check.intersector, std::string("intersector: ") + intersectorList());
  watertightCmd->add_option("--seed", check.seed, "random seed (default 1)")->check(CLI::Range(0LL, 1LL << 62));
  watertightCmd->add_option("--offset", check.offset, "move every volume by X,Y,Z (e.g. 1e5,1e5,1e5)");
  watertightCmd->add_option("--threads", check.threads, "worker threads (0: all cores, at most 1024)")->check(CLI::Range(0, 1024));
  watertightCmd->add_option("--json", check.json, "write the counts as JSON");
  CLI::App* benchCmd = app.add_subcommand("bench", "time per ray against error versus `reference`, per intersector");
  benchCmd->add_option("scene", benchFlags.scene, "scene file (JSON)")->required();
  benchFlags.rays = 20000;
  benchCmd->add_option("--intersector", benchFlags.intersector, "comma-separated intersectors (default: all, with 1-8 iterations)");
  benchCmd->add_option("--rays", benchFlags.rays, "rays of each kind per iso-surface and intersector (default 20000)")
      ->check(CLI::Range(1, 1 << 26));
  benchCmd->add_option("--seed", benchFlags.seed, "random seed (default 1)")->check(CLI::Range(0LL, 1LL << 62));
  benchCmd->add_option("--json", benchFlags.json, "write the results as JSON");
  MeshFlags meshFlags;
  CLI::App* meshCmd = app.add_subcommand("mesh", "write one iso-surface as a triangle mesh (glTF, world space)");
  meshCmd->add_option("scene", meshFlags.scene, "scene file (JSON)")->required();
  meshCmd->add_option("-o,--output", meshFlags.output, "output mesh, .glb or .gltf")->required();
  meshCmd->add_option("--volume", meshFlags.volume, "volume index in the scene, from 0 (default 0)");
  meshCmd->add_option("--surface", meshFlags.surface, "iso-surface index in that volume, from 0 (default 0)");
  for (CLI::App* sub : {renderCmd, viewCmd, infoCmd, watertightCmd, benchCmd, meshCmd}) sub->allow_extras();
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "isotrace: %s (see isotrace --help)\n", e.what());
    return 2;
  }
  // Arguments no option takes, in the order given (CLI11's own message lists them backwards).
  for (CLI::App* sub : app.get_subcommands()) {
    const std::vector<std::string> extra = sub->remaining();
    if (extra.empty()) continue;
    std::string list;
    for (const std::string& e : extra) list += (list.empty() ? "" : " ") + e;
    std::fprintf(stderr, "isotrace %s: unexpected argument%s '%s' (see isotrace %s --help)\n", sub->get_name().c_str(),
                 extra.size() > 1 ? "s" : "", list.c_str(), sub->get_name().c_str());
    return 2;
  }
  try {
    if (*renderCmd) return render(flags);
    if (*viewCmd) {
      if (!viewResolution.empty()) {
        parseResolution(viewResolution, viewOptions.width, viewOptions.height);
        if (double(viewOptions.width) * viewOptions.height > double(1 << 22))
          throw InputError("--resolution", "", "a live view holds at most 2^22 pixels (e.g. 2048x2048)");
      }
      return runView(viewScene, viewOptions);
    }
    if (*infoCmd) return info(infoScene);
    if (*watertightCmd) return watertight(check);
    if (*benchCmd) return bench(benchFlags);
    if (*meshCmd) return exportMesh(meshFlags);
  } catch (const InputError& e) {
    std::fprintf(stderr, "isotrace: %s\n", e.what());
    return 2;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "isotrace: out of memory\n");
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "isotrace: internal error: %s\n", e.what());
    return 1;
  }
  return 1;
}

}  // namespace iso
