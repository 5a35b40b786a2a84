#include "volume/bricks.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <limits>
#include <stdexcept>

#include "volume/child_process.h"

namespace iso {
namespace {

// tbb::parallel_for, or a plain loop in a reader child, which must not enter TBB (loaders.h).
template <typename Index, typename Body>
void forEach(Index begin, Index end, const Body& body) {
  if (inReaderChild())
    for (Index i = begin; i < end; ++i) body(i);
  else
    tbb::parallel_for(begin, end, body);
}

}  // namespace

BrickGrid::BrickGrid(Vec3i d) {
  m_cellDims = {d.x - 1, d.y - 1, d.z - 1};
  m_count = {(m_cellDims.x + kCells - 1) / kCells, (m_cellDims.y + kCells - 1) / kCells,
             (m_cellDims.z + kCells - 1) / kCells};
  const size_t n = size_t(m_count.x) * m_count.y * m_count.z;
  m_lo.assign(n, std::numeric_limits<float>::infinity());
  m_hi.assign(n, -std::numeric_limits<float>::infinity());
}

void BrickGrid::rangesOfRow(int bz, const float* samples, int count) {
  const size_t nx = size_t(m_cellDims.x) + 1, layer = nx * (size_t(m_cellDims.y) + 1);
  forEach(0, m_count.y, [&](int by) {
    for (int bx = 0; bx < m_count.x; ++bx) {
      const uint32_t b = uint32_t((size_t(bz) * m_count.y + by) * m_count.x + bx);
      const Vec3i c0 = cellBegin(b), c1 = cellEnd(b);
      float lo = m_lo[b], hi = m_hi[b];
      for (int z = 0; z < count; ++z)
        for (int y = c0.y; y <= c1.y; ++y) {
          const float* row = samples + size_t(z) * layer + size_t(y) * nx + size_t(c0.x);
          for (int x = 0; x <= c1.x - c0.x; ++x) {
            lo = std::min(lo, row[x]);
            hi = std::max(hi, row[x]);
          }
        }
      m_lo[b] = lo;
      m_hi[b] = hi;
    }
  });
}

void BrickGrid::finishRanges() {
  if (m_lo.empty()) return;
  m_min = *std::min_element(m_lo.begin(), m_lo.end());
  m_max = *std::max_element(m_hi.begin(), m_hi.end());
  if (m_min > m_max) m_min = m_max = 0;  // a window holding no whole brick
}

BrickGrid BrickGrid::fromRanges(Vec3i dims, const float* lo, const float* hi, size_t count) {
  BrickGrid g(dims);
  if (count != g.m_lo.size()) throw std::invalid_argument("BrickGrid::fromRanges: not one range per brick");
  g.m_lo.assign(lo, lo + count);
  g.m_hi.assign(hi, hi + count);
  g.finishRanges();
  return g;
}

BrickGrid::BrickGrid(const Grid& grid) : BrickGrid(grid.dims()) {
  const size_t n = m_lo.size();
  // Brick by brick over its own corner samples (a sample on a brick boundary is read by both
  // bricks): rows of up to 9 samples in the grid's own type, a tight loop the compiler keeps in
  // registers (one pass over the samples that scattered each into its bricks took 0.8 s for 512^3).
  if (const SparseSamples* sparse = grid.sparse()) {
    // The bricks are the sparse grid's own: a block's range, or its one value.
    forEach(size_t(0), n, [&](size_t b) {
      if (!grid.holdsCells(cellBegin(uint32_t(b)), cellEnd(uint32_t(b)))) return;  // (a window's: not held, never active)
      const int32_t slot = sparse->slot[b];
      if (slot < 0) {
        m_lo[b] = m_hi[b] = sparse->uniformValue(slot);
        return;
      }
      const float* v = sparse->block(slot);
      const auto [lo, hi] = std::minmax_element(v, v + SparseSamples::kBlockSize);
      m_lo[b] = *lo;
      m_hi[b] = *hi;
    });
  } else {
  grid.visitSamples([&](const auto* data) {
    // Slabs of bricks in parallel, each writing only its own bricks.
    forEach(0, m_count.z, [&](int bz) {
      for (int by = 0; by < m_count.y; ++by)
        for (int bx = 0; bx < m_count.x; ++bx) {
          const uint32_t b = uint32_t((size_t(bz) * m_count.y + by) * m_count.x + bx);
          const Vec3i c0 = cellBegin(b), c1 = cellEnd(b);
          if (!grid.holdsCells(c0, c1)) continue;  // (a window's: not held, never active)
          float lo = m_lo[b], hi = m_hi[b];
          for (int z = c0.z; z <= c1.z; ++z)
            for (int y = c0.y; y <= c1.y; ++y) {
              const auto* row = data + grid.index(c0.x, y, z);
              for (int x = 0; x <= c1.x - c0.x; ++x) {
                const float v = float(row[x]);
                lo = std::min(lo, v);
                hi = std::max(hi, v);
              }
            }
          m_lo[b] = lo;
          m_hi[b] = hi;
        }
    });
  });
  }
  finishRanges();
}

Vec3i BrickGrid::cellBegin(uint32_t b) const {
  const int x = int(b % uint32_t(m_count.x));
  const int y = int((b / uint32_t(m_count.x)) % uint32_t(m_count.y));
  const int z = int(b / (uint32_t(m_count.x) * uint32_t(m_count.y)));
  return {x * kCells, y * kCells, z * kCells};
}

Vec3i BrickGrid::cellEnd(uint32_t b) const {
  const Vec3i begin = cellBegin(b);
  return {std::min(begin.x + kCells, m_cellDims.x), std::min(begin.y + kCells, m_cellDims.y),
          std::min(begin.z + kCells, m_cellDims.z)};
}

std::vector<uint32_t> BrickGrid::activeBricks(float iso) const {
  std::vector<uint32_t> active;
  for (uint32_t b = 0; b < m_lo.size(); ++b)
    // A brick whose largest value equals the iso value can still hold a crossing: a ray
    // that was inside leaves the surface on its boundary, where the value is exactly iso
    // (volume/traversal.h carries the class across exact zeros). A brick entirely at the
    // iso value cannot change the class and stays out.
    if (m_lo[b] <= iso && m_hi[b] >= iso && !(m_lo[b] == iso && m_hi[b] == iso)) active.push_back(b);
  return active;
}

}  // namespace iso
