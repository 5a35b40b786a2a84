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

// The intersector of that name, as a scene file or --intersector gives it.
IntersectorSpec specNamed(const char* name) {
  IntersectorSpec spec;
  std::string error;
  EXPECT_TRUE(parseIntersector(name, spec, error)) << error;
  return spec;
}

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
// The spawn offset of a triangle hit rounds its origin away from the surface with nextFloatUp and
// nextFloatDown instead of std::nextafter: they must agree on every float, or images change.
TEST(Vec3, NextFloatMatchesNextafter) {
  auto same = [](float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0 || (std::isnan(a) && std::isnan(b)); };
  std::vector<float> values = {0.f, -0.f, 1.f, -1.f, INFINITY, -INFINITY, std::numeric_limits<float>::max(),
                               -std::numeric_limits<float>::max(), std::numeric_limits<float>::min(),
                               -std::numeric_limits<float>::min(), std::numeric_limits<float>::denorm_min(),
                               -std::numeric_limits<float>::denorm_min(), NAN};
  std::mt19937 rng(5);
  for (int i = 0; i < 200000; ++i) {
    const uint32_t bits = rng();
    float v;
    std::memcpy(&v, &bits, sizeof v);
    values.push_back(v);
  }
  for (float v : values) {
    ASSERT_TRUE(same(nextFloatUp(v), std::nextafter(v, INFINITY))) << v;
    ASSERT_TRUE(same(nextFloatDown(v), std::nextafter(v, -INFINITY))) << v;
  }
}

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
      for (uint32_t prim = 0; prim < surface.activeBricks().size(); ++prim) {
        SurfaceHit h;
        if (surface.intersectBrick(prim, org, dir, 0, tfar, h, stats)) { brick = h; tfar = h.t; b = true; }
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

// Counting crossings along a ray by restarting just past each hit (by its own error bound, in
// the class the hit led to, as spawned rays do) must give the parity that the classes at the
// two ends imply. A crack between cells or bricks shows as a missing crossing, a re-hit as an
// extra one.
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
    StartClass start = StartClass::Unknown;
    SurfaceHit hit;
    while (count < 1000 && surface.intersect(org, dir, tnear, 1e30, hit, stats, start)) {
      ++count;
      tnear = hit.t + hit.tError;
      start = hit.insideAfter ? StartClass::Inside : StartClass::Outside;
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

// A grid whose values vary along x only: `values[i]` at x = i, for every y and z in [0, 2].
Grid alongX(const std::vector<float>& values) {
  const Vec3i dims{int(values.size()), 3, 3};
  std::vector<float> v;
  for (int z = 0; z < dims.z; ++z)
    for (int y = 0; y < dims.y; ++y) v.insert(v.end(), values.begin(), values.end());
  return Grid(dims, std::move(v));
}

// A close pair of crossings at x = 0.999 and 1.001, then outside to the end. A restart past
// both (as a spawn offset can land) finds nothing when the field decides its class, and the
// second crossing at its start when it starts in the class the first hit led to.
TEST(StartClass, ACrossingSteppedOverIsReportedAtTheStart) {
  const Grid grid = alongX({-1, 0.001f, -1, -1, -1});
  const BrickGrid bricks(grid);
  for (const char* name : {"isolation", "reference", "linear"}) {
    SCOPED_TRACE(name);
    const IsoSurface surface(grid, bricks, 0, specNamed(name));
    TraversalStats stats;
    const Vec3d org{-1, 1.25, 0.75}, dir{1, 0, 0};
    SurfaceHit first;
    ASSERT_TRUE(surface.intersect(org, dir, 0, 1e30, first, stats));
    EXPECT_NEAR(first.t, 1.999, 1e-3);
    EXPECT_TRUE(first.insideAfter);
    const StartClass after = StartClass::Inside;

    SurfaceHit next;
    const double past = 2.0015;  // beyond the second crossing, in a solved cell
    EXPECT_FALSE(surface.intersect(org, dir, past, 1e30, next, stats));
    ASSERT_TRUE(surface.intersect(org, dir, past, 1e30, next, stats, after));
    EXPECT_NEAR(next.t, past, 1e-6);
    EXPECT_FALSE(next.insideAfter);
    EXPECT_TRUE(surface.occluded(org, dir, past, 1e30, stats, after));
    EXPECT_FALSE(surface.occluded(org, dir, past, 1e30, stats, StartClass::Outside));

    const double far = 3.5;  // in a cell that is outside at every corner
    ASSERT_TRUE(surface.intersect(org, dir, far, 1e30, next, stats, after));
    EXPECT_EQ(next.t, far);
    EXPECT_FALSE(next.insideAfter);
    EXPECT_FALSE(surface.intersect(org, dir, far, 1e30, next, stats, StartClass::Outside));

    // Starting in the class the field has there changes nothing: the restart just past
    // the first crossing finds the second (linear's bound on the first is its whole cell).
    if (std::string(name) == "linear") continue;
    ASSERT_TRUE(surface.intersect(org, dir, first.t + first.tError, 1e30, next, stats, after));
    EXPECT_NEAR(next.t, 2.001, 1e-3);
  }
}

// Inactive bricks are no Embree primitives, so a ray starting in one is seen by no brick
// query; crossesAtInactiveStart stands in for its first cell.
TEST(StartClass, AStartInAnInactiveBrickOfTheOtherClass) {
  std::vector<float> values(20, -1.f);  // x = 8..19 (the second brick) outside everywhere
  for (int x = 0; x < 8; ++x) values[x] = x % 2 ? 1.f : -1.f;
  const Grid grid = alongX(values);
  const BrickGrid bricks(grid);
  const IsoSurface surface(grid, bricks, 0, {});
  ASSERT_EQ(surface.activeBricks().size(), 1u);
  TraversalStats stats;
  SurfaceHit hit;
  const Vec3d inSecond{12.5, 1, 1}, inFirst{4.5, 1, 1}, dir{1, 0, 0};
  ASSERT_TRUE(surface.crossesAtInactiveStart(inSecond, dir, 0, 1e30, StartClass::Inside, &hit, stats));
  EXPECT_EQ(hit.t, 0);
  EXPECT_FALSE(hit.insideAfter);
  EXPECT_TRUE(surface.crossesAtInactiveStart(inSecond, dir, 0, 1e30, StartClass::Inside, nullptr, stats));
  EXPECT_FALSE(surface.crossesAtInactiveStart(inSecond, dir, 0, 1e30, StartClass::Outside, &hit, stats));
  EXPECT_FALSE(surface.crossesAtInactiveStart(inSecond, dir, 0, 1e30, StartClass::Unknown, &hit, stats));
  EXPECT_FALSE(surface.crossesAtInactiveStart(inFirst, dir, 0, 1e30, StartClass::Inside, &hit, stats));
}

// A world of one iso-surface, a sphere field at 0.6, and the class (value > 0.6) at a point.
struct SphereWorld {
  SphereWorld()
      : world(parseSceneText(R"({"volumes": [{"procedural": {"field": "sphere", "resolution": [24, 24, 24]},
                                              "isosurfaces": [{"value": 0.6}]}]})",
                             "sphere.json"),
              IntersectorSpec{}),
        grid(*world.volumes()[0].grid) {}
  bool insideAt(const Vec3d& p) const { return grid.interpolate((p - grid.origin()) / grid.spacing()) > 0.6; }
  World world;
  const Grid& grid;
};

// The renderer's spawned rays carry the class: on through the surface, the class the hit led
// to; back to the side the ray came from (a reflection, a shadow ray towards the light), the
// class before it.
TEST(StartClass, SpawnedRaysCarryTheClass) {
  const SphereWorld sphere;
  const World& world = sphere.world;
  auto insideAt = [&](const Vec3f& p) { return sphere.insideAt(Vec3d(p)); };
  TraversalStats stats;
  Ray ray;
  ray.org = {0.1f, -0.2f, -5};
  ray.dir = normalize(Vec3f{0.02f, 0.05f, 1});
  Hit hit;
  ASSERT_TRUE(world.intersect(ray, hit, stats));
  EXPECT_EQ(hit.insideAfter, insideAt(hit.position + ray.dir * 0.05f));
  EXPECT_NE(hit.insideAfter, insideAt(ray.org + ray.dir * (hit.t - 0.05f)));

  const Ray on = spawnRay(hit, ray.dir);
  EXPECT_EQ(on.fromSurface, hit.surface);
  EXPECT_EQ(on.fromInside, hit.insideAfter);
  const Vec3f n = hit.normal;
  EXPECT_EQ(spawnRay(hit, ray.dir - n * (2 * dot(ray.dir, n))).fromInside, !hit.insideAfter);
  EXPECT_EQ(spawnRayTo(hit, ray.org).fromInside, !hit.insideAfter);
  Hit next;
  ASSERT_TRUE(world.intersect(on, next, stats));
  EXPECT_GT(next.t, 0.1f);  // through the sphere to its far side
  EXPECT_EQ(next.insideAfter, !hit.insideAfter);
}

// A spawn offset can push a ray's origin outside its volume's box (by up to a cell for the
// loose bounds of linear or isolation:1); its class then applies where it meets the box, not
// after a fresh evaluation at the face. Here the ray runs nearly parallel to the face, so
// without moving the origin onto the box, Embree would not even visit the first brick.
TEST(StartClass, AnOriginJustOutsideTheBoxStartsOnIt) {
  const SphereWorld sphere;
  const World& world = sphere.world;
  const Grid& grid = sphere.grid;
  const Vec3d onFace = grid.origin() + Vec3d{0, 0.45 * 23, 0.55 * 23} * grid.spacing();
  const bool faceInside = sphere.insideAt(onFace);
  TraversalStats stats;
  for (bool fromInside : {faceInside, !faceInside}) {
    Ray ray;
    ray.org64 = onFace - Vec3d{0.3 * grid.spacing().x, 0, 0};
    ray.org = Vec3f(*ray.org64);
    ray.dir = normalize(Vec3f{0.03f, 1, -0.05f});
    ray.fromSurface = 0;
    ray.fromInside = fromInside;
    Hit hit;
    const bool got = world.intersect(ray, hit, stats);
    if (fromInside == faceInside) {
      EXPECT_TRUE(!got || hit.t > 0.1f * grid.spacing().x);  // the field's own class: nothing at the face
    } else {
      ASSERT_TRUE(got);
      EXPECT_LT(hit.t, 1e-3f * grid.spacing().x);
      EXPECT_EQ(hit.insideAfter, faceInside);
      EXPECT_TRUE(world.occluded(ray, stats));
    }
  }
}

// A spawned origin the offset pushed out of the box moves back along the offset's line, to
// where that line leaves the box: on the line (where the crossing's class was decided), not
// coordinate by coordinate onto the face (sideways off it). Also when rounding put the hit
// itself just outside the face.
TEST(StartClass, AnOriginPushedOutOfTheBoxReturnsAlongItsOffset) {
  const SphereWorld sphere;
  const World& world = sphere.world;
  const Grid& grid = sphere.grid;
  const Vec3d hi = grid.origin() + Vec3d(grid.dims() - Vec3i{1, 1, 1}) * grid.spacing();
  const Vec3d along = normalize(Vec3d{1, 0.4, -0.3});  // leaves the box through the face x = hi.x
  for (double hitInside : {1e-6, -1e-7}) {
    const Vec3d hitPoint{hi.x - hitInside * grid.spacing().x, 0.2 * hi.y, 0.6 * hi.z};
    const Vec3d offset = along * (4e-5 * grid.spacing().x);
    Ray ray;
    ray.org64 = hitPoint + offset;
    ray.org = Vec3f(*ray.org64);
    ray.dir = Vec3f(along);
    ray.fromSurface = 0;
    ray.fromOffset = offset;
    const Vec3d moved = world.startInsideVolume(ray).origin();
    EXPECT_EQ(moved.x, hi.x) << hitInside;  // on the face
    const Vec3d fromHit = moved - hitPoint;  // and on the line: no step across it
    EXPECT_LT(length(fromHit - along * dot(fromHit, along)), 1e-12 * length(hi)) << hitInside;
    // Coordinate by coordinate it would have kept y and z: off the line by about the offset.
    EXPECT_GT(std::fabs(moved.y - ray.org64->y), 0.1 * std::fabs(offset.y)) << hitInside;
  }
}

// A ray that starts inside the box starts in the cell of its exact origin, not of its float one.
// The field is z - 86.999999 (the surface 1e-6 below the face z = 87); the origin lies 2.2e-6
// below the face, outside, and heads down and away. In float its z rounds onto the face (float's
// spacing there is 7.6e-6): a walk begun in the cell above, positive all over, reported a
// crossing at the start where the ray meets none (found on lidc2, where each such ray spawned
// from a hit added a pair of crossings).
TEST(StartClass, AStartInTheCellOfTheExactOrigin) {
  const Vec3i dims{4, 3, 90};
  std::vector<float> v;
  for (int z = 0; z < dims.z; ++z)
    for (int i = 0; i < dims.x * dims.y; ++i) v.push_back(float(double(z) - 86.999999));
  const Grid grid(dims, std::move(v));
  const BrickGrid bricks(grid);
  const Vec3d org{0.5, 1, 86.9999978}, dir = normalize(Vec3d{1, 0, -0.022});
  ASSERT_EQ(float(org.z), 87.f);  // the premise: float's origin is on the face
  for (const char* name : {"isolation", "reference"}) {
    SCOPED_TRACE(name);
    const IsoSurface surface(grid, bricks, 0, specNamed(name));
    TraversalStats stats;
    SurfaceHit hit;
    for (StartClass start : {StartClass::Outside, StartClass::Unknown}) {
      EXPECT_FALSE(surface.intersect(org, dir, 0, 1e30, hit, stats, start));
      EXPECT_FALSE(surface.occluded(org, dir, 0, 1e30, stats, start));
    }
    // Given the other class, the crossing is at the start.
    ASSERT_TRUE(surface.intersect(org, dir, 0, 1e30, hit, stats, StartClass::Inside));
    EXPECT_LT(hit.t, 1e-4);
    EXPECT_FALSE(hit.insideAfter);
  }
}

// A brick whose face a spawned ray's float origin rounds onto, while its exact origin lies just
// beyond that face heading away, holds none of the exact ray and does not start it. The field is
// z - 88.000002 (the surface 2e-6 above the brick seam z = 88); the origin lies 3.5e-6 above the
// seam, inside, and heads up and away; in float its z rounds onto the seam. The brick below used
// to walk a zero-length segment comparing the given class with the seam's, which the exact ray
// crosses behind its origin, outside: a crossing at the start where the ray meets none (found on
// hydrogen, HeadMR, lidc2, smoke and example4d, each such spawned ray adding a pair).
TEST(StartClass, ABrickTheExactOriginLiesBeyondDoesNotStartTheRay) {
  // (Samples at x = y = 0 below the seam are 1: the brick below holds surface in the cells next
  // to the ray's start, so Embree calls it for this ray; the cells the ray walks keep z - 88.000002.)
  const Vec3i dims{4, 3, 100};
  std::string bytes;
  for (int z = 0; z < dims.z; ++z)
    for (int i = 0; i < dims.x * dims.y; ++i) {
      const float v = i == 0 && z >= 80 && z < 88 ? 1.f : float(double(z) - 88.000002);
      bytes.append(reinterpret_cast<const char*>(&v), sizeof v);
    }
  const std::string dir = test::scratchDir();
  test::writeBytes(dir + "/seam_4x3x100_float32.raw", bytes);
  for (const char* name : {"isolation", "reference"}) {
    SCOPED_TRACE(name);
    const World world(parseSceneText(R"({"volumes": [{"file": ")" + dir + R"(/seam_4x3x100_float32.raw",
                                                      "isosurfaces": [{"value": 0}]}]})",
                                     "seam.json"),
                      specNamed(name));
    ASSERT_EQ(BrickGrid::kCells * 11, 88);  // the premise: z = 88 is a seam between bricks
    Ray ray;
    ray.org64 = Vec3d{0.5, 1, 88.0000035};
    ray.org = Vec3f(*ray.org64);
    ASSERT_EQ(ray.org.z, 88.f);  // and the float origin lies on it
    ray.dir = normalize(Vec3f{1, 0, 0.022f});
    ray.fromSurface = 0;
    TraversalStats stats;
    Hit hit;
    ray.fromInside = true;
    EXPECT_FALSE(world.intersect(ray, hit, stats));
    EXPECT_FALSE(world.occluded(ray, stats));
    // Given the other class, the crossing is at the start.
    ray.fromInside = false;
    ASSERT_TRUE(world.intersect(ray, hit, stats));
    EXPECT_LT(hit.t, 1e-4f);
    EXPECT_TRUE(hit.insideAfter);
    EXPECT_TRUE(world.occluded(ray, stats));
  }
}

}  // namespace
}  // namespace iso
