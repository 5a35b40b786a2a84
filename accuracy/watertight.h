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
//   thin wall that disappears: linear interpolation inside one cell), which parity cannot see;
//   more, pairs the walk found that the reference has not (a float solve where the field
//   stays within its rounding of the iso value). Both are counted per ray (lost, extra).
// - shadow mismatch: the occlusion query between two random points disagrees with the
//   crossings traced between them (any crossing, or different classes, means occluded).
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "scene/scene.h"
#include "scene/world.h"  // Hit (RankAnswer)

namespace iso {

struct WatertightCounts {
  uint64_t rays = 0;  // per test: parity, inside and shadow each use this many
  uint64_t crossings = 0;
  uint64_t referenceCrossings = 0;  // on the parity rays' lines, by the double reference
  // Per parity ray, the reference's count minus the hits where that is positive (lost), the
  // hits minus the reference's where that is (extra): pairs of crossings one side has and the
  // other not, summed ray by ray so that one ray's lost pair does not hide another's extra one.
  uint64_t lostCrossings = 0;
  uint64_t extraCrossings = 0;
  uint64_t parityErrors = 0;
  uint64_t selfHits = 0;
  uint64_t insideEscapes = 0;
  uint64_t shadowMismatches = 0;
  void add(const WatertightCounts& o);
  uint64_t errors() const { return parityErrors + selfHits + insideEscapes + shadowMismatches; }
};

// A ray that failed one of the tests, with what it found, so that it can be replayed alone.
struct FailedRay {
  enum class Test { Parity, Inside, Shadow };
  Test test = Test::Parity;
  int volume = 0, surface = 0;  // scene indices: volumes[volume].isosurfaces[surface]
  uint64_t index = 0;           // the ray's number in its run (with the seed, it regenerates it)
  Vec3f org, dir;               // the first ray of the test, as traced
  float tfar = 0;
  double margin = 0;            // parity: how far before the box the ray starts and past it it ends
  bool startInside = false;     // the class where the test starts (parity: where the ray enters)
  bool endInside = false;       // the class where it ends (parity: where the chain's last ray leaves)
  std::vector<double> hits;     // the hits' distances along the first ray (in its t)
  std::vector<double> reference;  // parity: the reference's crossings on the line (same t)
  bool occluded = false;        // shadow: what the occlusion query said
  std::string what;             // the failure: "parity error (a hole)", "self hit", ...
  // Kept by WatertightOptions::keepCountDifferences: crossings differ, no error (kCountDifference).
  bool countDifference() const;
};
const char* testName(FailedRay::Test t);

struct WatertightReport {
  int volume = 0;
  std::string volumeName;
  double iso = 0;
  std::string intersector;
  WatertightCounts counts;
  std::vector<FailedRay> failures;  // when WatertightOptions::keepFailures, in ray order
};


// One query's answer on one rank, as the ranks exchange them (RankExchange::combine).
struct RankAnswer {
  enum Query : int32_t { kNone = 0, kClosest = 1, kBlocked = 2 };
  int32_t query = kNone;  // kNone: the lane asks nothing this round (its rays are done)
  int32_t found = 0;      // kClosest: a hit found (in `hit`); kBlocked: the segment is blocked
  Hit hit;
};

// Under mpirun (`isotrace watertight --data-parallel`): this process is rank `rank` of a
// data-parallel job; its World holds only its part of each volume (SceneDesc::dataPart, as in
// `render --data-parallel`), and every query's answer is combined with the other ranks'. The
// rays are tested on lanes (ray i on lane i mod lanes, a thread each), and the lanes' queries go
// through the ranks in rounds: each round one collective carries one query of every lane. Every
// rank makes the same rounds, since every rank gets the same combined answers. The reference and
// the classes stay the whole volume's, on every rank.
struct RankExchange {
  int rank = 0, ranks = 1;
  // Collective: this rank's answers to a round's queries in (the same queries, lane by lane, on
  // every rank), the ranks' combined answers out: for kClosest the closest of the hits found (of
  // equal ones the lowest rank's), for kBlocked whether any rank's segment is blocked.
  std::function<void(std::vector<RankAnswer>& answers)> combine;
  // The lowest rank's error ("" if none), on every rank: a failure on one rank ends all.
  std::function<std::string(const std::string& mine)> firstError;
};

struct WatertightOptions {
  int rays = 100000;
  uint64_t seed = 1;
  Vec3d offset{0, 0, 0};  // added to every volume's placement (e.g. 1e5 to test far away)
  int threads = 0;        // 0: all cores; the counts do not depend on it
  bool keepFailures = false;  // keep every failing ray (at most kMaxKeptFailures per surface)
  // With keepFailures: keep also the parity rays whose crossings differ from the reference's
  // count on the line (not an error: pairs one count has and the other not), their `what`
  // starting kCountDifference; a replay of such a ray reports the difference again.
  bool keepCountDifferences = false;
  // How the renderer's queries are made: `wavefront` traces each query as an 8-ray Embree packet
  // holding the ray in every lane (World::intersectPacket), so that every answer comes from the
  // packet walk of the bricks and its 8-lane solve; `scalar` one ray at a time.
  RayFlow rayFlow = RayFlow::Wavefront;
  // > 1: the volume split as a data-parallel render over that many ranks splits it, each part a
  // World of its own (SceneDesc::dataPart), and every query the closest of their hits (of equal
  // ones the lowest part's) or "blocked" if any part is: the checks across rank seams, in one
  // process. The reference and the classes stay the whole volume's.
  int ranks = 1;
  const RankExchange* exchange = nullptr;  // under mpirun: the parts are other processes' (above)
};
constexpr size_t kMaxKeptFailures = 100000;
constexpr const char* kCountDifference = "crossings differ from the reference's, parity intact";

std::vector<WatertightReport> checkWatertight(const SceneDesc& scene, const IntersectorSpec& intersector,
                                              const WatertightOptions& options);

// A failure file (`isotrace watertight --dump`): a header line naming the scene, intersector,
// seed and offset, then one line per failing ray with its doubles and floats in hexadecimal
// (exact). Read back by readFailures, which validates every field (InputErrors name the line).
struct FailureFile {
  std::string scene, intersector;
  RayFlow rayFlow = RayFlow::Scalar;  // files written before ray flows existed traced one ray at a time
  uint64_t seed = 1;
  Vec3d offset{0, 0, 0};
  int ranks = 1;  // WatertightOptions::ranks
  std::vector<FailedRay> rays;
};
void writeFailures(const std::string& path, const FailureFile& file);
FailureFile readFailures(const std::string& path);

// Replays failed rays alone against the scene (the same volume, surface, intersector and offset):
// each ray's test is run again and its outcome written into a copy (what is "" when it passes).
std::vector<FailedRay> replayFailures(const SceneDesc& scene, const IntersectorSpec& intersector, const Vec3d& offset, RayFlow flow,
                                      const std::vector<FailedRay>& rays, int ranks);
// (the whole volume)
std::vector<FailedRay> replayFailures(const SceneDesc& scene, const IntersectorSpec& intersector, const Vec3d& offset, RayFlow flow,
                                      const std::vector<FailedRay>& rays);

}  // namespace iso
