// OpenVDB files (.vdb): one scalar grid, placed by its own transform, held sparse: the bricks
// (8^3 cells) whose samples vary become 9^3 blocks, every other brick is one value (a tile's or
// the background's), so memory follows the leaves, not the bounding box. Over the active
// voxels' box plus one voxel of background (a level set closes against it). A dense copy
// (tests compare the two) is also here. The only file that reads VDB files.
#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>

#include <cstring>
#include <filesystem>
#include <map>
#include <optional>

#include "volume/input_error.h"
#include "volume/input_file.h"
#include "volume/loaders.h"

namespace iso {
namespace {

namespace fs = std::filesystem;

constexpr double kMaxDenseSamples = double(1 << 30);  // 4 GiB of float32

// Index space to world through the grid's transform: sample (i, j, k) of the grid is index
// `first` + (i, j, k).
void place(const openvdb::GridBase& grid, const openvdb::Coord& first, VolumeFile& out, const std::string& path) {
  const openvdb::math::Transform& t = grid.transform();
  if (!t.isLinear()) throw InputError(path, "grid '" + grid.getName() + "'", "a non-linear (frustum) transform is not supported");
  const openvdb::Vec3d o = t.indexToWorld(first.asVec3d());
  double a[3][4];
  for (int c = 0; c < 3; ++c) {
    openvdb::Vec3d step = first.asVec3d();
    step[c] += 1;
    const openvdb::Vec3d axis = t.indexToWorld(step) - o;
    for (int r = 0; r < 3; ++r) a[r][c] = axis[r];
  }
  for (int r = 0; r < 3; ++r) a[r][3] = o[r];
  placeByAffine(a, out.grid, out.toWorld, path, "grid '" + grid.getName() + "' transform");
  out.notes.push_back("transform: " + describeAffine(a));
}

template <typename GridT>
std::string describe(const GridT& grid) {
  return "grid '" + grid.getName() + "' (" + grid.valueType() + ", " +
         (grid.getGridClass() == openvdb::GRID_LEVEL_SET ? "level set" : "fog volume or other") + "), " +
         std::to_string(openvdb::tools::countActiveVoxels(grid.tree(), /*threaded=*/false)) + " active voxels, background " + std::to_string(double(grid.background()));
}

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
                         std::to_string(size.z()) + ") is above 2^30 samples as a dense grid");
  std::vector<float> values(static_cast<size_t>(samples));
  openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(box, values.data());
  openvdb::tools::copyToDense(grid, dense, /*serial=*/true);
  for (size_t i = 0; i < values.size(); ++i)
    if (!std::isfinite(values[i]))
      throw InputError(path, "grid '" + grid.getName() + "'", "a value is not finite (voxel " + std::to_string(i) + " of the dense copy)");
  VolumeFile out;
  out.format = "OpenVDB";
  out.grid = Grid(Vec3i{size.x(), size.y(), size.z()}, std::move(values));
  place(grid, box.min(), out, path);
  out.notes.push_back(describe(grid) + "; held dense over the active box plus one voxel");
  return out;
}

// Index-space origin and size of the sparse grid: the active box plus one voxel, its origin
// moved down to a multiple of 8 so that bricks line up with the tree's leaves and tiles, its
// size up to whole bricks.
struct SparseLayout {
  openvdb::Coord origin;
  Vec3i bricks;
  // The bricks whose samples are read, [keep0, keep1) (by default all): the others hold 0 (a
  // window's reader keeps only the bricks that reach into the window; the tree read clipped to
  // them has only their leaves' values loaded).
  Vec3i keep0{0, 0, 0}, keep1{0, 0, 0};
  bool keeps(int x, int y, int z) const {
    return x >= keep0.x && y >= keep0.y && z >= keep0.z && x < keep1.x && y < keep1.y && z < keep1.z;
  }
  Vec3i dims() const { return {8 * bricks.x + 1, 8 * bricks.y + 1, 8 * bricks.z + 1}; }
  // Index box of the samples of bricks [b0, b1) (each brick's 9^3: its last layer is the next's first).
  openvdb::CoordBBox samplesOf(const Vec3i& b0, const Vec3i& b1) const {
    return openvdb::CoordBBox(origin + openvdb::Coord(8 * b0.x, 8 * b0.y, 8 * b0.z),
                              origin + openvdb::Coord(8 * b1.x, 8 * b1.y, 8 * b1.z));
  }
};

SparseLayout sparseLayout(openvdb::CoordBBox box, const std::string& path, const std::string& gridName) {
  if (box.empty()) throw InputError(path, "grid '" + gridName + "'", "has no active voxels");
  box.expand(1);
  auto down8 = [](int v) { return v >= 0 ? v / 8 * 8 : -((-v + 7) / 8 * 8); };
  SparseLayout l;
  l.origin = openvdb::Coord(down8(box.min().x()), down8(box.min().y()), down8(box.min().z()));
  for (int a = 0; a < 3; ++a) {
    const int64_t cells = int64_t(box.max()[a]) - l.origin[a];
    l.bricks[a] = int(std::max<int64_t>(1, (cells + 7) / 8));
    if (l.bricks[a] > (1 << 17)) throw InputError(path, "grid '" + gridName + "'", "its active box is beyond 2^20 voxels on an axis");
  }
  if (size_t(l.bricks.x) * l.bricks.y * l.bricks.z > (size_t(1) << 28))
    throw InputError(path, "grid '" + gridName + "'", "its active box holds more than 2^28 bricks of 8^3 voxels");
  l.keep1 = l.bricks;
  return l;
}

// The grid as sparse bricks laid out by `layout` (by default its own active box's: a grid read
// clipped to a window is laid out as the whole grid is, so that its bricks are the same).
template <typename GridT>
VolumeFile toSparse(const GridT& grid, const std::string& path, const SparseLayout* given = nullptr,
                    const SampleWindow* window = nullptr) {
  const SparseLayout layout = given ? *given : sparseLayout(grid.evalActiveVoxelBoundingBox(), path, grid.getName());
  const openvdb::Coord origin = layout.origin;
  const Vec3i bricks = layout.bricks;
  const size_t brickCount = size_t(bricks.x) * bricks.y * bricks.z;
  // Bricks whose block reaches into a leaf: a leaf at 8m (relative) is read by bricks m - 1 and m.
  std::vector<uint8_t> touched(brickCount, 0);
  auto brickIndex = [&](int x, int y, int z) { return (size_t(z) * bricks.y + y) * bricks.x + x; };
  for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
    const openvdb::Coord m = (leaf->origin() - origin) >> 3;
    for (int z = m.z() - 1; z <= m.z(); ++z)
      for (int y = m.y() - 1; y <= m.y(); ++y)
        for (int x = m.x() - 1; x <= m.x(); ++x)
          if (x >= 0 && y >= 0 && z >= 0 && x < bricks.x && y < bricks.y && z < bricks.z) touched[brickIndex(x, y, z)] = 1;
  }
  struct Storage {
    std::vector<int32_t> slot;
    std::vector<float> blocks, uniform;
  };
  auto storage = std::make_shared<Storage>();
  storage->slot.resize(brickCount);
  constexpr int k = SparseSamples::kBlock;
  std::map<uint32_t, int32_t> uniformOf;  // by the value's bits
  auto uniform = [&](float v) {
    uint32_t bits;
    std::memcpy(&bits, &v, 4);
    auto [it, added] = uniformOf.emplace(bits, int32_t(storage->uniform.size()));
    if (added) storage->uniform.push_back(v);
    return -1 - it->second;
  };
  // Not registered with the tree (a registered one goes into a TBB hash map, allocated by TBB's
  // allocator, whose locks a forked reader may hold copies of: child_process.h, inReaderChild).
  auto accessor = grid.getConstUnsafeAccessor();
  auto base = [&](int bx, int by, int bz) { return origin + openvdb::Coord(8 * bx, 8 * by, 8 * bz); };
  // Fills a brick's block from the tree; true if its samples are not all one value.
  auto fill = [&](const openvdb::Coord& at, float* block) {
    bool varies = false;
    for (int z = 0; z < k; ++z)
      for (int y = 0; y < k; ++y)
        for (int x = 0; x < k; ++x) {
          const float v = float(accessor.getValue(at + openvdb::Coord(x, y, z)));
          block[(z * k + y) * k + x] = v;
          varies = varies || v != block[0];
        }
    return varies;
  };
  // Two passes, so that the blocks are allocated once at their exact size (a growing or
  // shrunk vector would hold twice the memory for a moment): first which bricks vary, then
  // their blocks.
  float block[SparseSamples::kBlockSize];
  size_t stored = 0;
  for (int bz = 0; bz < bricks.z; ++bz)
    for (int by = 0; by < bricks.y; ++by)
      for (int bx = 0; bx < bricks.x; ++bx) {
        const size_t b = brickIndex(bx, by, bz);
        const openvdb::Coord at = base(bx, by, bz);
        bool varies;
        if (!layout.keeps(bx, by, bz)) {
          block[0] = 0;
          varies = false;
        } else if (touched[b]) {
          varies = fill(at, block);
        } else {
          // Only tiles and background here, all aligned to 8: the block's 8 regions are those
          // of its 8 corners, so equal corners make a constant block.
          block[0] = float(accessor.getValue(at));
          varies = false;
          for (int c = 1; c < 8 && !varies; ++c)
            varies = float(accessor.getValue(at + openvdb::Coord(c & 1 ? 8 : 0, c & 2 ? 8 : 0, c & 4 ? 8 : 0))) != block[0];
        }
        storage->slot[b] = varies ? int32_t(stored++) : uniform(block[0]);
      }
  storage->blocks.resize(stored * SparseSamples::kBlockSize);
  for (int bz = 0; bz < bricks.z; ++bz)
    for (int by = 0; by < bricks.y; ++by)
      for (int bx = 0; bx < bricks.x; ++bx) {
        const int32_t slot = storage->slot[brickIndex(bx, by, bz)];
        if (slot >= 0) fill(base(bx, by, bz), storage->blocks.data() + size_t(slot) * SparseSamples::kBlockSize);
      }
  for (float v : storage->blocks)
    if (!std::isfinite(v)) throw InputError(path, "grid '" + grid.getName() + "'", "a value is not finite");
  for (float v : storage->uniform)
    if (!std::isfinite(v)) throw InputError(path, "grid '" + grid.getName() + "'", "a tile or background value is not finite");
  auto sparse = std::make_shared<SparseSamples>();
  sparse->bricks = bricks;
  sparse->slot = storage->slot.data();
  sparse->blocks = storage->blocks.data();
  sparse->uniform = storage->uniform.data();
  sparse->blockCount = stored;
  sparse->uniformCount = storage->uniform.size();
  sparse->owner = storage;
  VolumeFile out;
  out.format = "OpenVDB";
  const Vec3i dims{8 * bricks.x + 1, 8 * bricks.y + 1, 8 * bricks.z + 1};
  out.grid = Grid(dims, sparse);
  place(grid, origin, out, path);
  // A window's bricks were the only ones read (layout.keep0/keep1): the grid is that window as is
  // (what sparseWindow would copy).
  if (window) out.grid = Grid(dims, sparse, window->first, window->extent, out.grid.origin(), out.grid.spacing());
  out.notes.push_back(describe(grid) + "; held sparse: " + std::to_string(stored) + " of " + std::to_string(brickCount) +
                      " bricks of 8^3 cells stored, the others one value each");
  return out;
}

// The window of a sparse grid: every brick's slot, but only the blocks (and values) of the bricks
// whose 9^3 samples reach into the window; the others read as 0 (nothing reads them: BrickGrid
// leaves the bricks a window does not wholly hold inactive).
Grid sparseWindow(const Grid& grid, const SampleWindow& w) {
  const SparseSamples& s = *grid.sparse();
  struct Storage {
    std::vector<int32_t> slot;
    std::vector<float> blocks, uniform{0.f};
  };
  auto storage = std::make_shared<Storage>();
  storage->slot.assign(s.brickCount(), -1);  // uniform[0]: 0
  auto reaches = [&](int b, int a) { return 8 * b <= w.first[a] + w.extent[a] - 1 && 8 * b + 8 >= w.first[a]; };
  size_t blocks = 0;
  for (int pass = 0; pass < 2; ++pass) {  // count, then copy: the blocks allocated once
    if (pass == 1) storage->blocks.reserve(blocks * SparseSamples::kBlockSize);
    for (int bz = 0; bz < s.bricks.z; ++bz)
      for (int by = 0; by < s.bricks.y; ++by)
        for (int bx = 0; bx < s.bricks.x; ++bx) {
          if (!reaches(bx, 0) || !reaches(by, 1) || !reaches(bz, 2)) continue;
          const int32_t slot = s.slotOf(bx, by, bz);
          if (pass == 0) {
            blocks += slot >= 0;
            continue;
          }
          int32_t& kept = storage->slot[(size_t(bz) * s.bricks.y + size_t(by)) * s.bricks.x + size_t(bx)];
          if (slot >= 0) {
            kept = int32_t(storage->blocks.size() / SparseSamples::kBlockSize);
            storage->blocks.insert(storage->blocks.end(), s.block(slot), s.block(slot) + SparseSamples::kBlockSize);
          } else {
            kept = -1 - int32_t(storage->uniform.size());
            storage->uniform.push_back(s.uniformValue(slot));
          }
        }
  }
  auto sparse = std::make_shared<SparseSamples>();
  sparse->bricks = s.bricks;
  sparse->slot = storage->slot.data();
  sparse->blocks = storage->blocks.data();
  sparse->uniform = storage->uniform.data();
  sparse->blockCount = storage->blocks.size() / SparseSamples::kBlockSize;
  sparse->uniformCount = storage->uniform.size();
  sparse->owner = storage;
  return Grid(grid.dims(), std::move(sparse), w.first, w.extent, grid.origin(), grid.spacing());
}

// A read of part of a grid: the samples in the index box `samples` (only the leaves there are
// loaded: OpenVDB reads the file clipped), as the sparse grid `layout` (the whole grid's) holds them.
struct VdbPart {
  SparseLayout layout;
  openvdb::CoordBBox samples;
  const SampleWindow* window = nullptr;  // the grid is this window (layout.keep0/keep1: the bricks that reach into it)
};

VolumeFile readVdb(const std::string& path, const std::string& gridName, bool dense, const VdbPart* part = nullptr);
// The whole grid's sparse layout from its metadata (the active box OpenVDB stores with a grid it
// writes: file_bbox_min / file_bbox_max), without reading its leaves; none if the file has no such
// metadata. (Trusted as OpenVDB wrote it: a file whose metadata box leaves out active voxels gives
// a data-parallel render other bricks than one process reads.)
std::optional<SparseLayout> layoutFromMetadata(const std::string& path, const std::string& gridName);

void checkVdbPath(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(path, "", "file not found");
  if (fs::is_directory(path, ec)) throw InputError(path, "", "is a directory, not a file");
  checkInputFile(path, "file", false);
}

// The whole grid's sparse layout, read in a child process (none: the file has no bounding-box
// metadata, or the grid is to be held dense).
std::optional<SparseLayout> metadataLayout(const std::string& path, const std::string& gridName) {
  const ChildOutput out = runInChildProcess(path, "OpenVDB", [&](int) {
    const std::optional<SparseLayout> l = layoutFromMetadata(path, gridName);
    if (!l) return std::string();
    const int32_t v[6] = {l->origin.x(), l->origin.y(), l->origin.z(), l->bricks.x, l->bricks.y, l->bricks.z};
    return std::string(reinterpret_cast<const char*>(v), sizeof v);
  });
  if (out.report.empty()) return std::nullopt;
  int32_t v[6];
  if (out.report.size() != sizeof v) throw InputError(path, "", "OpenVDB's reader gave back a malformed layout");
  std::memcpy(v, out.report.data(), sizeof v);
  SparseLayout l;
  l.origin = openvdb::Coord(v[0], v[1], v[2]);
  l.bricks = {v[3], v[4], v[5]};
  l.keep1 = l.bricks;
  for (int a = 0; a < 3; ++a)
    if (l.bricks[a] < 1 || l.bricks[a] > (1 << 17)) throw InputError(path, "", "OpenVDB's reader gave back a malformed layout");
  if (size_t(l.bricks.x) * l.bricks.y * l.bricks.z > (size_t(1) << 28))
    throw InputError(path, "", "OpenVDB's reader gave back a malformed layout");
  return l;
}

}  // namespace

VolumeFile loadVdb(const std::string& path, const std::string& gridName, bool dense, const SampleWindow* window) {
  checkVdbPath(path);
  // A rank's window of a sparse grid: only the leaves of the bricks that reach into the window are
  // read (the grid read clipped to them), laid out as the whole grid is (its metadata says where).
  std::optional<SparseLayout> layout;
  if (window && !dense) layout = metadataLayout(path, gridName);
  // OpenVDB trusts the sizes in its streams (the fuzzer makes it ask for 2^56 bytes): it reads
  // in a child process.
  return readInChildProcess(path, "OpenVDB", [&] {
    if (layout) {
      checkWindow(*window, layout->dims(), path);
      // The bricks whose 9^3 samples reach into the window (those sparseWindow keeps):
      // 8 b + 8 >= first and 8 b <= last.
      SparseLayout kept = *layout;
      for (int a = 0; a < 3; ++a) {
        const int first = window->first[a], last = first + window->extent[a] - 1;
        kept.keep0[a] = first <= 8 ? 0 : (first - 8 + 7) / 8;
        kept.keep1[a] = std::min(layout->bricks[a], last / 8 + 1);
      }
      const VdbPart part{kept, kept.samplesOf(kept.keep0, kept.keep1), window};
      return readVdb(path, gridName, false, &part);
    }
    VolumeFile f = readVdb(path, gridName, dense);
    if (window) {
      checkWindow(*window, f.grid.dims(), path);
      f.grid = dense ? windowOf(f.grid, window->first, window->extent) : sparseWindow(f.grid, *window);
    }
    return f;
  });
}

BrickGrid vdbBrickRanges(const std::string& path, const std::string& gridName, int64_t samplesPerChild) {
  checkVdbPath(path);
  const std::optional<SparseLayout> layout = metadataLayout(path, gridName);
  if (!layout) return rangesInChildProcess(path, "OpenVDB", [&] { return BrickGrid(readVdb(path, gridName, false).grid); });
  // Runs of rows of bricks along z, in children that each read only their rows' leaves (the grid
  // read clipped): no process holds the whole grid.
  const Vec3i dims = layout->dims();
  const size_t bricks = size_t(layout->bricks.x) * layout->bricks.y * layout->bricks.z;
  const int rowsPerChild = int(std::clamp<int64_t>(samplesPerChild / (int64_t(dims.x) * dims.y * 8), 1, layout->bricks.z));
  std::vector<float> lo, hi;
  lo.reserve(bricks);
  hi.reserve(bricks);
  for (int z0 = 0; z0 < layout->bricks.z; z0 += rowsPerChild) {
    const int z1 = std::min(layout->bricks.z, z0 + rowsPerChild);
    SparseLayout rows = *layout;  // the rows as a grid of their own
    rows.origin = layout->origin + openvdb::Coord(0, 0, 8 * z0);
    rows.bricks.z = z1 - z0;
    rows.keep1 = rows.bricks;
    const BrickGrid part = rangesInChildProcess(path, "OpenVDB", [&] {
      const VdbPart p{rows, rows.samplesOf({0, 0, 0}, rows.bricks)};
      return BrickGrid(readVdb(path, gridName, false, &p).grid);
    });
    if (part.size() != size_t(rows.bricks.x) * rows.bricks.y * rows.bricks.z)
      throw InputError(path, "", "OpenVDB's reader gave back malformed brick ranges");
    for (uint32_t b = 0; b < part.size(); ++b) {  // (rows along z are consecutive runs of bricks)
      lo.push_back(part.brickMin(b));
      hi.push_back(part.brickMax(b));
    }
  }
  return BrickGrid::fromRanges(dims, lo.data(), hi.data(), bricks);
}

namespace {

std::optional<SparseLayout> layoutFromMetadata(const std::string& path, const std::string& gridName) {
  openvdb::initialize();
  try {
    openvdb::io::File file(path);
    file.open(false);
    const openvdb::GridPtrVecPtr metadata = file.readAllGridMetadata();
    file.close();
    new openvdb::GridPtrVecPtr(metadata);  // (never freed: see readVdb)
    for (const openvdb::GridBase::Ptr& g : *metadata) {
      const bool scalar = g->isType<openvdb::FloatGrid>() || g->isType<openvdb::DoubleGrid>();
      if (!(gridName.empty() ? scalar : g->getName() == gridName)) continue;
      const auto lo = g->getMetadata<openvdb::TypedMetadata<openvdb::Vec3i>>(openvdb::GridBase::META_FILE_BBOX_MIN);
      const auto hi = g->getMetadata<openvdb::TypedMetadata<openvdb::Vec3i>>(openvdb::GridBase::META_FILE_BBOX_MAX);
      if (!lo || !hi) return std::nullopt;
      const openvdb::Vec3i a = lo->value(), b = hi->value();
      return sparseLayout(openvdb::CoordBBox(openvdb::Coord(a), openvdb::Coord(b)), path, g->getName());
    }
    return std::nullopt;  // (no such grid: the whole read says so)
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {
    throw InputError(path, "", std::string("not a readable OpenVDB file (") + e.what() + ")");
  }
}

}  // namespace

namespace {

VolumeFile readVdb(const std::string& path, const std::string& gridName, bool dense, const VdbPart* part) {
  openvdb::initialize();
  try {
    openvdb::io::File file(path);
    file.open(false);  // no delayed loading: the file is read now, and closed (a part: only its leaves are kept)
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
    openvdb::GridBase::Ptr grid;
    if (part) {
      // The part's index box, one voxel wider (OpenVDB rounds the world box back to voxels), in
      // world space: the leaves outside it are skipped, not loaded.
      openvdb::CoordBBox box = part->samples;
      box.expand(1);
      openvdb::BBoxd world;
      for (int c = 0; c < 8; ++c) {
        const openvdb::Coord corner((c & 1) ? box.max().x() : box.min().x(), (c & 2) ? box.max().y() : box.min().y(),
                                    (c & 4) ? box.max().z() : box.min().z());
        world.expand(chosen->transform().indexToWorld(corner));
      }
      grid = file.readGrid(chosen->getName(), world);
    } else {
      grid = file.readGrid(chosen->getName());
    }
    file.close();
    // Never freed: OpenVDB frees a tree's nodes in a tbb::parallel_for, and this runs in a reader
    // child, which must not enter TBB (child_process.h, inReaderChild); the child's _exit frees it all.
    new openvdb::GridPtrVecPtr(metadata);
    new openvdb::GridBase::Ptr(grid);
    VolumeFile out;
    const SparseLayout* layout = part ? &part->layout : nullptr;
    if (auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(grid))
      out = dense ? toDense(*f, path) : toSparse(*f, path, layout, part ? part->window : nullptr);
    else if (auto d = openvdb::gridPtrCast<openvdb::DoubleGrid>(grid))
      out = dense ? toDense(*d, path) : toSparse(*d, path, layout, part ? part->window : nullptr);
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

}  // namespace

}  // namespace iso
