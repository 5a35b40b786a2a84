#pragma once
// Renders a frame: TBB over 16x16 tiles, each pixel's samples from its own Sampler.
#include <cstdint>

#include "integrators/integrator.h"
#include "renderer/film.h"

namespace iso {

struct RenderOptions {
  int spp = 4;
  uint64_t seed = 0;
  int threads = 0;  // 0: all cores
};

struct RenderResult {
  RayCounters counters;
  double seconds = 0;
};

RenderResult renderFrame(const Camera& camera, const Integrator& integrator,
                         const RenderOptions& options, Film& film);

}  // namespace iso
