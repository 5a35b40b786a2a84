#include <gtest/gtest.h>

#include "renderer/render.h"
#include "scene/world.h"
#include "tests/test_util.h"

namespace iso {
namespace {

RenderOptions options(int spp, uint64_t seed, int threads) {
  RenderOptions o;
  o.spp = spp;
  o.seed = seed;
  o.threads = threads;
  return o;
}

SceneDesc sphereScene(int resolution, double iso) {
  SceneDesc scene;
  VolumeDesc v;
  v.field = Field::Sphere;
  v.resolution = {resolution, resolution, resolution};
  IsoSurfaceDesc surface;
  surface.value = iso;
  v.isosurfaces.push_back(surface);
  scene.volumes.push_back(v);
  scene.camera.position = {0.3, 0.2, 4};
  scene.camera.lookAt = {0, 0, 0};
  scene.camera.fov = 30;
  return scene;
}

// The hit mask of a rendered procedural sphere matches the analytic silhouette: every
// pixel whose centre ray passes clearly inside the radius hits, clearly outside misses.
// The trilinear iso-surface of |p| lies within a small fraction of a cell of the sphere.
TEST(Render, SphereHitMaskMatchesTheSilhouette) {
  const double radius = 0.6;
  SceneDesc scene = sphereScene(48, radius);
  const int w = 160, h = 120;
  for (const char* name : {"isolation", "reference", "neubauer"}) {
    IntersectorSpec spec;
    std::string error;
    ASSERT_TRUE(parseIntersector(name, spec, error));
    World world(scene, spec);
    Camera camera(scene.camera, w, h);
    const double margin = 0.25 * 2.0 / 47;  // a quarter cell
    int mismatches = 0, inside = 0;
    TraversalStats stats;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const Ray ray = camera.generateRay(x + 0.5f, y + 0.5f);
        const Vec3d o(ray.org), d(ray.dir);
        const double distance = length(cross(-o, d));  // centre to the ray line
        Hit hit;
        const bool got = world.intersect(ray, hit, stats);
        if (distance < radius - margin) { ++inside; mismatches += !got; }
        if (distance > radius + margin) mismatches += got;
        if (got) {
          // The hit point lies on the sphere; the normal points to lower values of |p|,
          // that is towards the centre.
          EXPECT_NEAR(length(Vec3d(hit.position)), radius, 0.01);
          EXPECT_LT(dot(Vec3d(hit.normal), normalize(Vec3d(hit.position))), -0.95);
        }
      }
    EXPECT_EQ(mismatches, 0) << name;
    EXPECT_GT(inside, 1000);
  }
}

TEST(Render, NormalsAreExactlyZeroOnMissesAndUnitOnHits) {
  SceneDesc scene = sphereScene(32, 0.5);
  World world(scene, {});
  Camera camera(scene.camera, 64, 48);
  auto integrator = makeIntegrator("normals", world);
  Film film(64, 48);
  const RenderResult r = renderFrame(camera, *integrator, options(1, 7, 2), film);
  EXPECT_EQ(r.counters.camera, 64u * 48u);
  int hits = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const Vec3f n = film.at(x, y);
      if (n == Vec3f{0, 0, 0}) continue;
      ++hits;
      EXPECT_NEAR(length(n), 1.f, 1e-4f);
    }
  EXPECT_GT(hits, 100);
  EXPECT_LT(hits, 64 * 48);
}

TEST(Render, SameImageBitsWithOneAndTwoThreads) {
  SceneDesc scene = sphereScene(32, 0.5);
  World world(scene, {});
  Camera camera(scene.camera, 48, 40);
  auto integrator = makeIntegrator("eyelight", world);
  Film one(48, 40), two(48, 40);
  renderFrame(camera, *integrator, options(3, 11, 1), one);
  renderFrame(camera, *integrator, options(3, 11, 2), two);
  for (int y = 0; y < 40; ++y)
    for (int x = 0; x < 48; ++x) ASSERT_EQ(one.at(x, y), two.at(x, y)) << x << "," << y;
}

}  // namespace
}  // namespace iso
