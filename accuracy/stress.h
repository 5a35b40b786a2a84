#pragma once
// The numerical stress suite: constructed fields and rays that break naive intersectors
// (tangent rays, two crossings in one cell, rays along faces, edges and through vertices,
// axis-parallel rays, corner clips, far from the origin, tiny and huge spacing, values near
// 1e+-30, iso values equal to the data, plateaus at the iso value, NaN/Inf data, NaN/Inf/zero
// ray directions). Each intersector is compared with the double-precision reference on the
// same rays through the whole-grid traversal. Printed by bench/stress, bounded by
// tests/stress_test.cpp.
#include <cstdint>
#include <string>
#include <vector>

#include "volume/grid.h"
#include "volume/intersectors.h"

namespace iso {

struct StressRay {
  Vec3d org, dir;
};

struct StressCase {
  std::string name;  // short, used as the test name
  std::string what;  // one line: what it stresses
  Grid grid;
  double iso = 0;
  std::vector<StressRay> rays;
  bool checkParity = true;  // false where the field has no class (NaN data)
};

struct StressResult {
  uint64_t rays = 0;
  uint64_t referenceHits = 0;  // rays with a (crossing, not tangent) reference root
  uint64_t misses = 0;         // reference root, tested none or later than its bound
  uint64_t wrongRoots = 0;     // tested root earlier than the reference allows, or none there
  uint64_t nans = 0;           // non-finite t, error bound or normal
  uint64_t parityErrors = 0;   // crossings counted by restarting past each root vs the classes at the ends
};

std::vector<StressCase> stressCases();
StressResult runStress(const StressCase& c, const IntersectorSpec& spec);

}  // namespace iso
