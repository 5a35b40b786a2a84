#include "volume/bricks.h"

#include <algorithm>
#include <limits>

namespace iso {

BrickGrid::BrickGrid(const Grid& grid) {
  const Vec3i d = grid.dims();
  m_cellDims = {d.x - 1, d.y - 1, d.z - 1};
  m_count = {(m_cellDims.x + kCells - 1) / kCells, (m_cellDims.y + kCells - 1) / kCells,
             (m_cellDims.z + kCells - 1) / kCells};
  const size_t n = size_t(m_count.x) * m_count.y * m_count.z;
  m_lo.assign(n, std::numeric_limits<float>::infinity());
  m_hi.assign(n, -std::numeric_limits<float>::infinity());
  // One pass over the samples; a sample on a brick boundary belongs to both bricks.
  for (int z = 0; z < d.z; ++z) {
    const int bz0 = std::min(z / kCells, m_count.z - 1), bz1 = std::max((z - 1) / kCells, 0);
    for (int y = 0; y < d.y; ++y) {
      const int by0 = std::min(y / kCells, m_count.y - 1), by1 = std::max((y - 1) / kCells, 0);
      for (int x = 0; x < d.x; ++x) {
        const int bx0 = std::min(x / kCells, m_count.x - 1), bx1 = std::max((x - 1) / kCells, 0);
        const float v = grid.value(x, y, z);
        for (int bz = std::min(bz0, bz1); bz <= std::max(bz0, bz1); ++bz)
          for (int by = std::min(by0, by1); by <= std::max(by0, by1); ++by)
            for (int bx = std::min(bx0, bx1); bx <= std::max(bx0, bx1); ++bx) {
              const size_t b = (size_t(bz) * m_count.y + by) * m_count.x + bx;
              m_lo[b] = std::min(m_lo[b], v);
              m_hi[b] = std::max(m_hi[b], v);
            }
      }
    }
  }
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
