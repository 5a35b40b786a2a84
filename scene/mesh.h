#pragma once
// Triangle meshes as the renderer keeps them (from glTF or built-in shapes), in the
// object space of the mesh; a MeshInstance places one in the world.
#include <cstdint>
#include <string>
#include <vector>

#include "volume/transform.h"

namespace iso {

struct Vec2f {
  float x = 0, y = 0;
};

struct TriangleMesh {
  std::vector<Vec3f> positions;
  std::vector<Vec3f> normals;  // per vertex, or empty: flat normals
  std::vector<Vec2f> uvs;      // per vertex (TEXCOORD_0), or empty
  std::vector<uint32_t> indices;  // three per triangle, all < positions.size()
  int material = -1;  // index into the file's materials; -1: the default material
  size_t triangleCount() const { return indices.size() / 3; }
};

// A unit sphere (radius 1, centre 0; outward normals, lat-long UVs) and the square
// [-1, 1]^2 in the xz plane facing +y: shapes for scenes without a modelling tool.
TriangleMesh makeSphereMesh(int rings = 64, int segments = 128);
TriangleMesh makeQuadMesh();

}  // namespace iso
