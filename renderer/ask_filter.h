#pragma once
// The first test of whom a data-parallel rank asks about its rays (renderer/data_parallel.cpp,
// RankTracer::ask), eight rays per instruction in float: most rays lie wholly in the bricks the
// rank holds, or never come near another rank's box, and this test says so for them without
// the double-precision test, which then runs only for the rest. It is conservative: a ray it
// calls settled is one the double test would ask of nobody (its pad is twice the double
// test's, far more than float's rounding of the ray's points; a ray it cannot take, with an
// axis it does not move along or a non-finite origin, is left to the double test).
#include <cstddef>
#include <vector>

namespace iso {

// A box in float, [lo, hi] on each axis.
struct AskFilterBox {
  float lo[3], hi[3];
};

// One volume split over the ranks, in world space (a volume whose grid axes are the world's).
struct AskFilterVolume {
  AskFilterBox held;                 // the bricks this rank holds, rounded inwards (an open side: +-FLT_MAX)
  std::vector<AskFilterBox> others;  // the other ranks' own boxes, rounded outwards
  // The double test's pad for a ray: padPerReach * (2 * max |origin|) + padFixed.
  float padPerReach = 0, padFixed = 0;
};

// Rays as arrays (structure of arrays), each padded to a multiple of 8.
struct AskFilterRays {
  std::vector<float> ox, oy, oz, dx, dy, dz, t0, t1;
  // Room for n rays (at least; the arrays never shrink).
  void resize(size_t n);
};

// For rays [0, n): settled[i] stays 1 where this volume would have ray i asked of nobody (its
// segment [t0, t1] lies in the held box, or misses every other rank's box), else becomes 0.
void filterAsks(const AskFilterRays& rays, size_t n, const AskFilterVolume& volume, unsigned char* settled);

}  // namespace iso
