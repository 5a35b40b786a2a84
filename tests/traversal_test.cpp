#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <random>

#include "scene/world.h"
#include "tests/test_util.h"
#include "volume/iso_surface.h"
#include "volume/loaders.h"
#include "volume/procedural.h"

namespace iso {
namespace {

struct RandomRays {
  explicit RandomRays(const Grid& g, uint64_t seed) : grid(g), rng(seed) {}
  // From outside the grid's box towards a random point inside it.
  void next(Vec3d& org, Vec3d& dir) {
    const Vec3d lo = grid.origin();
    const Vec3d size = Vec3d(Vec3i{grid.dims().x - 1, grid.dims().y - 1, grid.dims().z - 1}) * grid.spacing();
    const Vec3d target = lo + Vec3d{u(rng), u(rng), u(rng)} * size;
    const double z = 2 * u(rng) - 1, phi = 2 * M_PI * u(rng), r = std::sqrt(1 - z * z);
    org = target + Vec3d{r * std::cos(phi), r * std::sin(phi), z} * (2 * length(size));
    dir = normalize(target - org);
  }
  const Grid& grid;
  std::mt19937_64 rng;
  std::uniform_real_distribution<double> u{0, 1};
};

// Bricks are separate Embree primitives; the answer must not depend on where they split
// the grid: the union of brick queries gives the whole-grid DDA's hit bit for bit.
TEST(Traversal, BricksAgreeWithTheWholeGridBitForBit) {
  const Grid grid = loadVolumeFile(test::dataPath("volumes/neghip_64x64x64_uint8.raw"));
  const BrickGrid bricks(grid);
  for (double isoValue : {40.0, 40.5, 100.0}) {
    const IsoSurface surface(grid, bricks, isoValue, {IntersectorKind::Isolation, 8});
    RandomRays rays(grid, 3);
    TraversalStats stats;
    int hits = 0;
    for (int i = 0; i < 20000; ++i) {
      Vec3d org, dir;
      rays.next(org, dir);
      SurfaceHit whole, brick;
      const bool a = surface.intersect(org, dir, 0, 1e30, whole, stats);
      bool b = false;
      double tfar = 1e30;
      for (uint32_t id : surface.activeBricks()) {
        SurfaceHit h;
        if (surface.intersectBrick(id, org, dir, 0, tfar, h, stats)) { brick = h; tfar = h.t; b = true; }
      }
      ASSERT_EQ(a, b) << "ray " << i;
      if (!a) continue;
      ++hits;
      EXPECT_EQ(whole.t, brick.t) << "ray " << i;
      EXPECT_EQ(whole.normal, brick.normal) << "ray " << i;
    }
    EXPECT_GT(hits, 5000);
  }
}

// The field at a world point, in double, from the grid (clamped to its box).
double fieldAt(const Grid& grid, const Vec3d& world) {
  const Vec3d p = (world - grid.origin()) / grid.spacing();
  Vec3i c;
  Vec3d local;
  for (int a = 0; a < 3; ++a) {
    const double x = std::clamp(p[a], 0.0, double(grid.dims()[a] - 1));
    c[a] = std::min(int(std::floor(x)), grid.dims()[a] - 2);
    local[a] = x - c[a];
  }
  float v[8];
  grid.cellCorners(c.x, c.y, c.z, v);
  double g[8];
  for (int i = 0; i < 8; ++i) g[i] = v[i];
  return trilinear(g, local);
}

// Counting crossings along a ray by restarting just past each hit (by its own error bound)
// must give the parity that the classes at the two ends imply. A crack between cells or
// bricks shows as a missing crossing, a re-hit as an extra one.
void expectParity(const Grid& grid, double isoValue, int n, uint64_t seed) {
  const BrickGrid bricks(grid);
  const IsoSurface surface(grid, bricks, isoValue, {IntersectorKind::Isolation, 8});
  RandomRays rays(grid, seed);
  TraversalStats stats;
  int errors = 0, crossings = 0, checked = 0;
  const Vec3d lo = grid.origin();
  const Vec3d hi = lo + Vec3d(Vec3i{grid.dims().x - 1, grid.dims().y - 1, grid.dims().z - 1}) * grid.spacing();
  for (int i = 0; i < n; ++i) {
    Vec3d org, dir;
    rays.next(org, dir);
    // Where the ray is inside the grid's box, and the classes at both ends.
    double t0 = 0, t1 = 1e30;
    for (int a = 0; a < 3; ++a) {
      const double ta = (lo[a] - org[a]) / dir[a], tb = (hi[a] - org[a]) / dir[a];
      t0 = std::max(t0, std::min(ta, tb));
      t1 = std::min(t1, std::max(ta, tb));
    }
    if (!(t0 < t1)) continue;
    const double f0 = fieldAt(grid, org + dir * t0) - isoValue;
    const double f1 = fieldAt(grid, org + dir * t1) - isoValue;
    // Skip rays whose ends are within rounding of the surface: their class is not exact.
    if (std::fabs(f0) < 1e-3 || std::fabs(f1) < 1e-3) continue;
    ++checked;
    int count = 0;
    double tnear = 0;
    SurfaceHit hit;
    while (count < 1000 && surface.intersect(org, dir, tnear, 1e30, hit, stats)) {
      ++count;
      tnear = hit.t + hit.tError;
    }
    crossings += count;
    if ((count % 2 != 0) != ((f0 > 0) != (f1 > 0))) ++errors;
  }
  EXPECT_EQ(errors, 0) << "parity errors in " << checked << " rays, " << crossings << " crossings";
  EXPECT_GT(checked, n * 9 / 10);
  EXPECT_GT(crossings, n / 2);
}

// Negated distance fields: value > iso inside the shape, so the boundary is outside.
Grid insideOut(const Grid& g) {
  std::vector<float> v(g.sampleCount());
  for (size_t i = 0; i < v.size(); ++i) v[i] = -g.value(i);
  return Grid(g.dims(), std::move(v), g.origin(), g.spacing());
}

TEST(Traversal, ParityOnProceduralFields) {
  expectParity(insideOut(makeProceduralGrid(Field::Sphere, {40, 40, 40})), -0.7, 20000, 1);
  expectParity(insideOut(makeProceduralGrid(Field::Torus, {48, 48, 48})), -0.25, 20000, 2);
}

TEST(Traversal, ParityOnRealVolumesNearAndFarFromTheOrigin) {
  Grid nucleon = loadVolumeFile(test::dataPath("volumes/nucleon/nucleon.nrrd"));
  Grid bucky = loadVolumeFile(test::dataPath("volumes/bucky_32x32x32_uint8.raw"));
  expectParity(nucleon, 60, 20000, 3);
  expectParity(bucky, 100, 20000, 4);
  nucleon.setOrigin({1e5, -1e5, 1e5});
  bucky.setOrigin({-1e5, 1e5, 1e5});
  expectParity(nucleon, 60, 20000, 5);
  expectParity(bucky, 100, 20000, 6);
}

TEST(Traversal, InvalidRaysHitNothing) {
  const Grid grid = makeProceduralGrid(Field::Sphere, {16, 16, 16});
  const BrickGrid bricks(grid);
  const IsoSurface surface(grid, bricks, 0.5, {});
  TraversalStats stats;
  SurfaceHit hit;
  const double nan = std::nan(""), inf = INFINITY;
  EXPECT_FALSE(surface.intersect({0, 0, -5}, {0, 0, 0}, 0, 1e30, hit, stats));
  EXPECT_FALSE(surface.intersect({0, 0, -5}, {nan, 0, 1}, 0, 1e30, hit, stats));
  EXPECT_FALSE(surface.intersect({0, 0, -5}, {inf, 0, 1}, 0, 1e30, hit, stats));
  EXPECT_FALSE(surface.intersect({nan, 0, -5}, {0, 0, 1}, 0, 1e30, hit, stats));
  EXPECT_FALSE(surface.occluded({0, 0, -5}, {0, 0, 0}, 0, 1e30, stats));
  // Axis-parallel rays through the centre do hit, at the analytic distance.
  ASSERT_TRUE(surface.intersect({0, 0, -5}, {0, 0, 1}, 0, 1e30, hit, stats));
  EXPECT_NEAR(hit.t, 4.5, 0.01);
  EXPECT_TRUE(surface.occluded({0, 0, -5}, {0, 0, 1}, 0, 1e30, stats));
  EXPECT_FALSE(surface.occluded({0, 0, -5}, {0, 0, 1}, 0, 4.4, stats));
}

}  // namespace
}  // namespace iso
