// The scene format: every documented key is read into the description, and each kind of
// error names the JSON path where it is.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>

#include "scene/colormap.h"
#include "scene/scene.h"
#include "scene/world.h"
#include "tests/test_util.h"
#include "volume/input_error.h"

namespace iso {
namespace {

const char* kFullScene = R"({
  "camera": { "position": [1, 2, 3], "look_at": [0, 1, 0], "up": [0, 0, 1], "fov": 35 },
  "film": { "width": 320, "height": 200 },
  "integrator": { "type": "normals", "spp": 16, "max_depth": 7, "ao_distance": 2.5, "seed": 9, "ray_flow": "scalar" },
  "intersector": "neubauer:5",
  "meshes": [
    { "file": "models/a.glb", "transform": { "translate": [1, 2, 3], "rotate": { "axis": [0, 1, 0], "degrees": 90 }, "scale": 2 }, "material": "red" },
    { "shape": "quad", "transform": { "matrix": [2, 0, 0, 1,  0, 3, 0, 2,  0, 0, 4, 3,  0, 0, 0, 1] } },
    { "shape": "sphere", "transform": { "scale": [1, 2, 3] } }
  ],
  "volumes": [ {
    "file": "v/x.raw", "dims": [4, 5, 6], "type": "uint16", "endian": "big",
    "origin": [-1, -2, -3], "spacing": [0.5, 0.25, 2],
    "transform": { "translate": [10, 0, 0] },
    "isosurfaces": [ { "value": 60, "material": "glass", "inside": "below" }, { "value": 100, "color": [0.1, 0.2, 0.3], "normals": "cell" } ]
  }, {
    "procedural": { "field": "gyroid", "resolution": [8, 9, 10] }, "isosurfaces": [ { "value": 0 } ]
  } ],
  "materials": {
    "red": { "type": "diffuse", "color": [0.9, 0.1, 0.1] },
    "plastic": { "type": "metallic_roughness", "color": 0.5, "metallic": 0.25, "roughness": 0.75 },
    "gold": { "type": "conductor", "color": [1, 0.8, 0.3], "roughness": 0.2 },
    "glass": { "type": "dielectric", "ior": 1.33, "color": [0.9, 1, 1] },
    "lamp": { "type": "emissive", "radiance": [10, 9, 8], "two_sided": true }
  },
  "lights": [
    { "type": "point", "position": [0, 5, 0], "intensity": [50, 40, 30] },
    { "type": "spot", "position": [1, 5, 0], "direction": [0, -2, 0], "intensity": 20, "inner_angle": 10, "outer_angle": 30 },
    { "type": "directional", "direction": [0, 0, -3], "irradiance": [2, 2, 2] },
    { "type": "environment", "radiance": 0.5, "file": "sky.exr" }
  ]
})";

TEST(SceneFormat, EveryDocumentedKeyIsRead) {
  const SceneDesc s = parseSceneText(kFullScene, "/scenes/full.json");
  EXPECT_EQ(s.camera.position, Vec3d(1, 2, 3));
  EXPECT_EQ(s.camera.lookAt, Vec3d(0, 1, 0));
  EXPECT_EQ(s.camera.up, Vec3d(0, 0, 1));
  EXPECT_EQ(s.camera.fov, 35);
  EXPECT_EQ(s.settings.width, 320);
  EXPECT_EQ(s.settings.height, 200);
  EXPECT_EQ(s.settings.integrator, "normals");
  EXPECT_EQ(s.settings.spp, 16);
  EXPECT_EQ(s.settings.maxDepth, 7);
  EXPECT_EQ(s.settings.aoDistance, 2.5);
  EXPECT_EQ(s.settings.seed, 9u);
  EXPECT_EQ(s.settings.rayFlow, RayFlow::Scalar);
  EXPECT_EQ(s.settings.intersector.kind, IntersectorKind::Neubauer);
  EXPECT_EQ(s.settings.intersector.iterations, 5);

  ASSERT_EQ(s.meshes.size(), 3u);
  EXPECT_EQ(s.meshes[0].file, "/scenes/models/a.glb");  // relative to the scene file
  EXPECT_EQ(s.meshes[0].material, "red");
  // scale 2, then 90 degrees about y, then translate: (1, 0, 0) -> (2, 0, 0) -> (0, 0, -2) -> (1, 2, 1).
  const Vec3d p = s.meshes[0].transform.point({1, 0, 0});
  EXPECT_NEAR(p.x, 1, 1e-12); EXPECT_NEAR(p.y, 2, 1e-12); EXPECT_NEAR(p.z, 1, 1e-12);
  EXPECT_EQ(s.meshes[1].shape, MeshShape::Quad);
  EXPECT_EQ(s.meshes[1].transform.point({1, 1, 1}), Vec3d(3, 5, 7));  // row-major matrix
  EXPECT_EQ(s.meshes[2].shape, MeshShape::Sphere);
  EXPECT_EQ(s.meshes[2].transform.point({1, 1, 1}), Vec3d(1, 2, 3));

  ASSERT_EQ(s.volumes.size(), 2u);
  const VolumeDesc& v = s.volumes[0];
  EXPECT_EQ(v.file, "/scenes/v/x.raw");
  ASSERT_TRUE(v.layout.dims && v.layout.type);
  EXPECT_EQ(*v.layout.dims, Vec3i(4, 5, 6));
  EXPECT_EQ(*v.layout.type, ScalarType::UInt16);
  EXPECT_TRUE(v.layout.bigEndian);
  EXPECT_EQ(*v.origin, Vec3d(-1, -2, -3));
  EXPECT_EQ(*v.spacing, Vec3d(0.5, 0.25, 2));
  EXPECT_EQ(v.transform.point({0, 0, 0}), Vec3d(10, 0, 0));
  ASSERT_EQ(v.isosurfaces.size(), 2u);
  EXPECT_EQ(v.isosurfaces[0].value, 60);
  EXPECT_EQ(v.isosurfaces[0].material, "glass");
  EXPECT_FALSE(v.isosurfaces[0].solidAbove);
  EXPECT_TRUE(v.isosurfaces[1].solidAbove);
  EXPECT_TRUE(v.isosurfaces[0].smoothNormals);
  EXPECT_FALSE(v.isosurfaces[1].smoothNormals);
  EXPECT_EQ(*v.isosurfaces[1].color, Vec3d(0.1, 0.2, 0.3));
  EXPECT_EQ(*s.volumes[1].field, Field::Gyroid);
  EXPECT_EQ(s.volumes[1].resolution, Vec3i(8, 9, 10));

  ASSERT_EQ(s.materials.size(), 5u);
  EXPECT_EQ(s.materials.at("red").type, MaterialType::Diffuse);
  EXPECT_EQ(s.materials.at("red").color, Vec3d(0.9, 0.1, 0.1));
  const MaterialDesc& plastic = s.materials.at("plastic");
  EXPECT_EQ(plastic.type, MaterialType::MetallicRoughness);
  EXPECT_EQ(plastic.color, Vec3d(0.5, 0.5, 0.5));
  EXPECT_EQ(plastic.metallic, 0.25);
  EXPECT_EQ(plastic.roughness, 0.75);
  EXPECT_EQ(s.materials.at("gold").type, MaterialType::Conductor);
  EXPECT_EQ(s.materials.at("gold").roughness, 0.2);
  EXPECT_EQ(s.materials.at("glass").type, MaterialType::Dielectric);
  EXPECT_EQ(s.materials.at("glass").ior, 1.33);
  EXPECT_EQ(s.materials.at("glass").color, Vec3d(0.9, 1, 1));
  EXPECT_EQ(s.materials.at("lamp").type, MaterialType::Emissive);
  EXPECT_EQ(s.materials.at("lamp").emission, Vec3d(10, 9, 8));
  EXPECT_TRUE(s.materials.at("lamp").twoSided);

  ASSERT_EQ(s.lights.size(), 4u);
  EXPECT_EQ(s.lights[0].type, LightType::Point);
  EXPECT_EQ(s.lights[0].position, Vec3d(0, 5, 0));
  EXPECT_EQ(s.lights[0].intensity, Vec3d(50, 40, 30));
  EXPECT_EQ(s.lights[1].type, LightType::Spot);
  EXPECT_EQ(s.lights[1].direction, Vec3d(0, -1, 0));  // normalised
  EXPECT_EQ(s.lights[1].intensity, Vec3d(20, 20, 20));
  EXPECT_EQ(s.lights[1].innerAngle, 10);
  EXPECT_EQ(s.lights[1].outerAngle, 30);
  EXPECT_EQ(s.lights[2].type, LightType::Directional);
  EXPECT_EQ(s.lights[2].direction, Vec3d(0, 0, -1));
  EXPECT_EQ(s.lights[2].irradiance, Vec3d(2, 2, 2));
  EXPECT_EQ(s.lights[3].type, LightType::Environment);
  EXPECT_EQ(s.lights[3].radiance, Vec3d(0.5, 0.5, 0.5));
  EXPECT_EQ(s.lights[3].file, "/scenes/sky.exr");
}

// Normals transform so that they stay perpendicular to transformed surfaces, for rotation,
// non-uniform scale, shear and mirroring; inverse() undoes the transform.
TEST(Transforms, NormalsStayPerpendicularAndInverseUndoes) {
  const double rows[12] = {0.3, 1.2, -0.4, 5, -0.7, 0.2, 0.9, -2, 0.5, -0.1, 1.7, 3};
  for (const Transform& t : {Transform::rotate(65, {1, 0, 0}), Transform::rotate(37, {1, 0.3, 0.2}) * Transform::scale({2, 0.5, 3}),
                             Transform::fromRows(rows), Transform::scale({-1, 2, 1})}) {
    const Vec3d a{1, 0.2, -0.3}, b{-0.4, 1, 0.7};
    const Vec3d n = t.normal(cross(a, b));
    EXPECT_NEAR(dot(n, t.vector(a)), 0, 1e-12);
    EXPECT_NEAR(dot(n, t.vector(b)), 0, 1e-12);
    EXPECT_GT(dot(normalize(n), normalize(cross(t.vector(a), t.vector(b)))) * (t.determinant() < 0 ? -1 : 1), 0.999);
    const Vec3d p{0.3, -2, 7};
    const Vec3d q = t.inverse().point(t.point(p));
    EXPECT_NEAR(q.x, p.x, 1e-12); EXPECT_NEAR(q.y, p.y, 1e-12); EXPECT_NEAR(q.z, p.z, 1e-12);
  }
}

TEST(SceneFormat, GltfCameraByNameOrIndex) {
  EXPECT_EQ(parseSceneText(R"({"camera": {"gltf_camera": "default"}})", "s.json").camera.gltfCamera, "default");
  EXPECT_EQ(parseSceneText(R"({"camera": {"gltf_camera": 2}})", "s.json").camera.gltfCamera, "#2");
}

// Each error names the file and the JSON path of the offending value.
void expectError(const std::string& text, const std::string& where, const std::string& what) {
  try {
    parseSceneText(text, "s.json");
    ADD_FAILURE() << "no error for " << text;
  } catch (const InputError& e) {
    const std::string msg = e.what();
    EXPECT_EQ(msg.rfind("s.json: " + where + ": ", 0), 0u) << msg;
    EXPECT_NE(msg.find(what), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
}

TEST(SceneFormat, ErrorsNameTheirJsonPath) {
  // Unknown keys, at every level.
  expectError(R"({"camra": {}})", "/camra", "unknown key");
  expectError(R"({"materials": {"m": {"type": "diffuse", "colour": 1}}})", "/materials/m/colour", "unknown key");
  expectError(R"({"materials": {"m": {"type": "diffuse", "ior": 1.5}}})", "/materials/m/ior", "unknown key");
  expectError(R"({"lights": [{"type": "point", "irradiance": 1}]})", "/lights/0/irradiance", "unknown key");
  expectError(R"({"meshes": [{"shape": "quad", "transform": {"shift": [0,0,0]}}]})", "/meshes/0/transform/shift", "unknown key");
  // Wrong types.
  expectError(R"({"film": {"width": "640"}})", "/film/width", "whole number");
  expectError(R"({"lights": [{"type": "point", "position": [0, "1", 0]}]})", "/lights/0/position/1", "number");
  expectError(R"({"materials": {"m": {"type": "emissive", "two_sided": 1}}})", "/materials/m/two_sided", "true or false");
  expectError(R"({"meshes": {"file": "a.glb"}})", "/meshes", "array");
  // Missing required keys.
  expectError(R"({"lights": [{"position": [0, 1, 0]}]})", "/lights/0/type", "required");
  expectError(R"({"lights": [{"type": "spot"}]})", "/lights/0/direction", "required");
  expectError(R"({"materials": {"m": {"color": 1}}})", "/materials/m/type", "required");
  expectError(R"({"meshes": [{"transform": {}}]})", "/meshes/0", "exactly one of");
  expectError(R"({"volumes": [{"procedural": {"field": "sphere"}, "isosurfaces": 3}]})", "/volumes/0/isosurfaces", "expected an array");
  // Undefined references and bad values.
  expectError(R"({"meshes": [{"shape": "quad", "material": "nope"}]})", "/meshes/0/material", "undefined material 'nope'");
  expectError(R"({"volumes": [{"procedural": {"field": "sphere"}, "isosurfaces": [{"value": 0.5, "material": "x"}]}]})",
              "/volumes/0/isosurfaces/0/material", "undefined material 'x'");
  expectError(R"({"lights": [{"type": "area"}]})", "/lights/0/type", "unknown value 'area'");
  expectError(R"({"integrator": {"ray_flow": "packets"}})", "/integrator/ray_flow", "unknown ray flow 'packets'");
  expectError(R"({"integrator": {"ray_flow": 1}})", "/integrator/ray_flow", "string");
  expectError(R"({"materials": {"g": {"type": "dielectric", "ior": 0.5}}})", "/materials/g/ior", "out of range");
  expectError(R"({"meshes": [{"shape": "quad", "transform": {"matrix": [1,0,0,0, 0,1,0,0, 0,0,0,0, 0,0,0,1]}}]})",
              "/meshes/0/transform/matrix", "not invertible");
  expectError(R"({"meshes": [{"shape": "quad", "transform": {"scale": 0}}]})", "/meshes/0/transform/scale", "flattens");
  expectError(R"({"camera": {"gltf_camera": "a", "fov": 30}})", "/camera/fov", "not allowed together");
  expectError(R"({"volumes": [{"procedural": {"field": "sphere"}, "grid": "density", "isosurfaces": [{"value": 0.5}]}]})",
              "/volumes/0/grid", "applies to volume files, not to a procedural field");
  expectError(R"({"volumes": [{"file": "a.vdb", "series": "", "isosurfaces": [{"value": 0.5}]}]})", "/volumes/0/series",
              "empty series UID");
  expectError("{\n  \"film\": {\"width\": 3,}\n}", "line 2, column 23", "JSON syntax error");
}

// "name" and "color_by": every malformed entry names its place.
TEST(SceneFormat, ColorByErrorsNameTheirJsonPath) {
  auto volumes = [](const std::string& colorBy, const std::string& second = R"({"procedural": {"field": "torus"}, "name": "t"})") {
    return R"({"volumes": [{"procedural": {"field": "sphere"}, "isosurfaces": [{"value": 0.5, "color_by": )" + colorBy +
           "}]}, " + second + "]}";
  };
  expectError(volumes(R"({"field": "t", "map": "rainbow", "range": [0, 1]})"), "/volumes/0/isosurfaces/0/color_by/map",
              "unknown colour map 'rainbow' (known: viridis, magma, inferno, plasma, cividis, turbo, cool_warm, grey");
  expectError(volumes(R"({"field": "t", "range": [1, 1]})"), "/volumes/0/isosurfaces/0/color_by/range", "an empty range");
  expectError(volumes(R"({"field": "t", "range": [2, 1]})"), "/volumes/0/isosurfaces/0/color_by/range", "an empty range");
  expectError(volumes(R"({"field": "t", "range": [0]})"), "/volumes/0/isosurfaces/0/color_by/range", "expected [low, high]");
  expectError(volumes(R"({"field": "t"})"), "/volumes/0/isosurfaces/0/color_by/range", "required key is missing");
  expectError(volumes(R"({"map": "grey", "range": [0, 1]})"), "/volumes/0/isosurfaces/0/color_by/field", "required key is missing");
  expectError(volumes(R"({"field": "temperature", "range": [0, 1]})"), "/volumes/0/isosurfaces/0/color_by/field",
              "no volume is named 'temperature' (named: t; or \"gradient_magnitude\")");
  expectError(volumes(R"({"field": "t", "range": [0, 1], "nan_color": [2, 0, 0]})"), "/volumes/0/isosurfaces/0/color_by/nan_color/0", "out of range");
  expectError(volumes(R"({"field": "t", "map": [[0, [0, 0, 0]]]})"), "/volumes/0/isosurfaces/0/color_by/map", "2 to 1024 stops");
  expectError(volumes(R"({"field": "t", "map": [[0, [0, 0, 0]], [0, [1, 1, 1]]]})"), "/volumes/0/isosurfaces/0/color_by/map/1/0", "must rise strictly");
  expectError(volumes(R"({"field": "t", "map": [[0, [0, 0, 0]], [1, [1, 1]]]})"), "/volumes/0/isosurfaces/0/color_by/map/1", "expected a stop");
  expectError(volumes(R"({"field": "t", "map": [[0, [0, 0, 0]], [1, [1, 1, 1]]], "range": [0, 1]})"), "/volumes/0/isosurfaces/0/color_by/range",
              "takes its range from their values");
  expectError(volumes(R"({"field": "t", "range": [0, 1], "colour": 1})"), "/volumes/0/isosurfaces/0/color_by/colour", "unknown key");
  expectError(volumes(R"({"field": "gradient_magnitude", "range": [0, 1]})", R"({"procedural": {"field": "torus"}, "name": ""})"),
              "/volumes/1/name", "empty name");
  expectError(volumes(R"({"field": "t", "range": [0, 1]})", R"({"procedural": {"field": "torus"}, "name": "gradient_magnitude"})"),
              "/volumes/1/name", "names the gradient");
  expectError(R"({"volumes": [{"procedural": {"field": "torus"}, "name": "a"}, {"procedural": {"field": "torus"}, "name": "a"}]})",
              "/volumes/1/name", "the name 'a' is taken by /volumes/0");
  // Well-formed: the field resolves to its volume (also one listed later), a user map's stops give the range.
  const SceneDesc s = parseSceneText(volumes(R"({"field": "t", "map": [[-2, [0, 0, 0]], [6, [1, 0.5, 0]]]})"), "s.json");
  const ColorByDesc& c = *s.volumes[0].isosurfaces[0].colorBy;
  EXPECT_EQ(c.volume, 1);
  EXPECT_EQ(c.lo, -2);
  EXPECT_EQ(c.hi, 6);
  EXPECT_EQ(c.map.srgb(0.5f), Vec3f(0.5f, 0.25f, 0));
  EXPECT_TRUE(s.volumes[1].isosurfaces.empty());
  EXPECT_EQ(parseSceneText(volumes(R"({"field": "gradient_magnitude", "range": [0, 1]})"), "s.json")
                .volumes[0].isosurfaces[0].colorBy->volume, -1);
}

// The built-in maps as published (8-bit sRGB), ends clamped, NaN to the first colour.
TEST(ColorMaps, NamedMapsGiveThePublishedColours) {
  ColorMap viridis, grey, coolWarm;
  ASSERT_TRUE(ColorMap::named("viridis", viridis));
  ASSERT_TRUE(ColorMap::named("grey", grey));
  ASSERT_TRUE(ColorMap::named("cool_warm", coolWarm));
  EXPECT_FALSE(ColorMap::named("jet", viridis));
  auto bytes = [](Vec3f c) { return Vec3i{int(std::lround(c.x * 255)), int(std::lround(c.y * 255)), int(std::lround(c.z * 255))}; };
  EXPECT_EQ(bytes(viridis.srgb(0)), Vec3i(68, 1, 84));      // #440154
  EXPECT_EQ(bytes(viridis.srgb(1)), Vec3i(253, 231, 37));   // #fde725
  EXPECT_EQ(bytes(viridis.srgb(-3)), Vec3i(68, 1, 84));
  EXPECT_EQ(bytes(viridis.srgb(7)), Vec3i(253, 231, 37));
  EXPECT_EQ(bytes(viridis.srgb(NAN)), Vec3i(68, 1, 84));
  EXPECT_EQ(bytes(grey.srgb(0.5f)), Vec3i(128, 128, 128));  // halfway between entries 127 and 128
  // ParaView's cool to warm: blue, a light grey in the middle, red.
  const Vec3i low = bytes(coolWarm.srgb(0)), high = bytes(coolWarm.srgb(1)), mid = bytes(coolWarm.srgb(0.5f));
  EXPECT_GT(low.z, low.x);
  EXPECT_GT(high.x, high.z);
  EXPECT_NEAR(mid.x, mid.y, 30);
  EXPECT_GT(mid.y, 190);
  // Linear light: the sRGB curve undone.
  EXPECT_NEAR(grey.linear(1).x, 1, 1e-6);
  EXPECT_NEAR(grey.linear(0.5f).x, 0.2158605f, 2e-3);
}

// The command line reports the same errors as one line and exit status 2.
TEST(SceneFormat, CommandLineReportsUndefinedMaterial) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", R"({"meshes": [{"shape": "quad", "material": "nope"}]})");
  for (const std::string& args : {"render " + dir + "/s.json -o " + dir + "/x.png", "info " + dir + "/s.json"}) {
    const auto r = test::runIsotrace(args);
    EXPECT_EQ(r.status, 2) << args;
    EXPECT_NE(r.err.find("s.json: /meshes/0/material: undefined material 'nope'"), std::string::npos) << r.err;
  }
}

// Shading normals of a coarse, anisotropic distance field (20x20x9 samples, spacing 1, 1, 2.5)
// against the analytic normals of the sphere it samples. The cell's own gradient jumps at
// every cell face (issue 12 measured a mean error of 3.45 degrees); the smooth gradient must
// stay within 1.5 degrees on average and 3 at the 95th percentile. The geometric normal is
// still the exact surface's.
TEST(ShadingNormals, SmoothGradientFollowsTheSampledSphere) {
  const std::string dir = test::scratchDir();
  const Vec3d centre{9.5, 9.7, 10.2};
  const double radius = 7;
  std::string bytes;
  for (int z = 0; z < 9; ++z)
    for (int y = 0; y < 20; ++y)
      for (int x = 0; x < 20; ++x) {
        const float v = float(length(Vec3d(x, y, 2.5 * z) - centre) - radius);
        char b[4];
        std::memcpy(b, &v, 4);
        bytes.append(b, 4);
      }
  test::writeBytes(dir + "/sphere.raw", bytes);
  auto angles = [&](const char* normals, bool& shadingIsGeometric) {
    test::writeText(dir + "/s.json", std::string(R"({ "volumes": [ { "file": "sphere.raw", "dims": [20, 20, 9],
        "type": "float32", "spacing": [1, 1, 2.5], "isosurfaces": [ { "value": 0, "inside": "below", "normals": ")") +
                                         normals + R"(" } ] } ] })");
    World world(parseSceneFile(dir + "/s.json"), IntersectorSpec{});
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(0, 1);
    std::vector<double> errors;
    TraversalStats stats;
    shadingIsGeometric = true;
    for (int i = 0; i < 4000; ++i) {
      const Vec3f w = sampleUniformSphere(u(rng), u(rng));
      Ray r;
      r.org = Vec3f(centre) + w * 40.f;
      r.dir = -w;
      Hit hit;
      if (!world.intersect(r, hit, stats)) continue;
      const Vec3d exact = normalize(hit.position64 - centre);
      const double c = std::clamp(dot(exact, Vec3d(hit.shading)), -1.0, 1.0);
      errors.push_back(std::acos(c) * 180 / M_PI);
      shadingIsGeometric = shadingIsGeometric && hit.shading == hit.normal;
    }
    std::sort(errors.begin(), errors.end());
    double mean = 0;
    for (double e : errors) mean += e;
    mean /= double(errors.size());
    const double p95 = errors[errors.size() * 95 / 100];
    std::printf("normals %s: %zu hits, mean %.2f deg, 95th percentile %.2f deg, max %.2f deg\n", normals,
                errors.size(), mean, p95, errors.back());
    EXPECT_GT(errors.size(), 3000u);
    return std::pair{mean, p95};
  };
  bool geometric = false;
  const auto [smoothMean, smoothP95] = angles("smooth", geometric);
  EXPECT_FALSE(geometric);
  EXPECT_LE(smoothMean, 1.5);
  EXPECT_LE(smoothP95, 3.0);
  const auto [cellMean, cellP95] = angles("cell", geometric);
  EXPECT_TRUE(geometric);  // "cell": the shading normal is the cell's gradient, the geometric one
  EXPECT_GT(cellMean, 2 * smoothMean);
  EXPECT_GT(cellP95, smoothP95);
}

}  // namespace
}  // namespace iso
