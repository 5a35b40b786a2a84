#pragma once
// A regular grid of scalar samples kept in its source type (uint8, uint16, int16, float32),
// x fastest, with its placement in world space (origin of sample 0, spacing between samples).
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "volume/vec3.h"

namespace iso {

enum class ScalarType { UInt8, UInt16, Int16, Float32 };

const char* scalarTypeName(ScalarType type);
size_t scalarTypeSize(ScalarType type);
// Accepts the names used by scene files and the Open SciVis convention; false if unknown.
bool parseScalarType(const std::string& name, ScalarType& type);

// The samples of a sparse grid (an OpenVDB tree), brick by brick: the bricks are those of
// BrickGrid (8^3 cells), and a brick is either a block of 9^3 float32 samples (its cells' corners,
// the faces it shares with its neighbours included, x fastest) or, where all of those are one
// value (background, tiles), that value alone. A cell's 8 corners always lie in its brick's
// block, and every sample a dense grid would hold is here with the same bits, so the traversal
// finds the same crossings as on the dense grid (tests check it). The grid's dims - 1 are a
// multiple of 8 on every axis.
struct SparseSamples {
  static constexpr int kBlock = 9;        // samples per block edge
  static constexpr size_t kBlockSize = 729;
  Vec3i bricks;                           // per axis: (dims - 1) / 8
  const int32_t* slot = nullptr;          // per brick (x fastest): block index >= 0, or -1 - index into `uniform`
  const float* blocks = nullptr;          // kBlockSize samples per stored block
  const float* uniform = nullptr;         // the values of the constant bricks
  size_t blockCount = 0, uniformCount = 0;
  std::shared_ptr<const void> owner;      // keeps the arrays alive (vectors, or a mapping)
  size_t brickCount() const { return size_t(bricks.x) * bricks.y * bricks.z; }
  // The slot of brick (bx, by, bz); a stored block's samples (x fastest), or a constant brick's value.
  int32_t slotOf(int bx, int by, int bz) const { return slot[(size_t(bz) * bricks.y + size_t(by)) * bricks.x + size_t(bx)]; }
  const float* block(int32_t s) const { return blocks + size_t(s) * kBlockSize; }
  float uniformValue(int32_t s) const { return uniform[size_t(-1 - s)]; }
  size_t bytes() const { return brickCount() * 4 + (blockCount * kBlockSize + uniformCount) * 4; }
};

class Grid {
 public:
  using Storage = std::variant<std::vector<uint8_t>, std::vector<uint16_t>,
                               std::vector<int16_t>, std::vector<float>>;

  Grid() = default;
  Grid(Vec3i dims, Storage samples, Vec3d origin = {0, 0, 0}, Vec3d spacing = {1, 1, 1});
  // Samples of `type` in a buffer the grid shares ownership of (a loader reads a file straight
  // into an uninitialised buffer: no zero-filling pass, no second copy).
  Grid(Vec3i dims, ScalarType type, std::shared_ptr<const void> samples, Vec3d origin = {0, 0, 0},
       Vec3d spacing = {1, 1, 1});
  // A sparse float32 grid; `dims - 1` must be 8 times `sparse.bricks`.
  Grid(Vec3i dims, std::shared_ptr<const SparseSamples> sparse, Vec3d origin = {0, 0, 0}, Vec3d spacing = {1, 1, 1});
  // A window of a sparse grid (as the dense one below): `sparse` has every brick's slot, but only
  // the bricks whose blocks reach into [first, first + extent) hold their samples.
  Grid(Vec3i dims, std::shared_ptr<const SparseSamples> sparse, Vec3i first, Vec3i extent, Vec3d origin, Vec3d spacing);
  // A window of a dense grid (a rank's part of a volume split for a data-parallel render): the
  // grid is the whole volume — dims(), origin() and every coordinate are the whole volume's, so
  // a ray computes the same bits in any window — but `samples` holds only the samples
  // [first, first + extent) on each axis, x fastest. Cells whose 8 corners lie in the window
  // read as they would in the whole grid; nothing may read a sample outside it (BrickGrid leaves
  // the bricks it does not hold out; callers keep queries to the held bricks).
  Grid(Vec3i dims, ScalarType type, std::shared_ptr<const void> samples, Vec3i first, Vec3i extent,
       Vec3d origin = {0, 0, 0}, Vec3d spacing = {1, 1, 1});
  // The samples held: the whole grid unless it is a window.
  Vec3i windowFirst() const { return m_first; }
  Vec3i windowExtent() const { return m_extent; }
  bool isWindow() const { return !(m_extent == m_dims); }
  // Whether every sample of the cells [lo, hi) is held.
  bool holdsCells(Vec3i lo, Vec3i hi) const {
    for (int a = 0; a < 3; ++a)
      if (lo[a] < m_first[a] || hi[a] + 1 > m_first[a] + m_extent[a]) return false;
    return true;
  }
  // Sparse grids have no dense array: data() is null and visitSamples must not be called;
  // value(), cellCorners() and the statistics below work on both.
  const SparseSamples* sparse() const { return m_sparse.get(); }

  Vec3i dims() const { return m_dims; }
  Vec3d origin() const { return m_origin; }
  Vec3d spacing() const { return m_spacing; }
  void setOrigin(Vec3d origin) { m_origin = origin; }
  void setSpacing(Vec3d spacing) { m_spacing = spacing; }
  ScalarType type() const { return m_type; }
  // The samples, of type type(), x fastest (dense grids only).
  const void* data() const { return m_data; }
  // Calls f(samples) with `samples` a `const T*` of the grid's own sample type: one switch for
  // the caller's whole loop (the traversal, brick ranges, mesh export) instead of one per value.
  template <typename F>
  decltype(auto) visitSamples(F&& f) const {
    switch (m_type) {
      case ScalarType::UInt8: return f(static_cast<const uint8_t*>(m_data));
      case ScalarType::UInt16: return f(static_cast<const uint16_t*>(m_data));
      case ScalarType::Int16: return f(static_cast<const int16_t*>(m_data));
      case ScalarType::Float32: break;
    }
    return f(static_cast<const float*>(m_data));
  }
  // The samples held (of a window: its own).
  size_t sampleCount() const { return size_t(m_extent.x) * m_extent.y * m_extent.z; }
  // Memory of the samples as held (a sparse grid: its blocks and brick table).
  size_t bytes() const {
    return m_sparse ? m_sparse->bytes() : sampleCount() * scalarTypeSize(m_type);
  }

  // The index into data() of sample (x, y, z) of the whole grid (it must be held).
  size_t index(int x, int y, int z) const {
    return (size_t(z - m_first.z) * size_t(m_extent.y) + size_t(y - m_first.y)) * size_t(m_extent.x) + size_t(x - m_first.x);
  }
  // Every source type converts to float exactly (uint16/int16 fit in 24 bits of mantissa),
  // so all cells sharing a corner see the same bits there.
  float value(size_t i) const {
    if (m_sparse) {
      const size_t x = i % size_t(m_dims.x), y = (i / size_t(m_dims.x)) % size_t(m_dims.y);
      return sparseValue(int(x), int(y), int(i / (size_t(m_dims.x) * m_dims.y)));
    }
    switch (m_type) {
      case ScalarType::UInt8: return static_cast<const uint8_t*>(m_data)[i];
      case ScalarType::UInt16: return static_cast<const uint16_t*>(m_data)[i];
      case ScalarType::Int16: return static_cast<const int16_t*>(m_data)[i];
      case ScalarType::Float32: return static_cast<const float*>(m_data)[i];
    }
    return 0.f;
  }
  float value(int x, int y, int z) const { return m_sparse ? sparseValue(x, y, z) : value(index(x, y, z)); }
  // The 8 corners of cell (x, y, z); corner c = bit0 x, bit1 y, bit2 z.
  void cellCorners(int x, int y, int z, float out[8]) const;
  // The cell holding continuous grid coordinates `p` (clamped to the grid) and p's cell-local
  // coordinates in it, in [0, 1].
  void locate(const Vec3d& p, Vec3i& cell, Vec3d& local) const;
  // The trilinear field in double at continuous grid coordinates (clamped to the grid): the
  // exact class of a point for checks and tests.
  double interpolate(const Vec3d& gridCoord) const;
  // A gradient that is continuous across cell faces, in value per grid step: central
  // differences at the 8 corners of the cell holding `gridCoord` (one-sided on the grid's
  // faces), interpolated trilinearly. The trilinear interpolant's own gradient jumps from cell
  // to cell and shades iso-surfaces in facets; this is the smooth one shading normals use.
  Vec3d smoothGradient(const Vec3d& gridCoord) const;

  // Sum of all samples in double: a cheap fingerprint for loader tests.
  double sum() const;
  // Value range over all samples.
  void range(float& lo, float& hi) const;
  // The values below which the shares `q` (each in [0, 1]) of the samples lie: exact for the
  // integer types (a count per value), within (max - min) / 65536 for float32 (a histogram).
  std::vector<double> quantiles(const std::vector<double>& q) const;

 private:
  Vec3i m_dims{0, 0, 0};
  Vec3i m_first{0, 0, 0}, m_extent{0, 0, 0};  // the samples held (all: 0 and dims)
  Vec3d m_origin{0, 0, 0};
  Vec3d m_spacing{1, 1, 1};
  ScalarType m_type = ScalarType::UInt8;
  std::shared_ptr<const void> m_samples;
  const void* m_data = nullptr;
  std::shared_ptr<const SparseSamples> m_sparse;
  float sparseValue(int x, int y, int z) const {
    const SparseSamples& s = *m_sparse;
    const int bx = std::min(x / 8, s.bricks.x - 1), by = std::min(y / 8, s.bricks.y - 1), bz = std::min(z / 8, s.bricks.z - 1);
    const int32_t slot = s.slotOf(bx, by, bz);
    if (slot < 0) return s.uniformValue(slot);
    constexpr int k = SparseSamples::kBlock;
    return s.block(slot)[(size_t(z - 8 * bz) * k + size_t(y - 8 * by)) * k + size_t(x - 8 * bx)];
  }
};

// A window of a dense grid (see Grid's window constructor): a copy of its samples
// [first, first + extent) on each axis, which must lie in the grid, with the whole grid's
// dims and placement. (The formats without a reader of their own for windows load whole, then
// cut the window: readVolumeFile.)
Grid windowOf(const Grid& grid, Vec3i first, Vec3i extent);

}  // namespace iso
