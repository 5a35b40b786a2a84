// `isotrace render`: a scene to an image (or a sequence, or the direct/global/indirect
// triple of `compare`), on threads, or on MPI ranks by tiles or frames.
#include <CLI/CLI.hpp>
#include <signal.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <regex>
#include <sstream>

#include "renderer/commands.h"
#include "renderer/distributed.h"
#include "renderer/render.h"
#include "renderer/sequence.h"
#include "renderer/video.h"
#include "scene/image_plugin.h"
#include "scene/time_series.h"
#include "volume/input_error.h"

namespace iso {
namespace {

struct RenderFlags {
  std::string scene, output, integrator, intersector, rayFlow, resolution, aov, stats, tonemap, isoSweep, denoise;
  bool denoiseGiven = false;
  int spp = 0, threads = -1, maxDepth = 0, frames = 0;  // frames 0: not given
  std::optional<double> orbit;
  long long seed = -1;
  bool quiet = false, alpha = false, allowLarge = false, colorbar = false, dataParallel = false, keepFrames = false;
  std::optional<double> fps;
  std::optional<double> exposure, clamp, adaptive, replicate;
  SceneOverrides overrides;
};

std::string fixed2(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.2f", v);
  return b;
}

// --exposure and --tonemap, checked; a warning when the output is EXR (which stays linear).
DisplaySettings displayFlags(const RenderFlags& f, const std::string& output) {
  DisplaySettings d;
  const ImageFormat format = isVideoName(output) ? ImageFormat::Png : imageFormatFor(output);  // (a video's frames show as PNG)
  if (f.exposure) {
    if (!(*f.exposure >= -30 && *f.exposure <= 30)) throw InputError("--exposure", "", "expected EV in [-30, 30]");
    d.exposure = *f.exposure;
  }
  if (!f.tonemap.empty() && !parseTonemap(f.tonemap, d.tonemap))
    throw InputError("--tonemap", "", "unknown curve '" + f.tonemap + "' (known: clamp, aces, filmic)");
  if (format == ImageFormat::Exr && (f.exposure || !f.tonemap.empty()))
    std::fprintf(stderr, "isotrace: warning: --exposure and --tonemap shape PNG and JPEG output; %s stays linear\n",
                 output.c_str());
  if (f.alpha && isVideoName(output)) throw InputError("--alpha", "", "a video has no alpha channel: write .png or .exr images");
  if (f.alpha && format == ImageFormat::Jpeg)
    throw InputError("--alpha", "", "JPEG has no alpha channel: write .png or .exr");
  if (f.colorbar) {
    if (format == ImageFormat::Exr)
      std::fprintf(stderr, "isotrace: warning: --colorbar draws under PNG and JPEG images; %s stays data\n", output.c_str());
    d.font = legendFont();
    if (d.font.empty())
      throw InputError("--colorbar", "", "no font for the legend's text (DejaVu Sans: install fonts-dejavu-core; scripts/setup.sh does)");
  }
  // JPEG and the legends' text are written through the image plugin: loaded now, so that an
  // installation without it stops before the render, not after it.
  if (format == ImageFormat::Jpeg || (f.colorbar && format != ImageFormat::Exr)) imagePlugin();
  return d;
}

// --colorbar: one legend per distinct map of the scene ("color_by" surfaces, slices), with the
// ranges the World resolved (a slice's default range is its volume's values).
std::vector<Legend> legendsOf(const World& world, const SceneDesc& scene) {
  std::vector<Legend> legends;
  auto add = [&](const std::string& title, const ColorMap& map, double lo, double hi) {
    for (const Legend& l : legends)
      if (l.title == title && l.map.name() == map.name() && l.lo == lo && l.hi == hi) return;
    legends.push_back({title, map, lo, hi});
  };
  for (const SurfaceInfo& s : world.surfaces()) {
    if (s.colorBy) add(s.colorBy->fieldName, s.colorBy->map, s.colorBy->lo, s.colorBy->hi);
    // (Caps are drawn only where a clip cuts the surface.)
    if (s.capColorBy && !s.surface->clip().empty())
      add(s.capColorBy->fieldName, s.capColorBy->map, s.capColorBy->lo, s.capColorBy->hi);
  }
  for (const SliceInfo& s : world.slices()) {
    const VolumeDesc& v = scene.volumes[size_t(s.volume)];
    add(!v.name.empty() ? v.name : v.field ? "procedural field" : std::filesystem::path(v.file).filename().string(), s.map,
        s.lo, s.hi);
  }
  return legends;
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
  if (!f.rayFlow.empty() && !parseRayFlow(f.rayFlow, s.rayFlow))
    throw InputError("--ray-flow", "", "unknown ray flow '" + f.rayFlow + "' (known: wavefront, scalar)");
  if (!f.resolution.empty()) parseResolution(f.resolution, s.width, s.height);
  // The film costs ~170 bytes per pixel while rendering (the sums of every layer, in double).
  if (double(s.width) * s.height > double(kMaxFilmPixels) && !f.allowLarge)
    throw InputError(f.resolution.empty() ? scene.path : "--resolution", f.resolution.empty() ? "/film" : "",
                     std::to_string(s.width) + "x" + std::to_string(s.height) + " is more than " +
                         std::to_string(kMaxFilmPixels) + " pixels (~" +
                         std::to_string(kMaxFilmPixels * 170 >> 30) + " GiB to render); --allow-large renders it anyway");
  if (f.dataParallel) s.dataParallel = true;
  if (f.replicate) {
    if (!(*f.replicate >= 0 && *f.replicate <= 1)) throw InputError("--replicate", "", "expected a fraction of the volume in [0, 1]");
    s.replicate = *f.replicate;
  }
  if (s.replicate > 0 && !s.dataParallel)
    throw InputError(f.replicate ? "--replicate" : scene.path, f.replicate ? "" : "/integrator/replicate",
                     "copies of other ranks' bricks are for data-parallel rendering (--data-parallel or \"distribution\": \"data\")");
  if (f.denoiseGiven) {
    const std::string mode = f.denoise.empty() ? "quality" : f.denoise;
    if (!parseDenoiseMode(mode, s.denoise))
      throw InputError("--denoise", "", "unknown mode '" + mode + "' (known: " + denoiseModeList() + ")");
  }
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
  if (isVideoName(output) || imageFormatFor(output) != ImageFormat::Exr)
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

// Under MPI, rendering by tiles: tiles and busy seconds per rank (summed over the frames), and
// busiest over idlest rank; the tiles each rank handed to others (taken by ranks that ran out,
// or dealt again between data-parallel passes).
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
  std::string dataParallel;
  if (!f->raysAsked.empty()) {
    auto list = [](const std::vector<double>& v) {
      std::string s;
      for (size_t r = 0; r < v.size(); ++r) s += (r ? ", " : "") + jsonNumber(v[r]);
      return "[" + s + "]";
    };
    dataParallel = "  \"rays_asked_per_rank\": " + list(f->raysAsked) + ",\n  \"rays_sent_per_rank\": " +
                   list(f->raysSent) + ",\n  \"rays_received_per_rank\": " + list(f->raysReceived) +
                   ",\n  \"bytes_sent_per_rank\": " +
                   list(f->bytesSent) + ",\n  \"exchange_seconds_per_rank\": " + list(f->waitSeconds) + ",\n";
  }
  if (!f->tilesMoved.empty()) {
    std::string moved;
    for (size_t r = 0; r < f->tilesMoved.size(); ++r) moved += (r ? ", " : "") + std::to_string(f->tilesMoved[r]);
    dataParallel += "  \"tiles_moved_per_rank\": [" + moved + "],\n";
  }
  return "  \"tiles_per_rank\": [" + tiles + "],\n  \"busy_seconds_per_rank\": [" + busy + "],\n  \"balance\": " +
         jsonNumber(least > 0 ? most / least : 0) + ",\n" + dataParallel;
}

}  // namespace

std::string statsJson(const SceneDesc& scene, double loadSeconds, double buildSeconds, const RenderResult& r, int frames,
                      int threads, double totalSeconds, int ranks, const RankFigures* perRank) {
  const RenderSettings& s = scene.settings;
  const RayCounters& c = r.counters;
  const uint64_t rays = c.camera + c.shadow + c.indirect;
  std::string overrides = "[";
  for (const std::string& o : scene.overrides) overrides += (overrides.size() > 1 ? ", " : "") + jsonString(o);
  overrides += "]";
  const std::string ranksText = rankFigures(perRank);
  std::vector<char> text(4096 + scene.path.size() + overrides.size() + ranksText.size() + s.integrator.size());
  std::snprintf(text.data(), text.size(),
               "{\n  \"scene\": %s,\n  \"width\": %d,\n  \"height\": %d,\n  \"spp\": %d,\n  \"spp_requested\": %d,\n"
               "  \"spp_mean\": %.4f,\n  \"spp_max\": %d,\n  \"noise_threshold\": %s,\n  \"clamp\": %s,\n"
               "  \"interrupted\": %s,\n  \"threads\": %d,\n  \"integrator\": %s,\n  \"intersector\": %s,\n  \"ray_flow\": %s,\n"
               "  \"overrides\": %s,\n  \"max_depth\": %d,\n  \"frames\": %d,\n  \"ranks\": %d,\n  \"distribution\": \"%s\",\n%s"
               "  \"denoise\": %s,\n"
               "  \"seconds\": {\"load\": %.6f, \"build\": %.6f, \"render\": %.6f, \"denoise\": %.6f, \"total\": %.6f},\n"
               "  \"rays\": {\"camera\": %llu, \"shadow\": %llu, \"indirect\": %llu, \"total\": %llu},\n"
               "  \"rays_per_second\": %.1f,\n"
               "  \"counters\": {\"Iso/CellsVisited\": %llu, \"Iso/CellsSolved\": %llu, \"Iso/RootsRefined\": %llu,\n"
               "    \"Packet/BrickQueries\": %llu, \"Packet/Lanes\": %llu, \"Packet/LockstepSteps\": %llu,"
               " \"Packet/SolveSteps\": %llu, \"Packet/SolveLanes\": %llu}\n}\n",
               jsonString(scene.path).c_str(), s.width, s.height, r.minSamples, s.spp, r.meanSamples, r.maxSamples,
               jsonNumber(s.noiseThreshold).c_str(), jsonNumber(s.clampIndirect).c_str(), r.interrupted ? "true" : "false",
               threads, jsonString(s.integrator).c_str(), jsonString(intersectorName(s.intersector)).c_str(),
               jsonString(rayFlowName(s.rayFlow)).c_str(), overrides.c_str(), s.maxDepth, frames, ranks, s.dataParallel ? "data" : "image", ranksText.c_str(), jsonString(denoiseModeName(r.denoised ? s.denoise : DenoiseMode::Off)).c_str(), loadSeconds, buildSeconds, r.seconds, r.denoiseSeconds, totalSeconds, (unsigned long long)c.camera,
               (unsigned long long)c.shadow, (unsigned long long)c.indirect, (unsigned long long)rays,
               r.seconds > 0 ? rays / r.seconds : 0.0, (unsigned long long)c.traversal.cellsVisited,
               (unsigned long long)c.traversal.cellsSolved, (unsigned long long)c.traversal.rootsRefined,
               (unsigned long long)c.traversal.packetQueries, (unsigned long long)c.traversal.packetLanes,
               (unsigned long long)c.traversal.lockstepSteps, (unsigned long long)c.traversal.solveSteps,
               (unsigned long long)c.traversal.solveLanes);
  return text.data();
}

namespace {

void writeStats(const std::string& path, const SceneDesc& scene, double loadSeconds, double buildSeconds,
                const RenderResult& r, int frames, int threads, double totalSeconds, int ranks,
                const RankFigures* perRank) {
  writeJsonFile(path, statsJson(scene, loadSeconds, buildSeconds, r, frames, threads, totalSeconds, ranks, perRank));
}

// OUT.png -> OUT.0007.png for frame 7 of a sequence (at least 4 digits, more for longer ones).
std::string frameName(const FrameSequence& seq, const std::string& output, int f) {
  if (seq.frames == 1) return output;
  const int digits = std::max<int>(4, int(std::to_string(seq.frames - 1).size()));
  std::string number = std::to_string(f);
  return withSuffix(output, std::string(size_t(digits) - number.size(), '0') + number);
}

// Loads the scene and checks every flag and output before any work: the part of a render
// that every rank of an MPI job does alike.
struct RenderSetup {
  SceneDesc scene;
  FrameSequence seq;
  std::string output;
  bool video = false;       // output is a video (.mp4, .webm): frames go to ffmpeg
  std::string frameImages;  // a video's numbered PNG frames too (--keep-frames): their base name; else empty
  double fps = 24;
  DisplaySettings display;
  RenderOptions options;
};

RenderSetup prepareRender(const RenderFlags& flags) {
  RenderSetup r;
  r.scene = parseSceneFile(flags.scene, flags.overrides);
  applyFlags(flags, r.scene);
  SequenceRequest request;
  if (flags.frames > 0) request.frames = flags.frames;
  request.isoSweep = flags.isoSweep;
  request.orbit = flags.orbit;
  r.seq = frameSequence(request, r.scene);
  if (r.scene.settings.dataParallel) checkDataParallel(r.scene);
  r.output = flags.output.empty() ? std::filesystem::path(flags.scene).stem().string() + ".png" : flags.output;
  std::error_code ec;
  if (std::filesystem::is_directory(r.output, ec)) throw InputError(r.output, "", "is a directory; name the output file");
  r.display = displayFlags(flags, r.output);  // bad names and values before any work
  if (flags.colorbar) {
    bool coloured = false;
    for (const VolumeDesc& v : r.scene.volumes) {
      coloured = coloured || !v.slices.empty();
      for (const IsoSurfaceDesc& iso : v.isosurfaces) coloured = coloured || iso.colorBy || iso.capColorBy;
    }
    if (!coloured) throw InputError("--colorbar", "", "the scene colours nothing by data (no \"color_by\", \"cap_color_by\" or slice)");
  }
  const RenderSettings& s = r.scene.settings;
  r.options = renderOptions(s);
  r.options.aovs = parseAovs(flags.aov, r.output);
  r.options.alpha = flags.alpha;
  r.options.progress = !flags.quiet && isatty(2);
  r.video = isVideoName(r.output);
  if (flags.fps && !r.video) throw InputError("--fps", "", "sets a video's frame rate: give -o NAME.mp4 or NAME.webm");
  if (flags.keepFrames && !r.video)
    throw InputError("--keep-frames", "", "keeps a video's frames as images: give -o NAME.mp4 or NAME.webm");
  if (flags.fps) {
    if (!(*flags.fps >= 1 && *flags.fps <= 240)) throw InputError("--fps", "", "expected frames per second in [1, 240]");
    r.fps = *flags.fps;
  }
  if (r.video) findFfmpeg("-o");  // before any work
  if (flags.keepFrames) r.frameImages = std::filesystem::path(r.output).replace_extension(".png").string();
  auto checkNames = [&](const std::string& name) {
    if (s.integrator == "compare") {
      for (const char* part : {"direct", "global", "indirect"}) checkWritable(withSuffix(name, part));
    } else {
      checkWritable(name);
    }
  };
  if (r.video) checkNames(r.output);
  if (!r.video || flags.keepFrames)
    for (int f : {0, r.seq.frames - 1})  // the first and last names: the same folder, other digits
      checkNames(frameName(r.seq, r.video ? r.frameImages : r.output, f));
  if (!flags.stats.empty()) checkWritable(flags.stats);
  if (s.denoise != DenoiseMode::Off && integratorDenoises(s.integrator)) {
    // The sums, the denoiser's input and its working planes are all held at once: said before
    // any work if this machine has not that much free.
    const double pixels = double(s.width) * s.height;
    const double need = pixels * double(sizeof(PixelSums) + denoiseInputBytesPerPixel(s.integrator == "compare") +
                                        denoiseBytesPerPixel(s.denoise));
    const uint64_t free = availableMemoryBytes();
    if (free > 0 && need > double(free)) {
      char text[200];
      std::snprintf(text, sizeof text, "denoising a %dx%d image needs about %.1f GiB while rendering, and this machine "
                    "has %.1f GiB free; render smaller or without --denoise", s.width, s.height, need / double(1 << 30),
                    double(free) / double(1 << 30));
      throw InputError(flags.denoiseGiven ? "--denoise" : r.scene.path, flags.denoiseGiven ? "" : "/film/denoise", text);
    }
  }
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
  const bool exrOutput = !setup.video && imageFormatFor(output) == ImageFormat::Exr;
  // A video per image a frame makes (compare: direct, global, indirect), started at the first frame.
  std::map<std::string, std::unique_ptr<VideoWriter>> videos;
  DisplaySettings display = setup.display;
  RenderOptions options = setup.options;
  options.progress = options.progress && job.rank() == 0;
  RenderResult total;
  RankFigures figures, frameFigures;  // all frames', the last frame's
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
    if (flags.colorbar) display.legends = legendsOf(*world, scene);
    warned = true;
    const double degrees = seq.degrees(frame);
    Camera camera(seq.camera(world->camera(), frame), s.width, s.height);
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
    options.sequenceFrame = frame;
    options.sequenceFrames = seq.frames;
    options.sequenceStart = start;
    DenoiseInput denoiseInput;
    const bool denoising = s.denoise != DenoiseMode::Off && integratorDenoises(s.integrator);
    options.denoiseInput = denoising ? &denoiseInput : nullptr;
    options.kept = keptSums(options, integrator->splitsDirect());
    RenderResult result =
        !byTiles ? renderFrame(camera, *integrator, options, film, direct.get())
        : s.dataParallel ? renderFrameDataParallel(job, camera, *integrator, options, film, direct.get(), &frameFigures)
                         : renderFrameDistributed(job, camera, *integrator, options, film, direct.get(), &frameFigures);
    figures.add(frameFigures);
    if (byTiles && job.rank() != 0) {  // rank 0 writes the image
      if (result.interrupted) return 130;
      continue;
    }
    // Denoised once, on the whole image (under MPI on rank 0 after the gather: the same bits as
    // one process).
    Film indirect(0, 0);
    if (denoising) {
      const DenoiseReport report = denoiseFrame(denoiseInput, s.denoise, s.threads,
                                                exrOutput, film, direct.get(),
                                                &indirect, result);
      if (report.nonFinitePixels > 0 && !flags.quiet)
        std::fprintf(stderr, "isotrace: warning: %llu pixels had samples that are not finite (NaN or infinity); "
                     "the denoiser left them out and filled them from their neighbours\n",
                     (unsigned long long)report.nonFinitePixels);
    }
    std::map<std::string, std::string> metadata = {
        {"Software", "isotrace"},
        {"isotrace:spp", std::to_string(result.minSamples)},
        {"isotrace:spp_requested", std::to_string(s.spp)},
        {"isotrace:integrator", s.integrator},
        {"isotrace:max_depth", std::to_string(s.maxDepth)},
        {"isotrace:intersector", intersectorName(s.intersector)},
        {"isotrace:ray_flow", rayFlowName(s.rayFlow)},
        {"isotrace:seed", std::to_string(s.seed)}};
    if (s.noiseThreshold > 0) {
      metadata["isotrace:noise_threshold"] = jsonNumber(s.noiseThreshold);
      metadata["isotrace:spp_mean"] = jsonNumber(result.meanSamples);
      metadata["isotrace:spp_max"] = std::to_string(result.maxSamples);
    }
    if (s.clampIndirect > 0) metadata["isotrace:clamp"] = jsonNumber(s.clampIndirect);
    if (result.denoised) metadata["isotrace:denoise"] = denoiseModeName(s.denoise);
    if (!scene.overrides.empty()) {  // --iso / --set, as applied: one POINTER=VALUE per line
      std::string text;
      for (const std::string& o : scene.overrides) text += (text.empty() ? "" : "\n") + o;
      metadata["isotrace:overrides"] = text;
    }
    if (result.interrupted) metadata["isotrace:interrupted"] = "1";
    if (seq.frames > 1) {
      metadata["isotrace:frame"] = std::to_string(frame) + "/" + std::to_string(seq.frames);
      if (seq.surface >= 0) metadata["isotrace:iso_value"] = jsonNumber(seq.isoValue(frame));
      if (seq.orbit != 0) metadata["isotrace:orbit_degrees"] = jsonNumber(degrees);
      if (seq.steps > 1) metadata["isotrace:time_step"] = std::to_string(timeStepOfFrame(frame, seq.frames, seq.steps));
    }
    if (!exrOutput) {
      metadata["isotrace:exposure"] = jsonNumber(display.exposure);
      metadata["isotrace:tonemap"] = tonemapName(display.tonemap);
    }
    const std::string frameOutput = frameName(seq, setup.video ? setup.frameImages : output, frame);
    std::vector<std::string> written;
    // One image of the frame (`part`: "" or compare's direct, global, indirect): a numbered
    // image, or the next frame of its video (and a numbered PNG with --keep-frames).
    auto emit = [&](const std::string& part, const Film& image, bool signedData) {
      if (setup.video) {
        std::unique_ptr<VideoWriter>& v = videos[part];
        const std::vector<uint8_t> rgb = displayFrame(image, signedData, display);
        if (!v) v = std::make_unique<VideoWriter>(part.empty() ? output : withSuffix(output, part), image.width(),
                                                  int(rgb.size() / (size_t(image.width()) * 3)), setup.fps);
        v->add(rgb);
        if (setup.frameImages.empty()) return;
      }
      const std::string name = part.empty() ? frameOutput : withSuffix(frameOutput, part);
      writeImage(name, image, signedData, metadata, display);
      written.push_back(name);
    };
    if (direct) {
      // global = everything, direct = paths of depth 1, indirect = global - direct (denoised:
      // direct and indirect apart, global their sum).
      if (!result.denoised) indirect = indirectOf(film, *direct);
      direct->alpha() = indirect.alpha() = film.alpha();
      emit("direct", *direct, false);
      emit("global", film, false);
      emit("indirect", indirect, false);
      const double ld = direct->meanLuminance(), lg = film.meanLuminance(), li = indirect.meanLuminance();
      std::fprintf(stderr, "isotrace: compare: mean luminance direct %.6g, global %.6g, indirect %.6g; "
                   "%.1f%% of the light is indirect\n", ld, lg, li, lg > 0 ? 100 * li / lg : 0.0);
    } else {
      emit("", film, integrator->signedOutput());
    }
    for (const std::string& path : written) std::printf("%s\n", path.c_str());
    std::fflush(stdout);
    total.counters.add(result.counters);
    total.seconds += result.seconds;
    total.denoiseSeconds += result.denoiseSeconds;
    total.denoised = total.denoised || result.denoised;
    total.minSamples = framesDone == 0 ? result.minSamples : std::min(total.minSamples, result.minSamples);
    total.maxSamples = std::max(total.maxSamples, result.maxSamples);
    total.meanSamples += result.meanSamples;  // averaged over the frames below
    total.interrupted = result.interrupted;
    ++framesDone;
    if (result.interrupted) break;
  }
  // The videos end with the frames done (an interrupted sequence's too).
  for (const char* part : {"", "direct", "global", "indirect"})
    if (auto it = videos.find(part); it != videos.end()) {
      it->second->finish();
      std::printf("%s\n", (*part ? withSuffix(output, part) : output).c_str());
      std::fflush(stdout);
    }
  if (byTiles && job.rank() != 0) return 0;  // (every frame done: rank 0 reports)
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
                 "isotrace: %dx%d%s, %s spp, %s, %s, %s flow, %d threads%s: load %.2fs, build %.2fs, render %.2fs%s, total %.2fs\n"
                 "isotrace: rays: %llu camera, %llu shadow, %llu indirect; %.2f Mrays/s; "
                 "iso-surface cells visited %llu, solved %llu, roots refined %llu\n",
                 s.width, s.height, frameSummary.c_str(), sppSummary.c_str(), s.integrator.c_str(),
                 intersectorName(s.intersector).c_str(), rayFlowName(s.rayFlow), threads,
                 job.distributed() ? (" x " + std::to_string(job.size()) + " ranks").c_str() : "", loadSeconds, buildSeconds, total.seconds,
                 total.denoised ? (", denoise (" + std::string(denoiseModeName(s.denoise)) + ") " + fixed2(total.denoiseSeconds) + "s").c_str() : "", seconds,
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
  // on rank f mod N, which writes it), except a data-parallel one: every frame over all ranks
  // (each holds only its part of the volumes), rank 0 writing each.
  RenderSetup setup;
  bool byTiles = false;  // set once the scene is read (a scene file may ask for data-parallel)
  auto mine = [&](int frame) { return byTiles || frame % job.size() == job.rank(); };
  std::unique_ptr<World> world;
  int worldFrame = -1;
  double loadSeconds = 0, buildSeconds = 0;
  // A data-parallel rank holds part of the volumes: the framing and the lights' power are the
  // whole scene's, the union of the ranks' bounds (bit for bit the single process's). Collective.
  auto shareSceneBounds = [&] {
    Vec3d lower = world->lower(), upper = world->upper();
    job.unionOfBounds(lower, upper);
    world->setSceneBounds(setup.scene, lower, upper);
  };
  // A time series' next step is read on a second thread while a frame renders (one process, or
  // one rank of an image-parallel job): at most the current and the next step are held.
  TimeStepsAhead ahead;
  std::vector<VolumeShape> firstShapes;  // each volume's at the first frame: a series' steps must agree
  auto nextFrame = [&](int frame) {
    for (int f = frame + 1; f < setup.seq.frames; ++f)
      if (mine(f)) return f;
    return -1;
  };
  auto buildWorld = [&](int frame) {
    SceneDesc& scene = setup.scene;
    const FrameSequence& seq = setup.seq;
    // A new iso value or time step is a new World (its bricks and BVH); a camera move is not.
    if (!seq.apply(scene, frame) && world) return;
    // Volumes whose step has not changed stay loaded from the previous frame's World. Not so for a
    // data-parallel rank: its part of a volume is balanced by the bricks the iso values make
    // active, so each frame has its own parts (read again).
    const bool dataParallel = scene.settings.dataParallel && job.distributed();
    const bool first = !world;  // (the first World's bounds are shared once every rank has loaded, below)
    world = std::make_unique<World>(scene, scene.settings.intersector, dataParallel ? nullptr : world.get(), ahead.loader());
    worldFrame = frame;
    loadSeconds += world->loadSeconds();
    buildSeconds += world->buildSeconds();
    for (size_t v = 0; v < scene.volumes.size(); ++v) {
      const Grid& grid = *world->volumes()[v].grid;
      if (first) firstShapes.push_back({grid.dims(), grid.type()});
      else if (scene.volumes[v].time.varying()) checkSameShape(scene, scene.volumes[v], firstShapes[v], grid);
    }
    if (dataParallel && !first) shareSceneBounds();  // (every rank builds every frame's World)
    if (const int next = nextFrame(frame); next >= 0 && !dataParallel) ahead.startFrame(seq, scene, next);
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
      // (A video is written by rank 0 in order: each of its frames over all ranks, by tiles.)
      byTiles = setup.seq.frames == 1 || setup.scene.settings.dataParallel || setup.video;
      if (setup.scene.settings.dataParallel) setup.scene.dataPart = DataPart{job.rank(), job.size()};
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
    // Every rank must render the same frames (an MPMD launch may give ranks other scenes or
    // flags): tiles and samples of different frames would be gathered into a wrong image.
    const RenderSettings& s = setup.scene.settings;
    char settings[256];
    std::snprintf(settings, sizeof settings,
                  "%dx%d, %d spp, seed %llu, %s, depth %d, ao distance %.17g, clamp %.17g, noise threshold %.17g, %d "
                  "frame(s)%s%s",
                  s.width, s.height, s.spp, (unsigned long long)s.seed, s.integrator.c_str(), s.maxDepth, s.aoDistance,
                  s.clampIndirect, s.noiseThreshold, setup.seq.frames, s.dataParallel ? ", data-parallel" : "",
                  setup.video ? ", video" : "");
    if (!job.sameOnEveryRank(std::hash<std::string>()(settings))) {
      if (job.rank() == 0)
        std::fprintf(stderr,
                     "isotrace: the ranks were given different render settings (rank 0: %s): every rank must render "
                     "the same frames\n",
                     settings);
      return 2;
    }
    if (setup.scene.settings.dataParallel && world) {
      try {
        shareSceneBounds();
      } catch (const InputError& e) {
        error = e.what();
      }
      error = job.firstError(error);
      if (!error.empty()) {
        if (job.rank() == 0) std::fprintf(stderr, "isotrace: %s\n", error.c_str());
        return 2;
      }
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

}  // namespace

Command addRenderCommand(CLI::App& app) {
  auto flags = std::make_shared<RenderFlags>();
  RenderFlags& f = *flags;
  CLI::App* cmd = app.add_subcommand("render", "render a scene to an EXR or PNG image");
  cmd->add_option("scene", f.scene, "scene file (JSON)")->required();
  cmd->add_option("-o,--output", f.output, "output image, .exr (linear), .png or .jpg (sRGB), or a sequence's video, .mp4 "
                                           "(H.264) or .webm (VP9), through the ffmpeg program; default <scene>.png");
  cmd->add_option("--spp", f.spp, "samples per pixel")->check(CLI::Range(1, 1 << 20));
  cmd->add_option("--integrator", f.integrator, std::string("integrator: ") + integratorList());
  cmd->add_option("--max-depth", f.maxDepth, "longest path for direct/path/compare (1: direct light only)")
      ->check(CLI::Range(1, 1000));
  cmd->add_option("--aov", f.aov, "extra EXR layers, comma-separated: albedo, normal, depth, variance, samples");
  cmd->add_option("--stats", f.stats, "write times, ray counts and counters as JSON to this file");
  cmd->add_option("--intersector", f.intersector, std::string("intersector: ") + intersectorList());
  cmd->add_flag("--data-parallel", f.dataParallel,
                "under mpirun: each rank holds only its part of each volume and the ranks answer each other's rays "
                "(\"distribution\": \"data\"; docs/distributed.md); the same image as one process");
  cmd->add_option("--replicate", f.replicate,
                  "with --data-parallel: each rank also holds copies of the bricks around its part, up to this fraction of each "
                  "volume (0 to 1, default 0), and asks other ranks only about rays that leave them (\"replicate\")");
  cmd->add_option("--ray-flow", f.rayFlow, "wavefront (default: paths in flight, rays traced in packets) or scalar (one ray at a time, the reference); the same image");
  cmd->add_option("--resolution", f.resolution, "image size WIDTHxHEIGHT");
  cmd->add_option("--threads", f.threads, "worker threads (0: all cores, at most 1024)")->check(CLI::Range(0, 1024));
  cmd->add_option("--seed", f.seed, "random seed (0 to 2^62)")->check(CLI::Range(0LL, 1LL << 62));
  cmd->add_flag("--allow-large", f.allowLarge, "allow images above 2^25 pixels (each side stays <= 16384)");
  cmd->add_flag("--quiet", f.quiet, "print only the output path");
  cmd->add_option("--exposure", f.exposure, "PNG/JPEG: scale radiance by 2^EV before tone mapping (default 0)");
  cmd->add_option("--tonemap", f.tonemap, "PNG/JPEG: clamp (default), aces or filmic");
  cmd->add_flag("--colorbar", f.colorbar, "PNG/JPEG: a legend below the image for each colour map (color_by, slices): the map, its range, the field's name");
  cmd->add_flag("--alpha", f.alpha, "transparent background: an alpha channel of coverage (PNG, EXR)");
  cmd->add_option("--clamp", f.clamp, "clip each sample's indirect radiance to X (biased; 0: off, the default)");
  CLI::Option* denoise = cmd->add_option("--denoise", f.denoise,
                                         "denoise the image: quality (the default mode: feature regression) or fast "
                                         "(a-trous), or off; an EXR keeps the raw image as layer \"raw\"")
                             ->expected(0, 1);
  cmd->add_option("--adaptive", f.adaptive, "stop pixels whose relative standard error is below T (e.g. 0.02)");
  cmd->add_option("--frames", f.frames, "render a sequence of N frames, OUT.0000.png ... (with --iso-sweep, --orbit, or "
                                        "volumes that change over time: then one frame per time step unless given)")
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--fps", f.fps, "a video's frames per second (default 24)");
  cmd->add_flag("--keep-frames", f.keepFrames, "with a video output: also write its frames as numbered PNG images (NAME.0000.png ...)");
  cmd->add_option("--iso-sweep", f.isoSweep, "SURFACE:FROM:TO: sweep iso-surface SURFACE (from 0, over all volumes) from FROM to TO over the frames");
  addSceneOverrides(cmd, f.overrides);
  cmd->add_option("--orbit", f.orbit, "turn the camera about its look-at point by DEGREES over the frames (360: a turntable)");
  return {cmd, [flags, denoise] {
            flags->denoiseGiven = denoise->count() > 0;
            return render(*flags);
          }};
}

}  // namespace iso
