// The split of a volume over data-parallel ranks (volume/partition.h, `isotrace info --ranks N`):
// boxes of whole bricks that cover every brick once, share the sample layer at each seam, and
// balance the active bricks; too many ranks is refused in one line.
#include <gtest/gtest.h>

#include <set>

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

TEST(Partition, InfoShowsEachRanksBox) {
  const std::string scene = std::string(ISOTRACE_SOURCE_DIR) + "/examples/quick_look.json";
  const auto r = test::runIsotrace("info " + scene + " --ranks 3");
  ASSERT_EQ(r.status, 0) << r.err;
  for (const char* rank : {"volume 0, rank 0:", "volume 0, rank 1:", "volume 0, rank 2:"})
    EXPECT_NE(r.out.find(rank), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("the largest rank holds"), std::string::npos) << r.out;
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
