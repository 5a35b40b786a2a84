#pragma once
// An iso-surface as triangles (OpenVDB's volumeToMesh): for `isotrace mesh` (take the surface
// into Blender or ParaView) and as the triangle baseline the iso-surface is benchmarked
// against. The only file that sees OpenVDB is iso_mesh.cpp (its headers are heavy).
#include <cstdint>
#include <vector>

#include "volume/grid.h"

namespace iso {

struct IsoMesh {
  std::vector<Vec3d> positions;   // grid coordinates: sample (i, j, k) is at (i, j, k)
  std::vector<Vec3d> gradients;   // the shading gradient at each vertex (grid units), as the
                                  // traced surface shades (iso_mesh.cpp)
  std::vector<uint32_t> indices;  // three per triangle, wound counter-clockwise seen from
                                  // the side of lower values (where the gradient points away)
};

// The surface value == iso of the trilinear field. Vertices lie inside the cells whose corners
// straddle the iso value (OpenVDB places one per such cell, adaptivity 0); the surface is open
// where it meets the grid's box, as the traced iso-surface is (the caps OpenVDB would close
// against the background outside the box are dropped).
IsoMesh extractIsoMesh(const Grid& grid, double iso);

// The version of the OpenVDB library this was built with (for isotrace --version).
const char* openVdbVersion();

}  // namespace iso
