#pragma once
// Renders a frame: progressive passes over all pixels (1, 1, 2, 4, ... up to 16 samples per
// pass), each pass TBB-parallel over 16x16 tiles. A pixel's samples come from its own
// Sampler keyed on (pixel, sample index, seed) and are summed in sample order, so images are
// bit-identical for any thread count. A stop request (SIGINT) ends the frame at the next tile
// boundary; the image then averages the samples each pixel has.
#include <cstdint>
#include <csignal>
#include <string>
#include <vector>

#include "integrators/integrator.h"
#include "renderer/film.h"

namespace iso {

struct RenderOptions {
  int spp = 4;
  uint64_t seed = 0;
  int threads = 0;  // 0: all cores
  bool progress = false;  // a progress bar on stderr
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
};

struct RenderResult {
  RayCounters counters;
  double seconds = 0;
  bool interrupted = false;
  int minSamples = 0;  // samples in the pixel that has fewest (spp unless interrupted or adaptive)
  int maxSamples = 0;
  double meanSamples = 0;
};

// The main layer of `film` gets radiance; `direct` (optional, same size) the direct part for
// integrators that split it.
RenderResult renderFrame(const Camera& camera, const Integrator& integrator,
                         const RenderOptions& options, Film& film, Film* direct = nullptr);

// Asks a running renderFrame to stop at the next tile boundary (async-signal-safe).
void requestStop();
void clearStopRequest();
bool stopRequested();

}  // namespace iso
