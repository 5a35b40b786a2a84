// `isotrace mesh`'s extraction: the mesh is closed wherever the surface does not leave the
// grid, every vertex lies within a cell of the exact surface, and the winding agrees with the
// gradient. On a procedural sphere (exact answer known) and on real volumes.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <utility>

#include "renderer/commands.h"
#include "scene/gltf.h"
#include "tests/test_util.h"
#include "volume/input_error.h"
#include "volume/iso_mesh.h"
#include "volume/loaders.h"
#include "volume/procedural.h"

namespace iso {
namespace {

// Edges used by exactly one triangle (the mesh's boundary), as vertex index pairs.
std::vector<std::pair<uint32_t, uint32_t>> openEdges(const IsoMesh& m) {
  std::map<std::pair<uint32_t, uint32_t>, int> uses;
  for (size_t t = 0; t < m.indices.size(); t += 3)
    for (int e = 0; e < 3; ++e) {
      const uint32_t a = m.indices[t + e], b = m.indices[t + (e + 1) % 3];
      ++uses[{std::min(a, b), std::max(a, b)}];
    }
  std::vector<std::pair<uint32_t, uint32_t>> open;
  for (const auto& [edge, n] : uses) {
    EXPECT_LE(n, 2) << "an edge shared by " << n << " triangles";
    if (n == 1) open.push_back(edge);
  }
  return open;
}

// True when the cell holding p, or one of its neighbours, has corners on both sides of iso or on
// it (OpenVDB counts a value equal to iso as outside, the traversal as inside's complement; at
// integer iso values on integer data the two differ, and both are the surface): p lies within
// a cell of the surface.
bool nearSurface(const Grid& g, const Vec3d& p, double iso) {
  const Vec3i d = g.dims();
  for (int dz = -1; dz <= 1; ++dz)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        const Vec3i c{int(std::floor(p.x)) + dx, int(std::floor(p.y)) + dy, int(std::floor(p.z)) + dz};
        if (c.x < 0 || c.y < 0 || c.z < 0 || c.x > d.x - 2 || c.y > d.y - 2 || c.z > d.z - 2) continue;
        float v[8];
        g.cellCorners(c.x, c.y, c.z, v);
        bool above = false, below = false;
        for (float f : v) {
          above = above || f >= iso;
          below = below || f <= iso;
        }
        if (above && below) return true;
      }
  return false;
}

// The trilinear field's own gradient at grid coordinates p (central differences of the
// interpolant, in double).
Vec3d fieldGradient(const Grid& g, const Vec3d& p) {
  const double h = 1e-4;
  Vec3d grad;
  for (int a = 0; a < 3; ++a) {
    Vec3d lo = p, hi = p;
    lo[a] -= h;
    hi[a] += h;
    grad[a] = (g.interpolate(hi) - g.interpolate(lo)) / (2 * h);
  }
  return grad;
}

// Share of triangles whose face normal points to lower values of the field (the documented
// winding), judged by the field's gradient at the triangle's centre.
double windingAgreement(const Grid& g, const IsoMesh& m) {
  size_t agree = 0;
  for (size_t t = 0; t < m.indices.size(); t += 3) {
    const Vec3d a = m.positions[m.indices[t]], b = m.positions[m.indices[t + 1]], c = m.positions[m.indices[t + 2]];
    agree += dot(cross(b - a, c - a), fieldGradient(g, (a + b + c) / 3.0)) < 0;
  }
  return double(agree) / double(m.indices.size() / 3);
}

// Share of vertices whose exported (shading) gradient agrees in direction with the field's.
double gradientAgreement(const Grid& g, const IsoMesh& m) {
  size_t agree = 0;
  for (size_t i = 0; i < m.positions.size(); ++i) agree += dot(m.gradients[i], fieldGradient(g, m.positions[i])) > 0;
  return double(agree) / double(m.positions.size());
}

TEST(IsoMesh, SphereIsClosedAndOnTheSurface) {
  const int n = 33;
  const Grid g = makeProceduralGrid(Field::Sphere, {n, n, n});
  const double r = 0.6;
  const IsoMesh m = extractIsoMesh(g, r);
  ASSERT_GT(m.indices.size(), 3000u);
  ASSERT_EQ(m.positions.size(), m.gradients.size());
  EXPECT_TRUE(openEdges(m).empty()) << "a sphere inside the grid must give a closed mesh";
  const double cell = 2.0 / (n - 1);
  for (const Vec3d& p : m.positions) {
    const Vec3d world = Vec3d{-1, -1, -1} + p * cell;
    EXPECT_LT(std::fabs(length(world) - r), cell) << "vertex farther than a cell from the sphere";
    EXPECT_TRUE(nearSurface(g, p, r));
  }
  EXPECT_GT(windingAgreement(g, m), 0.999);
  EXPECT_GT(gradientAgreement(g, m), 0.999);
}

// Real volumes whose surfaces reach the grid's faces: open only there, and on the surface.
TEST(IsoMesh, RealVolumesAreClosedAwayFromTheGridBoxAndOnTheSurface) {
  const struct { const char* file; double iso; } cases[] = {
      {"volumes/neghip_64x64x64_uint8.raw", 40}, {"volumes/hydrogen_atom_128x128x128_uint8.raw", 20},
      {"volumes/lidc2_chest_ct_256x256x133_uint8.raw.gz", 150}, {"volumes/lidc2_chest_ct_256x256x133_uint8.raw.gz", 150.5}};
  for (const auto& c : cases) {
    SCOPED_TRACE(std::string(c.file) + " iso " + std::to_string(c.iso));
    const Grid g = loadVolumeFile(test::dataPath(c.file), {});
    const IsoMesh m = extractIsoMesh(g, c.iso);
    ASSERT_GT(m.indices.size(), 3000u);
    const Vec3i d = g.dims();
    for (const auto& [a, b] : openEdges(m)) {
      // Both ends of an open edge lie within a cell of one of the grid's faces.
      for (uint32_t v : {a, b}) {
        const Vec3d& p = m.positions[v];
        const bool atFace = p.x < 1 || p.y < 1 || p.z < 1 || p.x > d.x - 2 || p.y > d.y - 2 || p.z > d.z - 2;
        EXPECT_TRUE(atFace) << "open edge inside the grid at (" << p.x << ", " << p.y << ", " << p.z << ")";
      }
    }
    size_t off = 0;
    for (const Vec3d& p : m.positions) off += !nearSurface(g, p, c.iso);
    EXPECT_EQ(off, 0u) << "vertices farther than a cell from the surface";
    EXPECT_GT(windingAgreement(g, m), 0.98);
    EXPECT_GT(gradientAgreement(g, m), 0.99);
  }
}

TEST(IsoMesh, NoSurfaceGivesNoTriangles) {
  const Grid g = makeProceduralGrid(Field::Sphere, {9, 9, 9});
  EXPECT_TRUE(extractIsoMesh(g, 5.0).indices.empty());
}

}  // namespace
}  // namespace iso

namespace iso {
namespace {

// A ball of radius 0.6 (the procedural sphere field, solid below 0.6) cut by `clip` JSON.
SceneDesc clippedBall(const std::string& clip, const std::string& surfaceKeys = "") {
  return parseSceneText(R"({"volumes": [{"procedural": {"field": "sphere", "resolution": [41, 41, 41]},
      "isosurfaces": [{"value": 0.6, "inside": "below")" + surfaceKeys + R"(}], "clip": )" + clip + "}]}",
                        "ball.json");
}

// Every edge of the mesh used by exactly two triangles (a closed surface).
size_t edgesNotShared(const GltfMeshOut& m) {
  std::map<std::pair<uint32_t, uint32_t>, int> uses;
  for (size_t t = 0; t < m.indices.size(); t += 3)
    for (int e = 0; e < 3; ++e) {
      const uint32_t a = m.indices[t + e], b = m.indices[t + (e + 1) % 3];
      ++uses[{std::min(a, b), std::max(a, b)}];
    }
  size_t bad = 0;
  for (const auto& [edge, n] : uses) bad += n != 2;
  return bad;
}

// The enclosed volume by the divergence theorem: positive when the triangles face outwards.
double signedVolume(const GltfMeshOut& m) {
  double v = 0;
  for (size_t t = 0; t < m.indices.size(); t += 3)
    v += dot(Vec3d(m.positions[m.indices[t]]), cross(Vec3d(m.positions[m.indices[t + 1]]), Vec3d(m.positions[m.indices[t + 2]])));
  return v / 6;
}

// `isotrace mesh` of a clipped surface: what the render shows, closed by its cap (a plane cut
// off a ball leaves a ball less a spherical cap, its flat side on the plane), facing outwards.
TEST(IsoMesh, AClippedSurfaceIsCutAndCappedClosed) {
  const double r = 0.6, cell = 2.0 / 40;
  const Vec3d n = normalize(Vec3d{0.3, 0, 1});
  const double h = 0.1 * n.z;  // the plane through (0, 0, 0.1): n . p = h
  const GltfMeshOut m = surfaceMesh(clippedBall(R"([{"plane": {"point": [0, 0, 0.1], "normal": [0.3, 0, 1]}}])"), 0, 0,
                                    "--volume", "--surface");
  ASSERT_GT(m.indices.size(), 3000u);
  EXPECT_EQ(edgesNotShared(m), 0u) << "the cut is capped: no open edge";
  const double cap = M_PI * (r - h) * (r - h) * (3 * r - (r - h)) / 3;
  const double expected = 4 * M_PI * r * r * r / 3 - cap;
  EXPECT_NEAR(signedVolume(m), expected, 0.03 * expected);
  size_t onPlane = 0, planeNormals = 0;
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const double side = dot(n, Vec3d(m.positions[i])) - h;
    EXPECT_LT(side, 0.5 * cell) << "a vertex beyond the clip plane";
    if (std::fabs(side) < 1e-3 * cell && length(Vec3d(m.positions[i])) < r - 2 * cell) {
      ++onPlane;
      planeNormals += dot(Vec3d(m.normals[i]), n) > 0.99;  // the cap faces out of the kept part
    }
  }
  EXPECT_GT(onPlane, 200u);
  EXPECT_EQ(planeNormals, onPlane);
  // Unclipped, the same surface is the whole ball.
  const GltfMeshOut whole = surfaceMesh(clippedBall("[]"), 0, 0, "--volume", "--surface");
  EXPECT_EQ(edgesNotShared(whole), 0u);
  EXPECT_NEAR(signedVolume(whole), 4 * M_PI * r * r * r / 3, 0.03 * 4 * M_PI * r * r * r / 3);
  // A box keeps a cube's corner of the ball: its three faces capped.
  const GltfMeshOut corner = surfaceMesh(clippedBall(R"([{"box": {"min": [0, 0, 0], "max": [1, 1, 1]}}])"), 0, 0,
                                         "--volume", "--surface");
  EXPECT_EQ(edgesNotShared(corner), 0u);
  EXPECT_NEAR(signedVolume(corner), M_PI * r * r * r / 6, 0.05 * M_PI * r * r * r / 6);
  // Cut away entirely: said, not an empty file.
  test::expectRefusal<InputError>(
      [&] { surfaceMesh(clippedBall(R"([{"plane": {"point": [0, 0, -0.9], "normal": [0, 0, 1]}}])"), 0, 0, "--volume", "--surface"); },
      "ball.json: /volumes/0/isosurfaces/0", "or the clip cuts it all away");
}

// "color_by" and "cap_color_by" become vertex colours: the surface's map on the surface, the
// cap's on the cut (here maps of one colour each, so the side is plain to see).
TEST(IsoMesh, ColorByBecomesVertexColours) {
  const GltfMeshOut m = surfaceMesh(
      clippedBall(R"([{"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}}])",
                  R"(, "color_by": {"field": "gradient_magnitude", "map": [[0, [0, 0, 1]], [100, [0, 0, 1]]]},
                     "cap_color_by": {"field": "gradient_magnitude", "map": [[0, [1, 0, 0]], [100, [1, 0, 0]]]})"),
      0, 0, "--volume", "--surface");
  ASSERT_EQ(m.colors.size(), m.positions.size());
  EXPECT_EQ(m.color, (Vec3f{1, 1, 1}));
  const double cell = 2.0 / 40;
  size_t cap = 0, surface = 0;
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const Vec3d p(m.positions[i]);
    if (std::fabs(p.z) < 1e-3 * cell && length(p) < 0.6 - 2 * cell) {
      EXPECT_EQ(m.colors[i], (Vec3f{1, 0, 0})) << "a cap vertex";
      ++cap;
    } else if (p.z < -2 * cell) {
      EXPECT_EQ(m.colors[i], (Vec3f{0, 0, 1})) << "a surface vertex";
      ++surface;
    }
  }
  EXPECT_GT(cap, 100u);
  EXPECT_GT(surface, 100u);
  // The .glb carries them (COLOR_0).
  const std::string dir = test::scratchDir();
  saveGltfMesh(dir + "/c.glb", m);
  std::ifstream in(dir + "/c.glb", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(bytes.find("\"COLOR_0\""), std::string::npos);
}

}  // namespace
}  // namespace iso
