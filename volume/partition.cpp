#include "volume/partition.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "volume/input_error.h"

namespace iso {
namespace {

// The index of brick (x, y, z).
uint32_t brickIndex(const BrickGrid& bricks, int x, int y, int z) {
  const Vec3i n = bricks.count();
  return uint32_t((size_t(z) * size_t(n.y) + size_t(y)) * size_t(n.x) + size_t(x));
}

// The cells [cellLo, cellHi) of the bricks [brickLo, brickHi) of `box`.
void setCells(RankBox& box, const BrickGrid& bricks) {
  box.cellLo = bricks.cellBegin(brickIndex(bricks, box.brickLo.x, box.brickLo.y, box.brickLo.z));
  box.cellHi = bricks.cellEnd(brickIndex(bricks, box.brickHi.x - 1, box.brickHi.y - 1, box.brickHi.z - 1));
}

struct Splitter {
  const BrickGrid& bricks;
  const std::vector<double>& weights;
  bool byCount;
  std::string where;
  std::vector<RankBox> out;

  double weightOf(uint32_t b) const { return byCount ? 1.0 : weights[b]; }
  uint32_t index(int x, int y, int z) const { return brickIndex(bricks, x, y, z); }

  void split(Vec3i lo, Vec3i hi, int ranks) {
    const Vec3i n{hi.x - lo.x, hi.y - lo.y, hi.z - lo.z};
    const size_t count = size_t(n.x) * n.y * n.z;
    if (ranks == 1) {
      RankBox box;
      box.brickLo = lo;
      box.brickHi = hi;
      box.bricks = count;
      setCells(box, bricks);
      for (int z = lo.z; z < hi.z; ++z)
        for (int y = lo.y; y < hi.y; ++y)
          for (int x = lo.x; x < hi.x; ++x) box.weight += weightOf(index(x, y, z));
      out.push_back(box);
      return;
    }
    if (count < size_t(ranks))
      throw InputError(where, "", "has " + std::to_string(bricks.size()) + " bricks (of 8^3 cells): too few for " +
                                      std::to_string(ranks) + " more ranks in one of its boxes");
    // The longest axis that can be cut; along it, the slabs' weights.
    int axis = 0;
    for (int a = 1; a < 3; ++a)
      if (n[a] > n[axis]) axis = a;
    std::vector<double> slab(size_t(n[axis]), 0.0);
    for (int z = lo.z; z < hi.z; ++z)
      for (int y = lo.y; y < hi.y; ++y)
        for (int x = lo.x; x < hi.x; ++x) {
          const int k = (axis == 0 ? x : axis == 1 ? y : z) - lo[axis];
          slab[size_t(k)] += weightOf(index(x, y, z));
        }
    double total = 0;
    for (double w : slab) total += w;
    const int left = ranks / 2, right = ranks - left;
    const size_t perSlab = count / size_t(n[axis]);
    // The cut after slab s - 1 closest to the left's share, leaving each side a brick per rank.
    int best = -1;
    double bestMiss = INFINITY, prefix = 0;
    for (int s = 1; s < n[axis]; ++s) {
      prefix += slab[size_t(s - 1)];
      if (size_t(s) * perSlab < size_t(left) || size_t(n[axis] - s) * perSlab < size_t(right)) continue;
      const double miss = std::fabs(prefix - total * double(left) / double(ranks));
      if (miss < bestMiss) bestMiss = miss, best = s;
    }
    if (best < 0)
      throw InputError(where, "", "cannot be cut into " + std::to_string(ranks) + " boxes of whole bricks along its longest axis (" +
                                      std::to_string(n[axis]) + " bricks)");
    Vec3i mid = hi;
    mid[axis] = lo[axis] + best;
    split(lo, mid, left);
    Vec3i start = lo;
    start[axis] = lo[axis] + best;
    split(start, hi, right);
  }
};

}  // namespace

std::vector<RankBox> partitionBricks(const BrickGrid& bricks, const std::vector<double>& weights, int ranks,
                                     const std::string& where) {
  if (ranks < 1) throw InputError(where, "", "needs at least one rank");
  if (weights.size() != bricks.size()) throw InputError(where, "", "one weight per brick is needed");
  double total = 0;
  for (double w : weights) total += w;
  Splitter s{bricks, weights, !(total > 0), where, {}};
  s.split({0, 0, 0}, bricks.count(), ranks);
  return s.out;
}

RankBox heldBox(const RankBox& own, const BrickGrid& bricks, double replicate) {
  const Vec3i n = bricks.count();
  const double budget = replicate * double(bricks.size());
  auto grown = [&](int layers) {
    RankBox b = own;
    b.bricks = 1;
    for (int a = 0; a < 3; ++a) {
      b.brickLo[a] = std::max(own.brickLo[a] - layers, 0);
      b.brickHi[a] = std::min(own.brickHi[a] + layers, n[a]);
      b.bricks *= size_t(b.brickHi[a] - b.brickLo[a]);
    }
    return b;
  };
  int layers = 0;
  for (const int most = std::max({n.x, n.y, n.z}); layers < most;) {
    const RankBox next = grown(layers + 1);
    if (double(next.bricks - own.bricks) > budget) break;
    ++layers;
  }
  if (layers == 0) return own;
  RankBox held = grown(layers);
  setCells(held, bricks);
  held.weight = 0;  // (not summed: the weights are the own box's business)
  return held;
}

Vec3i RankBox::windowFirst() const {
  return {std::max(cellLo.x - 1, 0), std::max(cellLo.y - 1, 0), std::max(cellLo.z - 1, 0)};
}

Vec3i RankBox::windowExtent(Vec3i dims) const {
  const Vec3i first = windowFirst();
  Vec3i e;
  for (int a = 0; a < 3; ++a) e[a] = std::min(cellHi[a] + 1, dims[a] - 1) - first[a] + 1;
  return e;
}

}  // namespace iso
