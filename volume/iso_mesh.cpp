#include "volume/iso_mesh.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <algorithm>
#include <cmath>
#include <type_traits>

#include "volume/cell_cubic.h"

namespace iso {
namespace {

// The shading gradient at a vertex, as the traced surface shades (World::fillIsoHit): the
// smooth gradient, unless it points against the trilinear field's own gradient there (thin
// or noisy features a central difference straddles), where the cell's gradient stays.
Vec3d shadingGradient(const Grid& grid, const Vec3d& p) {
  Vec3i cell;
  Vec3d local;
  grid.locate(p, cell, local);
  float corners[8];
  grid.cellCorners(cell.x, cell.y, cell.z, corners);
  const Vec3d own(trilinearGradient(corners, Vec3f(local)));
  const Vec3d smooth = grid.smoothGradient(p);
  return dot(smooth, own) > 0 ? smooth : own;
}

}  // namespace

const char* openVdbVersion() { return OPENVDB_LIBRARY_VERSION_STRING; }

IsoMesh extractIsoMesh(const Grid& grid, double iso) {
  openvdb::initialize();
  const Vec3i d = grid.dims();
  // The grid's own samples seen as an OpenVDB dense grid in index space (voxel (i, j, k) =
  // sample (i, j, k); LayoutXYZ is x fastest, as the grid is: no copy), made sparse as floats.
  // The background lies below the iso value, so the only surface it adds is the cap outside
  // the box, dropped below.
  const openvdb::CoordBBox box(openvdb::Coord(0, 0, 0), openvdb::Coord(d.x - 1, d.y - 1, d.z - 1));
  openvdb::FloatGrid::Ptr vdb = openvdb::FloatGrid::create(float(iso) - 1.f);
  if (const SparseSamples* sparse = grid.sparse()) {
    // Brick by brick: a constant brick as one filled box, a block voxel by voxel (each brick
    // writes its samples [8b, 8b + 8), the last one on an axis its far face too).
    auto acc = vdb->getAccessor();
    constexpr int k = SparseSamples::kBlock;
    const Vec3i n = sparse->bricks;
    for (int bz = 0; bz < n.z; ++bz)
      for (int by = 0; by < n.y; ++by)
        for (int bx = 0; bx < n.x; ++bx) {
          const int32_t slot = sparse->slotOf(bx, by, bz);
          const Vec3i lo{8 * bx, 8 * by, 8 * bz};
          const Vec3i hi{bx + 1 == n.x ? 8 : 7, by + 1 == n.y ? 8 : 7, bz + 1 == n.z ? 8 : 7};
          if (slot < 0) {
            vdb->tree().fill(openvdb::CoordBBox(openvdb::Coord(lo.x, lo.y, lo.z),
                                                openvdb::Coord(lo.x + hi.x, lo.y + hi.y, lo.z + hi.z)),
                             sparse->uniformValue(slot), true);
            continue;
          }
          const float* block = sparse->block(slot);
          for (int z = 0; z <= hi.z; ++z)
            for (int y = 0; y <= hi.y; ++y)
              for (int x = 0; x <= hi.x; ++x)
                acc.setValue(openvdb::Coord(lo.x + x, lo.y + y, lo.z + z), block[(z * k + y) * k + x]);
        }
  } else {
    grid.visitSamples([&](const auto* samples) {
      using T = std::remove_const_t<std::remove_pointer_t<decltype(samples)>>;
      openvdb::tools::Dense<T, openvdb::tools::LayoutXYZ> dense(box, const_cast<T*>(samples));
      openvdb::tools::copyFromDense(dense, *vdb, /*tolerance=*/float(0));
    });
  }
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*vdb, points, triangles, quads, iso, /*adaptivity=*/0.0);

  IsoMesh mesh;
  // Vertices outside the sample box belong to the caps against the background.
  const double slack = 1e-4;
  std::vector<char> inBox(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    const openvdb::Vec3s& p = points[i];
    inBox[i] = p.x() >= -slack && p.y() >= -slack && p.z() >= -slack && p.x() <= d.x - 1 + slack &&
               p.y() <= d.y - 1 + slack && p.z() <= d.z - 1 + slack;
  }
  std::vector<uint32_t> remap(points.size(), UINT32_MAX);
  auto vertex = [&](uint32_t i) {
    if (remap[i] == UINT32_MAX) {
      remap[i] = uint32_t(mesh.positions.size());
      const Vec3d p{points[i].x(), points[i].y(), points[i].z()};
      mesh.positions.push_back(p);
      mesh.gradients.push_back(shadingGradient(grid, p));
    }
    return remap[i];
  };
  auto triangle = [&](uint32_t a, uint32_t b, uint32_t c) {
    if (!inBox[a] || !inBox[b] || !inBox[c]) return;
    mesh.indices.insert(mesh.indices.end(), {vertex(a), vertex(b), vertex(c)});
  };
  for (const openvdb::Vec3I& t : triangles) triangle(t[0], t[1], t[2]);
  for (const openvdb::Vec4I& q : quads) {
    triangle(q[0], q[1], q[2]);
    triangle(q[0], q[2], q[3]);
  }
  // OpenVDB's winding follows its own inside convention (values below iso); make it agree
  // with the gradient: counter-clockwise seen from lower values.
  double agreement = 0;
  for (size_t t = 0; t < mesh.indices.size(); t += 3) {
    const Vec3d& a = mesh.positions[mesh.indices[t]];
    const Vec3d n = cross(mesh.positions[mesh.indices[t + 1]] - a, mesh.positions[mesh.indices[t + 2]] - a);
    agreement += dot(n, mesh.gradients[mesh.indices[t]] + mesh.gradients[mesh.indices[t + 1]] +
                            mesh.gradients[mesh.indices[t + 2]]);
  }
  if (agreement > 0)
    for (size_t t = 0; t < mesh.indices.size(); t += 3) std::swap(mesh.indices[t + 1], mesh.indices[t + 2]);
  return mesh;
}

}  // namespace iso
