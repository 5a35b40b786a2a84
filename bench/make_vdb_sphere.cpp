// Writes OpenVDB files for the benchmarks of docs/BENCHMARKS.md:
//   make_vdb_sphere RADIUS_IN_VOXELS OUT.vdb   a narrow-band level-set sphere ("Sparse OpenVDB")
//   make_vdb_sphere --gyroid N OUT.vdb         an N^3 gyroid ball, every voxel active (a fog volume:
//                                              the dense case of bench/data_parallel_memory.sh vdb)
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace {

int gyroid(int n, const char* out) {
  openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(-1.0f);
  grid->setName("gyroid");
  grid->setGridClass(openvdb::GRID_FOG_VOLUME);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(1.0 / n));
  auto acc = grid->getAccessor();
  const double s = 3 * M_PI;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const double x = (i + 0.5) / n * 2 - 1, y = (j + 0.5) / n * 2 - 1, z = (k + 0.5) / n * 2 - 1;
        const double g = std::sin(s * x) * std::cos(s * y) + std::sin(s * y) * std::cos(s * z) + std::sin(s * z) * std::cos(s * x);
        acc.setValue(openvdb::Coord(i, j, k), float(std::max(g, std::sqrt(x * x + y * y + z * z) - 0.9)));
      }
  openvdb::io::File(out).write({grid});
  std::printf("%s: %d^3 gyroid ball, %llu active voxels\n", out, n, (unsigned long long)grid->activeVoxelCount());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  openvdb::initialize();
  if (argc == 4 && std::strcmp(argv[1], "--gyroid") == 0) {
    const int n = std::atoi(argv[2]);
    if (n < 8 || n > 2048) {
      std::fprintf(stderr, "make_vdb_sphere: --gyroid N: N must be 8 to 2048\n");
      return 2;
    }
    return gyroid(n, argv[3]);
  }
  if (argc != 3) {
    std::fprintf(stderr, "usage: make_vdb_sphere RADIUS_IN_VOXELS OUT.vdb | make_vdb_sphere --gyroid N OUT.vdb\n");
    return 2;
  }
  const float radius = float(std::atof(argv[1]));
  if (!(radius >= 1 && radius <= 4000)) {
    std::fprintf(stderr, "make_vdb_sphere: the radius must be 1 to 4000 voxels\n");
    return 2;
  }
  // Voxel size 1/radius: a unit sphere; half width 3 voxels (OpenVDB's default band).
  openvdb::FloatGrid::Ptr sphere =
      openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(1.0f, openvdb::Vec3f(0, 0, 0), 1.0f / radius);
  sphere->setName("sphere");
  openvdb::io::File(argv[2]).write({sphere});
  const openvdb::Coord box = sphere->evalActiveVoxelBoundingBox().dim();
  std::printf("%s: radius %g voxels, %llu active voxels, bounding box %dx%dx%d\n", argv[2], double(radius),
              (unsigned long long)sphere->activeVoxelCount(), box.x(), box.y(), box.z());
  return 0;
}
