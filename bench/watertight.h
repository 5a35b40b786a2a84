#pragma once
// The watertightness check under secondary rays (`isotrace watertight`): every iso-surface of
// a scene, alone in its own world, traced the way the path tracer traces it — each ray
// continues from its last hit through the renderer's own spawnRay().
//
// - parity: a random line through the volume's box, entered from outside; the number of hits
//   up to the exit must be odd exactly when the field's class (value > iso) differs at the
//   entry and exit points (evaluated in double). A mismatch is a hole or a double count.
// - self hit: a hit within the two hits' position error bounds of the previous one.
// - inside escape: a ray from a random point whose class differs from the class where the ray
//   leaves the box must hit; one that reports nothing escaped through a hole.
// - shadow mismatch: the occlusion query between two random points disagrees with the
//   crossings traced between them (any crossing, or different classes, means occluded).
#include <cstdint>
#include <string>
#include <vector>

#include "scene/scene.h"

namespace iso {

struct WatertightCounts {
  uint64_t rays = 0;  // per test: parity, inside and shadow each use this many
  uint64_t crossings = 0;
  uint64_t parityErrors = 0;
  uint64_t selfHits = 0;
  uint64_t insideEscapes = 0;
  uint64_t shadowMismatches = 0;
  void add(const WatertightCounts& o);
  uint64_t errors() const { return parityErrors + selfHits + insideEscapes + shadowMismatches; }
};

struct WatertightReport {
  int volume = 0;
  std::string volumeName;
  double iso = 0;
  std::string intersector;
  WatertightCounts counts;
};

struct WatertightOptions {
  int rays = 100000;
  uint64_t seed = 1;
  Vec3d offset{0, 0, 0};  // added to every volume's placement (e.g. 1e5 to test far away)
  int threads = 0;        // 0: all cores; the counts do not depend on it
};

std::vector<WatertightReport> checkWatertight(const SceneDesc& scene, const IntersectorSpec& intersector,
                                              const WatertightOptions& options);

}  // namespace iso
