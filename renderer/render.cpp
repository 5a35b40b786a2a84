#include "renderer/render.h"

#include "renderer/wavefront.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <thread>

namespace iso {

namespace {

volatile std::sig_atomic_t g_stop = 0;

double seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

void formatDuration(double s, char* buf, size_t n) {
  const long t = long(s + 0.5);
  if (t >= 3600) std::snprintf(buf, n, "%ld:%02ld:%02ld", t / 3600, t / 60 % 60, t % 60);
  else std::snprintf(buf, n, "%ld:%02ld", t / 60, t % 60);
}

}  // namespace

void requestStop() { g_stop = 1; }
void clearStopRequest() { g_stop = 0; }
bool stopRequested() { return g_stop != 0; }

TileRenderer::TileRenderer(const Camera& camera, const Integrator& integrator, const RenderOptions& options,
                           int width, int height)
    : m_camera(camera), m_integrator(integrator), m_options(options), m_width(width), m_height(height),
      m_tilesX((width + kTile - 1) / kTile), m_tilesY((height + kTile - 1) / kTile) {}

TileRenderer::Rect TileRenderer::rect(int tile) const {
  const int x0 = (tile % m_tilesX) * kTile, y0 = (tile / m_tilesX) * kTile;
  return {x0, y0, std::min(x0 + kTile, m_width), std::min(y0 + kTile, m_height)};
}

int TileRenderer::nextPassStart(int passStart, int pass, int spp) {
  const int size = pass <= 1 ? 1 : std::min(1 << std::min(pass - 1, 4), 16);
  return std::min(spp, passStart + size);
}

bool TileRenderer::converges(const PixelSums& p) const {
  const double n = p.samples, mean = p.luminance / n;
  const double variance = n > 1 ? std::max(0.0, p.luminance2 / n - mean * mean) * n / (n - 1) : 0;
  return std::sqrt(variance / n) <= m_options.noiseThreshold * std::max(mean, 0.01);
}

RenderOptions renderOptions(const RenderSettings& settings) {
  RenderOptions o;
  o.rayFlow = settings.rayFlow;
  o.spp = settings.spp;
  o.seed = settings.seed;
  o.threads = settings.threads;
  o.noiseThreshold = settings.noiseThreshold;
  return o;
}

namespace {

// Each thread's wave and batch, reused from tile to tile: at most kTile^2 pixels x 16 samples
// (the largest pass) = 4,096 paths, whatever the image size.
struct TileWave {
  Wave wave;
  RayBatch batch;
  std::vector<Wave::Pixel> pixels;  // the tile's open pixels, in packet order
};
thread_local TileWave t_wave;

}  // namespace

// Never inlined: bench/iso_vs_mesh.py --instructions and the callgrind breakdowns in
// docs/BENCHMARKS.md count instructions inside this function (one tile's pass, either flow).
[[gnu::noinline]] uint64_t TileRenderer::renderPass(int tile, int s0, int s1, PixelSums* sums, size_t stride,
                                                    RayCounters& counters) const {
  const Rect r = rect(tile);
  if (m_options.rayFlow == RayFlow::Scalar) return renderPassScalar(r, s0, s1, sums, stride, counters);
  return renderPassWavefront(r, s0, s1, sums, stride, counters);
}

uint64_t TileRenderer::renderPassScalar(const Rect& r, int s0, int s1, PixelSums* sums, size_t stride,
                                        RayCounters& counters) const {
  uint64_t taken = 0;
  const uint64_t seedKey = Sampler::seedKey(m_options.seed);
  for (int y = r.y0; y < r.y1; ++y)
    for (int x = r.x0; x < r.x1; ++x) {
      PixelSums& p = sums[size_t(y - r.y0) * stride + size_t(x - r.x0)];
      if (p.converged) continue;
      const Sampler::PixelKey pixelKey = Sampler::pixelKey(seedKey, uint32_t(x), uint32_t(y));
      for (int s = s0; s < s1; ++s) {
        Sampler sampler(pixelKey, uint32_t(s));
        const float jx = sampler.next(), jy = sampler.next();
        SampleResult result;
        m_integrator.Li(m_camera.generateRay(x + jx, y + jy), sampler, counters, result);
        addSample(p, result, m_options.alpha, m_options.kept);
      }
      taken += uint64_t(s1 - s0);
    }
  return taken;
}

// The wavefront flow: every open pixel's samples [s0, s1) of the tile are the paths of a Wave,
// traced stage by stage against the World: camera rays in Embree packets of 4x2 pixels of one
// sample (rtcIntersect8: the iso-surfaces' bricks are walked by the packet's lanes together), then
// shadow rays and continuation rays one at a time: they are incoherent (bounces, lights sampled
// anywhere), and Embree's packets lose on them (docs/BENCHMARKS.md, "Rays in queues, traced in
// packets").
uint64_t TileRenderer::renderPassWavefront(const Rect& r, int s0, int s1, PixelSums* sums, size_t stride,
                                           RayCounters& counters) const {
  TileWave& t = t_wave;
  auto sumsAt = [&](int x, int y) -> PixelSums& { return sums[size_t(y - r.y0) * stride + size_t(x - r.x0)]; };
  t.pixels.clear();
  forEachPixelInPacketOrder(r, [&](int x, int y) {
    if (!sumsAt(x, y).converged) t.pixels.emplace_back(x, y);
  });
  if (t.pixels.empty()) return 0;
  t.wave.start(m_camera, m_integrator, m_options, t.pixels.data(), t.pixels.size(), s0, s1);
  const World& world = m_integrator.world();
  while (t.wave.pending()) {
    t.wave.collect(t.batch);
    traceBatch(world, t.batch, 0, t.batch.units(), counters.traversal);
    t.wave.deliver(t.batch, 0, t.batch.size(), counters);
  }
  t.wave.finish([&](size_t i) -> PixelSums& { return sumsAt(t.pixels[i].first, t.pixels[i].second); });
  return t.wave.size();
}

ProgressBar::ProgressBar(const RenderOptions& options, uint64_t pixels)
    : m_options(options), m_total(double(pixels) * options.spp), m_start(std::chrono::steady_clock::now()) {}

void ProgressBar::add(uint64_t samples) {
  m_done += samples;
  if (m_options.workDone) *m_options.workDone += samples;
  if (!m_options.progress) return;
  std::unique_lock<std::mutex> lock(m_printing, std::try_to_lock);
  if (lock) print(false);
}

void ProgressBar::finish() {
  if (!m_options.progress || !m_printed) return;
  std::lock_guard<std::mutex> lock(m_printing);
  print(true);
  std::fprintf(stderr, "\n");
}

void ProgressBar::print(bool final) {
  const bool sequence = m_options.sequenceFrames > 1;
  const double now = seconds(m_start);
  if (!final && m_lastPrint >= 0 && now - m_lastPrint < 0.25) return;  // the first tile, then every quarter second
  m_lastPrint = now;
  const double frameFraction = std::min(1.0, double(m_done.load()) / std::max(1.0, m_total));
  // A sequence's bar: its frames done and this one's share, over all its frames.
  const double fraction =
      sequence ? (m_options.sequenceFrame + frameFraction) / m_options.sequenceFrames : frameFraction;
  const double elapsed = sequence ? seconds(m_options.sequenceStart) : now;
  char e[32], eta[32], which[48] = "";
  formatDuration(elapsed, e, sizeof e);
  formatDuration(fraction > 0 ? elapsed * (1 - fraction) / fraction : 0, eta, sizeof eta);
  if (sequence)
    std::snprintf(which, sizeof which, "  frame %d/%d", m_options.sequenceFrame + 1, m_options.sequenceFrames);
  const int bar = int(fraction * 30);
  std::fprintf(stderr, "\r[%.*s%*s] %5.1f%%%s  elapsed %s  ETA %s ", bar, "==============================", 30 - bar, "",
               fraction * 100, which, e, fraction > 0 ? eta : "?");
  std::fflush(stderr);
  m_printed = true;
}

RenderResult renderTiles(const TileRenderer& tiles, TileSet& set, const RenderOptions& options, ProgressBar& progress,
                         const std::function<void()>& between) {
  tbb::enumerable_thread_specific<RayCounters> counters;
  const auto start = std::chrono::steady_clock::now();
  const std::thread::id caller = std::this_thread::get_id();
  const int minSamples = std::min(options.spp, RenderOptions::kAdaptiveMinSamples);
  // One pass of one tile, then the adaptive test of its pixels (a pixel's test reads only its
  // own sums: the same decisions as a test over the whole frame after the pass).
  auto renderTile = [&](TileSlot& slot) {
    const int s1 = TileRenderer::nextPassStart(slot.s0, slot.pass, options.spp);
    tiles.renderPass(slot.tile, slot.s0, s1, slot.first, slot.stride, counters.local());
    const TileRenderer::Rect r = tiles.rect(slot.tile);
    progress.add(uint64_t(r.pixels()) * uint64_t(s1 - slot.s0));
    bool open = s1 < options.spp;
    if (open && options.noiseThreshold > 0 && !stopRequested()) {
      open = false;
      for (int y = 0; y < r.y1 - r.y0; ++y)
        for (int x = 0; x < r.x1 - r.x0; ++x) {
          PixelSums& p = slot.first[size_t(y) * slot.stride + size_t(x)];
          if (!p.converged && p.samples >= minSamples) {
            p.converged = tiles.converges(p);
            if (p.converged) progress.add(uint64_t(options.spp - p.samples));  // (the progress bar's work)
          }
          open = open || !p.converged;
        }
    }
    std::lock_guard<std::mutex> lock(set.mutex);
    ++slot.pass;
    slot.s0 = s1;
    slot.open = open;
    slot.busy = false;
  };

  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  RenderResult result;
  std::vector<size_t> list;
  // A stop request is honoured once the first pass is done: an interrupted image has every
  // pixel sampled (a second Ctrl-C ends the process at once).
  for (int pass = 0; pass == 0 || !stopRequested(); ++pass) {
    bool later = false;
    list.clear();
    {
      std::lock_guard<std::mutex> lock(set.mutex);
      for (size_t i = 0; i < set.slots.size(); ++i) {
        const TileSlot& slot = set.slots[i];
        if (!slot.ours || !slot.open || slot.pass < pass) continue;
        if (slot.pass == pass) list.push_back(i);
        later = later || slot.pass > pass;
      }
    }
    if (list.empty() && !later) break;
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, list.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
          TileSlot& slot = set.slots[list[i]];
          {
            std::lock_guard<std::mutex> lock(set.mutex);
            if (!slot.ours || (pass > 0 && stopRequested())) continue;  // (handed to another rank meanwhile)
            slot.busy = true;
          }
          renderTile(slot);
          if (between && std::this_thread::get_id() == caller) between();
        }
      });
    });
  }
  result.seconds = seconds(start);
  for (const RayCounters& c : counters) result.counters.add(c);
  return result;
}

RenderResult renderFrame(const Camera& camera, const Integrator& integrator,
                         const RenderOptions& options, Film& film, Film* directFilm) {
  const int w = film.width(), h = film.height();
  const TileRenderer tiles(camera, integrator, options, w, h);
  std::vector<PixelSums> sums(size_t(w) * h);
  TileSet set;
  set.slots.reserve(size_t(tiles.tiles()));
  for (int t = 0; t < tiles.tiles(); ++t) {
    const TileRenderer::Rect r = tiles.rect(t);
    set.slots.push_back(TileSlot{t, &sums[size_t(r.y0) * size_t(w) + size_t(r.x0)], size_t(w)});
  }
  ProgressBar progress(options, uint64_t(w) * uint64_t(h));
  RenderResult result = renderTiles(tiles, set, options, progress);
  progress.finish();
  resolveFrame(sums, options, film, directFilm, result);
  return result;
}

namespace {

// What the denoiser reads, from the sums: per image (the beauty; with `split` also the direct
// and indirect parts) the mean, the means of the even and of the odd samples and the variance of
// the mean; the features' means.
void resolveDenoiseInput(const std::vector<PixelSums>& sums, int w, int h, bool split, DenoiseInput& in) {
  in = DenoiseInput();
  in.width = w, in.height = h;
  const size_t n = size_t(w) * size_t(h);
  std::vector<NoisyImage*> images = {&in.color};
  if (split) images = {&in.color, &in.direct, &in.indirect};
  for (NoisyImage* image : images) {
    image->mean.resize(n);
    image->a.resize(n);
    image->b.resize(n);
    image->variance.resize(n);
  }
  in.albedo.resize(n);
  in.normal.resize(n);
  in.depth.resize(n);
  in.samples.resize(n);
  in.featureVariance.resize(n);
  for (size_t i = 0; i < n; ++i) {
    const PixelSums& p = sums[i];
    const int all = p.samples, odd = p.samples / 2, even = all - odd;
    auto fill = [&](NoisyImage& image, const Vec3d& sum, const Vec3d& oddSum, const Vec3d& sum2) {
      if (all == 0) {
        image.mean[i] = image.a[i] = image.b[i] = image.variance[i] = Vec3f(0, 0, 0);
        return;
      }
      const Vec3d mean = sum / double(all);
      image.mean[i] = Vec3f(mean);
      image.a[i] = Vec3f((sum - oddSum) / double(even));
      image.b[i] = odd > 0 ? Vec3f(oddSum / double(odd)) : image.a[i];
      Vec3d variance{0, 0, 0};
      if (all > 1)
        for (int c = 0; c < 3; ++c) variance[c] = std::max(0.0, sum2[c] / all - mean[c] * mean[c]) / (all - 1);
      image.variance[i] = Vec3f(variance);
    };
    fill(in.color, p.L, p.oddL, p.L2);
    if (split) {
      fill(in.direct, p.direct, p.oddDirect, p.direct2);
      fill(in.indirect, p.L - p.direct, p.oddL - p.oddDirect, p.L2 - p.directL * 2.0 + p.direct2);
    }
    const double count = std::max(all, 1);
    in.albedo[i] = Vec3f(p.albedo / count);
    in.normal[i] = Vec3f(p.normal / count);
    in.depth[i] = p.depthHits ? float(p.depth / p.depthHits) : INFINITY;
    in.samples[i] = float(all);
    Vec3d spread{0, 0, 0};
    if (odd > 0) {
      auto halves = [&](const Vec3d& sum, const Vec3d& oddSum) {
        const Vec3d d = (sum - oddSum) / double(even) - oddSum / double(odd);
        return dot(d, d) / 4;
      };
      spread.x = halves(p.albedo, p.oddAlbedo);
      spread.y = halves(p.normal, p.oddNormal);
      const int evenHits = p.depthHits - p.oddDepthHits;
      if (evenHits > 0 && p.oddDepthHits > 0) {
        const double d = (p.depth - p.oddDepth) / evenHits - p.oddDepth / p.oddDepthHits;
        spread.z = d * d / 4;
      }
    }
    in.featureVariance[i] = Vec3f(spread);
  }
}

// Whether `options` asks for the AOV layer `name`.
bool wantsLayer(const RenderOptions& options, const char* name) {
  return std::find(options.aovs.begin(), options.aovs.end(), name) != options.aovs.end();
}

}  // namespace

KeptSums keptSums(const RenderOptions& options, bool splitsDirect) {
  const bool denoising = options.denoiseInput != nullptr;  // the denoiser reads them all
  KeptSums k;
  k.denoiser = denoising;
  k.features = denoising || wantsLayer(options, "albedo") || wantsLayer(options, "normal");
  k.moments = denoising || wantsLayer(options, "variance") || options.noiseThreshold > 0;
  k.direct = denoising || splitsDirect;
  return k;
}

void resolveFrame(const std::vector<PixelSums>& sums, const RenderOptions& options, Film& film, Film* directFilm,
                  RenderResult& result) {
  if (options.denoiseInput) resolveDenoiseInput(sums, film.width(), film.height(), directFilm != nullptr, *options.denoiseInput);
  const int w = film.width(), h = film.height();
  result.minSamples = options.spp;
  result.maxSamples = 0;
  result.interrupted = false;
  double totalSamples = 0;
  for (const PixelSums& p : sums) {
    result.minSamples = std::min(result.minSamples, p.samples);
    result.maxSamples = std::max(result.maxSamples, p.samples);
    totalSamples += p.samples;
    result.interrupted = result.interrupted || (stopRequested() && !p.converged && p.samples < options.spp);
  }
  result.meanSamples = sums.empty() ? 0 : totalSamples / double(sums.size());
  // Averages; what a pixel lacks (no sample yet, or no hit for depth) is 0 / infinity.
  Film::Layer* albedo = wantsLayer(options, "albedo") ? &film.addLayer("albedo", {"R", "G", "B"}) : nullptr;
  Film::Layer* normal = wantsLayer(options, "normal") ? &film.addLayer("normal", {"X", "Y", "Z"}) : nullptr;
  Film::Layer* depth = wantsLayer(options, "depth") ? &film.addLayer("depth", {"Z"}) : nullptr;
  Film::Layer* variance = wantsLayer(options, "variance") ? &film.addLayer("variance", {"R", "G", "B"}) : nullptr;
  Film::Layer* samples = wantsLayer(options, "samples") ? &film.addLayer("samples", {"N"}) : nullptr;
  if (options.alpha) film.alpha().assign(size_t(w) * h, 0.f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const size_t i = size_t(y) * w + x;
      const PixelSums& p = sums[i];
      const double n = std::max(p.samples, 1);
      film.at(x, y) = Vec3f(p.L / n);
      if (directFilm) directFilm->at(x, y) = Vec3f(p.direct / n);
      for (int c = 0; c < 3; ++c) {
        if (albedo) albedo->data[3 * i + c] = float(p.albedo[c] / n);
        if (normal) normal->data[3 * i + c] = float(p.normal[c] / n);
        if (variance) {
          const double mean = p.L[c] / n;
          variance->data[3 * i + c] =
              p.samples > 1 ? float(std::max(0.0, p.L2[c] / n - mean * mean) / (p.samples - 1)) : 0.f;
        }
      }
      if (depth) depth->data[i] = p.depthHits ? float(p.depth / p.depthHits) : INFINITY;
      if (options.alpha) film.alpha()[i] = float(p.depthHits / n);
      if (samples) samples->data[i] = float(p.samples);
    }
}

bool integratorDenoises(const std::string& integrator) {
  return integrator != "normals" && integrator != "eyelight";
}

DenoiseReport denoiseFrame(const DenoiseInput& in, DenoiseMode mode, int threads, bool keepRaw, Film& film,
                           Film* direct, Film* indirect, RenderResult& result) {
  DenoiseReport report;
  auto keep = [&](Film& f) {
    if (!keepRaw) return;
    Film::Layer& raw = f.addLayer("raw", {"R", "G", "B"});
    for (size_t i = 0; i < f.pixels().size(); ++i)
      for (int c = 0; c < 3; ++c) raw.data[3 * i + size_t(c)] = f.pixels()[i][c];
  };
  if (direct && indirect && !in.direct.empty()) {
    if (indirect->pixels().size() != film.pixels().size()) *indirect = indirectOf(film, *direct);
    keep(film);
    keep(*direct);
    keep(*indirect);
    direct->pixels() = denoise(in, in.direct, mode, threads, &report);
    indirect->pixels() = denoise(in, in.indirect, mode, threads, &report);
    for (size_t i = 0; i < film.pixels().size(); ++i) film.pixels()[i] = direct->pixels()[i] + indirect->pixels()[i];
  } else {
    keep(film);
    film.pixels() = denoise(in, in.color, mode, threads, &report);
  }
  result.denoised = true;
  result.denoiseSeconds += report.seconds;
  return report;
}

}  // namespace iso
