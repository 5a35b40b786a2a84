#pragma once
// A volume split over the ranks of a data-parallel render (issue 30; `isotrace info --ranks N`
// shows it before anyone runs one): boxes of whole bricks, cut k-d along the box's longest axis
// (in bricks) so that each side holds active bricks in proportion to its ranks. A box of cells
// [cellLo, cellHi) needs the samples [cellLo, cellHi] on every axis: neighbouring boxes share the
// layer of samples at their seam, as neighbouring bricks do.
#include <cstdint>
#include <string>
#include <vector>

#include "volume/bricks.h"

namespace iso {

struct RankBox {
  Vec3i brickLo, brickHi;  // bricks [brickLo, brickHi) on each axis
  Vec3i cellLo, cellHi;    // cells [cellLo, cellHi)
  size_t bricks = 0;       // bricks in the box
  double weight = 0;       // of the weights given (active bricks)
  // The samples a rank holds for the box (a window of the grid, Grid::windowFirst/Extent): its
  // cells' corners, plus one more layer where the grid has one, for the central differences of
  // smooth shading normals (Grid::smoothGradient) in its cells next to the seams.
  Vec3i windowFirst() const;
  Vec3i windowExtent(Vec3i dims) const;
  size_t samples(Vec3i dims) const {
    const Vec3i e = windowExtent(dims);
    return size_t(e.x) * size_t(e.y) * size_t(e.z);
  }
};

// Sample rays of the camera in the volume's index space (cell (i, j, k) at (i, j, k)): where
// they pass, rays go between the ranks' boxes (cameraCutRays in scene/world.h makes them).
struct CutRays {
  std::vector<Vec3d> org, dir;
};

// The weights a data-parallel render balances its boxes by (one per brick of `bricks`): 1 for a
// brick active for some of the iso values (BrickGrid::activeBricks), else 0. (The render and
// `isotrace info --ranks` both take them from here.)
std::vector<double> activeBrickWeights(const BrickGrid& bricks, const std::vector<double>& isoValues);

// `weights`: one per brick of `bricks` (e.g. 1 for a brick active for some iso-surface); all 0:
// the boxes are balanced by brick count. `ranks` boxes, every brick in exactly one; an
// InputError (naming `where`) if the volume has fewer bricks than ranks along the cuts.
// Each cut is the one along its axis closest to the weights' share; the axis is the box's
// longest, or with `camera` the one whose cut the fewest sample rays pass: of the camera's rays,
// and of rays in 26 directions from the centres of the weighted bricks (standing for the rays
// that leave the surfaces), each counted as a fraction of its kind. Every ray that passes a cut
// between two ranks' boxes is one a rank may have to ask the other about. `cutAxes`: the axis of
// each cut, in the order made (for `isotrace info`).
std::vector<RankBox> partitionBricks(const BrickGrid& bricks, const std::vector<double>& weights, int ranks,
                                     const std::string& where, const CutRays* camera = nullptr,
                                     std::vector<int>* cutAxes = nullptr);

// What a rank holds of the volume when it may also hold copies of other ranks' bricks ("replicate":
// a fraction of the volume's bricks, 0 to 1): its box grown by the most layers of bricks on every
// side (clamped to the volume) whose bricks beyond its own number at most `replicate` of all. Rays
// whose way through another rank's box lies inside these copies need not be asked of that rank.
// 0: the box itself; 1: the whole volume.
RankBox heldBox(const RankBox& own, const BrickGrid& bricks, double replicate);

}  // namespace iso
