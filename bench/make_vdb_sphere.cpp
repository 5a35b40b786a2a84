// Writes a narrow-band level-set sphere as an OpenVDB file: the sparse-memory benchmark of
// docs/BENCHMARKS.md ("Sparse OpenVDB"). Usage: make_vdb_sphere RADIUS_IN_VOXELS OUT.vdb
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <cstdio>
#include <cstdlib>

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: make_vdb_sphere RADIUS_IN_VOXELS OUT.vdb\n");
    return 2;
  }
  const float radius = float(std::atof(argv[1]));
  if (!(radius >= 1 && radius <= 4000)) {
    std::fprintf(stderr, "make_vdb_sphere: the radius must be 1 to 4000 voxels\n");
    return 2;
  }
  openvdb::initialize();
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
