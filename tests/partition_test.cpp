// The split of a volume over data-parallel ranks (volume/partition.h, `isotrace info --ranks N`):
// boxes of whole bricks that cover every brick once, share the sample layer at each seam, and
// balance the active bricks; too many ranks is refused in one line.
#include <gtest/gtest.h>

#include <set>

#include "scene/scene.h"
#include "scene/world.h"
#include "volume/bricks.h"
#include "volume/input_error.h"
#include "volume/loaders.h"
#include "volume/partition.h"
#include "tests/test_util.h"

namespace iso {
namespace {

TEST(Partition, BoxesCoverEveryBrickOnceAndBalanceTheActiveOnes) {
  const Grid grid = readVolumeFile(test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw"), {}, {}).grid;
  const BrickGrid bricks(grid);
  std::vector<double> weights(bricks.size(), 0.0);
  double active = 0;
  for (uint32_t b : bricks.activeBricks(20.f)) weights[b] = 1, active += 1;
  ASSERT_GT(active, 100);
  for (int ranks = 1; ranks <= 7; ++ranks) {
    SCOPED_TRACE("ranks " + std::to_string(ranks));
    const std::vector<RankBox> boxes = partitionBricks(bricks, weights, ranks, "hydrogen");
    ASSERT_EQ(boxes.size(), size_t(ranks));
    std::vector<int> owner(bricks.size(), -1);
    double most = 0;
    for (size_t r = 0; r < boxes.size(); ++r) {
      const RankBox& box = boxes[r];
      for (int z = box.brickLo.z; z < box.brickHi.z; ++z)
        for (int y = box.brickLo.y; y < box.brickHi.y; ++y)
          for (int x = box.brickLo.x; x < box.brickHi.x; ++x) {
            const Vec3i n = bricks.count();
            const size_t b = (size_t(z) * n.y + y) * n.x + x;
            EXPECT_EQ(owner[b], -1) << "brick " << b << " in two boxes";
            owner[b] = int(r);
          }
      // Cells of whole bricks; the samples held run from one before the first cell to two past
      // the last (the seam layer, and one more for smooth normals), within the grid.
      EXPECT_EQ(box.cellLo.x % BrickGrid::kCells, 0);
      const Vec3i first = box.windowFirst(), extent = box.windowExtent(grid.dims());
      for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(first[a], std::max(box.cellLo[a] - 1, 0));
        EXPECT_EQ(first[a] + extent[a] - 1, std::min(box.cellHi[a] + 1, grid.dims()[a] - 1));
      }
      EXPECT_EQ(box.samples(grid.dims()), size_t(extent.x) * size_t(extent.y) * size_t(extent.z));
      most = std::max(most, box.weight);
    }
    for (int o : owner) EXPECT_GE(o, 0) << "a brick in no box";
    // Balanced to within the slab the cut cannot divide (a slab of this grid holds at most
    // 16 x 16 = 256 bricks; the active ones are a sphere's shell): here within 35% of the mean.
    EXPECT_LE(most, 1.35 * active / ranks + 1);
  }
  // Neighbouring boxes share the seam's samples: a box's last cell + 1 is the next one's first.
  const std::vector<RankBox> two = partitionBricks(bricks, weights, 2, "hydrogen");
  int touching = 0;
  for (int a = 0; a < 3; ++a) touching += two[0].cellHi[a] == two[1].cellLo[a];
  EXPECT_EQ(touching, 1);
}

// "replicate": a rank's held box is its own grown by whole layers of bricks (clamped to the
// volume) while the extra bricks stay within the fraction; 0 holds the box alone, 1 the volume.
TEST(Partition, HeldBoxesGrowByLayersWithinTheFraction) {
  const Grid grid = readVolumeFile(test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw"), {}, {}).grid;  // 16^3 bricks
  const BrickGrid bricks(grid);
  const std::vector<double> none(bricks.size(), 0.0);
  for (int ranks : {2, 3, 5}) {
    SCOPED_TRACE("ranks " + std::to_string(ranks));
    for (const RankBox& own : partitionBricks(bricks, none, ranks, "hydrogen")) {
      const RankBox zero = heldBox(own, bricks, 0);
      EXPECT_EQ(zero.brickLo, own.brickLo);
      EXPECT_EQ(zero.brickHi, own.brickHi);
      const RankBox all = heldBox(own, bricks, 1);
      EXPECT_EQ(all.brickLo, (Vec3i{0, 0, 0}));
      EXPECT_EQ(all.brickHi, bricks.count());
      EXPECT_EQ(all.cellLo, (Vec3i{0, 0, 0}));
      EXPECT_EQ(all.cellHi, (grid.dims() - Vec3i{1, 1, 1}));
      size_t before = own.bricks;
      for (double f : {0.02, 0.1, 0.25, 0.5}) {
        const RankBox held = heldBox(own, bricks, f);
        size_t count = 1;
        int layers = -1;
        for (int a = 0; a < 3; ++a) {
          EXPECT_LE(held.brickLo[a], own.brickLo[a]);
          EXPECT_GE(held.brickHi[a], own.brickHi[a]);
          count *= size_t(held.brickHi[a] - held.brickLo[a]);
          // The same number of layers on every side the volume does not end.
          for (int side : {own.brickLo[a] - held.brickLo[a], held.brickHi[a] - own.brickHi[a]})
            if ((side > 0) && layers < 0) layers = side;
          if (held.brickLo[a] > 0) {
            EXPECT_EQ(own.brickLo[a] - held.brickLo[a], std::max(layers, 0));
          }
          if (held.brickHi[a] < bricks.count()[a]) {
            EXPECT_EQ(held.brickHi[a] - own.brickHi[a], std::max(layers, 0));
          }
        }
        EXPECT_EQ(held.bricks, count);
        EXPECT_LE(double(count - own.bricks), f * double(bricks.size()) + 1e-9) << f;
        EXPECT_GE(count, before) << "more of the volume for a larger fraction";
        before = count;
        // One more layer would pass the fraction (or the box is the volume already).
        if (!(held.brickLo == Vec3i{0, 0, 0}) || !(held.brickHi == bricks.count())) {
          size_t more = 1;
          const int next = std::max(layers, 0) + 1;
          for (int a = 0; a < 3; ++a)
            more *= size_t(std::min(own.brickHi[a] + next, bricks.count()[a]) - std::max(own.brickLo[a] - next, 0));
          EXPECT_GT(double(more - own.bricks), f * double(bricks.size())) << f;
        }
        // Its window holds the samples of every cell it holds.
        EXPECT_EQ(held.cellLo, bricks.cellBegin(uint32_t((size_t(held.brickLo.z) * bricks.count().y + size_t(held.brickLo.y)) *
                                                             bricks.count().x + size_t(held.brickLo.x))));
      }
    }
  }
}

TEST(Partition, MoreRanksThanBricksIsRefused) {
  const Grid grid = readVolumeFile(test::dataPath("volumes/bucky_32x32x32_uint8.raw"), {}, {}).grid;  // 4^3 bricks
  const BrickGrid bricks(grid);
  const std::vector<double> none(bricks.size(), 0.0);
  EXPECT_EQ(partitionBricks(bricks, none, 64, "bucky").size(), 64u);
  try {
    partitionBricks(bricks, none, 65, "bucky");
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("bucky"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("too few"), std::string::npos) << e.what();
  }
}

// Camera rays along `axis` through a grid over the volume's face, in index space.
CutRays raysAlong(int axis, Vec3i dims) {
  CutRays rays;
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  for (int i = 0; i < 16; ++i)
    for (int j = 0; j < 16; ++j) {
      Vec3d o, d{0, 0, 0};
      o[axis] = -10;
      o[u] = (i + 0.5) * (dims[u] - 1) / 16;
      o[v] = (j + 0.5) * (dims[v] - 1) / 16;
      d[axis] = 1;
      rays.org.push_back(o);
      rays.dir.push_back(d);
    }
  return rays;
}

TEST(Partition, TheCutIsWhereTheFewestCameraRaysPass) {
  const Grid grid = readVolumeFile(test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw"), {}, {}).grid;
  const BrickGrid bricks(grid);  // 16^3 bricks: every axis as long
  std::vector<double> weights(bricks.size(), 0.0);
  for (uint32_t b : bricks.activeBricks(20.f)) weights[b] = 1;
  std::vector<int> cuts;
  partitionBricks(bricks, weights, 2, "hydrogen", nullptr, &cuts);
  EXPECT_EQ(cuts, std::vector<int>{0}) << "without the camera, the longest (here the first) axis";
  for (int axis = 0; axis < 3; ++axis) {
    SCOPED_TRACE("camera rays along axis " + std::to_string(axis));
    const CutRays camera = raysAlong(axis, grid.dims());
    for (int ranks : {2, 3, 4}) {
      const std::vector<RankBox> boxes = partitionBricks(bricks, weights, ranks, "hydrogen", &camera, &cuts);
      ASSERT_EQ(boxes.size(), size_t(ranks));
      ASSERT_EQ(cuts.size(), size_t(ranks - 1));
      // Rays along the axis pass every cut across it: none is made there; the boxes still cover
      // the volume and touch along the other axes.
      for (int a : cuts) EXPECT_NE(a, axis);
      size_t covered = 0;
      for (const RankBox& box : boxes) {
        covered += box.bricks;
        EXPECT_EQ(box.brickLo[axis], 0);
        EXPECT_EQ(box.brickHi[axis], bricks.count()[axis]);
      }
      EXPECT_EQ(covered, bricks.size());
    }
  }
  // Rays that meet nothing leave the choice to the rays leaving the surfaces: a cut is still made.
  CutRays away = raysAlong(0, grid.dims());
  for (Vec3d& d : away.dir) d = -d;
  EXPECT_EQ(partitionBricks(bricks, weights, 2, "hydrogen", &away, &cuts).size(), 2u);
  EXPECT_EQ(cuts.size(), 1u);
}

TEST(Partition, CameraRaysAreInTheVolumesIndexSpace) {
  const std::string text = R"({
    "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "fov": 30},
    "film": {"width": 320, "height": 180},
    "volumes": [{"procedural": {"field": "sphere", "resolution": [33, 33, 33]}, "isosurfaces": [{"value": 0.5}]},
                {"file": "MHD", "isosurfaces": [{"value": 50}]},
                {"file": "MHD", "spacing": [2, 2, 2], "isosurfaces": [{"value": 50}]},
                {"file": "VDB", "isosurfaces": [{"value": 0.5}]}]
  })";
  std::string withFiles = text;
  withFiles.replace(withFiles.find("MHD"), 3, test::dataPath("volumes/HeadMRVolume.mhd"));
  withFiles.replace(withFiles.find("MHD"), 3, test::dataPath("volumes/HeadMRVolume.mhd"));
  withFiles.replace(withFiles.find("VDB"), 3, test::dataPath("volumes/smoke.vdb"));
  const SceneDesc scene = parseSceneText(withFiles, "inline.json");
  const CutRays none = cameraCutRays(scene, nullptr, 0);
  EXPECT_TRUE(none.org.empty()) << "no camera (the scene is framed): no rays";
  const CutRays rays = cameraCutRays(scene, &scene.camera, 0);
  ASSERT_EQ(rays.org.size(), 32u * 18u);
  ASSERT_EQ(rays.dir.size(), rays.org.size());
  // The field spans [-1, 1] in 32 cells: index = (world + 1) * 16.
  for (const Vec3d& o : rays.org) {
    EXPECT_NEAR(o.x, 16, 1e-9);
    EXPECT_NEAR(o.y, 16, 1e-9);
    EXPECT_NEAR(o.z, 80, 1e-9);
  }
  // The middle rays head for the grid's centre (index 16, 16, 16), within the grid's spacing.
  const size_t middle = 9 * 32 + 16;
  const Vec3d o = rays.org[middle], d = rays.dir[middle];
  const double t = (16 - o.z) / d.z;
  EXPECT_NEAR(o.x + t * d.x, 16, 1.0);
  EXPECT_NEAR(o.y + t * d.y, 16, 1.0);
  // A MetaImage's spacing from its header (4), or the scene's where it gives one (2).
  for (size_t v : {size_t(1), size_t(2)}) {
    const double spacing = v == 1 ? 4 : 2;
    const CutRays file = cameraCutRays(scene, &scene.camera, v);
    ASSERT_EQ(file.org.size(), 32u * 18u);
    EXPECT_NEAR(file.org[0].z, 4 / spacing, 1e-9);
    EXPECT_NEAR(length(file.dir[middle]) * spacing, 1, 1e-6);
  }
  // A file whose placement is known only once it is read (OpenVDB): none.
  EXPECT_TRUE(cameraCutRays(scene, &scene.camera, 3).org.empty());
}

TEST(Partition, InfoShowsEachRanksBox) {
  const std::string scene = std::string(ISOTRACE_SOURCE_DIR) + "/examples/quick_look.json";
  const auto r = test::runIsotrace("info " + scene + " --ranks 3");
  ASSERT_EQ(r.status, 0) << r.err;
  for (const char* rank : {"volume 0, rank 0:", "volume 0, rank 1:", "volume 0, rank 2:"})
    EXPECT_NE(r.out.find(rank), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("the largest rank holds"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("volume 0: cut along "), std::string::npos) << r.out;
  for (const char* bad : {"--ranks 0", "--ranks x", "--ranks 100000"}) {
    const auto b = test::runIsotrace("info " + scene + " " + bad);
    EXPECT_EQ(b.status, 2) << bad;
    EXPECT_EQ(std::count(b.err.begin(), b.err.end(), '\n'), 1) << bad << ": " << b.err;
  }
  const auto many = test::runIsotrace("info " + scene + " --ranks 600");  // neghip: 512 bricks
  EXPECT_EQ(many.status, 2) << many.out;
  EXPECT_NE(many.err.find("too few"), std::string::npos) << many.err;
}

}  // namespace
}  // namespace iso
