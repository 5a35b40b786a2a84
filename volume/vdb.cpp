// OpenVDB files (.vdb): one scalar grid, copied to a dense float32 grid over its active voxels'
// bounding box (plus one voxel of background around it, so that a level set closes), placed by
// the grid's own transform. Sparse rendering (memory in proportion to the active voxels) is not
// built yet: the dense copy is refused above 2^30 samples. The only file that reads VDB files.
#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>

#include <filesystem>

#include "volume/input_error.h"
#include "volume/loaders.h"

namespace iso {
namespace {

namespace fs = std::filesystem;

constexpr double kMaxDenseSamples = double(1 << 30);  // 4 GiB of float32

template <typename GridT>
VolumeFile toDense(const GridT& grid, const std::string& path) {
  openvdb::CoordBBox box = grid.evalActiveVoxelBoundingBox();
  if (box.empty()) throw InputError(path, "grid '" + grid.getName() + "'", "has no active voxels");
  box.expand(1);  // one voxel of background around the active ones
  const openvdb::Coord size = box.dim();
  const double samples = double(size.x()) * size.y() * size.z();
  if (samples > kMaxDenseSamples)
    throw InputError(path, "grid '" + grid.getName() + "'",
                     "its active bounding box (" + std::to_string(size.x()) + "x" + std::to_string(size.y()) + "x" +
                         std::to_string(size.z()) + ") is above 2^30 samples as a dense grid; sparse rendering of "
                         "VDB grids is not built yet");
  std::vector<float> values(static_cast<size_t>(samples));
  openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(box, values.data());
  openvdb::tools::copyToDense(grid, dense);
  for (size_t i = 0; i < values.size(); ++i)
    if (!std::isfinite(values[i]))
      throw InputError(path, "grid '" + grid.getName() + "'", "a value is not finite (voxel " + std::to_string(i) + " of the dense copy)");
  VolumeFile out;
  out.format = "OpenVDB";
  out.grid = Grid(Vec3i{size.x(), size.y(), size.z()}, std::move(values));
  // Index space to world through the grid's transform: voxel (i, j, k) of the copy is index
  // box.min() + (i, j, k).
  const openvdb::math::Transform& t = grid.transform();
  if (!t.isLinear()) throw InputError(path, "grid '" + grid.getName() + "'", "a non-linear (frustum) transform is not supported");
  const openvdb::Vec3d o = t.indexToWorld(box.min().asVec3d());
  double a[3][4];
  for (int c = 0; c < 3; ++c) {
    openvdb::Vec3d step = box.min().asVec3d();
    step[c] += 1;
    const openvdb::Vec3d axis = t.indexToWorld(step) - o;
    for (int r = 0; r < 3; ++r) a[r][c] = axis[r];
  }
  for (int r = 0; r < 3; ++r) a[r][3] = o[r];
  placeByAffine(a, out.grid, out.toWorld, path, "grid '" + grid.getName() + "' transform");
  out.notes.push_back("grid '" + grid.getName() + "' (" + grid.valueType() + ", " +
                      (grid.getGridClass() == openvdb::GRID_LEVEL_SET ? "level set" : "fog volume or other") +
                      "), " + std::to_string(grid.activeVoxelCount()) + " active voxels, background " +
                      std::to_string(double(grid.background())) + "; held dense over the active box plus one voxel");
  return out;
}

}  // namespace

VolumeFile loadVdb(const std::string& path, const std::string& gridName) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(path, "", "file not found");
  if (fs::is_directory(path, ec)) throw InputError(path, "", "is a directory, not a file");
  openvdb::initialize();
  try {
    openvdb::io::File file(path);
    file.open(false);  // no delayed loading: the file is read now, and closed
    const openvdb::GridPtrVecPtr metadata = file.readAllGridMetadata();
    std::string names;
    openvdb::GridBase::Ptr chosen;
    for (const openvdb::GridBase::Ptr& g : *metadata) {
      names += (names.empty() ? "" : ", ") + (g->getName().empty() ? std::string("(unnamed)") : g->getName()) + " (" +
               g->valueType() + ")";
      const bool scalar = g->isType<openvdb::FloatGrid>() || g->isType<openvdb::DoubleGrid>();
      if (!chosen && (gridName.empty() ? scalar : g->getName() == gridName)) chosen = g;
    }
    if (!gridName.empty() && !chosen)
      throw InputError(path, "", "no grid '" + gridName + "'; the file holds " + (names.empty() ? "none" : names));
    if (!chosen) throw InputError(path, "", "no float or double grid; the file holds " + (names.empty() ? "none" : names));
    const openvdb::GridBase::Ptr grid = file.readGrid(chosen->getName());
    file.close();
    VolumeFile out;
    if (auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(grid))
      out = toDense(*f, path);
    else if (auto d = openvdb::gridPtrCast<openvdb::DoubleGrid>(grid))
      out = toDense(*d, path);
    else
      throw InputError(path, "grid '" + chosen->getName() + "'", "is of type " + grid->valueType() + "; float or double grids only");
    out.notes.push_back("grids in the file: " + names);
    return out;
  } catch (const InputError&) {
    throw;
  } catch (const openvdb::Exception& e) {
    throw InputError(path, "", std::string("not a readable OpenVDB file (") + e.what() + ")");
  } catch (const std::bad_alloc&) {
    throw InputError(path, "", "not a readable OpenVDB file (it asks for more memory than there is)");
  } catch (const std::exception& e) {
    throw InputError(path, "", std::string("not a readable OpenVDB file (") + e.what() + ")");
  }
}

}  // namespace iso
