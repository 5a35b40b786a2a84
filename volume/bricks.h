#pragma once
// Min/max per brick of 8^3 cells (macro cells). A brick's range covers its own corner
// samples, including those it shares with its neighbours, so a brick whose range does not
// bracket the iso value cannot contain a crossing and never becomes an Embree primitive.
// Of a window of a grid (Grid::isWindow), a brick not wholly held has the empty range
// (+inf, -inf): it is never active, so nothing reads its samples.
#include <algorithm>
#include <cstdint>
#include <vector>

#include "volume/grid.h"

namespace iso {

class BrickGrid {
 public:
  static constexpr int kCells = 8;  // cells per brick edge: 2 bytes of range per 512 cells

  explicit BrickGrid(const Grid& grid);
  // The ranges of a grid of `dims` that is not held: `layers(z0, z1)` returns the samples of
  // layers z0..z1 (whole layers, x fastest, as float), valid until its next call; it is asked for
  // each row of bricks along z in turn (their shared layers twice). Every range is the one the
  // grid's own constructor gives.
  template <typename Layers>
  static BrickGrid fromLayers(Vec3i dims, Layers&& layers) {
    BrickGrid g(dims);
    for (int bz = 0; bz < g.m_count.z; ++bz) {
      const int z0 = bz * kCells, z1 = std::min(z0 + kCells, g.m_cellDims.z);
      g.rangesOfRow(bz, layers(z0, z1), z1 - z0 + 1);
    }
    g.finishRanges();
    return g;
  }
  // The same from a stream: `feed(layer)` calls layer(z, samples) for z = 0, 1, ..., dims.z - 1
  // in turn (one whole layer each, x fastest, as float; e.g. as a gzip file inflates).
  template <typename Feed>
  static BrickGrid fromStream(Vec3i dims, Feed&& feed) {
    BrickGrid g(dims);
    feed([&](int z, const float* layer) {
      const int bz = std::min(z / kCells, g.m_count.z - 1);
      g.rangesOfRow(bz, layer, 1);
      if (z % kCells == 0 && bz > 0 && bz * kCells == z) g.rangesOfRow(bz - 1, layer, 1);  // a layer two rows share
    });
    g.finishRanges();
    return g;
  }

  // The bricks of a grid of `dims` with the given ranges (brick b's min and max, as brickMin and
  // brickMax give them): ranges computed elsewhere (a reader's child process). `count` must be
  // the bricks' number (std::invalid_argument otherwise).
  static BrickGrid fromRanges(Vec3i dims, const float* lo, const float* hi, size_t count);

  Vec3i count() const { return m_count; }
  Vec3i dims() const { return {m_cellDims.x + 1, m_cellDims.y + 1, m_cellDims.z + 1}; }  // the grid's samples
  size_t size() const { return m_lo.size(); }
  // The cell range [begin, end) of brick b.
  Vec3i cellBegin(uint32_t b) const;
  Vec3i cellEnd(uint32_t b) const;
  // The brick holding cell c.
  uint32_t brickOf(const Vec3i& c) const {
    return uint32_t((size_t(c.z / kCells) * m_count.y + c.y / kCells) * m_count.x + c.x / kCells);
  }
  // Bricks that can hold a crossing of `iso`: min <= iso <= max, not all equal to iso (inside
  // means > iso; a brick whose max is iso holds a crossing on its boundary).
  std::vector<uint32_t> activeBricks(float iso) const;
  // Brick b's value range.
  float brickMin(uint32_t b) const { return m_lo[b]; }
  float brickMax(uint32_t b) const { return m_hi[b]; }
  size_t bytes() const { return m_lo.size() * 2 * sizeof(float); }
  // The grid's value range (every sample is some brick's corner).
  float minValue() const { return m_min; }
  float maxValue() const { return m_max; }

 private:
  explicit BrickGrid(Vec3i dims);  // the bricks of a grid of `dims`, no ranges yet
  // The ranges of the bricks of row bz (along z) from its `count` layers of samples.
  void rangesOfRow(int bz, const float* samples, int count);
  void finishRanges();  // the grid's value range from the bricks'
  Vec3i m_cellDims;
  Vec3i m_count;
  std::vector<float> m_lo, m_hi;
  float m_min = 0, m_max = 0;
};

}  // namespace iso
