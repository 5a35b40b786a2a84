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
  const CutRays* camera;  // (null: the longest axis is cut)
  std::vector<RankBox> out;
  std::vector<int> cuts;  // the axis of each cut, in the order made

  double weightOf(uint32_t b) const { return byCount ? 1.0 : weights[b]; }
  uint32_t index(int x, int y, int z) const { return brickIndex(bricks, x, y, z); }

  // The cut of bricks [lo, hi) along `axis` (bricks from lo[axis]) whose left side's weight is
  // closest to its share (ranks / 2 of `ranks`), each side left a brick per rank; -1 if none.
  int cutAlong(Vec3i lo, Vec3i hi, int axis, int ranks) const {
    const Vec3i n{hi.x - lo.x, hi.y - lo.y, hi.z - lo.z};
    const size_t count = size_t(n.x) * n.y * n.z;
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
    int best = -1;
    double bestMiss = INFINITY, prefix = 0;
    for (int s = 1; s < n[axis]; ++s) {
      prefix += slab[size_t(s - 1)];
      if (size_t(s) * perSlab < size_t(left) || size_t(n[axis] - s) * perSlab < size_t(right)) continue;
      const double miss = std::fabs(prefix - total * double(left) / double(ranks));
      if (miss < bestMiss) bestMiss = miss, best = s;
    }
    return best;
  }

  // The centres of the box's weighted bricks (every brick's if none is), at most ~1024 of them,
  // evenly: where the rays leaving the surfaces start (crossings).
  std::vector<Vec3d> sourcesIn(Vec3i lo, Vec3i hi) const {
    std::vector<uint32_t> bricksIn;
    for (bool weighted : {true, false}) {
      for (int z = lo.z; z < hi.z; ++z)
        for (int y = lo.y; y < hi.y; ++y)
          for (int x = lo.x; x < hi.x; ++x)
            if (!weighted || weightOf(index(x, y, z)) > 0) bricksIn.push_back(index(x, y, z));
      if (!bricksIn.empty()) break;
    }
    std::vector<Vec3d> centres;
    const size_t stride = (bricksIn.size() + 1023) / 1024;
    for (size_t i = 0; i < bricksIn.size(); i += stride)
      centres.push_back((Vec3d(bricks.cellBegin(bricksIn[i])) + Vec3d(bricks.cellEnd(bricksIn[i]))) * 0.5);
    return centres;
  }

  // What cutting bricks [lo, hi) before brick `at` on `axis` would send between the two sides,
  // estimated: the fraction of the camera's sample rays that meet the box and pass the cut inside
  // it, plus the fraction of rays from `sources` (sourcesIn), 26 directions each, that pass it on
  // their way out of the box.
  double crossings(Vec3i lo, Vec3i hi, int axis, int at, const std::vector<Vec3d>& sources) const {
    const Vec3d boxLo(bricks.cellBegin(index(lo.x, lo.y, lo.z)));
    const Vec3d boxHi(bricks.cellEnd(index(hi.x - 1, hi.y - 1, hi.z - 1)));
    const double plane = double(bricks.cellBegin(index(axis == 0 ? at : lo.x, axis == 1 ? at : lo.y, axis == 2 ? at : lo.z))[axis]);
    auto passes = [&](const Vec3d& a, const Vec3d& b) { return (a[axis] < plane) != (b[axis] < plane); };
    size_t met = 0, passed = 0;
    for (size_t r = 0; r < camera->org.size(); ++r) {
      double t0 = 0, t1 = INFINITY;
      const Vec3d& o = camera->org[r];
      const Vec3d& d = camera->dir[r];
      if (!lineInBox(o, d, boxLo, boxHi, t0, t1) || !(t1 >= 0)) continue;
      t0 = std::max(t0, 0.0);
      ++met;
      passed += passes(o + d * t0, o + d * t1);
    }
    size_t left = 0, crossed = 0;
    for (const Vec3d& c : sources) {
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            if (!dx && !dy && !dz) continue;
            const Vec3d d{double(dx), double(dy), double(dz)};
            double t0 = 0, t1 = INFINITY;
            if (!lineInBox(c, d, boxLo, boxHi, t0, t1)) continue;
            ++left;
            crossed += passes(c, c + d * t1);
          }
    }
    return (met ? double(passed) / double(met) : 0.0) + (left ? double(crossed) / double(left) : 0.0);
  }

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
    // Along each axis the cut closest to the weights' share; the axis cut is the longest, or,
    // with sample rays, the one across whose cut the fewest of them pass.
    int longest = 0;
    for (int a = 1; a < 3; ++a)
      if (n[a] > n[longest]) longest = a;
    int axis = longest, best = -1;
    if (camera && !camera->org.empty()) {
      const std::vector<Vec3d> sources = sourcesIn(lo, hi);
      double cheapest = INFINITY;
      for (int a : {longest, (longest + 1) % 3, (longest + 2) % 3}) {
        const int cut = cutAlong(lo, hi, a, ranks);
        if (cut < 0) continue;
        const double cost = crossings(lo, hi, a, lo[a] + cut, sources);
        if (cost < cheapest) cheapest = cost, axis = a, best = cut;
      }
    } else {
      best = cutAlong(lo, hi, longest, ranks);
    }
    if (best < 0)
      throw InputError(where, "", "cannot be cut into " + std::to_string(ranks) + " boxes of whole bricks along its longest axis (" +
                                      std::to_string(n[axis]) + " bricks)");
    cuts.push_back(axis);
    const int left = ranks / 2, right = ranks - left;
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
                                     const std::string& where, const CutRays* camera, std::vector<int>* cutAxes) {
  if (ranks < 1) throw InputError(where, "", "needs at least one rank");
  if (weights.size() != bricks.size()) throw InputError(where, "", "one weight per brick is needed");
  double total = 0;
  for (double w : weights) total += w;
  Splitter s{bricks, weights, !(total > 0), where, camera, {}, {}};
  s.split({0, 0, 0}, bricks.count(), ranks);
  if (cutAxes) *cutAxes = s.cuts;
  return s.out;
}

std::vector<double> activeBrickWeights(const BrickGrid& bricks, const std::vector<double>& isoValues) {
  std::vector<double> weights(bricks.size(), 0.0);
  for (double iso : isoValues)
    for (uint32_t b : bricks.activeBricks(float(iso))) weights[b] = 1;
  return weights;
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
