#include "volume/grid.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include <limits>
#include <type_traits>

namespace iso {

const char* scalarTypeName(ScalarType type) {
  switch (type) {
    case ScalarType::UInt8: return "uint8";
    case ScalarType::UInt16: return "uint16";
    case ScalarType::Int16: return "int16";
    case ScalarType::Float32: return "float32";
  }
  return "?";
}

size_t scalarTypeSize(ScalarType type) {
  switch (type) {
    case ScalarType::UInt8: return 1;
    case ScalarType::UInt16: return 2;
    case ScalarType::Int16: return 2;
    case ScalarType::Float32: return 4;
  }
  return 0;
}

bool parseScalarType(const std::string& name, ScalarType& type) {
  if (name == "uint8") type = ScalarType::UInt8;
  else if (name == "uint16") type = ScalarType::UInt16;
  else if (name == "int16") type = ScalarType::Int16;
  else if (name == "float32" || name == "float") type = ScalarType::Float32;
  else return false;
  return true;
}

Grid::Grid(Vec3i dims, Storage samples, Vec3d origin, Vec3d spacing)
    : m_dims(dims), m_extent(dims), m_origin(origin), m_spacing(spacing) {
  m_type = static_cast<ScalarType>(samples.index());
  std::visit([this](auto& v) {
    auto owned = std::make_shared<std::decay_t<decltype(v)>>(std::move(v));
    m_data = owned->data();
    m_samples = std::move(owned);
  }, samples);
}

Grid::Grid(Vec3i dims, ScalarType type, std::shared_ptr<const void> samples, Vec3d origin, Vec3d spacing)
    : m_dims(dims), m_extent(dims), m_origin(origin), m_spacing(spacing), m_type(type), m_samples(std::move(samples)),
      m_data(m_samples.get()) {}

Grid::Grid(Vec3i dims, ScalarType type, std::shared_ptr<const void> samples, Vec3i first, Vec3i extent,
           Vec3d origin, Vec3d spacing)
    : m_dims(dims), m_first(first), m_extent(extent), m_origin(origin), m_spacing(spacing), m_type(type),
      m_samples(std::move(samples)), m_data(m_samples.get()) {}

Grid::Grid(Vec3i dims, std::shared_ptr<const SparseSamples> sparse, Vec3d origin, Vec3d spacing)
    : m_dims(dims), m_extent(dims), m_origin(origin), m_spacing(spacing), m_type(ScalarType::Float32), m_sparse(std::move(sparse)) {}

Grid::Grid(Vec3i dims, std::shared_ptr<const SparseSamples> sparse, Vec3i first, Vec3i extent, Vec3d origin, Vec3d spacing)
    : m_dims(dims), m_first(first), m_extent(extent), m_origin(origin), m_spacing(spacing), m_type(ScalarType::Float32),
      m_sparse(std::move(sparse)) {}

void Grid::cellCorners(int x, int y, int z, float out[8]) const {
  if (m_sparse) {
    for (int c = 0; c < 8; ++c) out[c] = sparseValue(x + (c & 1), y + (c >> 1 & 1), z + (c >> 2 & 1));
    return;
  }
  const size_t sx = 1, sy = size_t(m_extent.x), sz = size_t(m_extent.x) * m_extent.y;
  const size_t i = index(x, y, z);
  const size_t offsets[8] = {0, sx, sy, sx + sy, sz, sx + sz, sy + sz, sx + sy + sz};
  visitSamples([&](const auto* p) {
    for (int c = 0; c < 8; ++c) out[c] = float(p[i + offsets[c]]);
  });
}

// Calls f(v) for every sample (of the grid's type, or float for a sparse grid), in order.
template <typename F>
static void forEachSample(const Grid& g, F&& f) {
  if (g.sparse()) {
    const Vec3i d = g.dims();
    for (int z = 0; z < d.z; ++z)
      for (int y = 0; y < d.y; ++y)
        for (int x = 0; x < d.x; ++x) f(g.value(x, y, z));
    return;
  }
  g.visitSamples([&](const auto* v) {
    for (size_t i = 0, n = g.sampleCount(); i < n; ++i) f(v[i]);
  });
}

double Grid::sum() const {
  double s = 0;
  forEachSample(*this, [&](auto v) { s += double(v); });
  return s;
}

void Grid::range(float& lo, float& hi) const {
  lo = std::numeric_limits<float>::infinity();
  hi = -lo;
  forEachSample(*this, [&](auto v) {
    lo = std::min(lo, float(v));
    hi = std::max(hi, float(v));
  });
}

std::vector<double> Grid::quantiles(const std::vector<double>& q) const {
  float lo, hi;
  range(lo, hi);
  const size_t n = sampleCount();
  constexpr int kBins = 65536;
  std::vector<uint64_t> counts(kBins, 0);
  // Integer samples index their own bin (int16 shifted by 32768); floats a bin of the range.
  double binLo = 0, binWidth = 1;
  const bool integral = type() != ScalarType::Float32;
  if (integral) binLo = type() == ScalarType::Int16 ? -32768.0 : 0.0;
  else binLo = lo, binWidth = hi > lo ? (double(hi) - lo) / kBins : 1;
  forEachSample(*this, [&](auto v) {
    if constexpr (std::is_integral_v<decltype(v)>)
      ++counts[size_t(int64_t(v) - int64_t(binLo))];
    else
      ++counts[std::min(size_t((double(v) - lo) / binWidth), size_t(kBins - 1))];
  });
  const bool exact = type() != ScalarType::Float32;
  std::vector<double> out;
  for (double share : q) {
    const uint64_t rank = std::min<uint64_t>(n - 1, uint64_t(std::clamp(share, 0.0, 1.0) * double(n)));
    uint64_t seen = 0;
    int bin = 0;
    while (bin < kBins - 1 && seen + counts[bin] <= rank) seen += counts[bin++];
    out.push_back(exact ? binLo + bin : std::clamp(binLo + (bin + 0.5) * binWidth, double(lo), double(hi)));
  }
  return out;
}

void Grid::locate(const Vec3d& p, Vec3i& cell, Vec3d& local) const {
  for (int a = 0; a < 3; ++a) {
    const double x = std::clamp(p[a], 0.0, double(m_dims[a] - 1));
    cell[a] = std::min(int(std::floor(x)), m_dims[a] - 2);
    local[a] = x - cell[a];
  }
}

double Grid::interpolate(const Vec3d& p) const {
  Vec3i c;
  Vec3d f;
  locate(p, c, f);
  float v[8];
  cellCorners(c.x, c.y, c.z, v);
  double r = 0;
  for (int i = 0; i < 8; ++i)
    r += double(v[i]) * (i & 1 ? f[0] : 1 - f[0]) * (i & 2 ? f[1] : 1 - f[1]) * (i & 4 ? f[2] : 1 - f[2]);
  return r;
}

Vec3d Grid::smoothGradient(const Vec3d& p) const {
  Vec3i c;
  Vec3d f;
  locate(p, c, f);
  const int64_t stride[3] = {1, m_extent.x, int64_t(m_extent.x) * m_extent.y};
  // Per axis: the central differences at the cell's two corners along it, interpolated
  // along it, then bilinearly across it. Away from the grid's faces every neighbour exists
  // (the common case, written out below without a branch); on them the differences become
  // one-sided.
  bool interior = true;
  for (int a = 0; a < 3; ++a) interior = interior && c[a] >= 1 && c[a] + 2 <= m_dims[a] - 1;
  const float w[3][2] = {{float(1 - f.x), float(f.x)}, {float(1 - f.y), float(f.y)}, {float(1 - f.z), float(f.z)}};
  Vec3d g{0, 0, 0};
  if (m_sparse) {  // the same differences through value(): a sparse grid has no array to offset into
    for (int a = 0; a < 3; ++a) {
      const int b = (a + 1) % 3, d = (a + 2) % 3;
      const bool lo = c[a] > 0, hi = c[a] + 2 <= m_dims[a] - 1;
      float sum = 0;
      for (int j = 0; j < 2; ++j)
        for (int k = 0; k < 2; ++k) {
          auto at = [&](int step) {
            Vec3i q = c;
            q[b] += j;
            q[d] += k;
            q[a] += step;
            return value(q.x, q.y, q.z);
          };
          const float g0 = (at(1) - at(lo ? -1 : 0)) / (lo ? 2.f : 1.f);
          const float g1 = (at(hi ? 2 : 1) - at(0)) / (hi ? 2.f : 1.f);
          sum += w[b][j] * w[d][k] * (w[a][0] * g0 + w[a][1] * g1);
        }
      g[a] = sum;
    }
    return g;
  }
  if (interior) {
    // Constant strides, no branch per sample; the arithmetic of the loop below where both
    // neighbours exist (lo and hi: a difference over 2), in the same order.
    visitSamples([&](const auto* v) {
      const size_t base = index(c.x, c.y, c.z);
      const size_t sx = 1, sy = size_t(stride[1]), sz = size_t(stride[2]);
      auto along = [&](size_t sa, size_t sb, size_t sd, const float* wa, const float* wb, const float* wd) {
        float sum = 0;
        for (size_t j = 0; j < 2; ++j)
          for (size_t k = 0; k < 2; ++k) {
            const size_t row = base + j * sb + k * sd;
            const float g0 = 0.5f * (float(v[row + sa]) - float(v[row - sa]));
            const float g1 = 0.5f * (float(v[row + 2 * sa]) - float(v[row]));
            sum += wb[j] * wd[k] * (wa[0] * g0 + wa[1] * g1);
          }
        return sum;
      };
      g = Vec3d{along(sx, sy, sz, w[0], w[1], w[2]), along(sy, sz, sx, w[1], w[2], w[0]),
                along(sz, sx, sy, w[2], w[0], w[1])};
    });
    return g;
  }
  visitSamples([&](const auto* v) {
    const size_t base = index(c.x, c.y, c.z);
    for (int a = 0; a < 3; ++a) {
      const int b = (a + 1) % 3, d = (a + 2) % 3;  // the two other axes
      const int64_t sa = stride[a];
      float sum = 0;
      for (int j = 0; j < 2; ++j)
        for (int k = 0; k < 2; ++k) {
          const size_t row = base + size_t(j * stride[b] + k * stride[d]);
          const bool lo = c[a] > 0, hi = c[a] + 2 <= m_dims[a] - 1;
          const float g0 = (float(v[row + sa]) - float(v[lo ? row - sa : row])) / (lo ? 2.f : 1.f);
          const float g1 = (float(v[hi ? row + 2 * sa : row + sa]) - float(v[row])) / (hi ? 2.f : 1.f);
          sum += w[b][j] * w[d][k] * (w[a][0] * g0 + w[a][1] * g1);
        }
      g[a] = sum;
    }
  });
  return g;
}

Grid windowOf(const Grid& grid, Vec3i first, Vec3i extent) {
  for (int a = 0; a < 3; ++a)
    if (first[a] < grid.windowFirst()[a] || extent[a] < 1 ||
        first[a] + extent[a] > grid.windowFirst()[a] + grid.windowExtent()[a])
      throw std::invalid_argument("windowOf: the window is not within the grid's samples");
  if (grid.sparse()) throw std::invalid_argument("windowOf: a sparse grid has no window");
  const size_t size = scalarTypeSize(grid.type()), row = size_t(extent.x) * size;
  std::shared_ptr<uint8_t[]> samples(new uint8_t[row * size_t(extent.y) * size_t(extent.z)]);
  const auto* src = static_cast<const uint8_t*>(grid.data());
  uint8_t* dst = samples.get();
  for (int z = 0; z < extent.z; ++z)
    for (int y = 0; y < extent.y; ++y, dst += row)
      std::memcpy(dst, src + grid.index(first.x, first.y + y, first.z + z) * size, row);
  return Grid(grid.dims(), grid.type(), std::shared_ptr<const void>(samples, samples.get()), first, extent,
              grid.origin(), grid.spacing());
}

}  // namespace iso
