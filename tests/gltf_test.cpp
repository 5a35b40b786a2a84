// glTF import against the real models of examples/data/meshes (counts and values computed
// independently from the files with Python), small files written here for what the real
// ones lack, and malformed files that must be refused cleanly.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "scene/gltf.h"
#include "scene/world.h"
#include "tests/test_util.h"
#include "volume/input_error.h"

namespace iso {
namespace {

namespace fs = std::filesystem;
using test::dataPath;

SceneDesc meshScene(const std::string& file) {
  SceneDesc s;
  s.path = "test.json";
  MeshDesc m;
  m.file = file;
  s.meshes.push_back(m);
  return s;
}

TEST(Gltf, TriangleCountsOfEveryModel) {
  struct Case {
    const char* file;
    size_t world, stored, placements;
  };
  // Python over the files: sum of index counts / 3 per primitive, per node using the mesh.
  for (const Case& c : {Case{"meshes/Box.glb", 12, 12, 1}, Case{"meshes/BoxTextured/BoxTextured.gltf", 12, 12, 1},
                        Case{"meshes/2CylinderEngine.glb", 121496, 75730, 67},
                        Case{"meshes/cornell/cornellBox.gltf", 16732, 16720, 10}}) {
    World world(meshScene(dataPath(c.file)), IntersectorSpec{});
    ASSERT_EQ(world.meshes().size(), 1u);
    EXPECT_EQ(world.meshes()[0].triangles, c.world) << c.file;
    EXPECT_EQ(world.meshes()[0].uniqueTriangles, c.stored) << c.file;
    EXPECT_EQ(world.meshes()[0].instances, c.placements) << c.file;
  }
}

TEST(Gltf, NodeTransformsPlaceVertices) {
  // BoxTextured: node 0's column-major matrix maps (x, y, z) to (x, z, -y).
  const GltfModel box = loadGltf(dataPath("meshes/BoxTextured/BoxTextured.gltf"));
  ASSERT_EQ(box.instances.size(), 1u);
  const Vec3f v0 = box.meshes[0][0].positions[0];
  EXPECT_EQ(v0, Vec3f(-0.5f, -0.5f, 0.5f));
  const Vec3d p = box.instances[0].toFile.point(Vec3d(v0));
  EXPECT_NEAR(p.x, -0.5, 1e-12); EXPECT_NEAR(p.y, 0.5, 1e-12); EXPECT_NEAR(p.z, 0.5, 1e-12);

  // Cornell: the light (mesh 4, node 7) is scaled by (3, 1, 3) and raised to y = 4.626.
  const GltfModel cornell = loadGltf(dataPath("meshes/cornell/cornellBox.gltf"));
  int found = 0;
  for (const GltfInstance& inst : cornell.instances)
    if (inst.mesh == 4) {
      ++found;
      const Vec3d q = inst.toFile.point(Vec3d(cornell.meshes[4][0].positions[0]));  // (-0.5, -0.05, -0.5)
      EXPECT_NEAR(q.x, -1.5, 1e-6); EXPECT_NEAR(q.y, 4.626189558760184 - 0.05, 1e-6); EXPECT_NEAR(q.z, -1.5, 1e-6);
    }
  EXPECT_EQ(found, 1);
}

TEST(Gltf, MaterialValuesAndATexel) {
  const GltfModel cornell = loadGltf(dataPath("meshes/cornell/cornellBox.gltf"));
  ASSERT_EQ(cornell.materials.size(), 9u);
  EXPECT_NEAR(cornell.materials[2].baseColor.x, 0.054592281579971313, 1e-7);
  EXPECT_EQ(cornell.materials[2].baseColor.y, 1.f);
  EXPECT_EQ(cornell.materials[2].metallic, 1.f);  // glTF default
  EXPECT_EQ(cornell.materials[4].emissive, Vec3f(10, 10, 10));
  EXPECT_EQ(cornell.materials[4].roughness, 0.f);
  EXPECT_TRUE(cornell.materials[4].doubleSided);

  // BoxTextured's base colour texture, decoded as sRGB: texel (128, 60) is (91, 156, 215)/255
  // in the PNG (read with oiiotool).
  World world(meshScene(dataPath("meshes/BoxTextured/BoxTextured.gltf")), IntersectorSpec{});
  ASSERT_EQ(world.textures().size(), 1u);
  const Texture& t = world.textures()[0];
  EXPECT_EQ(t.width(), 256);
  EXPECT_EQ(t.height(), 256);
  auto linear = [](double c) { c /= 255; return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); };
  const Vec4f texel = t.lookup(128.5f / 256, 60.5f / 256);
  EXPECT_NEAR(texel.x, linear(91), 1e-5);
  EXPECT_NEAR(texel.y, linear(156), 1e-5);
  EXPECT_NEAR(texel.z, linear(215), 1e-5);
  EXPECT_EQ(world.materials()[1].colorTexture, 0);
  EXPECT_EQ(world.materials()[1].metallic, 0.f);
}

TEST(Gltf, CameraFromCornellBox) {
  SceneDesc s = meshScene(dataPath("meshes/cornell/cornellBox.gltf"));
  s.camera.gltfCamera = "default";
  World world(s, IntersectorSpec{});
  const CameraDesc& c = world.camera();
  EXPECT_NEAR(c.position.z, 19.992091970966317, 1e-9);
  EXPECT_NEAR(c.position.x, 0, 1e-12);
  EXPECT_NEAR(c.fov, 0.7175414562225342 * 180 / M_PI, 1e-9);
  EXPECT_NEAR(c.lookAt.z - c.position.z, -1, 1e-12);  // looks down -z
  EXPECT_NEAR(c.up.y, 1, 1e-12);
  s.camera.gltfCamera = "#0";
  EXPECT_EQ(World(s, IntersectorSpec{}).camera().position, c.position);
  s.camera.gltfCamera = "nope";
  EXPECT_THROW(World(s, IntersectorSpec{}), InputError);
}

// A one-triangle glTF with a separate .bin; `json` is spliced into the top-level object.
struct TriangleFile {
  std::string dir, gltf, bin;
  static std::string binary(std::vector<uint16_t> indices = {0, 1, 2}) {
    const float p[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    std::string b(reinterpret_cast<const char*>(p), sizeof(p));
    b.append(reinterpret_cast<const char*>(indices.data()), indices.size() * 2);
    return b;
  }
  static std::string json(const std::string& extra, const std::string& nodes = R"([{"mesh": 0}])",
                          const std::string& uri = "tri.bin", int byteLength = 42) {
    return R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": )" + nodes + R"(,
      "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
      "materials": [{"emissiveFactor": [1, 1, 1], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4}}}],
      "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
                    {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}],
      "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
      "buffers": [{"uri": ")" + uri + R"(", "byteLength": )" + std::to_string(byteLength) + "}]" + extra + "}";
  }
};

// A glTF camera node with scale 0 has no view direction: bad input naming the camera, not an
// Embree assertion on NaN rays (issue 14).
TEST(Gltf, DegenerateCameraNodeIsBadInput) {
  const std::string dir = test::scratchDir();
  test::writeBytes(dir + "/tri.bin", TriangleFile::binary());
  test::writeText(dir + "/cam.gltf", TriangleFile::json(R"(, "cameras": [{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1}}])",
                                                        R"([{"mesh": 0, "children": [1]}, {"camera": 0, "scale": [0, 0, 0]}])"));
  const SceneDesc s = parseSceneText(R"({"meshes": [{"file": "cam.gltf"}], "camera": {"gltf_camera": "#0"}})", dir + "/s.json");
  try {
    World world(s, IntersectorSpec{});
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/camera/gltf_camera: the camera has no view direction"), std::string::npos) << e.what();
  }
}

TEST(Gltf, PunctualLightsAndEmissiveStrength) {
  const std::string dir = test::scratchDir();
  test::writeBytes(dir + "/tri.bin", TriangleFile::binary());
  // A spot light at (1, 2, 3), rotated -90 degrees about x so that it shines down -y.
  test::writeText(dir + "/l.gltf", TriangleFile::json(
      R"(, "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_emissive_strength", "EXT_unknown"],
         "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "spot", "color": [1, 0.5, 0.25], "intensity": 5, "spot": {"innerConeAngle": 0.1, "outerConeAngle": 0.7853981633974483}}]}})",
      R"([{"mesh": 0, "children": [1]},
          {"translation": [1, 2, 3], "rotation": [-0.7071067811865476, 0, 0, 0.7071067811865476],
           "extensions": {"KHR_lights_punctual": {"light": 0}}}])"));
  const GltfModel m = loadGltf(dir + "/l.gltf");
  ASSERT_EQ(m.lights.size(), 1u);
  const LightDesc& l = m.lights[0];
  EXPECT_EQ(l.type, LightType::Spot);
  EXPECT_NEAR(l.position.x, 1, 1e-12); EXPECT_NEAR(l.position.y, 2, 1e-12); EXPECT_NEAR(l.position.z, 3, 1e-12);
  EXPECT_NEAR(l.direction.x, 0, 1e-12); EXPECT_NEAR(l.direction.y, -1, 1e-12); EXPECT_NEAR(l.direction.z, 0, 1e-12);
  EXPECT_EQ(l.intensity, Vec3d(5, 2.5, 1.25));
  EXPECT_NEAR(l.outerAngle, 45, 1e-9);
  EXPECT_NEAR(l.innerAngle, 0.1 * 180 / M_PI, 1e-9);
  EXPECT_EQ(m.materials[0].emissive, Vec3f(4, 4, 4));
  // The unknown optional extension is one warning; the file still loads.
  ASSERT_EQ(m.warnings.size(), 1u);
  EXPECT_NE(m.warnings[0].find("EXT_unknown"), std::string::npos);
  // The emissive triangle becomes an area light.
  World world(meshScene(dir + "/l.gltf"), IntersectorSpec{});
  int area = 0;
  for (const Light& light : world.lights()) area += light.kind() == Light::Kind::Area;
  EXPECT_EQ(area, 1);
  EXPECT_EQ(world.lights().size(), 2u);
}

std::string base64(const std::string& bytes) {
  static const char* table = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  for (size_t i = 0; i < bytes.size(); i += 3) {
    uint32_t v = uint8_t(bytes[i]) << 16;
    if (i + 1 < bytes.size()) v |= uint8_t(bytes[i + 1]) << 8;
    if (i + 2 < bytes.size()) v |= uint8_t(bytes[i + 2]);
    out += table[v >> 18 & 63];
    out += table[v >> 12 & 63];
    out += i + 1 < bytes.size() ? table[v >> 6 & 63] : '=';
    out += i + 2 < bytes.size() ? table[v & 63] : '=';
  }
  return out;
}

TEST(Gltf, EmbeddedBuffersLoad) {
  const std::string dir = test::scratchDir();
  const std::string uri = "data:application/octet-stream;base64," + base64(TriangleFile::binary());
  test::writeText(dir + "/e.gltf", TriangleFile::json("", R"([{"mesh": 0, "translation": [0, 0, 5]}])", uri));
  const GltfModel m = loadGltf(dir + "/e.gltf");
  ASSERT_EQ(m.meshes.size(), 1u);
  ASSERT_EQ(m.meshes[0][0].triangleCount(), 1u);
  EXPECT_EQ(m.meshes[0][0].positions[1], Vec3f(1, 0, 0));
  EXPECT_EQ(m.instances[0].toFile.point({1, 0, 0}), Vec3d(1, 0, 5));
}

TEST(Gltf, StripsAndFansBecomeTriangles) {
  const std::string dir = test::scratchDir();
  // Four vertices of a unit square; the strip 0 1 2 3 and the fan 0 1 3 2 give two triangles each.
  const float p[12] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0};
  const uint16_t strip[4] = {0, 1, 2, 3}, fan[4] = {0, 1, 3, 2};
  for (int mode : {5, 6}) {
    std::string bin(reinterpret_cast<const char*>(p), sizeof(p));
    bin.append(reinterpret_cast<const char*>(mode == 5 ? strip : fan), sizeof(strip));
    test::writeBytes(dir + "/q.bin", bin);
    test::writeText(dir + "/q.gltf", R"({"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
      "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": )" + std::to_string(mode) + R"(}]}],
      "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
                    {"bufferView": 1, "componentType": 5123, "count": 4, "type": "SCALAR"}],
      "bufferViews": [{"buffer": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 8}],
      "buffers": [{"uri": "q.bin", "byteLength": 56}]})");
    const GltfModel m = loadGltf(dir + "/q.gltf");
    ASSERT_EQ(m.meshes[0].size(), 1u);
    const TriangleMesh& t = m.meshes[0][0];
    ASSERT_EQ(t.triangleCount(), 2u) << mode;
    // Both triangles keep the counter-clockwise winding (+z normal).
    for (size_t k = 0; k < 2; ++k) {
      const Vec3f a = t.positions[t.indices[3 * k]], b = t.positions[t.indices[3 * k + 1]], c = t.positions[t.indices[3 * k + 2]];
      EXPECT_GT(cross(b - a, c - a).z, 0) << "mode " << mode << " triangle " << k;
    }
  }
}

// Bad files: exit 2, one line naming the file and what is wrong, no image; info refuses too.
void expectRefused(const std::string& dir, const std::string& model, const std::string& fragment) {
  test::writeText(dir + "/s.json", R"({"meshes": [{"file": ")" + model + R"("}], "film": {"width": 8, "height": 8}})");
  const std::string image = dir + "/out.png";
  for (const std::string& args : {"render " + dir + "/s.json -o " + image + " --quiet", "info " + dir + "/s.json"}) {
    const auto r = test::runIsotrace(args);
    EXPECT_EQ(r.status, 2) << args << "\n" << r.err;
    EXPECT_NE(r.err.find(model), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(fragment), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_FALSE(fs::exists(image));
  }
}

TEST(Gltf, BadFilesAreRefusedWithOneLine) {
  const std::string dir = test::scratchDir();
  std::ifstream in(dataPath("meshes/Box.glb"), std::ios::binary);
  std::stringstream box;
  box << in.rdbuf();
  test::writeBytes(dir + "/cut.glb", box.str().substr(0, box.str().size() / 2));
  expectRefused(dir, "cut.glb", "truncated");
  test::writeBytes(dir + "/head.glb", box.str().substr(0, 10));
  expectRefused(dir, "head.glb", "not a binary glTF");
  // A BIN chunk longer than the file (tinygltf called it "not aligned to a 4-byte boundary").
  std::string longBin = box.str();
  uint32_t jsonLength;
  std::memcpy(&jsonLength, &longBin[12], 4);
  const uint32_t huge = 0x7ffffff0;
  std::memcpy(&longBin[20 + jsonLength], &huge, 4);
  test::writeBytes(dir + "/longbin.glb", longBin);
  expectRefused(dir, "longbin.glb", "the BIN chunk of 2147483632 bytes runs past the end of the file");

  test::writeBytes(dir + "/tri.bin", TriangleFile::binary());
  test::writeText(dir + "/missing.gltf", TriangleFile::json("", R"([{"mesh": 0}])", "nothere.bin"));
  expectRefused(dir, "missing.gltf", "nothere.bin");
  test::writeBytes(dir + "/short.bin", TriangleFile::binary().substr(0, 20));
  test::writeText(dir + "/short.gltf", TriangleFile::json("", R"([{"mesh": 0}])", "short.bin"));
  expectRefused(dir, "short.gltf", "short.bin");
  test::writeBytes(dir + "/range.bin", TriangleFile::binary({0, 1, 7}));
  test::writeText(dir + "/range.gltf", TriangleFile::json("", R"([{"mesh": 0}])", "range.bin"));
  expectRefused(dir, "range.gltf", "/accessors/1: index 7 (element 2) is out of range");
  test::writeText(dir + "/cycle.gltf", TriangleFile::json("", R"([{"mesh": 0, "children": [1]}, {"children": [0]}])"));
  expectRefused(dir, "cycle.gltf", "cycle");
  test::writeText(dir + "/typed.gltf", TriangleFile::json("", R"([{"mesh": "0"}])"));
  expectRefused(dir, "typed.gltf", "/nodes/0/mesh: expected a whole number");
  test::writeText(dir + "/nomesh.gltf", TriangleFile::json("", R"([{"mesh": 3}])"));
  expectRefused(dir, "nomesh.gltf", "/nodes/0/mesh: mesh 3 does not exist");
  test::writeText(dir + "/draco.gltf", TriangleFile::json(R"(, "extensionsRequired": ["KHR_draco_mesh_compression"],
                                                            "extensionsUsed": ["KHR_draco_mesh_compression"])"));
  expectRefused(dir, "draco.gltf", "required extension KHR_draco_mesh_compression is not supported");
  test::writeText(dir + "/syntax.gltf", "{\"asset\": ");
  expectRefused(dir, "syntax.gltf", "JSON syntax error");
  expectRefused(dir, "absent.glb", "glTF file not found");
  // Issue 14: negative indices (tinygltf reads -1 as "absent"), a count whose byte span wraps
  // 64 bits, a buffer naming a directory.
  test::writeText(dir + "/negative.gltf", TriangleFile::json("", R"([{"mesh": -3}])"));
  expectRefused(dir, "negative.gltf", "/nodes/0/mesh: expected a whole number >= 0");
  std::string wrap = TriangleFile::json("");
  wrap.replace(wrap.find("\"count\": 3"), 10, "\"count\": 4611686018427387905");
  test::writeText(dir + "/wrap.gltf", wrap);
  expectRefused(dir, "wrap.gltf", "/accessors/0: 4611686018427387905 elements do not fit in buffer view 0");
  fs::create_directories(dir + "/adir");
  test::writeText(dir + "/dir.gltf", TriangleFile::json("", R"([{"mesh": 0}])", "adir"));
  expectRefused(dir, "dir.gltf", "/buffers/0/uri: 'adir' is a directory");
  test::writeText(dir + "/datauri.gltf", TriangleFile::json("", R"([{"mesh": 0}])", "data:application/octet-stream;base64,@@@@"));
  expectRefused(dir, "datauri.gltf", "/buffers/0/uri: the data URI's payload is not valid base64");
}

// One ray known to reach the mesh first and one known to reach the iso-surface first.
TEST(Gltf, MixedSceneReturnsTheRightObjectAndMaterial) {
  SceneDesc s = parseSceneText(R"({
    "meshes": [{"shape": "quad", "transform": {"scale": 3}, "material": "floor"}],
    "volumes": [{"procedural": {"field": "sphere", "resolution": [33, 33, 33]},
                 "transform": {"translate": [0, 1, 0]},
                 "isosurfaces": [{"value": 0.5, "material": "ball", "inside": "below"}]}],
    "materials": {"floor": {"type": "diffuse", "color": 0.5}, "ball": {"type": "conductor"}}
  })", "mixed.json");
  World world(s, IntersectorSpec{});
  TraversalStats stats;
  auto trace = [&](Vec3f org, Vec3f dir, Hit& hit) {
    Ray ray;
    ray.org = org;
    ray.dir = normalize(dir);
    return world.intersect(ray, hit, stats);
  };
  const std::string& floorName = world.materials()[1].name;
  Hit hit;
  ASSERT_TRUE(trace({0, 5, 0}, {0, -1, 0}, hit));  // the ball is on top of the floor
  EXPECT_EQ(hit.surface, 0);
  EXPECT_EQ(hit.mesh, -1);
  EXPECT_EQ(world.materials()[hit.material].name, "ball");
  EXPECT_NEAR(hit.position.y, 1.5, 0.01);
  EXPECT_GT(hit.normal.y, 0.99);  // "inside": "below" puts the solid inside the sphere
  EXPECT_GT(hit.tError, 0);
  ASSERT_TRUE(trace({2, 5, 0}, {0, -1, 0}, hit));  // beside the ball: the floor
  EXPECT_EQ(hit.mesh, 0);
  EXPECT_EQ(hit.surface, -1);
  EXPECT_EQ(floorName, "floor");
  EXPECT_EQ(world.materials()[hit.material].name, "floor");
  EXPECT_NEAR(hit.position.y, 0, 1e-6);
  ASSERT_TRUE(trace({0, -1, 0}, {0, 1, 0}, hit));  // from below, the floor hides the ball
  EXPECT_EQ(hit.mesh, 0);
  EXPECT_NEAR(hit.position.y, 0, 1e-6);
  ASSERT_TRUE(trace({0, 1, -5}, {0, 0, 1}, hit));  // sideways into the transformed volume
  EXPECT_EQ(hit.surface, 0);
  EXPECT_NEAR(hit.position.z, -0.5, 0.01);
  EXPECT_LT(hit.normal.z, -0.99);
}

}  // namespace
}  // namespace iso
