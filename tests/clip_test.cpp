// Clipping with closed caps ("clip" on a volume or the scene): the clip region's geometry, the
// capped solid seen by camera rays, watertightness of clipped surfaces under secondary rays
// (planes at random angles, through samples exactly, boxes, near and far from the origin),
// clipped meshes, caps coloured by data, and the scene keys' refusals.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "accuracy/watertight.h"
#include "scene/world.h"
#include "volume/clip.h"
#include "volume/input_error.h"
#include "tests/test_util.h"

namespace iso {
namespace {

Vec3d randomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> g;
  return normalize(Vec3d{g(rng), g(rng), g(rng)});
}

TEST(ClipRegion, ExtentIsWhereTheRayIsKept) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-2, 2);
  for (int trial = 0; trial < 200; ++trial) {
    ClipRegion clip;
    for (int k = 0; k < 3; ++k) clip.addPlane({u(rng), u(rng), u(rng)}, randomUnit(rng));
    if (trial % 2) clip.addBox({-1.5, -1, -1.2}, {1.1, 1.4, 0.9});
    const Vec3d o{u(rng), u(rng), u(rng)}, d = randomUnit(rng);
    double k0, k1;
    int p0, p1;
    clip.extent(o, d, k0, k1, p0, p1);
    for (double t = -5; t <= 5; t += 0.01) {
      const bool inside = t > k0 + 1e-9 && t < k1 - 1e-9, outside = t < k0 - 1e-9 || t > k1 + 1e-9;
      if (inside) {
        EXPECT_TRUE(clip.keeps(o + d * t)) << trial << " t " << t;
      }
      if (outside) {
        EXPECT_FALSE(clip.keeps(o + d * t)) << trial << " t " << t;
      }
    }
    // The bounding planes pass through the extent's ends.
    if (k0 <= k1 && p0 >= 0) {
      EXPECT_NEAR(dot(clip.planes()[size_t(p0)].normal, o + d * k0), clip.planes()[size_t(p0)].offset, 1e-12);
    }
    if (k0 <= k1 && p1 >= 0) {
      EXPECT_NEAR(dot(clip.planes()[size_t(p1)].normal, o + d * k1), clip.planes()[size_t(p1)].offset, 1e-12);
    }
  }
}

TEST(ClipRegion, TransformedKeepsTheImagesOfWhatItKept) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-2, 2);
  ClipRegion clip;
  clip.addPlane({0.2, -0.1, 0.3}, {1, 2, -0.5});
  clip.addBox({-1, -1, -1}, {1, 0.5, 1.5});
  const Transform to = Transform::translate({1e5, -3, 7}) * Transform::rotate(37, {1, 1, 0}) * Transform::scale({2, 0.5, 3});
  const ClipRegion moved = clip.transformed(to);
  for (int i = 0; i < 2000; ++i) {
    const Vec3d p{u(rng), u(rng), u(rng)};
    if (clip.planeDistance(p) < 1e-6) continue;
    EXPECT_EQ(clip.keeps(p), moved.keeps(to.point(p))) << i;
  }
}

TEST(ClipRegion, BoxesAreKeptCutOrMetByTheBoundary) {
  ClipRegion clip;
  clip.addPlane({0, 0, 0}, {1, 0, 0});
  clip.addPlane({0, 0, 0}, {0, 1, 0});
  EXPECT_EQ(clip.classify({-3, -3, -3}, {-1, -1, 3}, 0.1), ClipRegion::BoxSide::Kept);
  EXPECT_EQ(clip.classify({1, -3, -3}, {2, -1, 3}, 0.1), ClipRegion::BoxSide::Cut);
  EXPECT_EQ(clip.classify({-1, -1, -1}, {1, -0.5, 1}, 0.1), ClipRegion::BoxSide::Boundary);
  // Within the margin of a plane: met.
  EXPECT_EQ(clip.classify({-3, -3, -3}, {-0.05, -1, 3}, 0.1), ClipRegion::BoxSide::Boundary);
}

// A ball (the sphere field's values below 0.5: radius 0.5) cut by `normal` through `point`.
std::string cutBall(const Vec3d& point, const Vec3d& normal, const std::string& more = "") {
  char text[1024];
  std::snprintf(text, sizeof text,
                R"({"camera": {"position": [0, 0, 3], "look_at": [0, 0, 0]},
                    "volumes": [{"procedural": {"field": "sphere", "resolution": [40, 40, 40]},
                                 "isosurfaces": [{"value": 0.5, "inside": "below"}],
                                 "clip": [{"plane": {"point": [%.17g, %.17g, %.17g], "normal": [%.17g, %.17g, %.17g]}}%s]}]})",
                point.x, point.y, point.z, normal.x, normal.y, normal.z, more.c_str());
  return text;
}

// A float vector in double, out of line: GCC 12.2 at -O2 folded Vec3d(Vec3f(v)) back to the double
// v it was rounded from here (the float ray's origin came out as the unrounded double; the
// disassembly shows the rounded copy stored and the double passed on), and the line checked was
// not the line traced.
[[gnu::noinline]] Vec3d widened(const Vec3f& v) { return Vec3d(v); }

// The chord of the line o + t d through the ball of radius r about the origin, cut to the half-space
// kept by the plane through `point` with normal `n`: [t0, t1] (empty: t0 > t1).
void keptChord(const Vec3d& o, const Vec3d& d, const Vec3d& n, const Vec3d& point, double r, double& t0, double& t1) {
  const double b = dot(o, d) / dot(d, d), disc = b * b - (dot(o, o) - r * r) / dot(d, d);
  t0 = INFINITY, t1 = -INFINITY;
  if (disc > 0) t0 = -b - std::sqrt(disc), t1 = -b + std::sqrt(disc);
  const double nd = dot(n, d), gap = dot(n, point - o);
  if (nd > 0) t1 = std::min(t1, gap / nd);
  else if (nd < 0) t0 = std::max(t0, gap / nd);
  else if (gap < 0) t1 = -INFINITY;
}

// Every ray whose line passes through the kept half of the ball (by a margin larger than the
// grid's interpolation error) hits it, on the surface or on the cap; every ray that misses it by
// that margin hits nothing. Cap hits lie on the plane, inside the ball; surface hits in the kept half.
TEST(ClippedSurface, RaysIntoTheKeptHalfBallHitTheSurfaceOrTheCap) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-0.7, 0.7);
  for (int plane = 0; plane < 4; ++plane) {
    const Vec3d n = randomUnit(rng), point = n * (plane * 0.1 - 0.15);
    const World world(parseSceneText(cutBall(point, n), "ball.json"), IntersectorSpec{});
    TraversalStats stats;
    int caps = 0, surfaces = 0, checked = 0;
    for (int i = 0; i < 4000; ++i) {
      Ray ray;
      const Vec3d from = randomUnit(rng) * 3.0, to{u(rng), u(rng), u(rng)};
      ray.org = Vec3f(from);
      ray.dir = Vec3f(normalize(to - from));
      const Vec3d o = widened(ray.org), d = widened(ray.dir);
      // The trilinear sphere is off the true one by less than 0.01 at 40^3: a margin of 0.03.
      double inner0, inner1, outer0, outer1;
      keptChord(o, d, n, point, 0.47, inner0, inner1);
      keptChord(o, d, n, point, 0.53, outer0, outer1);
      Hit hit;
      const bool found = world.intersect(ray, hit, stats);
      if (inner1 - inner0 > 0.03) {
        ++checked;
        ASSERT_TRUE(found) << "plane " << plane << " ray " << i;
        const Vec3d p = hit.position64;
        if (hit.cap) {
          ++caps;
          EXPECT_NEAR(dot(n, p - point), 0, 1e-9);
          EXPECT_LT(length(p), 0.5 + 0.01);
          EXPECT_NEAR(dot(Vec3d(hit.normal), n), 1, 1e-6);  // out of the solid: the plane's normal
        } else {
          ++surfaces;
          EXPECT_LE(dot(n, p - point), 1e-9);
          EXPECT_NEAR(length(p), 0.5, 0.01);
        }
        const double t = dot(p - o, d) / dot(d, d);
        EXPECT_GE(t, outer0 - 1e-9);
        EXPECT_LE(t, inner0 + 1e-9);
      } else if (!(outer1 >= outer0)) {
        EXPECT_FALSE(found) << "plane " << plane << " ray " << i << " hits the part cut away at t " << hit.t;
      }
    }
    EXPECT_GT(checked, 500);
    EXPECT_GT(caps, 50) << "plane " << plane;
    EXPECT_GT(surfaces, 50) << "plane " << plane;
  }
}

WatertightReport checkOne(const std::string& scene, RayFlow flow, int rays, const Vec3d& offset, uint64_t seed = 7) {
  WatertightOptions options;
  options.rays = rays;
  options.seed = seed;
  options.offset = offset;
  options.rayFlow = flow;
  const std::vector<WatertightReport> reports = checkWatertight(parseSceneText(scene, "clip.json"), IntersectorSpec{}, options);
  EXPECT_EQ(reports.size(), 1u);
  return reports.at(0);
}

void expectWatertight(const WatertightReport& r, int rays) {
  EXPECT_EQ(r.counts.rays, uint64_t(rays));
  EXPECT_GT(r.counts.crossings, uint64_t(rays / 10));
  EXPECT_EQ(r.counts.parityErrors, 0u);
  EXPECT_EQ(r.counts.selfHits, 0u);
  EXPECT_EQ(r.counts.insideEscapes, 0u);
  EXPECT_EQ(r.counts.shadowMismatches, 0u);
}

// 10^6 rays per test over planes at random angles (the ball's solid and, "inside": "above", the
// grid's box less the ball), near the origin and 1e5 away; and through the packet walk.
TEST(ClippedSurface, WatertightWithPlanesAtRandomAnglesNearAndFar) {
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  for (int plane = 0; plane < 4; ++plane) {
    const Vec3d n = randomUnit(rng), point{u(rng), u(rng), u(rng)};
    std::string scene = cutBall(point, n);
    if (plane % 2) scene.replace(scene.find("\"below\""), 7, "\"above\"");
    for (const Vec3d offset : {Vec3d{0, 0, 0}, Vec3d{1e5, -1e5, 1e5}}) {
      SCOPED_TRACE("plane " + std::to_string(plane) + " offset " + std::to_string(offset.x));
      expectWatertight(checkOne(scene, RayFlow::Scalar, 125000, offset), 125000);
      if (plane == 0) expectWatertight(checkOne(scene, RayFlow::Wavefront, 20000, offset), 20000);
    }
  }
}

// Integer data cut exactly through samples, cell faces and edges (planes on whole grid
// coordinates, a diagonal through sample rows), by a box, and two planes at once.
TEST(ClippedSurface, WatertightThroughSamplesAndBoxes) {
  const std::string hydrogen = test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw");
  const std::string bucky = test::dataPath("volumes/bucky_32x32x32_uint8.raw");
  const std::vector<std::string> scenes = {
      R"({"volumes": [{"file": ")" + hydrogen + R"(", "isosurfaces": [{"value": 20}],
          "clip": [{"plane": {"point": [64, 0, 0], "normal": [1, 0, 0]}}, {"plane": {"point": [60, 60, 60], "normal": [0, -1, 1]}}]}]})",
      R"({"volumes": [{"file": ")" + bucky + R"(", "isosurfaces": [{"value": 128}],
          "clip": [{"box": {"min": [4, 8, 3], "max": [27, 24, 16]}}]}]})",
      R"({"clip": [{"plane": {"point": [16, 16, 16], "normal": [1, 1, 1]}}],
          "volumes": [{"file": ")" + bucky + R"(", "isosurfaces": [{"value": 64}]}]})",
  };
  for (const std::string& scene : scenes)
    for (const Vec3d offset : {Vec3d{0, 0, 0}, Vec3d{1e5, 1e5, -1e5}}) {
      SCOPED_TRACE(scene.substr(0, 160) + " offset " + std::to_string(offset.x));
      expectWatertight(checkOne(scene, RayFlow::Scalar, 60000, offset), 60000);
    }
}

// A clip that keeps the whole grid is dropped: the same primitives as without it, nothing per ray.
TEST(ClippedSurface, AClipThatCutsNothingIsDropped) {
  const std::string scene = cutBall({2, 0, 0}, {1, 0, 0});
  const World clipped(parseSceneText(scene, "a.json"), IntersectorSpec{});
  SceneDesc plain = parseSceneText(scene, "b.json");
  plain.volumes[0].clip = ClipRegion();
  const World unclipped(plain, IntersectorSpec{});
  EXPECT_TRUE(clipped.surfaces()[0].surface->clip().empty());
  EXPECT_EQ(clipped.surfaces()[0].surface->activeBricks(), unclipped.surfaces()[0].surface->activeBricks());
  // One that cuts: bricks wholly cut away are dropped.
  const World half(parseSceneText(cutBall({0, 0, 0}, {1, 0, 0}), "c.json"), IntersectorSpec{});
  EXPECT_FALSE(half.surfaces()[0].surface->clip().empty());
  EXPECT_LT(half.surfaces()[0].surface->activeBricks().size(), unclipped.surfaces()[0].surface->activeBricks().size());
}

// The scene's clip cuts meshes too (no caps): a quad cut in half, traced alone and in packets.
TEST(ClippedSurface, SceneClipCutsMeshes) {
  const SceneDesc scene = parseSceneText(R"({"meshes": [{"shape": "quad", "transform": {"scale": 2}}],
      "clip": [{"plane": {"point": [0.25, 0, 0], "normal": [1, 0, 0]}}]})", "quad.json");
  const World world(scene, IntersectorSpec{});
  TraversalStats stats;
  // The quad: y = 0 from -1 to 1 (check on which axis it lies by tracing down and along z).
  int kept = 0, cut = 0;
  for (int i = 0; i < 40; ++i) {
    const float x = -0.95f + 0.05f * float(i);
    Ray down;
    down.org = {x, 1, 0.1f};
    down.dir = {0, -1, 0};
    Ray along;
    along.org = {x, 0.1f, 1};
    along.dir = {0, 0, -1};
    Hit hit;
    const bool hitDown = world.intersect(down, hit, stats), hitAlong = world.intersect(along, hit, stats);
    const bool hitsQuad = hitDown || hitAlong;
    if (std::fabs(x - 0.25f) < 1e-3f) continue;
    EXPECT_EQ(hitsQuad, x < 0.25f) << "x " << x;
    (x < 0.25f ? kept : cut) += 1;
    Ray rays[World::kPacket];
    std::fill(std::begin(rays), std::end(rays), hitDown ? down : along);
    Hit hits[World::kPacket];
    bool found[World::kPacket], blocked[World::kPacket];
    world.intersectPacket(rays, World::kPacket, hits, found, stats);
    world.occludedPacket(rays, World::kPacket, blocked, stats);
    for (int l = 0; l < World::kPacket; ++l) {
      EXPECT_EQ(found[l], hitsQuad) << "x " << x << " lane " << l;
      EXPECT_EQ(blocked[l], hitsQuad) << "x " << x << " lane " << l;
    }
    EXPECT_EQ(world.occluded(hitDown ? down : along, stats), hitsQuad);
  }
  EXPECT_GT(kept, 10);
  EXPECT_GT(cut, 10);
}

// "cap_color_by": a cap's base colour is the map's colour of the field on the plane.
TEST(ClippedSurface, CapsAreColouredByTheFieldOnThePlane) {
  const SceneDesc scene = parseSceneText(cutBall({0, 0, 0}, {0, 0, 1}), "ball.json");
  SceneDesc coloured = scene;
  ColorByDesc by;
  by.volume = 0;
  ASSERT_TRUE(ColorMap::named("viridis", by.map));
  by.lo = 0;
  by.hi = 0.5;
  coloured.volumes[0].isosurfaces[0].capColorBy = by;
  const World world(coloured, IntersectorSpec{});
  TraversalStats stats;
  int caps = 0;
  for (int i = 0; i < 20; ++i) {
    Ray ray;
    ray.org = {-0.4f + 0.04f * float(i), 0.05f, 3};
    ray.dir = {0, 0, -1};
    Hit hit;
    if (!world.intersect(ray, hit, stats) || !hit.cap) continue;
    ++caps;
    const Grid& grid = *world.volumes()[0].grid;
    const double value = grid.interpolate((hit.position64 - grid.origin()) / grid.spacing());
    EXPECT_NEAR(value, length(hit.position64), 0.03);  // the sphere field: the distance from the centre
    const Vec3f want = by.map.linear(value, 0, 0.5);
    const Vec3f got = world.albedo(hit);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(got[k], want[k], 1e-6) << i;
  }
  EXPECT_GT(caps, 10);
}

// Two solids cut by one plane (an outer ball of radius 0.5 and an inner one of 0.3, both of the
// sphere field, "inside": "below"): a ray into the cut meets both caps at the same point, in the
// scene's order whichever comes first in the file, each once; with the outer one a thin sheet,
// what a ray sees through it on the cut is the inner one's cap, not the inner solid's far side.
TEST(ClippedSurface, CapsOfNestedSolidsOnOnePlaneAreEachMetOnce) {
  for (const bool innerFirst : {false, true}) {
    for (const bool bothThin : {false, true}) {
      SCOPED_TRACE(std::string(innerFirst ? "inner first" : "outer first") + (bothThin ? ", both thin" : ""));
      const std::string outer = R"({"value": 0.5, "inside": "below", "material": "glass"})";
      const std::string inner = std::string(R"({"value": 0.3, "inside": "below", "material": ")") +
                                (bothThin ? "glass" : "core") + R"("})";
      const SceneDesc scene = parseSceneText(
          R"({"materials": {"glass": {"type": "dielectric", "thin": true}, "core": {"type": "diffuse"}},
              "volumes": [{"procedural": {"field": "sphere", "resolution": [48, 48, 48]},
                           "isosurfaces": [)" + (innerFirst ? inner + ", " + outer : outer + ", " + inner) + R"(],
                           "clip": [{"plane": {"point": [0, 0, 0], "normal": [0, 0.3, 1]}}]}]})",
          "nested.json");
      const World world(scene, IntersectorSpec{});
      const int innerIndex = innerFirst ? 0 : 1;
      TraversalStats stats;
      int checked = 0;
      for (int i = 0; i < 25; ++i) {
        Ray ray;
        ray.org = {-0.12f + 0.01f * float(i), 0.03f, 3};
        ray.dir = {0, 0, -1};
        if (!bothThin) {
          Hit hit;
          Vec3f T;
          ASSERT_TRUE(world.intersectPastThin(ray, hit, T, stats));
          EXPECT_EQ(hit.surface, innerIndex);
          EXPECT_TRUE(hit.cap);
          // On the plane, or (met by the ray that went through the outer cap) at that ray's
          // start, a spawn offset (the float traversal's rounding, ~5e-7 here) off it.
          EXPECT_NEAR(hit.position64.z + 0.3 * hit.position64.y, 0, 2e-6);
          ++checked;
          continue;
        }
        // Both thin: the chain through the cut meets the two caps once each, then leaves the
        // inner solid and the outer one through their surfaces: 4 hits, no cap met twice.
        std::vector<Hit> hits;
        Hit hit;
        for (Ray r = ray; hits.size() < 10 && world.intersect(r, hit, stats); r = spawnRay(hit, r.dir)) hits.push_back(hit);
        ASSERT_EQ(hits.size(), 4u);
        EXPECT_TRUE(hits[0].cap && hits[1].cap);
        EXPECT_EQ(std::min(hits[0].surface, hits[1].surface), 0);
        EXPECT_EQ(std::max(hits[0].surface, hits[1].surface), 1);
        EXPECT_EQ(hits[0].surface, 0) << "the scene's order at the tie";
        EXPECT_FALSE(hits[2].cap || hits[3].cap);
        EXPECT_EQ(hits[2].surface, innerIndex);
        ++checked;
      }
      EXPECT_EQ(checked, 25);
    }
  }
}

TEST(ClipScene, BadClipsAreRefusedInOneLine) {
  auto refused = [](const std::string& clip, const std::string& where, const std::string& what) {
    const std::string text = R"({"volumes": [{"procedural": {"field": "sphere"}, "isosurfaces": [{"value": 0.5}], "clip": )" + clip + "}]}";
    try {
      parseSceneText(text, "bad.json");
      ADD_FAILURE() << "accepted " << clip;
    } catch (const InputError& e) {
      const std::string m = e.what();
      EXPECT_NE(m.find("bad.json"), std::string::npos) << m;
      EXPECT_NE(m.find(where), std::string::npos) << m;
      EXPECT_NE(m.find(what), std::string::npos) << m;
      EXPECT_EQ(m.find('\n'), std::string::npos) << m;
    }
  };
  refused(R"({"plane": {}})", "/volumes/0/clip", "expected an array");
  refused(R"([{"plane": {"point": [0, 0, 0], "normal": [0, 0, 0]}}])", "/volumes/0/clip/0/plane/normal", "zero length");
  refused(R"([{"plane": {"point": [0, 0, 0]}}])", "/volumes/0/clip/0/plane/normal", "missing");
  refused(R"([{"plane": {"point": [0, 0, 0], "normal": [1, 0, 0], "offset": 1}}])", "/volumes/0/clip/0/plane/offset", "unknown key");
  refused(R"([{"box": {"min": [0, 0, 0], "max": [1, 0, 1]}}])", "/volumes/0/clip/0/box/max", "not above min on y");
  refused(R"([{"box": {"min": [0, 0, 0]}}])", "/volumes/0/clip/0/box/max", "missing");
  refused(R"([{"plane": {"point": [0, 0, 0], "normal": [1, 0, 0]}, "box": {"min": [0, 0, 0], "max": [1, 1, 1]}}])",
          "/volumes/0/clip/0", "either");
  refused(R"([{"sphere": 1}])", "/volumes/0/clip/0/sphere", "unknown key");
  refused(R"([{"plane": {"point": [0, 1e300, 0], "normal": [1, 0, 0]}}])", "/volumes/0/clip/0/plane/point", "not finite");
  refused(R"([{"plane": {"point": [0, 0, 0], "normal": [1, "a", 0]}}])", "/volumes/0/clip/0/plane/normal/1", "expected a number");
  // The scene's clip, and a cap colour of a field that is not there.
  try {
    parseSceneText(R"({"clip": [{"box": {"min": [0, 0, 0], "max": [-1, 1, 1]}}]})", "bad.json");
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/clip/0/box/max"), std::string::npos) << e.what();
  }
  try {
    parseSceneText(R"({"volumes": [{"procedural": {"field": "sphere"}, "isosurfaces": [{"value": 0.5,
        "cap_color_by": {"field": "dose", "map": "magma", "range": [0, 1]}}]}]})", "bad.json");
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/volumes/0/isosurfaces/0/cap_color_by/field"), std::string::npos) << e.what();
  }
}

TEST(ClipScene, AnEmissiveSurfaceIsNotClipped) {
  const SceneDesc scene = parseSceneText(R"({"materials": {"lamp": {"type": "emissive", "radiance": 3}},
      "volumes": [{"procedural": {"field": "sphere"}, "isosurfaces": [{"value": 0.5, "material": "lamp"}],
                   "clip": [{"plane": {"point": [0, 0, 0], "normal": [0, 1, 0]}}]}]})", "lamp.json");
  try {
    const World world(scene, IntersectorSpec{});
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/volumes/0/isosurfaces/0"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("emissive"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace iso
