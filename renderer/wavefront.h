#pragma once
// The wavefront ray flow's paths, in one place for every way of tracing them. A Wave holds the
// paths of one pass over a run of pixels (each pixel's samples [s0, s1)), and takes them through
// their stages: the camera rays, then shadow rays and closest-hit rays in turn until no path asks
// for a ray, then each pixel's samples summed in sample order. What traces a stage's rays is the
// caller's: one process traces a batch against its World (traceBatch: TileRenderer's wavefront
// pass), a data-parallel rank sends the rays through the ranks (renderer/data_parallel.cpp's
// RankTracer). Every way gives each path the same hits, so the images are the same bits.
#include <cstdint>
#include <utility>
#include <vector>

#include "renderer/render.h"

namespace iso {

// One stage's rays of a Wave, and what tracing them found.
struct RayBatch {
  bool shadow = false;
  std::vector<Ray> rays;
  std::vector<uint32_t> paths;  // the path (of the Wave) each ray is of
  std::vector<char> found;      // a hit found (closest-hit rays), the ray blocked (shadow rays)
  std::vector<Hit> hits;        // closest-hit rays: the hit, where found
  // Coherent rays (a camera's 4x2 pixels of one sample): rays [ends[j - 1], ends[j]) are
  // packet j, at most World::kPacket rays. Empty: the rays are traced one at a time.
  std::vector<uint32_t> packetEnds;

  size_t size() const { return rays.size(); }
  // The units a tracer hands out to threads: packets if there are any, else rays.
  size_t units() const { return packetEnds.empty() ? rays.size() : packetEnds.size(); }
  // found[] and hits[] sized for the rays (hits are written only where found).
  void prepareResults();
};

// Traces units [u0, u1) of `batch` (RayBatch::units) against `world`: shadow rays with
// World::occluded, closest-hit rays with World::intersect, packets with World::intersectPacket
// (the same hits, bit for bit).
void traceBatch(const World& world, RayBatch& batch, size_t u0, size_t u1, TraversalStats& stats);

// A tile's pixels in packet order: its 4x2 blocks row by row, each block's pixels row by row
// (f(x, y)). A Wave's camera rays go to Embree in packets of one block and one sample.
template <typename F>
void forEachPixelInPacketOrder(const TileRenderer::Rect& r, F&& f) {
  for (int by = r.y0; by < r.y1; by += 2)
    for (int bx = r.x0; bx < r.x1; bx += 4)
      for (int y = by; y < std::min(by + 2, r.y1); ++y)
        for (int x = bx; x < std::min(bx + 4, r.x1); ++x) f(x, y);
}

class Wave {
 public:
  using Pixel = std::pair<int, int>;  // (x, y)

  // Paths for samples [s0, s1) of the `n` pixels at `pixels` (kept by pointer until finish),
  // listed in packet order (forEachPixelInPacketOrder), each path begun and started.
  void start(const Camera& camera, const Integrator& integrator, const RenderOptions& options, const Pixel* pixels,
             size_t n, int s0, int s1);
  size_t size() const { return m_count; }
  // The rays of the paths' next stage into `batch`: the camera rays (in packets) first, then
  // shadow rays and closest-hit rays in turn. A stage may have no rays.
  void collect(RayBatch& batch);
  // What rays [k0, k1) of the batch found, to their paths (each path's next stage): safe to call
  // for disjoint ranges from several threads.
  void deliver(const RayBatch& batch, size_t k0, size_t k1, RayCounters& counters);
  // Whether any path asks for a ray.
  bool pending() const;
  // Each pixel's samples, in sample order, finished and added to sumsOf(i), pixel i's sums.
  template <typename Sums>
  void finish(Sums&& sumsOf) {
    for (size_t i = 0; i < m_pixels; ++i) {
      PixelSums& sums = sumsOf(i);
      for (size_t s = 0; s < m_samples; ++s) {
        PathState& p = m_paths[i * m_samples + s];
        m_integrator->finish(p);
        addSample(sums, p.out, m_alpha, m_kept);
      }
    }
  }

 private:
  void collectCamera(RayBatch& batch);

  const Integrator* m_integrator = nullptr;
  bool m_alpha = false;
  KeptSums m_kept;
  const Pixel* m_pixel = nullptr;
  size_t m_pixels = 0, m_samples = 0, m_count = 0;  // pixels, samples of each (s1 - s0), paths
  enum class Stage { Camera, Shadow, Closest } m_next = Stage::Camera;
  std::vector<PathState> m_paths;  // pixel i's sample s at i * (s1 - s0) + (s - s0); reused
  // The paths that may still ask for a ray, in increasing order: all of them at the start; a path
  // found asking for none when a stage is collected has none in flight either, and is dropped.
  // (Later stages look at these alone, not at every path of the wave.)
  std::vector<uint32_t> m_live;
};

}  // namespace iso
