#pragma once
// The error study: an intersector against the double-precision reference on the same rays.
// Used by bench programs (which print it) and by tests (which bound it).
#include <cstdint>
#include <vector>

#include "volume/iso_surface.h"

namespace iso {

enum class RayKind {
  Camera,     // from a point outside the volume towards a random point inside
  Secondary,  // from a random point inside the volume in a random direction
};

struct AccuracyReport {
  uint64_t rays = 0;
  uint64_t referenceHits = 0;  // crossings the reference finds (first hit per ray)
  uint64_t tangentOnly = 0;    // rays whose first reference root touches without crossing
  uint64_t misses = 0;         // reference crossing; tested hit absent or later than its bound
  uint64_t falseHits = 0;      // tested hit earlier than its bound allows, or none there
  double medianDt = 0, p99Dt = 0, maxDt = 0;  // |t - t_ref| in cell units, agreeing hits
  double nsPerRay = 0;                         // of the tested intersector
};

// `rays` random rays of `kind` from a fixed seed through `grid`, placed where the grid says.
// `packets`: the tested intersector walks the rays 8 at a time (IsoSurface::intersectPacket, the
// packet walk of `--ray-flow wavefront`) instead of one at a time; the hits are the same bits.
AccuracyReport measureAccuracy(const Grid& grid, double iso, const IntersectorSpec& tested,
                               RayKind kind, int rays, uint64_t seed, bool packets = false);

}  // namespace iso
