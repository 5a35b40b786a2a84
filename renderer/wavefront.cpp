#include "renderer/wavefront.h"

#include <algorithm>

namespace iso {

void RayBatch::prepareResults() {
  found.assign(rays.size(), 0);
  if (!shadow && hits.size() < rays.size()) hits.resize(rays.size());  // written before read
}

void traceBatch(const World& world, RayBatch& batch, size_t u0, size_t u1, TraversalStats& stats) {
  if (batch.shadow) {
    for (size_t i = u0; i < u1; ++i) batch.found[i] = world.occluded(batch.rays[i], stats) ? 1 : 0;
    return;
  }
  if (batch.packetEnds.empty()) {
    for (size_t i = u0; i < u1; ++i) batch.found[i] = world.intersect(batch.rays[i], batch.hits[i], stats) ? 1 : 0;
    return;
  }
  for (size_t j = u0; j < u1; ++j) {
    const size_t i = j == 0 ? 0 : batch.packetEnds[j - 1];
    const int n = int(batch.packetEnds[j] - i);
    bool hit[World::kPacket];
    world.intersectPacket(&batch.rays[i], n, &batch.hits[i], hit, stats);
    for (int k = 0; k < n; ++k) batch.found[i + size_t(k)] = hit[k] ? 1 : 0;
  }
}

void Wave::start(const Camera& camera, const Integrator& integrator, const RenderOptions& options,
                 const Pixel* pixels, size_t n, int s0, int s1) {
  m_integrator = &integrator;
  m_alpha = options.alpha;
  m_kept = options.kept;
  m_pixel = pixels;
  m_pixels = n;
  m_samples = size_t(s1 - s0);
  m_next = Stage::Camera;
  const size_t ns = m_samples;
  m_count = n * ns;
  if (m_paths.size() < m_count) m_paths.resize(m_count);  // reset path by path (PathState::begin)
  m_live.resize(m_count);
  for (size_t i = 0; i < m_count; ++i) m_live[i] = uint32_t(i);
  const uint64_t seedKey = Sampler::seedKey(options.seed);
  for (size_t i = 0; i < n; ++i) {
    const auto [x, y] = pixels[i];
    const Sampler::PixelKey pixelKey = Sampler::pixelKey(seedKey, uint32_t(x), uint32_t(y));
    for (int s = s0; s < s1; ++s) {
      PathState& p = m_paths[i * ns + size_t(s - s0)];
      Sampler sampler(pixelKey, uint32_t(s));
      const float jx = sampler.next(), jy = sampler.next();
      p.begin(camera.generateRay(x + jx, y + jy), sampler);
      integrator.start(p);
    }
  }
}

// The camera rays by sample, in packets of one sample's 4x2 block (pixels that share x / 4 and
// y / 2, consecutive in packet order).
void Wave::collectCamera(RayBatch& batch) {
  // The rays of the packet being filled; closing it marks where it ends.
  auto open = [&] { return batch.rays.size() - (batch.packetEnds.empty() ? 0 : batch.packetEnds.back()); };
  auto close = [&] {
    if (open() > 0) batch.packetEnds.push_back(uint32_t(batch.rays.size()));
  };
  for (size_t s = 0; s < m_samples; ++s) {
    int blockX = -1, blockY = -1;
    for (size_t i = 0; i < m_pixels; ++i) {
      PathState& p = m_paths[i * m_samples + s];
      if (!p.tracing) continue;
      p.tracing = false;
      const auto [x, y] = m_pixel[i];
      if (x / 4 != blockX || y / 2 != blockY || open() == World::kPacket) {
        close();
        blockX = x / 4;
        blockY = y / 2;
      }
      batch.rays.push_back(p.ray);
      batch.paths.push_back(uint32_t(i * m_samples + s));
    }
    close();
  }
}

void Wave::collect(RayBatch& batch) {
  batch.rays.clear();
  batch.paths.clear();
  batch.packetEnds.clear();
  batch.shadow = m_next == Stage::Shadow;
  if (m_next == Stage::Camera) {
    collectCamera(batch);
  } else {
    size_t live = 0;
    for (size_t k = 0; k < m_live.size(); ++k) {
      const uint32_t i = m_live[k];
      PathState& p = m_paths[i];
      if (!p.tracing && !p.shadowing) continue;  // (no ray of it in flight: it asks for none again)
      m_live[live++] = i;
      bool& asks = batch.shadow ? p.shadowing : p.tracing;
      if (!asks) continue;
      asks = false;
      batch.rays.push_back(batch.shadow ? p.shadow : p.ray);
      batch.paths.push_back(i);
    }
    m_live.resize(live);
  }
  m_next = batch.shadow ? Stage::Closest : Stage::Shadow;
  batch.prepareResults();
}

void Wave::deliver(const RayBatch& batch, size_t k0, size_t k1, RayCounters& counters) {
  for (size_t k = k0; k < k1; ++k) {
    PathState& p = m_paths[batch.paths[k]];
    if (batch.shadow)
      m_integrator->afterShadow(p, batch.found[k] != 0);
    else
      m_integrator->afterTrace(p, batch.found[k] != 0, batch.hits[k], counters);
  }
}

bool Wave::pending() const {
  for (uint32_t i : m_live)
    if (m_paths[i].tracing || m_paths[i].shadowing) return true;
  return false;
}

}  // namespace iso
