#include "renderer/render.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <chrono>

namespace iso {

RenderResult renderFrame(const Camera& camera, const Integrator& integrator,
                         const RenderOptions& options, Film& film) {
  constexpr int kTile = 16;
  const int tilesX = (film.width() + kTile - 1) / kTile;
  const int tilesY = (film.height() + kTile - 1) / kTile;
  tbb::enumerable_thread_specific<RayCounters> counters;
  const auto start = std::chrono::steady_clock::now();
  auto renderTile = [&](int tile) {
    RayCounters& local = counters.local();
    const int x0 = (tile % tilesX) * kTile, y0 = (tile / tilesX) * kTile;
    for (int y = y0; y < std::min(y0 + kTile, film.height()); ++y)
      for (int x = x0; x < std::min(x0 + kTile, film.width()); ++x) {
        Vec3f sum{0, 0, 0};
        for (int s = 0; s < options.spp; ++s) {
          Sampler sampler(uint32_t(x), uint32_t(y), uint32_t(s), options.seed);
          const float jx = sampler.next(), jy = sampler.next();
          sum += integrator.Li(camera.generateRay(x + jx, y + jy), sampler, local);
        }
        film.at(x, y) = sum / float(options.spp);
      }
  };
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, tilesX * tilesY, 1),
                      [&](const tbb::blocked_range<int>& r) {
                        for (int t = r.begin(); t < r.end(); ++t) renderTile(t);
                      });
  });
  RenderResult result;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  for (const RayCounters& c : counters) result.counters.add(c);
  return result;
}

}  // namespace iso
