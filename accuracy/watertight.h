#pragma once
// The watertightness check under secondary rays (`isotrace watertight`): every iso-surface of
// a scene, alone in its own world, traced the way the path tracer traces it — each ray
// continues from its last hit through the renderer's own spawnRay().
//
// - parity: a random line through the volume's box, entered from outside and followed by
//   spawned rays until the chain leaves the box; the number of hits must be odd exactly when
//   the field's class (value > iso) differs where the chain enters and where its last ray
//   leaves the box (evaluated in double; each spawned ray starts off the line by its offset,
//   so the chain drifts from it a little). A mismatch is a hole or a double count.
// - self hit: a parity error with more hits than the double-precision reference finds on
//   the line.
// - inside escape: a ray from a random point whose class differs from the class where the ray
//   leaves the box must hit; one that reports nothing escaped through a hole.
// - reference crossings: what the double-precision reference counts on the parity lines.
//   Fewer crossings than that with no parity error means pairs of crossings lost whole (a
//   thin wall that disappears: linear interpolation inside one cell), which parity cannot see.
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
  uint64_t referenceCrossings = 0;  // on the parity rays' lines, by the double reference
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
