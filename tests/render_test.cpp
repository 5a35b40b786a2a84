#include <gtest/gtest.h>

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>

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

// Renders `scene` with 1 and with 2 threads and requires the same bits in every pixel.
void expectSameBitsWithOneAndTwoThreads(const SceneDesc& scene, const std::string& integratorName, int w, int h,
                                        int spp, uint64_t seed) {
  World world(scene, {});
  Camera camera(world.camera(), w, h);
  auto integrator = makeIntegrator(integratorName, world, scene.settings);
  Film one(w, h), two(w, h);
  renderFrame(camera, *integrator, options(spp, seed, 1), one);
  renderFrame(camera, *integrator, options(spp, seed, 2), two);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) ASSERT_EQ(one.at(x, y), two.at(x, y)) << x << "," << y;
}

TEST(Render, SameImageBitsWithOneAndTwoThreads) {
  expectSameBitsWithOneAndTwoThreads(sphereScene(32, 0.5), "eyelight", 48, 40, 3, 11);
}

TEST(Render, PathTracingIsTheSameWithOneAndTwoThreads) {
  SceneDesc scene = parseSceneText(R"({
    "camera": {"position": [0, 1.5, 4], "look_at": [0, 0.5, 0]},
    "meshes": [{"shape": "quad", "transform": {"scale": 3}, "material": "floor"}],
    "volumes": [{"procedural": {"field": "torus", "resolution": [32, 32, 32]}, "transform": {"translate": [0, 1, 0]},
                 "isosurfaces": [{"value": 0.25, "inside": "below", "material": "glass"}]}],
    "materials": {"floor": {"type": "diffuse", "color": 0.7}, "glass": {"type": "dielectric"}},
    "lights": [{"type": "point", "position": [2, 4, 2], "intensity": 30}, {"type": "environment", "radiance": 0.3}]})",
                                   "threads.json");
  scene.settings.maxDepth = 12;
  expectSameBitsWithOneAndTwoThreads(scene, "path", 40, 30, 8, 5);
}

// Renders `scene` with both ray flows and requires the same bits in every pixel of every layer
// (radiance, the direct part, the AOVs, alpha), with the given thread count and adaptive setting.
void expectSameBitsWithBothRayFlows(const SceneDesc& scene, const std::string& integratorName, int w, int h, int spp,
                                    int threads, double adaptive) {
  SCOPED_TRACE(integratorName + ", " + std::to_string(threads) + " threads, adaptive " + std::to_string(adaptive));
  World world(scene, {});
  Camera camera(world.camera(), w, h);
  auto integrator = makeIntegrator(integratorName, world, scene.settings);
  Film films[2] = {Film(w, h), Film(w, h)}, direct[2] = {Film(w, h), Film(w, h)};
  RenderResult results[2];
  for (int i = 0; i < 2; ++i) {
    RenderOptions o = options(spp, 3, threads);
    o.rayFlow = i == 0 ? RayFlow::Scalar : RayFlow::Wavefront;
    o.noiseThreshold = adaptive;
    o.alpha = true;
    o.aovs = {"albedo", "normal", "depth", "variance", "samples"};
    results[i] = renderFrame(camera, *integrator, o, films[i], &direct[i]);
  }
  EXPECT_EQ(results[0].counters.camera, results[1].counters.camera);
  EXPECT_EQ(results[0].counters.shadow, results[1].counters.shadow);
  EXPECT_EQ(results[0].counters.indirect, results[1].counters.indirect);
  // (The traversal counters differ: packets visit bricks in another order, so other bricks are
  // culled behind a closer hit. The answers do not depend on that order.)
  int lit = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      ASSERT_EQ(films[0].at(x, y), films[1].at(x, y)) << x << "," << y;
      ASSERT_EQ(direct[0].at(x, y), direct[1].at(x, y)) << x << "," << y;
      lit += films[0].at(x, y).x != 0;
    }
  EXPECT_GT(lit, w * h / 10);  // the image shows something
  ASSERT_EQ(films[0].layers().size(), 5u);
  ASSERT_EQ(films[1].layers().size(), 5u);
  for (size_t l = 0; l < films[0].layers().size(); ++l)
    EXPECT_TRUE(std::memcmp(films[0].layers()[l].data.data(), films[1].layers()[l].data.data(),
                            films[0].layers()[l].data.size() * sizeof(float)) == 0)
        << films[0].layers()[l].name;
  EXPECT_EQ(films[0].alpha(), films[1].alpha());
}

// The wavefront flow against the scalar one, image bits: every integrator, one and two
// threads, with and without adaptive sampling, on a scene of meshes, iso-surfaces (one of them
// glass, refracting: long paths) and every kind of light, including an iso-surface light (its
// rays are traced at once, not queued) and a thin sheet (shadow rays through it, likewise).
TEST(Render, BothRayFlowsGiveTheSameImageBits) {
  const SceneDesc scene = parseSceneText(R"({
    "camera": {"position": [0.3, 1.6, 4], "look_at": [0, 0.6, 0], "fov": 45},
    "meshes": [{"shape": "quad", "transform": {"scale": 4}, "material": "floor"},
               {"shape": "sphere", "transform": {"scale": 0.35, "translate": [-1.2, 0.35, 0.6]}, "material": "sheet"}],
    "volumes": [{"procedural": {"field": "torus", "resolution": [32, 32, 32]}, "transform": {"translate": [0, 1, 0]},
                 "isosurfaces": [{"value": 0.25, "inside": "below", "material": "glass"}]},
                {"file": ")" + std::string(ISOTRACE_SOURCE_DIR) + R"(/examples/data/volumes/neghip_64x64x64_uint8.raw",
                 "spacing": [0.02, 0.02, 0.02], "origin": [0.6, 0, -0.8],
                 "isosurfaces": [{"value": 40, "material": "clay"}, {"value": 120, "material": "lamp"}]}],
    "materials": {"floor": {"type": "diffuse", "color": 0.7}, "glass": {"type": "dielectric"},
                  "sheet": {"type": "dielectric", "thin": true, "color": [0.9, 0.6, 0.5]},
                  "clay": {"type": "metallic_roughness", "color": [0.8, 0.5, 0.3], "roughness": 0.5},
                  "lamp": {"type": "emissive", "radiance": [6, 5, 4]}},
    "lights": [{"type": "point", "position": [2, 4, 2], "intensity": 30},
               {"type": "directional", "direction": [-0.3, -1, -0.2], "irradiance": 1.5},
               {"type": "environment", "radiance": 0.3}]})",
                                         "flows.json");
  for (const char* name : {"normals", "eyelight", "ao", "direct", "path", "compare"})
    for (int threads : {1, 2}) expectSameBitsWithBothRayFlows(scene, name, 40, 30, 6, threads, 0);
  expectSameBitsWithBothRayFlows(scene, "path", 40, 30, 40, 2, 0.05);
  // Embree's SSE kernels (as on a CPU without AVX) have no native 8-wide packets: the wavefront
  // flow traces its rays one at a time there, to the same bits (it had half its pixels black).
  struct EmbreeConfig {
    EmbreeConfig() { setenv("ISOTRACE_EMBREE_CONFIG", "isa=sse4.2", 1); }
    ~EmbreeConfig() { unsetenv("ISOTRACE_EMBREE_CONFIG"); }
  } sse;
  for (const char* name : {"direct", "path"}) expectSameBitsWithBothRayFlows(scene, name, 40, 30, 6, 2, 0);
}

// The Cornell example at 48x36 against a stored reference (tests/data/cornell_torus_ref.exr,
// 4096 spp, made by tests/data/make_references.sh), per pixel: the difference must lie within
// a few standard errors of the two means (from their variance layers). Unidirectional path
// tracing of the Cornell box's glossy spheres has rare caustic fireflies, so the variance has
// a floor of a tenth of the image's mean variance and 0.5% of the pixels may exceed the bound.
TEST(Render, CornellExampleMatchesItsReference) {
  const std::string dir = test::scratchDir();
  const std::string source = ISOTRACE_SOURCE_DIR;
  const auto r = test::runIsotrace("render " + source + "/examples/cornell_torus.json --resolution 48x36 --spp 256 "
                                   "--seed 7 --aov variance --quiet -o " + dir + "/c.exr");
  ASSERT_EQ(r.status, 0) << r.err;
  auto read = [](const std::string& path, std::vector<float>& rgb, std::vector<float>& var) {
    auto in = OIIO::ImageInput::open(path);
    ASSERT_TRUE(in) << path;
    const OIIO::ImageSpec& spec = in->spec();
    ASSERT_EQ(spec.width, 48);
    ASSERT_EQ(spec.height, 36);
    std::vector<float> all(size_t(spec.width) * spec.height * spec.nchannels);
    in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, all.data());
    auto index = [&](const std::string& name) {
      return int(std::find(spec.channelnames.begin(), spec.channelnames.end(), name) - spec.channelnames.begin());
    };
    const int c[6] = {index("R"), index("G"), index("B"), index("variance.R"), index("variance.G"), index("variance.B")};
    for (int k = 0; k < 6; ++k) ASSERT_LT(c[k], spec.nchannels);
    for (size_t p = 0; p < size_t(spec.width) * spec.height; ++p)
      for (int k = 0; k < 3; ++k) {
        rgb.push_back(all[p * spec.nchannels + c[k]]);
        var.push_back(all[p * spec.nchannels + c[k + 3]]);
      }
  };
  std::vector<float> test, testVar, ref, refVar;
  read(dir + "/c.exr", test, testVar);
  read(source + "/tests/data/cornell_torus_ref.exr", ref, refVar);
  ASSERT_EQ(test.size(), ref.size());
  double meanVar = 0, meanTest = 0, meanRef = 0;
  for (size_t i = 0; i < test.size(); ++i) {
    meanVar += (testVar[i] + refVar[i]) / test.size();
    meanTest += test[i] / test.size();
    meanRef += ref[i] / test.size();
  }
  int outliers = 0;
  double worst = 0;
  for (size_t i = 0; i < test.size(); ++i) {
    const double sigma = std::sqrt(std::max(double(testVar[i]) + refVar[i], 0.1 * meanVar));
    const double z = std::fabs(test[i] - ref[i]) / sigma;
    worst = std::max(worst, z);
    outliers += z > 5;
  }
  std::printf("mean %.5f vs reference %.5f, worst z %.2f, %d of %zu values beyond 5 sigma\n", meanTest, meanRef, worst,
              outliers, test.size());
  EXPECT_LE(outliers, int(0.005 * test.size()));
  EXPECT_NEAR(meanTest, meanRef, 0.02 * meanRef);
}

// Every example loads with every iso-surface non-empty (no iso value outside its volume's
// values), and its camera sees them: iso-surfaces fill at least 5% of the centre of the view.
TEST(Examples, EveryExampleLoadsAndItsCameraSeesItsSurfaces) {
  int examples = 0;
  for (const auto& entry : std::filesystem::directory_iterator(std::string(ISOTRACE_SOURCE_DIR) + "/examples")) {
    if (entry.path().extension() != ".json") continue;
    SCOPED_TRACE(entry.path().string());
    ++examples;
    const SceneDesc scene = parseSceneFile(entry.path().string());
    World world(scene, scene.settings.intersector);
    for (const std::string& w : world.warnings()) EXPECT_EQ(w.find("iso value"), std::string::npos) << w;
    for (const SurfaceInfo& s : world.surfaces()) EXPECT_FALSE(s.surface->activeBricks().empty()) << "iso " << s.iso;
    // The iso-surfaces fill a good part of the centre of the view.
    const int w = 32, h = 24;
    Camera camera(world.camera(), w, h);
    TraversalStats stats;
    int isoHits = 0, centre = 0;
    for (int y = h / 4; y < 3 * h / 4; ++y)
      for (int x = w / 4; x < 3 * w / 4; ++x) {
        Hit hit;
        ++centre;
        if (world.intersect(camera.generateRay(x + 0.5f, y + 0.5f), hit, stats) && hit.surface >= 0) ++isoHits;
      }
    EXPECT_GT(isoHits, centre / 20) << "the camera hardly sees the iso-surfaces";
  }
  EXPECT_GE(examples, 6);
}

}  // namespace
}  // namespace iso
