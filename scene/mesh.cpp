#include "scene/mesh.h"

#include <cmath>

namespace iso {

TriangleMesh makeSphereMesh(int rings, int segments) {
  TriangleMesh m;
  for (int r = 0; r <= rings; ++r) {
    const double theta = M_PI * r / rings;
    for (int s = 0; s <= segments; ++s) {
      const double phi = 2 * M_PI * s / segments;
      const Vec3f p{float(std::sin(theta) * std::cos(phi)), float(std::cos(theta)),
                    float(-std::sin(theta) * std::sin(phi))};
      m.positions.push_back(p);
      m.normals.push_back(p);
      m.uvs.push_back({float(s) / segments, float(r) / rings});
    }
  }
  const uint32_t row = uint32_t(segments + 1);
  for (int r = 0; r < rings; ++r)
    for (int s = 0; s < segments; ++s) {
      const uint32_t a = r * row + s, b = a + row;
      // Counter-clockwise seen from outside; the degenerate triangles at the poles are left out.
      if (r != 0) m.indices.insert(m.indices.end(), {a, b, a + 1});
      if (r != rings - 1) m.indices.insert(m.indices.end(), {a + 1, b, b + 1});
    }
  return m;
}

TriangleMesh makeQuadMesh() {
  TriangleMesh m;
  m.positions = {{-1, 0, -1}, {-1, 0, 1}, {1, 0, 1}, {1, 0, -1}};
  m.normals = {{0, 1, 0}, {0, 1, 0}, {0, 1, 0}, {0, 1, 0}};
  m.uvs = {{0, 0}, {0, 1}, {1, 1}, {1, 0}};
  m.indices = {0, 1, 2, 0, 2, 3};
  return m;
}

}  // namespace iso
