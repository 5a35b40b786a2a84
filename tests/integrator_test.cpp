// Integrators against analytic answers (furnaces), sampling routines by chi-square tests,
// and the max_depth convention.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "integrators/path.h"
#include "renderer/render.h"
#include "scene/world.h"
#include "tests/test_util.h"

namespace iso {
namespace {

struct ImageStats {
  double mean = 0;
  double standardError = 0;  // of the mean over all pixels, from the per-pixel variances
  double worstZ = 0;         // the largest |pixel - expected| / (pixel standard error + slack)
  int beyond4 = 0;           // pixels with that ratio above 4
  int pixels = 0;
};

// Renders the scene's camera view and compares every pixel's luminance with `expected`.
ImageStats renderAndCompare(const SceneDesc& scene, const std::string& integratorName, int spp, double expected,
                            double slack, int size = 24) {
  World world(scene, scene.settings.intersector);
  Camera camera(world.camera(), size, size);
  auto integrator = makeIntegrator(integratorName, world, scene.settings);
  Film film(size, size);
  RenderOptions options;
  options.spp = spp;
  options.seed = 1;
  options.aovs = {"variance"};
  renderFrame(camera, *integrator, options, film);
  const Film::Layer& variance = film.layers()[0];
  ImageStats s;
  double varianceSum = 0;
  for (size_t i = 1; i < variance.data.size(); i += 3) varianceSum += variance.data[i];
  // A pixel's own variance estimate is unreliable when Russian roulette makes its samples
  // heavy-tailed (64 samples may contain no rare event): the image-wide mean is a floor.
  const double pooled = varianceSum / (size * size);
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const Vec3f p = film.at(x, y);
      const double v = std::max(pooled, double(variance.data[3 * (size_t(y) * size + x) + 1]));  // green
      s.mean += p.y;
      const double z = std::fabs(p.y - expected) / (std::sqrt(v) + slack);
      s.worstZ = std::max(s.worstZ, z);
      s.beyond4 += z > 4;
      ++s.pixels;
    }
  s.mean /= s.pixels;
  s.standardError = std::sqrt(varianceSum) / s.pixels;
  std::printf("%s spp %d: mean %.5f (expected %.5f), standard error %.5f, worst z %.2f, %d of %d pixels beyond 4\n",
              integratorName.c_str(), spp, s.mean, expected, s.standardError, s.worstZ, s.beyond4, s.pixels);
  return s;
}

// A diffuse sphere of radius 1 and albedo 0.5 around a point light of intensity pi at its
// centre, seen from inside: direct light gives radiance 0.5 everywhere; each bounce adds half
// of the one before, so depth d gives 1 - 0.5^d and global illumination 1.
SceneDesc furnace(bool isoSurface) {
  SceneDesc s;
  s.path = "furnace.json";
  s.camera.position = {0.1, 0.2, 0.3};
  s.camera.lookAt = {0.5, -0.3, -1};
  s.camera.fov = 70;
  MaterialDesc grey;
  grey.type = MaterialType::Diffuse;
  grey.color = {0.5, 0.5, 0.5};
  s.materials["grey"] = grey;
  if (isoSurface) {
    // |p| = 0.8 on a 64^3 grid over [-1, 1]^3, scaled by 1.25: radius 1 (trilinear error ~1e-4).
    VolumeDesc v;
    v.field = Field::Sphere;
    v.resolution = {64, 64, 64};
    v.transform = Transform::scale({1.25, 1.25, 1.25});
    IsoSurfaceDesc iso;
    iso.value = 0.8;
    iso.material = "grey";
    iso.solidAbove = true;
    v.isosurfaces.push_back(iso);
    s.volumes.push_back(v);
  } else {
    MeshDesc m;
    m.shape = MeshShape::Sphere;
    m.material = "grey";
    s.meshes.push_back(m);
  }
  LightDesc l;
  l.type = LightType::Point;
  l.intensity = {M_PI, M_PI, M_PI};
  s.lights.push_back(l);
  return s;
}

void checkFurnace(bool isoSurface) {
  SceneDesc s = furnace(isoSurface);
  // The sphere is 64 x 128 facets (or trilinear patches): a 0.3% geometric allowance.
  const double geometry = 0.003;
  const ImageStats direct = renderAndCompare(s, "direct", 4, 0.5, geometry);
  EXPECT_NEAR(direct.mean, 0.5, 0.5 * geometry) << "direct";
  EXPECT_LT(direct.worstZ, 1.0) << "direct light of a point light is noise-free here";
  for (int depth : {2, 3}) {
    s.settings.maxDepth = depth;
    const double expected = 1 - std::pow(0.5, depth);
    const ImageStats st = renderAndCompare(s, "path", 64, expected, expected * geometry);
    EXPECT_NEAR(st.mean, expected, 5 * st.standardError + expected * geometry) << "depth " << depth;
    EXPECT_LT(st.worstZ, 6) << "depth " << depth;
  }
  s.settings.maxDepth = 200;
  const ImageStats global = renderAndCompare(s, "path", 64, 1.0, geometry);
  EXPECT_NEAR(global.mean, 1.0, 5 * global.standardError + geometry);
  EXPECT_LT(global.standardError, 0.01);
  EXPECT_LT(global.worstZ, 6);
}

TEST(Furnace, TriangleMeshSphere) { checkFurnace(false); }
TEST(Furnace, IsoSurfaceSphere) { checkFurnace(true); }

// The furnace can see holes: Schwarze's float cubic solver loses crossings on this smooth
// field (docs/BENCHMARKS.md), light escapes through them and the image darkens.
TEST(Furnace, SeesTheHolesOfSchwarze) {
  SceneDesc s = furnace(true);
  s.settings.intersector.kind = IntersectorKind::Schwarze;
  const ImageStats direct = renderAndCompare(s, "direct", 4, 0.5, 0.003);
  EXPECT_LT(direct.mean, 0.45);
  EXPECT_GT(direct.beyond4, 10);
}

// A closed iso-surface of albedo 1 under a uniform sky of radiance 1 renders as 1 everywhere:
// a hole lets a path into the solid, where it is trapped and returns 0; a double hit
// re-scatters inside the surface and shows as dark or bright deviations.
TEST(Furnace, WhiteFurnaceTorus) {
  SceneDesc s;
  s.path = "white.json";
  s.camera.position = {0.4, 2.2, 2.6};
  s.camera.fov = 45;
  MaterialDesc white;
  white.type = MaterialType::Diffuse;
  white.color = {1, 1, 1};
  s.materials["white"] = white;
  VolumeDesc v;
  v.field = Field::Torus;
  v.resolution = {48, 48, 48};
  IsoSurfaceDesc iso;
  iso.value = 0.3;
  iso.material = "white";
  iso.solidAbove = false;
  v.isosurfaces.push_back(iso);
  s.volumes.push_back(v);
  LightDesc sky;
  sky.type = LightType::Environment;
  sky.radiance = {1, 1, 1};
  s.lights.push_back(sky);
  s.settings.maxDepth = 1000;
  const ImageStats st = renderAndCompare(s, "path", 64, 1.0, 0.002, 32);
  EXPECT_NEAR(st.mean, 1.0, 5 * st.standardError + 0.002);
  EXPECT_LT(st.worstZ, 6);
}

// The max_depth convention: depth 1 is direct lighting, bit for bit the same as `direct`
// (and the direct part of `compare`), from the same samples.
TEST(Integrators, PathAtDepthOneIsDirectAndCompareSplitsIt) {
  SceneDesc s = furnace(false);
  s.settings.maxDepth = 1;
  World world(s, IntersectorSpec{});
  Camera camera(world.camera(), 16, 16);
  RenderOptions o;
  o.spp = 4;
  Film direct(16, 16), path(16, 16), global(16, 16), split(16, 16);
  renderFrame(camera, *makeIntegrator("direct", world, s.settings), o, direct);
  renderFrame(camera, *makeIntegrator("path", world, s.settings), o, path);
  s.settings.maxDepth = 5;
  renderFrame(camera, *makeIntegrator("compare", world, s.settings), o, global, &split);
  double mean = 0;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) {
      ASSERT_EQ(direct.at(x, y), path.at(x, y));
      ASSERT_EQ(direct.at(x, y), split.at(x, y));
      mean += global.at(x, y).x / 256;
    }
  EXPECT_NEAR(mean, 1 - std::pow(0.5, 5), 0.05);
}

// A diffuse plane at y = 0 (hits there have no rounding error in y, so shadow rays depend on
// the spawn offset's floor) under a point light: every pixel has the analytic radiance
// albedo/pi * I cos(theta) / d^2.
TEST(Integrators, DirectLightOnAPlaneMatchesTheAnalyticValue) {
  SceneDesc s = parseSceneText(R"({
    "camera": {"position": [0.3, 3, 0.2], "look_at": [0, 0, 0], "up": [0, 0, -1], "fov": 60},
    "meshes": [{"shape": "quad", "transform": {"scale": 4}, "material": "m"}],
    "materials": {"m": {"type": "diffuse", "color": 0.5}},
    "lights": [{"type": "point", "position": [0.5, 2, -0.25], "intensity": 3.14159265}]})", "plane.json");
  World world(s, IntersectorSpec{});
  const int size = 32;
  Camera camera(world.camera(), size, size);
  Film film(size, size);
  RenderOptions o;
  o.spp = 1;
  renderFrame(camera, *makeIntegrator("direct", world, s.settings), o, film);
  const Vec3d light{0.5, 2, -0.25};
  int checked = 0;
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      Sampler sampler(uint32_t(x), uint32_t(y), 0, 0);  // the renderer's jitter for sample 0
      const float jx = sampler.next(), jy = sampler.next();
      const Ray r = camera.generateRay(x + jx, y + jy);
      const Vec3d o(r.org), d(r.dir);
      const Vec3d p = o + d * (-o.y / d.y);
      if (std::fabs(p.x) > 3.9 || std::fabs(p.z) > 3.9) continue;
      const Vec3d toLight = light - p;
      const double dist = length(toLight), expected = 0.5 / M_PI * 3.14159265 * (toLight.y / dist) / (dist * dist);
      EXPECT_NEAR(film.at(x, y).x, expected, 1e-4 * expected) << x << "," << y;
      ++checked;
    }
  EXPECT_GT(checked, 500);
}

TEST(Integrators, MisWeightsSumToOne) {
  std::mt19937 rng(2);
  std::uniform_real_distribution<float> u(-8, 8);
  for (int i = 0; i < 10000; ++i) {
    const float a = std::exp(u(rng)), b = std::exp(u(rng));
    EXPECT_NEAR(powerHeuristic(a, b) + powerHeuristic(b, a), 1, 1e-6);
  }
  EXPECT_EQ(powerHeuristic(1, 0), 1);
  EXPECT_EQ(powerHeuristic(0, 1), 0);
  EXPECT_EQ(powerHeuristic(INFINITY, 1), 1);
}

// Pearson's chi-square test of a direction sampler against its density, on a grid of
// (cos theta, phi) cells; cells expecting fewer than 5 samples are pooled (Mitsuba 3's
// approach). Fails below a significance of 1e-4 (Wilson-Hilferty critical value).
template <typename SampleFn, typename PdfFn>
void chiSquare(const std::string& name, SampleFn sample, PdfFn pdf) {
  const int thetaBins = 16, phiBins = 32, n = 400000;
  std::vector<double> observed(thetaBins * phiBins, 0), expected(thetaBins * phiBins, 0);
  std::mt19937 rng(123);
  std::uniform_real_distribution<float> u(0, 1);
  auto cell = [&](const Vec3f& w) {
    const int t = std::min(int((w.z + 1) * 0.5f * thetaBins), thetaBins - 1);
    float phi = std::atan2(w.y, w.x);
    if (phi < 0) phi += 2 * float(M_PI);
    const int p = std::min(int(phi / (2 * M_PI) * phiBins), phiBins - 1);
    return t * phiBins + p;
  };
  for (int i = 0; i < n; ++i) {
    Vec3f w;
    if (sample(u(rng), u(rng), u(rng), w)) observed[cell(w)] += 1;
  }
  // The density integrated over each cell (uniform in cos theta and phi: d omega = dz dphi).
  const int sub = 12;
  for (int t = 0; t < thetaBins; ++t)
    for (int p = 0; p < phiBins; ++p) {
      double sum = 0;
      for (int i = 0; i < sub; ++i)
        for (int j = 0; j < sub; ++j) {
          const double z = -1 + 2.0 * (t + (i + 0.5) / sub) / thetaBins;
          const double phi = 2 * M_PI * (p + (j + 0.5) / sub) / phiBins;
          const double r = std::sqrt(std::max(0.0, 1 - z * z));
          sum += pdf(Vec3f{float(r * std::cos(phi)), float(r * std::sin(phi)), float(z)});
        }
      expected[t * phiBins + p] = sum / (sub * sub) * (2.0 / thetaBins) * (2 * M_PI / phiBins) * n;
    }
  double chi2 = 0, pooledObs = 0, pooledExp = 0;
  int dof = 0;
  for (size_t i = 0; i < observed.size(); ++i) {
    if (expected[i] < 5) {
      pooledObs += observed[i];
      pooledExp += expected[i];
      continue;
    }
    chi2 += (observed[i] - expected[i]) * (observed[i] - expected[i]) / expected[i];
    ++dof;
  }
  if (pooledExp >= 5) {
    chi2 += (pooledObs - pooledExp) * (pooledObs - pooledExp) / pooledExp;
    ++dof;
  } else {
    EXPECT_LT(pooledObs, 5 + 5 * std::sqrt(pooledExp + 1)) << name << ": samples where the density says none";
  }
  --dof;
  const double z = 3.719;  // one-sided 1e-4
  const double k = dof, critical = k * std::pow(1 - 2 / (9 * k) + z * std::sqrt(2 / (9 * k)), 3);
  EXPECT_LT(chi2, critical) << name << ": chi2 " << chi2 << " with " << dof << " degrees of freedom";
}

TEST(Sampling, ChiSquareOfBsdfs) {
  const Frame frame{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  struct Case {
    const char* name;
    Bsdf bsdf;
  };
  const Case cases[] = {
      {"diffuse", Bsdf(MaterialType::Diffuse, frame, {0.5f, 0.5f, 0.5f}, 0, 1, 1.5f)},
      {"plastic", Bsdf(MaterialType::MetallicRoughness, frame, {0.7f, 0.3f, 0.2f}, 0, 0.5f, 1.5f)},
      {"metal", Bsdf(MaterialType::MetallicRoughness, frame, {0.9f, 0.8f, 0.6f}, 1, 0.6f, 1.5f)},
      {"conductor", Bsdf(MaterialType::Conductor, frame, {0.9f, 0.9f, 0.9f}, 0, 0.7f, 1.5f)},
  };
  for (const Case& c : cases)
    for (float cosO : {0.8f, 0.3f, -0.5f}) {
      const Vec3f wo{std::sqrt(1 - cosO * cosO), 0, cosO};
      chiSquare(std::string(c.name) + " cos " + std::to_string(cosO),
                [&](float a, float b, float d, Vec3f& w) {
                  BsdfSample s;
                  if (!c.bsdf.sampleLocal(wo, a, b, d, s)) return false;
                  w = s.wi;
                  return true;
                },
                [&](const Vec3f& w) { return c.bsdf.pdfLocal(wo, w); });
    }
}

TEST(Sampling, ChiSquareOfLights) {
  std::vector<Vec4f> texels(32 * 16);
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 32; ++x) texels[y * 32 + x] = {0.2f + 0.05f * x, 0.5f + 0.1f * (y % 4), 0.1f, 1};
  texels[5 * 32 + 20] = {30, 30, 30, 1};
  const Texture image = Texture::fromTexels(32, 16, texels);
  LightDesc d;
  d.type = LightType::Environment;
  const Light env = Light::fromDesc(d, &image);
  chiSquare("environment image",
            [&](float a, float b, float c, Vec3f& w) {
              LightSample s;
              if (!env.sample({0, 0, 0}, a, b, c, s)) return false;
              w = s.wi;
              return true;
            },
            [&](const Vec3f& w) { return env.pdfEnvironment(w); });
  const Light uniform = Light::fromDesc(d, nullptr);
  chiSquare("constant environment",
            [&](float a, float b, float c, Vec3f& w) {
              LightSample s;
              if (!uniform.sample({0, 0, 0}, a, b, c, s)) return false;
              w = s.wi;
              return true;
            },
            [&](const Vec3f& w) { return uniform.pdfEnvironment(w); });
}

// Iso-surface lights sample directions towards points in boxes; their density, a sum over
// the boxes a direction crosses, must be the one sampled: overlapping boxes of unequal weight,
// seen from outside all of them and from inside one.
TEST(Sampling, ChiSquareOfIsoSurfaceLights) {
  Material lamp;
  lamp.type = MaterialType::Emissive;
  lamp.emission = {1, 1, 1};
  const Light light = Light::isoSurface(0, {{1, -0.5f, -0.5f}, {1.5f, 0, -1}, {-1, 1, 0.2f}},
                                        {{2, 0.5f, 0.5f}, {2.5f, 1.5f, 0.3f}, {-0.4f, 1.6f, 0.8f}}, {3, 1, 2}, lamp, 1);
  for (const Vec3f p : {Vec3f{0, 0, 0}, Vec3f{1.2f, 0.1f, 0}}) {
    chiSquare("iso-surface light from (" + std::to_string(p.x) + ", " + std::to_string(p.y) + ")",
              [&](float a, float b, float c, Vec3f& w) {
                LightSample s;
                if (!light.sample(p, a, b, c, s)) return false;
                EXPECT_TRUE(s.traced);
                EXPECT_NEAR(s.pdf, light.pdfIsoSurface(p, s.wi), 1e-3f * s.pdf);
                w = s.wi;
                return true;
              },
              [&](const Vec3f& w) { return light.pdfIsoSurface(p, w); });
  }
}

// A thin glass sheet ("thin": true) between a floor and a uniform sky passes the light
// straight through, tinted: a floor of albedo 0.5 under a sheet of tint 0.5 (ior 1.0001: no
// reflection to speak of) shows 0.5 * 0.5 * 1 = 0.25, by shadow rays through the sheet
// (direct) and with BSDF paths through it combined by MIS (path): no double counting, and the
// sheet uses up no depth. A sheet of real (not thin) glass stops the shadow rays.
TEST(Integrators, ThinGlassLetsShadowRaysThrough) {
  auto scene = [](bool thin) {
    return parseSceneText(std::string(R"({"camera": {"position": [0, 0.5, 0], "look_at": [0.3, 0, -1], "fov": 40},
      "meshes": [{"shape": "quad", "transform": {"scale": 1000}, "material": "floor"},
                 {"shape": "quad", "transform": {"scale": 1000, "translate": [0, 1, 0]}, "material": "sheet"}],
      "materials": {"floor": {"type": "diffuse", "color": 0.5},
                    "sheet": {"type": "dielectric", "ior": 1.0001, "color": 0.5, "thin": )") +
                              (thin ? "true" : "false") + R"(}},
      "lights": [{"type": "environment", "radiance": 1}]})", "/t/sheet.json");
  };
  SceneDesc thin = scene(true);
  thin.settings.maxDepth = 1;
  const ImageStats direct = renderAndCompare(thin, "direct", 64, 0.25, 0.002, 16);
  EXPECT_NEAR(direct.mean, 0.25, 5 * direct.standardError + 0.002);
  thin.settings.maxDepth = 5;
  const ImageStats path = renderAndCompare(thin, "path", 64, 0.25, 0.002, 16);
  EXPECT_NEAR(path.mean, 0.25, 5 * path.standardError + 0.002);
  SceneDesc glass = scene(false);
  const ImageStats blocked = renderAndCompare(glass, "direct", 16, 0, 0.002, 16);
  EXPECT_LT(blocked.mean, 0.01);
}

// Lights are chosen in proportion to their power (pbrt-v4's power light sampler): a point light
// 4 pi I, a spot 2 pi I (1 - (cos inner + cos outer) / 2), a directional light pi r^2 E over
// the scene's bounding sphere; black lights are never chosen.
TEST(Integrators, LightsAreChosenByPower) {
  const SceneDesc s = parseSceneText(R"({"meshes": [{"shape": "quad", "transform": {"scale": 2}}],
    "lights": [{"type": "point", "position": [0, 1, 0], "intensity": 1},
               {"type": "point", "position": [0, 1, 0], "intensity": 3},
               {"type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0], "intensity": 2, "inner_angle": 60, "outer_angle": 60},
               {"type": "directional", "direction": [0, -1, 0], "irradiance": 0.5},
               {"type": "point", "position": [0, 1, 0], "intensity": 0}]})", "/t/lights.json");
  World world(s, IntersectorSpec{});
  ASSERT_EQ(world.lights().size(), 5u);
  const double r = std::sqrt(2.0) * 2;  // the quad [-2, 2]^2 at y = 0: half its diagonal
  const double powers[5] = {4 * M_PI, 12 * M_PI, 2 * M_PI * 2 * 0.5, M_PI * r * r * 0.5, 0};
  double total = 0;
  for (double p : powers) total += p;
  for (int i = 0; i < 5; ++i) EXPECT_NEAR(world.lightProbability(i), powers[i] / total, 1e-4) << "light " << i;
  float probability;
  for (float u : {0.f, 0.3f, 0.7f, 0.99999f}) {
    const int picked = world.pickLight(u, probability);
    EXPECT_NE(picked, 4);
    EXPECT_FLOAT_EQ(probability, world.lightProbability(picked));
  }
}

// A closed room lit only by an emissive iso-surface sphere, against the same room lit by a
// sphere of emissive triangles: the means agree (both estimators are unbiased) and, with the
// iso-surface sampled as a light, its noise is no worse than 1.3 times the triangles'
// (issue 12: by BSDF sampling alone it was 3.7 times, with 59% black pixels at 16 spp).
// Noise = the RMS difference of two renders with different seeds, over sqrt(2).
TEST(Integrators, IsoSurfaceLampMatchesTheTriangleLamp) {
  auto room = [](const std::string& lamp) {
    return parseSceneText(R"({"camera": {"position": [0, 1, 2.8], "look_at": [0, 0.9, 0], "fov": 50},
      "integrator": {"type": "path", "max_depth": 4},
      "meshes": [{"file": ")" + test::dataPath("meshes/Box.glb") + R"(", "transform": {"scale": [4, 2, 6], "translate": [0, 1, 0]},
                  "material": "wall"})" + lamp + R"(],
      "materials": {"wall": {"type": "diffuse", "color": 0.7}, "lamp": {"type": "emissive", "radiance": 8}}})", "/t/room.json");
  };
  SceneDesc iso = room(R"(], "volumes": [{"procedural": {"field": "sphere", "resolution": [32, 32, 32]},
      "transform": {"scale": 0.6, "translate": [0.4, 1.3, -0.8]},
      "isosurfaces": [{"value": 0.5, "inside": "below", "material": "lamp"}]})");
  SceneDesc tri = room(R"(, {"shape": "sphere", "transform": {"scale": 0.3, "translate": [0.4, 1.3, -0.8]}, "material": "lamp"})");
  struct Result { double mean = 0, noise = 0; };
  auto measure = [](const SceneDesc& scene) {
    World world(scene, scene.settings.intersector);
    EXPECT_EQ(world.lights().size(), 1u);
    const int w = 64, h = 48;
    Camera camera(world.camera(), w, h);
    auto integrator = makeIntegrator("path", world, scene.settings);
    Film a(w, h), b(w, h);
    RenderOptions options;
    options.spp = 16;
    options.seed = 1;
    renderFrame(camera, *integrator, options, a);
    options.seed = 2;
    renderFrame(camera, *integrator, options, b);
    Result r;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        r.mean += 0.5 * (a.at(x, y).y + b.at(x, y).y);
        r.noise += double(a.at(x, y).y - b.at(x, y).y) * (a.at(x, y).y - b.at(x, y).y);
      }
    r.mean /= w * h;
    r.noise = std::sqrt(r.noise / (w * h) / 2);
    return r;
  };
  const Result i = measure(iso), t = measure(tri);
  std::printf("iso-surface lamp: mean %.5f, noise %.5f; triangle lamp: mean %.5f, noise %.5f (ratio %.2f)\n", i.mean,
              i.noise, t.mean, t.noise, i.noise / t.noise);
  EXPECT_NEAR(i.mean, t.mean, 0.01 * t.mean);
  EXPECT_LT(i.noise, 1.3 * t.noise);
}

// Indirect rays leave an iso-surface without re-hitting it: from points on the inside of the
// furnace sphere, rays spawned into the sphere must reach its far side, never the point they
// left.
TEST(Integrators, SpawnedRaysDoNotReHitTheirSurface) {
  SceneDesc s = furnace(true);
  World world(s, IntersectorSpec{});
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(0, 1);
  TraversalStats stats;
  int selfHits = 0, tested = 0;
  for (int i = 0; i < 20000; ++i) {
    Ray r;
    r.org = {0, 0, 0};
    r.dir = sampleUniformSphere(u(rng), u(rng));
    Hit hit;
    ASSERT_TRUE(world.intersect(r, hit, stats));
    // Leave towards a random inward direction: the next hit must be the far side (distance
    // well above 0), never the point we left.
    const Vec3f n = -normalize(hit.position);
    const Frame f = Frame::fromNormal(n, {1, 0, 0});
    const Vec3f wi = f.toWorld(sampleCosineHemisphere(u(rng), u(rng)));
    Hit next;
    ASSERT_TRUE(world.intersect(spawnRay(hit, wi), next, stats));
    ++tested;
    if (length(next.position - hit.position) < 1e-3f) ++selfHits;
  }
  EXPECT_EQ(selfHits, 0) << "of " << tested;
}

// The same for triangles, including a plane whose hits have no rounding error at all in y
// (y = 0 exactly), tilted planes, and a plane far from the origin.
TEST(Integrators, SpawnedRaysLeaveTriangles) {
  for (const char* transform : {R"({"scale": 3})", R"({"scale": 3, "rotate": {"axis": [1, 0.3, 0.2], "degrees": 37}})",
                                R"({"scale": 3, "translate": [1e5, -2e5, 5e4]})"}) {
    SceneDesc s = parseSceneText(std::string(R"({"meshes": [{"shape": "quad", "transform": )") + transform + "}]}", "q.json");
    World world(s, IntersectorSpec{});
    const Vec3f centre = Vec3f(s.meshes[0].transform.point({0, 0, 0}));
    const Vec3f up = normalize(Vec3f(s.meshes[0].transform.normal({0, 1, 0})));
    std::mt19937 rng(4);
    std::uniform_real_distribution<float> u(0, 1);
    TraversalStats stats;
    int reHits = 0, blocked = 0, leaks = 0;
    for (int i = 0; i < 5000; ++i) {
      Ray r;
      const Vec3f target = centre + Vec3f{u(rng) - 0.5f, 0, u(rng) - 0.5f};
      const Vec3f side = u(rng) < 0.5f ? up : -up;
      r.org = target + side * 2.f + Vec3f{u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f} * 0.2f;
      r.dir = normalize(target - r.org);
      Hit hit;
      ASSERT_TRUE(world.intersect(r, hit, stats)) << transform;
      const Frame f = Frame::fromNormal(side, {1, 0, 0});
      // Reflected: nothing else in the scene to hit. Transmitted: the same.
      const Vec3f out = f.toWorld(sampleCosineHemisphere(u(rng), u(rng)));
      Hit next;
      reHits += world.intersect(spawnRay(hit, out), next, stats);
      reHits += world.intersect(spawnRay(hit, -out), next, stats);
      // A shadow ray to a point on either side is free: it leaves to that side.
      blocked += world.occluded(spawnRayTo(hit, hit.position + side * 1.5f + out * 0.5f), stats);
      blocked += world.occluded(spawnRayTo(hit, hit.position - side * 1.5f - out * 0.5f), stats);
      // A ray from a point above towards one below, through the hit, is blocked.
      Ray through;
      through.org = hit.position + side * 0.5f;
      through.dir = -side;
      through.tfar = 1;
      leaks += !world.occluded(through, stats);
    }
    EXPECT_EQ(reHits, 0) << transform;
    EXPECT_EQ(blocked, 0) << transform;
    EXPECT_EQ(leaks, 0) << transform;
  }
}

// A renderer hashes the seed once and each pixel once (Sampler::seedKey, pixelKey): the numbers
// are the one hash of (pixel, sample, dimension, seed) that every image so far was made with.
TEST(Sampler, PixelKeysGiveTheHashOfPixelSampleAndSeed) {
  for (uint64_t seed : {0ull, 7ull, 0xffffffffffffffffull})
    for (uint32_t x : {0u, 5u, 4095u})
      for (uint32_t y : {0u, 3u, 2159u})
        for (uint32_t s : {0u, 1u, 1023u}) {
          Sampler keyed(Sampler::pixelKey(Sampler::seedKey(seed), x, y), s), whole(x, y, s, seed);
          const uint64_t key = mixBits(mixBits(mixBits(seed) ^ (uint64_t(x) << 32 | y)) ^ s);
          for (uint64_t d = 1; d <= 4; ++d) {
            const float expected = float(mixBits(key + 0x9e3779b97f4a7c15ull * d) >> 40) * 0x1p-24f;
            EXPECT_EQ(keyed.next(), expected);
            EXPECT_EQ(whole.next(), expected);
          }
        }
}

}  // namespace
}  // namespace iso
