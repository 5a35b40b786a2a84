#pragma once
// Renders a frame: progressive passes over all pixels (1, 1, 2, 4, ... up to 16 samples per
// pass), each pass TBB-parallel over 16x16 tiles. A pixel's samples come from its own
// Sampler keyed on (pixel, sample index, seed) and are summed in sample order, so images are
// bit-identical for any thread count. A stop request (SIGINT, SIGTERM) ends the frame at the
// next tile boundary once the first pass is done; the image then averages the samples each
// pixel has (at least one).
#include <atomic>
#include <chrono>
#include <cstdint>
#include <csignal>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include "integrators/integrator.h"
#include "renderer/denoise.h"
#include "renderer/film.h"

namespace iso {

// Which of PixelSums' sums a frame keeps, each some 10 to 40 instructions a sample: all of them by
// default (the view and Python may resolve or denoise a frame any way after it is rendered); a CLI
// render keeps what its outputs read (keptSums). The radiance, the sample count and
// the depth (coverage for alpha) are always kept.
struct KeptSums {
  bool denoiser = true;  // the odd samples' half sums, the direct part's moments
  bool features = true;  // albedo and normal (their AOVs, the denoiser)
  bool moments = true;   // the squared radiance and luminance (variance AOV, adaptive sampling, the denoiser)
  bool direct = true;    // the direct part (compare)
};

struct RenderOptions {
  // How rays are traced: one path at a time (the reference), or a tile's paths in flight at
  // once, their rays traced stage by stage in Embree packets (RayFlow in scene/scene.h). The
  // image bits are the same either way.
  RayFlow rayFlow = RayFlow::Wavefront;
  int spp = 4;
  uint64_t seed = 0;
  int threads = 0;  // 0: all cores
  bool progress = false;  // a progress bar on stderr
  // In a sequence of frames: this frame's place and when the sequence began. The bar then shows
  // the whole sequence's share done, the frame, and the sequence's ETA.
  int sequenceFrame = 0, sequenceFrames = 1;
  std::chrono::steady_clock::time_point sequenceStart{};
  // If set, renderFrame adds the pixel samples it has done to it as it goes (out of width x
  // height x spp; pixels that adaptive sampling stops count as done): the Python module's
  // progress callback reads it from another thread.
  std::atomic<uint64_t>* workDone = nullptr;
  // Extra layers: any of "albedo", "normal", "depth", "variance" (of the pixel mean),
  // "samples" (how many each pixel took).
  std::vector<std::string> aovs;
  // Adaptive sampling (0: off): after each pass, a pixel with at least kAdaptiveMinSamples
  // (or spp, if fewer) stops once the standard error of its mean luminance is at most
  // noiseThreshold * max(mean luminance, 0.01) (the floor keeps near-black pixels from
  // sampling forever). Decided only at pass boundaries, from the pixel's own samples: still
  // bit-identical for any thread count.
  double noiseThreshold = 0;
  static constexpr int kAdaptiveMinSamples = 16;
  // Coverage in Film::alpha(); samples whose camera ray hits nothing add no radiance (the
  // background is transparent, though it still lights the scene).
  bool alpha = false;
  // If set, resolveFrame fills it with what the denoiser reads (renderer/denoise.h): the means
  // of the even and odd samples, variances and features, for the beauty and, where the
  // integrator splits it, the direct and indirect parts.
  DenoiseInput* denoiseInput = nullptr;
  // Which of PixelSums' sums the frame keeps (KeptSums).
  KeptSums kept;
};

// The sums resolveFrame reads for `options` (its AOV layers, adaptive sampling, the denoiser's
// input) and, where `splitsDirect`, a film of the direct part: a frame that is resolved once.
KeptSums keptSums(const RenderOptions& options, bool splitsDirect);

// The scene's render settings as renderFrame takes them (ray flow, spp, seed, threads, adaptive
// threshold): the one place the CLI, the view and the Python module turn settings into options;
// each then adds what only it has (AOVs, alpha, progress, a work counter).
RenderOptions renderOptions(const RenderSettings& settings);

struct RenderResult {
  RayCounters counters;
  double seconds = 0;
  bool interrupted = false;
  int minSamples = 0;  // samples in the pixel that has fewest (spp unless interrupted or adaptive)
  int maxSamples = 0;
  double meanSamples = 0;
  bool denoised = false;      // the image went through the denoiser (settings' mode)
  double denoiseSeconds = 0;  // its time (all frames')
};

// The main layer of `film` gets radiance; `direct` (optional, same size) the direct part for
// integrators that split it.
RenderResult renderFrame(const Camera& camera, const Integrator& integrator,
                         const RenderOptions& options, Film& film, Film* direct = nullptr);

// What a pixel has gathered so far; sums in double, in sample order. Plain data: the MPI
// layer sends a tile's sums as bytes.
struct PixelSums {
  Vec3d L, L2, direct, albedo, normal;
  double luminance = 0, luminance2 = 0;
  double depth = 0;
  int depthHits = 0;  // samples whose camera ray hit something
  int samples = 0;
  bool converged = false;  // adaptive sampling: takes no more samples
  // For the denoiser: the odd samples' share of the sums (the even half is the rest: two
  // independent half images), and the direct part's moments (the compare integrator's direct
  // and indirect variances).
  Vec3d oddL, oddDirect, oddAlbedo, oddNormal, direct2, directL;
  double oddDepth = 0;
  int oddDepthHits = 0;
};

// Adds one sample to its pixel's sums (every ray flow and the MPI layers, in sample order),
// those `kept` says.
[[gnu::always_inline]] inline void addSample(PixelSums& p, const SampleResult& result, bool alpha, const KeptSums& kept) {
  const bool background = !std::isfinite(result.depth);
  const Vec3d L = alpha && background ? Vec3d{0, 0, 0} : Vec3d(result.L);
  p.L += L;
  if (kept.moments) {
    p.L2 += L * L;
    const double lum = 0.2126 * L.x + 0.7152 * L.y + 0.0722 * L.z;
    p.luminance += lum;
    p.luminance2 += lum * lum;
  }
  const Vec3d direct(result.direct), albedo(result.albedo), normal(result.normal);
  if (kept.direct) p.direct += direct;
  if (kept.features) {
    p.albedo += albedo;
    p.normal += normal;
  }
  if (!background) {
    p.depth += result.depth;
    ++p.depthHits;
  }
  if (kept.denoiser) {
    p.direct2 += direct * direct;
    p.directL += direct * L;
    if (p.samples & 1) {
      p.oddL += L;
      p.oddDirect += direct;
      p.oddAlbedo += albedo;
      p.oddNormal += normal;
      if (!background) {
        p.oddDepth += result.depth;
        ++p.oddDepthHits;
      }
    }
  }
  ++p.samples;
}

// The frame's tiles (16x16 pixels) and how samples reach a tile's pixels, pass by pass: the
// single-process renderFrame, the view and the MPI layers (renderer/distributed.h), whose ranks
// render shares of the tiles, share it, so a pixel gets the same sums in the same order.
class TileRenderer {
 public:
  static constexpr int kTile = 16;
  struct Rect {
    int x0, y0, x1, y1;
    int pixels() const { return (x1 - x0) * (y1 - y0); }
  };

  TileRenderer(const Camera& camera, const Integrator& integrator, const RenderOptions& options, int width, int height);
  int tiles() const { return m_tilesX * m_tilesY; }
  Rect rect(int tile) const;
  // Samples [s0, s1) of every pixel of `tile` that has not converged, into `sums` (pixel (x0,
  // y0) of the tile at sums[0], rows `stride` apart). Returns the samples taken.
  uint64_t renderPass(int tile, int s0, int s1, PixelSums* sums, size_t stride, RayCounters& counters) const;
  // The passes: [passStart(i), passStart(i + 1)) holds 1, 1, 2, 4, 8, 16, 16, ... samples.
  static int nextPassStart(int passStart, int pass, int spp);
  // Adaptive sampling: after a pass, whether pixel `p` takes no more samples.
  bool converges(const PixelSums& p) const;

 private:
  uint64_t renderPassScalar(const Rect& r, int s0, int s1, PixelSums* sums, size_t stride, RayCounters& counters) const;
  uint64_t renderPassWavefront(const Rect& r, int s0, int s1, PixelSums* sums, size_t stride,
                               RayCounters& counters) const;

  const Camera& m_camera;
  const Integrator& m_integrator;
  const RenderOptions& m_options;
  int m_width, m_height, m_tilesX, m_tilesY;
};

// The progress bar on stderr (options.progress) and the work counter (options.workDone) of a
// render of `pixels` pixels at options.spp: add() from any thread as samples are taken (or
// skipped by adaptive sampling), finish() once at the end.
class ProgressBar {
 public:
  ProgressBar(const RenderOptions& options, uint64_t pixels);
  void add(uint64_t samples);
  void finish();

 private:
  void print(bool final);
  const RenderOptions& m_options;
  double m_total;
  std::chrono::steady_clock::time_point m_start;
  std::atomic<uint64_t> m_done{0};
  std::mutex m_printing;
  double m_lastPrint = -1;
  bool m_printed = false;
};

// One tile of a render, as renderTiles works through its passes: where its sums are (pixel
// (x0, y0) of the tile at `first`, rows `stride` apart) and how far its passes have gone.
struct TileSlot {
  int tile = 0;
  PixelSums* first = nullptr;
  size_t stride = 0;
  int pass = 0, s0 = 0;  // its next pass and that pass's first sample
  bool open = true;      // pixels that take more samples (after each pass: the adaptive test)
  bool ours = true;      // false once handed to another rank (renderer/distributed.h)
  bool busy = false;     // a render thread is on it
};

// The tiles a render works through; `mutex` guards the slots' pass, s0, open, ours and busy
// while renderTiles runs (the MPI layer hands idle tiles to other ranks meanwhile).
struct TileSet {
  std::vector<TileSlot> slots;
  std::mutex mutex;
};

// renderFrame's loop over some of a frame's tiles (all of them in one process; a rank's share
// under MPI): pass by pass over the set's open tiles that are still ours, each pass TBB-parallel
// on options.threads threads, each tile's adaptive test after its pass; a tile starts at its own
// next pass (tiles taken from another rank join at theirs). A stop request is honoured once a
// tile's first pass is done. `between`, if set, runs on the calling thread after each tile it
// renders (where the MPI layer answers other ranks). Returns the counters and the seconds; the
// caller resolves the frame.
RenderResult renderTiles(const TileRenderer& tiles, TileSet& set, const RenderOptions& options, ProgressBar& progress,
                         const std::function<void()>& between = {});

// Averages the sums into `film` (and `direct`, and the AOV layers the options ask for), and the
// sample figures and `interrupted` of `result`.
void resolveFrame(const std::vector<PixelSums>& sums, const RenderOptions& options, Film& film, Film* direct,
                  RenderResult& result);

// Whether the denoiser has anything to do for this integrator: not for `normals` (data, not
// radiance) nor `eyelight` (no noise but the pixel's footprint); they pass through unchanged.
bool integratorDenoises(const std::string& integrator);

// Denoises a frame resolved with options.denoiseInput = &in (renderFrame, the MPI layers) in
// `mode` (not Off): the main layer; for an integrator that splits the direct part, `direct` and
// `indirect` (made from the film when empty) are denoised apart and the main layer becomes their
// sum. `keepRaw`: each film keeps what was rendered as a layer "raw" (EXR output). Sets
// result.denoised and adds the time to result.denoiseSeconds; returns the report.
DenoiseReport denoiseFrame(const DenoiseInput& in, DenoiseMode mode, int threads, bool keepRaw, Film& film,
                           Film* direct, Film* indirect, RenderResult& result);

// Asks a running renderFrame to stop at the next tile boundary (async-signal-safe).
void requestStop();
void clearStopRequest();
bool stopRequested();

}  // namespace iso
