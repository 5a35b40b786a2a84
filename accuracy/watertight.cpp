#include "accuracy/watertight.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <ucontext.h>

#include <algorithm>
#include <cerrno>
#include <exception>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <sstream>
#include <type_traits>

#include "scene/world.h"
#include "volume/input_error.h"
#include "volume/input_file.h"

namespace iso {

void WatertightCounts::add(const WatertightCounts& o) {
  rays += o.rays;
  crossings += o.crossings;
  referenceCrossings += o.referenceCrossings;
  lostCrossings += o.lostCrossings;
  extraCrossings += o.extraCrossings;
  parityErrors += o.parityErrors;
  selfHits += o.selfHits;
  insideEscapes += o.insideEscapes;
  shadowMismatches += o.shadowMismatches;
}

namespace {

// The parameter range where the line o + t d lies in the box [0, hi]; false if it misses or
// only touches it.
bool clipToBox(const Vec3d& o, const Vec3d& d, const Vec3d& hi, double& t0, double& t1) {
  return lineInBox(o, d, Vec3d{0, 0, 0}, hi, t0, t1) && t0 < t1;
}

// Under mpirun (RankExchange): the rays' tests on lanes (ray i on lane i mod kLanes, each lane
// taking its rays in order), whose queries go through the ranks in rounds. A lane is a fiber
// (ucontext) of the calling thread, the one that talks MPI: each round it runs every lane still
// testing up to its next query, sends the round's answers through the ranks in one collective,
// and resumes each lane with its combined answer. Every rank makes the same rounds (the same
// lanes ask the same queries, since the combined answers are the same on every rank), and the
// counts are those of one ray after another: a test depends on its own ray's answers only.
// (Threads instead of fibers: a switch per query on the rank's one core cost more than the
// collectives they saved.)
class LaneRounds {
 public:
  static constexpr int kLanes = 64;

  explicit LaneRounds(const RankExchange& exchange) : m_exchange(exchange) {}

  // Runs test(i, lane) for every ray i in [0, n) on the lanes; returns when every lane is done.
  template <typename Test>
  void run(int n, Test&& test) {
    using Body = std::decay_t<Test>;
    struct Start {
      LaneRounds* rounds;
      Body* test;
      int n;
    } start{this, &test, n};
    m_lanes.clear();
    m_lanes.resize(kLanes);
    m_answers.assign(kLanes, RankAnswer{});
    m_failure = nullptr;
    for (int l = 0; l < kLanes; ++l) {
      Lane& lane = m_lanes[size_t(l)];
      lane.stack.reset(new char[kStackBytes]);
      getcontext(&lane.context);
      lane.context.uc_stack.ss_sp = lane.stack.get();
      lane.context.uc_stack.ss_size = kStackBytes;
      lane.context.uc_link = &m_scheduler;
      // (makecontext passes ints: the pointer in two halves.)
      const uintptr_t p = reinterpret_cast<uintptr_t>(&start);
      makecontext(&lane.context, reinterpret_cast<void (*)()>(&LaneRounds::laneMain<Start, Body>), 3, l,
                  unsigned(p & 0xffffffffu), unsigned(p >> 32));
    }
    for (;;) {
      bool any = false;
      for (int l = 0; l < kLanes; ++l) {
        Lane& lane = m_lanes[size_t(l)];
        if (!lane.done) {
          m_current = l;
          swapcontext(&m_scheduler, &lane.context);  // runs the lane up to its next query, or to its end
        }
        if (lane.done) m_answers[size_t(l)] = RankAnswer{};  // asks nothing
        any = any || !lane.done;
      }
      if (!any) break;
      m_exchange.combine(m_answers);  // in place: each lane's combined answer, read as it resumes
    }
    m_lanes.clear();
    if (m_failure) std::rethrow_exception(m_failure);
  }

  // From a lane's test: this rank's answer in, the ranks' combined answer out.
  void ask(RankAnswer& answer) {
    const int l = m_current;
    m_answers[size_t(l)] = answer;
    swapcontext(&m_lanes[size_t(l)].context, &m_scheduler);  // back when the round is combined
    answer = m_answers[size_t(l)];
  }

 private:
  static constexpr size_t kStackBytes = size_t(1) << 20;  // (touched pages only)
  struct Lane {
    ucontext_t context{};
    std::unique_ptr<char[]> stack;
    bool done = false;
  };

  template <typename Start, typename Body>
  static void laneMain(int lane, unsigned lo, unsigned hi) {
    Start& start = *reinterpret_cast<Start*>(uintptr_t(lo) | uintptr_t(hi) << 32);
    LaneRounds& self = *start.rounds;
    try {
      for (int i = lane; i < start.n; i += kLanes) (*start.test)(i, lane);
    } catch (...) {  // (an exception may not leave a fiber)
      if (!self.m_failure) self.m_failure = std::current_exception();
    }
    self.m_lanes[size_t(lane)].done = true;  // returns to the scheduler (uc_link)
  }

  const RankExchange& m_exchange;
  ucontext_t m_scheduler{};
  std::vector<Lane> m_lanes;
  std::vector<RankAnswer> m_answers;
  int m_current = -1;
  std::exception_ptr m_failure;
};

class SurfaceChecker {
 public:
  SurfaceChecker(const World& world, const Transform& toWorld, double iso, RayFlow flow)
      : m_world(world), m_flow(flow), m_grid(*world.volumes()[0].grid), m_toWorld(toWorld), m_iso(iso),
        m_clip(world.surfaces()[0].surface->clip()), m_solidAbove(world.surfaces()[0].surface->solidAbove()),
        m_reference(m_grid, *world.volumes()[0].bricks, iso, IntersectorSpec{IntersectorKind::Reference, 8}, m_clip,
                    m_solidAbove) {
    // World -> grid coordinates: the inverse placement, then origin and spacing.
    m_toGrid = toWorld.inverse();
    const Vec3i d = m_grid.dims();
    m_hi = {double(d.x - 1), double(d.y - 1), double(d.z - 1)};
  }

  // WatertightOptions::keepCountDifferences: parity rays whose crossings differ from the
  // reference's (no error) are kept too.
  void keepCountDifferences(bool keep) { m_keepCountDifferences = keep; }

  // WatertightOptions::ranks: the parts' Worlds answer instead of the whole one.
  void setParts(std::vector<const World*> parts) { m_parts = std::move(parts); }
  // WatertightOptions::exchange: this rank's part answers, combined with the other ranks' in
  // the lanes' rounds (the tests then run on the rounds' lanes).
  void setRankPart(const World* part, LaneRounds* rounds) {
    m_parts = {part};
    m_rounds = rounds;
  }

  Vec3d toGrid(const Vec3d& world) const {
    return (m_toGrid.point(world) - m_grid.origin()) / m_grid.spacing();
  }
  Vec3d toWorldPoint(const Vec3d& grid) const { return m_toWorld.point(grid * m_grid.spacing() + m_grid.origin()); }
  bool inside(const Vec3d& grid) const { return m_grid.interpolate(grid) > m_iso; }
  // The class at a test's end point, and whether it has one: a point on the surface (the field
  // within 1e-12 of the iso value, exactly on it with integer data) has none. The walk gives an
  // exact zero the class the ray approaches it from (CellWalk), the field alone says outside:
  // a test ending there compares only what does not depend on that convention.
  // A clipped surface's class outside the clip region is the one outside its solid; a point on
  // a clip plane (within 1e-12 of the grid's extent) has none either.
  bool classAt(const Vec3d& grid, bool& defined) const {
    const double v = m_grid.interpolate(grid);
    defined = std::fabs(v - m_iso) > 1e-12 * (std::fabs(m_iso) + std::fabs(v));
    if (m_clip.empty()) return v > m_iso;
    const Vec3d object = grid * m_grid.spacing() + m_grid.origin();
    const double extent = length(m_hi * m_grid.spacing()) + length(m_grid.origin());
    if (!(m_clip.planeDistance(object) > 1e-12 * extent)) defined = false;
    return m_clip.keeps(object) ? v > m_iso : !m_solidAbove;
  }

  // Crossings of the line o + t d, t in [t0, t1] (world space), by the reference intersector
  // in double, restarting just past each root; their t in `ts` if given. A crossing is a change
  // of class: a root after which the line has the class it already had is the last root found
  // again (the restart, past it by its error bound, landed within rounding of it: on lidc2 at
  // iso 18 about once per 7e5 roots), and is stepped over, not counted. (A tangent touch, which
  // changes no class, is counted as one, as the walk reports it.)
  int referenceCrossings(const Vec3d& o, const Vec3d& d, double t0, double t1, TraversalStats& stats,
                         std::vector<double>* ts = nullptr) const {
    const Vec3d oo = m_toGrid.point(o), dd = m_toGrid.vector(d);
    int n = 0;
    SurfaceHit h;
    double t = t0;
    bool counted = false, insideAfter = false;
    for (int found = 0; found < 100000 && m_reference.intersect(oo, dd, t, t1, h, stats); ++found) {
      const double past = h.t + std::max(h.tError, 1e-300);
      t = past > h.t ? past : std::nextafter(h.t, 1e300);
      if (h.tangent) {  // a touch (reported by the reference, counted as before; no class change)
        ++n;
        if (ts) ts->push_back(h.t);
        continue;
      }
      if (counted && h.insideAfter == insideAfter) continue;
      counted = true;
      insideAfter = h.insideAfter;
      ++n;
      if (ts) ts->push_back(h.t);
    }
    return n;
  }

  // Hits from `ray` to its tfar, each next ray spawned from the last hit and continued to
  // the plane through `end` across the ray (the spawned origins leave the line by their
  // offsets), or without end if `end` is null; `last` gets the chain's last ray, `ts` the
  // hits' distances along the first ray (in its t).
  int trace(Ray ray, const Vec3d* end, TraversalStats& stats, Ray* last = nullptr, std::vector<double>* ts = nullptr) const {
    const Vec3d o0 = ray.origin(), d0(ray.dir);
    Hit hit;
    int hits = 0;
    while (hits < 100000 && intersect(ray, hit, stats)) {
      ++hits;
      if (ts) ts->push_back(dot(hit.position64 - o0, d0) / dot(d0, d0));
      ray = spawnRay(hit, ray.dir);
      if (end) {
        const Vec3d d(ray.dir);
        const float rest = float(dot(*end - ray.origin(), d) / dot(d, d));
        if (!(rest > 0)) break;
        ray.tfar = rest;
      }
    }
    if (last) *last = ray;
    return hits;
  }

  // Where a ray leaves the box, in grid coordinates; false if it misses the box. The origin of
  // a spawned ray that lies outside the box is first moved onto it, as World does
  // (World::startInsideVolume): a chain of rays that left the box in a spawn offset ends there.
  bool exitPoint(const Ray& ray, bool spawned, Vec3d& exit) const {
    const Vec3d world = spawned ? m_world.startInsideVolume(ray).origin() : ray.origin();
    Vec3d o = toGrid(world);
    const Vec3d d = toGrid(world + Vec3d(ray.dir)) - o;
    if (spawned)  // (rounding of the transform to grid coordinates)
      for (int a = 0; a < 3; ++a) o[a] = std::clamp(o[a], 0.0, m_hi[a]);
    double t0, t1;
    if (clipToBox(o, d, m_hi, t0, t1) && t1 >= 0) {
      exit = o + d * t1;
      return true;
    }
    exit = o;
    return spawned;
  }

  // The three tests of one ray number: each makes its ray from `rng` (always drawing the same
  // numbers, so ray i is the same whatever the others did), then judges it. A ray that fails
  // is appended to `failures` if given.
  void one(std::mt19937_64& rng, WatertightCounts& c, TraversalStats& stats, std::vector<FailedRay>* failures) const {
    std::uniform_real_distribution<double> u(0, 1);
    auto randomPoint = [&] { return Vec3d{u(rng) * m_hi.x, u(rng) * m_hi.y, u(rng) * m_hi.z}; };
    auto randomDirection = [&] {
      const double z = 1 - 2 * u(rng), r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * M_PI * u(rng);
      return Vec3d{r * std::cos(phi), r * std::sin(phi), z};
    };
    ++c.rays;
    FailedRay r;
    // Parity: a line through two random points, from outside the box to outside the box.
    {
      const Vec3d a = randomPoint(), b = randomPoint();
      const Vec3d wa = toWorldPoint(a), wb = toWorldPoint(b);
      if (length(wb - wa) > 0) {
        const Vec3f dir = Vec3f(normalize(wb - wa));
        const Vec3d gd = toGrid(wa + Vec3d(dir)) - toGrid(wa);
        double t0, t1;
        if (clipToBox(toGrid(wa), gd, m_hi, t0, t1)) {
          const Vec3d wEntry = wa + Vec3d(dir) * t0;
          const double margin = 0.05 * (t1 - t0) + 1e-3;
          r.test = FailedRay::Test::Parity;
          r.org = Vec3f(wEntry - Vec3d(dir) * margin);
          r.dir = dir;
          r.margin = margin;
          judge(r, c, stats, failures);
        }
      }
    }
    // Inside: from a random point, a ray that must cross must hit.
    {
      const Vec3d p = randomPoint();
      r.test = FailedRay::Test::Inside;
      r.org = Vec3f(toWorldPoint(p));
      r.dir = Vec3f(randomDirection());
      r.tfar = 3.4e38f;
      judge(r, c, stats, failures);
    }
    // Shadow: occlusion between two points against the crossings traced between them.
    {
      const Vec3d p = toWorldPoint(randomPoint()), q = toWorldPoint(randomPoint());
      r.test = FailedRay::Test::Shadow;
      r.org = Vec3f(p);
      r.dir = Vec3f(q) - r.org;
      r.tfar = 1;
      if (length(r.dir) > 0) judge(r, c, stats, failures);
    }
  }

  // Runs `r`'s test on its ray (org, dir, tfar, end) and counts the outcome. r.what is set to
  // the failure ("" if none), with what the test found; a failure is appended to `failures`.
  void judge(FailedRay& r, WatertightCounts& c, TraversalStats& stats, std::vector<FailedRay>* failures) const {
    r.what.clear();
    r.hits.clear();
    r.reference.clear();
    const bool keep = failures != nullptr;
    std::vector<double>* hitTs = keep ? &r.hits : nullptr;
    Ray ray;
    ray.org = r.org;
    ray.dir = r.dir;
    ray.tfar = r.tfar;
    const Vec3d o(ray.org), d(ray.dir);
    if (r.test == FailedRay::Test::Parity) {
      // The classes where the chain of rays enters and leaves the box: where this float ray
      // (not the double line) enters, and where the chain's last ray leaves (each spawned
      // ray starts off the line by its offset, so the chain drifts from it a little).
      // Everything from the float ray as traced: where it meets the box, and its end a margin
      // past the exit (the reference's line ends there too), so that a replay is the same test.
      double t0, t1;
      if (!clipToBox(toGrid(o), toGrid(o + d) - toGrid(o), m_hi, t0, t1)) return;
      const double end = t1 + r.margin;
      ray.tfar = r.tfar = float(end);
      Ray last;
      const int hits = trace(ray, nullptr, stats, &last, hitTs);
      c.crossings += hits;
      const int expected = referenceCrossings(o, d, 0, end, stats, keep ? &r.reference : nullptr);
      c.referenceCrossings += expected;
      if (expected > hits) c.lostCrossings += uint64_t(expected - hits);
      if (hits > expected) c.extraCrossings += uint64_t(hits - expected);
      Vec3d exit;
      const bool leaves = exitPoint(last, hits > 0, exit);
      // (The ray's extent in the box begins at its origin where rounding the origin to float
      // put it inside the box: a line that grazes a face, entered just behind the origin.)
      // An end exactly on the surface has no class: parity is undefined for that ray.
      bool startDefined, endDefined = false;
      r.startInside = classAt(toGrid(o + d * std::max(t0, 0.0)), startDefined);
      r.endInside = leaves && classAt(exit, endDefined);
      if (startDefined && endDefined && (hits % 2 == 1) != (r.startInside != r.endInside)) {
        ++c.parityErrors;
        r.what = "parity error (a hole)";
        // Which way it went wrong: a root counted twice, or one missed (a hole).
        if (hits > expected) {
          ++c.selfHits;
          r.what = "parity error and self hit (a root counted twice)";
        }
      } else if (m_keepCountDifferences && hits != expected) {
        // Not an error: pairs of crossings one count has and the other not (parity intact).
        r.what = std::string(kCountDifference) + " (" + std::to_string(hits) + " traced, " + std::to_string(expected) +
                 " by the reference)";
      }
    } else if (r.test == FailedRay::Test::Inside) {
      double t0, t1;
      if (!(clipToBox(toGrid(o), toGrid(o + d) - toGrid(o), m_hi, t0, t1) && t1 > 0)) return;
      // The class where the ray's extent in the box begins: its origin, or where it enters the
      // box if the origin (a random point in the box, rounded to float far from the origin)
      // lies just outside it. The field has no class outside the box.
      bool startDefined, endDefined;
      r.startInside = classAt(toGrid(o + d * std::max(t0, 0.0)), startDefined);
      r.endInside = classAt(toGrid(o + d * t1), endDefined);
      Hit hit;
      const bool found = intersect(ray, hit, stats);
      if (keep && found) r.hits.push_back(hit.t);
      if (startDefined && endDefined && r.startInside != r.endInside && !found) {
        ++c.insideEscapes;
        r.what = "inside escape (no hit where the class changes)";
      }
    } else {
      r.occluded = occluded(ray, stats);
      // The same ray as the occlusion query (a normalised copy ends elsewhere by rounding).
      const Vec3d end = o + d;
      const int hits = trace(ray, &end, stats, nullptr, hitTs);
      // The classes at the ends of the segment's extent in the box (its end points, unless
      // rounding to float put them just outside); a segment that misses the box has none.
      double t0, t1;
      const bool meets = clipToBox(toGrid(o), toGrid(o + d) - toGrid(o), m_hi, t0, t1) && t0 <= 1 && t1 >= 0;
      bool startDefined = true, endDefined = true;
      r.startInside = meets && classAt(toGrid(o + d * std::max(t0, 0.0)), startDefined);
      r.endInside = meets && classAt(toGrid(o + d * std::min(t1, 1.0)), endDefined);
      // (An end on the surface: only hits say whether the segment crosses.)
      const bool classesDiffer = startDefined && endDefined && r.startInside != r.endInside;
      if (r.occluded != (hits > 0 || classesDiffer)) {
        ++c.shadowMismatches;
        r.what = r.occluded ? "shadow mismatch (occluded, but no crossing traced)" : "shadow mismatch (not occluded, but crossings traced)";
      }
    }
    if (keep && !r.what.empty()) failures->push_back(r);
  }

 private:
  // The renderer's queries in the chosen ray flow (WatertightOptions::rayFlow), of the whole
  // World or of its parts.
  bool intersect(const Ray& ray, Hit& hit, TraversalStats& stats) const {
    if (m_parts.empty()) return intersectIn(m_world, ray, hit, stats);
    if (m_rounds) {
      RankAnswer a;
      a.query = RankAnswer::kClosest;
      a.found = intersectIn(*m_parts[0], ray, a.hit, stats) ? 1 : 0;
      m_rounds->ask(a);
      if (a.found) hit = a.hit;
      return a.found != 0;
    }
    bool found = false;
    for (const World* part : m_parts) {
      Hit h;
      if (intersectIn(*part, ray, h, stats) && (!found || h.t < hit.t)) {
        hit = h;
        found = true;
      }
    }
    return found;
  }
  bool occluded(const Ray& ray, TraversalStats& stats) const {
    if (m_parts.empty()) return occludedIn(m_world, ray, stats);
    if (m_rounds) {
      RankAnswer a;
      a.query = RankAnswer::kBlocked;
      a.found = occludedIn(*m_parts[0], ray, stats) ? 1 : 0;
      m_rounds->ask(a);
      return a.found != 0;
    }
    for (const World* part : m_parts)
      if (occludedIn(*part, ray, stats)) return true;
    return false;
  }
  bool intersectIn(const World& world, const Ray& ray, Hit& hit, TraversalStats& stats) const {
    if (m_flow == RayFlow::Scalar) return world.intersect(ray, hit, stats);
    Ray rays[World::kPacket];
    Hit hits[World::kPacket];
    bool found[World::kPacket];
    std::fill(std::begin(rays), std::end(rays), ray);
    TraversalStats lanes;
    world.intersectPacket(rays, World::kPacket, hits, found, lanes);
    addOneLane(stats, lanes);
    hit = hits[0];
    return found[0];
  }
  bool occludedIn(const World& world, const Ray& ray, TraversalStats& stats) const {
    if (m_flow == RayFlow::Scalar) return world.occluded(ray, stats);
    Ray rays[World::kPacket];
    bool blocked[World::kPacket];
    std::fill(std::begin(rays), std::end(rays), ray);
    TraversalStats lanes;
    world.occludedPacket(rays, World::kPacket, blocked, lanes);
    addOneLane(stats, lanes);
    return blocked[0];
  }
  // The packet's lanes did the same work: one lane's share.
  static void addOneLane(TraversalStats& to, const TraversalStats& packet) {
    TraversalStats share = packet;
    share.forEach([](uint64_t& v) { v /= World::kPacket; });
    to.add(share);
  }

  const World& m_world;
  std::vector<const World*> m_parts;
  LaneRounds* m_rounds = nullptr;
  RayFlow m_flow;
  const Grid& m_grid;
  Transform m_toWorld, m_toGrid;
  double m_iso;
  ClipRegion m_clip;  // the surface's, in its object space
  bool m_solidAbove;
  IsoSurface m_reference;
  Vec3d m_hi;
  bool m_keepCountDifferences = false;
};

// Iso-surface k of volume v alone in a world (no mesh, no other surface can hide a hole or add
// a hit), its volume moved by `offset`.
struct AloneSurface {
  VolumeDesc desc;
  std::unique_ptr<World> world;
  std::unique_ptr<SurfaceChecker> checker;
  std::vector<std::unique_ptr<World>> parts;  // WatertightOptions::ranks, or this rank's (exchange)
  std::unique_ptr<LaneRounds> rounds;         // under mpirun
  AloneSurface(const SceneDesc& scene, size_t v, size_t k, const IntersectorSpec& intersector, const Vec3d& offset,
               RayFlow flow, int ranks, const RankExchange* exchange = nullptr) {
    SceneDesc alone;
    alone.path = scene.path;
    desc = scene.volumes[v];
    desc.transform = Transform::translate(offset) * desc.transform;
    // The clip regions (the scene's and the volume's, in world space) move with the volume.
    ClipRegion clip = scene.clip;
    clip.add(desc.clip);
    desc.clip = clip.transformed(Transform::translate(offset));
    desc.isosurfaces = {scene.volumes[v].isosurfaces[k]};
    desc.isosurfaces[0].material.clear();
    alone.volumes.push_back(desc);
    world = std::make_unique<World>(alone, intersector);
    // Grid space to world as the World places it: a file's own affine (NIfTI), then the scene's.
    checker = std::make_unique<SurfaceChecker>(*world, world->volumes()[0].transform, desc.isosurfaces[0].value, flow);
    if (ranks > 1) {
      std::vector<const World*> views;
      for (int r = 0; r < ranks; ++r) {
        alone.dataPart = DataPart{r, ranks};
        parts.push_back(std::make_unique<World>(alone, intersector));
        views.push_back(parts.back().get());
      }
      checker->setParts(std::move(views));
    }
    if (exchange) {
      alone.dataPart = DataPart{exchange->rank, exchange->ranks};
      parts.push_back(std::make_unique<World>(alone, intersector));
      rounds = std::make_unique<LaneRounds>(*exchange);
      checker->setRankPart(parts.back().get(), rounds.get());
    }
  }
};

}  // namespace

std::vector<WatertightReport> checkWatertight(const SceneDesc& scene, const IntersectorSpec& intersector,
                                              const WatertightOptions& options) {
  std::vector<WatertightReport> reports;
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  for (size_t v = 0; v < scene.volumes.size(); ++v)
    for (size_t k = 0; k < scene.volumes[v].isosurfaces.size(); ++k) {
      std::unique_ptr<AloneSurface> made;
      std::string error;
      try {
        made = std::make_unique<AloneSurface>(scene, v, k, intersector, options.offset, options.rayFlow, options.ranks,
                                              options.exchange);
      } catch (const InputError& e) {
        if (!options.exchange) throw;
        error = e.what();
      } catch (const std::bad_alloc&) {
        if (!options.exchange) throw;
        error = "out of memory";
      }
      // Under mpirun no rank goes on to the collectives when one failed to load its part.
      if (options.exchange) error = options.exchange->firstError(error);
      if (!error.empty()) throw InputError(error);
      const AloneSurface& alone = *made;
      alone.checker->keepCountDifferences(options.keepCountDifferences);
      tbb::enumerable_thread_specific<WatertightCounts> counts;
      tbb::enumerable_thread_specific<std::vector<FailedRay>> failures;
      // Ray i's three tests, counted into `local` (failures into `kept`, if kept).
      auto testRay = [&](int i, WatertightCounts& local, std::vector<FailedRay>* kept, TraversalStats& stats) {
        // One generator per ray: the counts do not depend on the thread count.
        std::mt19937_64 rng(options.seed * 0x9e3779b97f4a7c15ull + uint64_t(i) * 0xbf58476d1ce4e5b9ull + v * 131 + k);
        const size_t before = kept ? kept->size() : 0;
        alone.checker->one(rng, local, stats, kept && kept->size() < kMaxKeptFailures ? kept : nullptr);
        if (kept)
          for (size_t f = before; f < kept->size(); ++f) {
            (*kept)[f].volume = int(v);
            (*kept)[f].surface = int(k);
            (*kept)[f].index = uint64_t(i);
          }
      };
      if (alone.rounds) {
        // Under mpirun: on the rounds' lanes (their queries go through the ranks together).
        std::vector<WatertightCounts> laneCounts(LaneRounds::kLanes);
        std::vector<std::vector<FailedRay>> laneFailures(LaneRounds::kLanes);
        std::vector<TraversalStats> laneStats(LaneRounds::kLanes);
        alone.rounds->run(options.rays, [&](int i, int lane) {
          testRay(i, laneCounts[size_t(lane)], options.keepFailures ? &laneFailures[size_t(lane)] : nullptr,
                  laneStats[size_t(lane)]);
        });
        for (int l = 0; l < LaneRounds::kLanes; ++l) {
          counts.local().add(laneCounts[size_t(l)]);
          std::vector<FailedRay>& f = failures.local();
          f.insert(f.end(), laneFailures[size_t(l)].begin(), laneFailures[size_t(l)].end());
        }
      } else {
        arena.execute([&] {
          tbb::parallel_for(tbb::blocked_range<int>(0, options.rays, 256), [&](const tbb::blocked_range<int>& r) {
            WatertightCounts& local = counts.local();
            std::vector<FailedRay>* kept = options.keepFailures ? &failures.local() : nullptr;
            TraversalStats stats;
            for (int i = r.begin(); i < r.end(); ++i) testRay(i, local, kept, stats);
          });
        });
      }
      WatertightReport report;
      report.volume = int(v);
      report.volumeName = alone.desc.field ? "procedural" : alone.desc.file;
      report.iso = alone.desc.isosurfaces[0].value;
      report.intersector = intersectorName(intersector);
      for (const WatertightCounts& c : counts) report.counts.add(c);
      for (std::vector<FailedRay>& f : failures) report.failures.insert(report.failures.end(), f.begin(), f.end());
      std::sort(report.failures.begin(), report.failures.end(), [](const FailedRay& a, const FailedRay& b) {
        return a.index != b.index ? a.index < b.index : int(a.test) < int(b.test);
      });
      if (report.failures.size() > kMaxKeptFailures) report.failures.resize(kMaxKeptFailures);
      reports.push_back(std::move(report));
    }
  return reports;
}

bool FailedRay::countDifference() const { return what.rfind(kCountDifference, 0) == 0; }

const char* testName(FailedRay::Test t) {
  switch (t) {
    case FailedRay::Test::Parity: return "parity";
    case FailedRay::Test::Inside: return "inside";
    case FailedRay::Test::Shadow: return "shadow";
  }
  return "?";
}

namespace {

std::string hex(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%a", v);
  return buf;
}

std::string hex3(const Vec3f& v) { return hex(v.x) + "," + hex(v.y) + "," + hex(v.z); }

std::string hexList(const std::vector<double>& ts) {
  std::string s;
  for (double t : ts) s += (s.empty() ? "" : ";") + hex(t);
  return s.empty() ? "-" : s;
}

}  // namespace

void writeFailures(const std::string& path, const FailureFile& file) {
  std::string text = "# isotrace watertight failures: intersector=" + file.intersector + " ray_flow=" + rayFlowName(file.rayFlow) + " seed=" + std::to_string(file.seed) +
                     " offset=" + hex(file.offset.x) + "," + hex(file.offset.y) + "," + hex(file.offset.z) +
                     (file.ranks > 1 ? " ranks=" + std::to_string(file.ranks) : std::string()) +
                     " scene=" + file.scene + "\n";
  for (const FailedRay& r : file.rays)
    text += std::string(testName(r.test)) + " volume=" + std::to_string(r.volume) + " surface=" + std::to_string(r.surface) +
            " index=" + std::to_string(r.index) + " org=" + hex3(r.org) + " dir=" + hex3(r.dir) + " tfar=" + hex(r.tfar) +
            " margin=" + hex(r.margin) + " start=" + (r.startInside ? "1" : "0") + " endclass=" + (r.endInside ? "1" : "0") +
            " occluded=" + (r.occluded ? "1" : "0") + " hits=" + hexList(r.hits) + " reference=" + hexList(r.reference) +
            " what=" + r.what + "\n";
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw InputError(path, "", std::string("cannot write: ") + std::strerror(errno));
  const bool ok = std::fputs(text.c_str(), f) >= 0;
  if (std::fclose(f) != 0 || !ok) throw InputError(path, "", "cannot write");
}

FailureFile readFailures(const std::string& path) {
  const std::string text = readWholeFile(path, "failure file", uint64_t(256) << 20);
  FailureFile file;
  std::istringstream in(text);
  std::string line;
  int number = 0;
  auto fail = [&](const std::string& what) -> void { throw InputError(path, "line " + std::to_string(number), what); };
  auto number64 = [&](const std::string& key, const std::string& v) {
    char* end = nullptr;
    errno = 0;
    const double d = std::strtod(v.c_str(), &end);
    if (v.empty() || *end != '\0' || errno == ERANGE || !std::isfinite(d)) fail(key + ": '" + v + "' is not a finite number");
    return d;
  };
  auto integer = [&](const std::string& key, const std::string& v, uint64_t most) {
    if (v.empty() || v.size() > 19 || v.find_first_not_of("0123456789") != std::string::npos) fail(key + ": '" + v + "' is not a count");
    const uint64_t n = std::stoull(v);
    if (n > most) fail(key + ": " + v + " is more than " + std::to_string(most));
    return n;
  };
  auto three = [&](const std::string& key, const std::string& v) {
    std::istringstream parts(v);
    Vec3d r;
    std::string p;
    for (int a = 0; a < 3; ++a) {
      if (!std::getline(parts, p, ',')) fail(key + ": expected three comma-separated numbers");
      r[a] = number64(key, p);
    }
    if (std::getline(parts, p, ',')) fail(key + ": expected three comma-separated numbers");
    return r;
  };
  auto list = [&](const std::string& key, const std::string& v) {
    std::vector<double> ts;
    if (v == "-") return ts;
    std::istringstream parts(v);
    for (std::string p; std::getline(parts, p, ';');) {
      if (ts.size() >= 100000) fail(key + ": more than 100000 values");
      ts.push_back(number64(key, p));
    }
    return ts;
  };
  bool header = false;
  while (std::getline(in, line)) {
    ++number;
    if (line.empty()) continue;
    if (!header) {
      const std::string magic = "# isotrace watertight failures: ";
      if (line.compare(0, magic.size(), magic) != 0) fail("not an isotrace failure file (its first line must start '" + magic + "')");
      const size_t at = line.find(" scene=");
      if (at == std::string::npos) fail("the header names no scene");
      file.scene = line.substr(at + 7);
      std::istringstream fields(line.substr(magic.size(), at - magic.size()));
      for (std::string field; fields >> field;) {
        const size_t eq = field.find('=');
        const std::string key = field.substr(0, eq), value = eq == std::string::npos ? "" : field.substr(eq + 1);
        if (key == "intersector") file.intersector = value;
        else if (key == "ray_flow") {
          if (!parseRayFlow(value, file.rayFlow)) fail("ray_flow: unknown ray flow '" + value + "' (known: wavefront, scalar)");
        }
        else if (key == "seed") file.seed = integer(key, value, uint64_t(1) << 62);
        else if (key == "offset") file.offset = three(key, value);
        else if (key == "ranks") {
          file.ranks = int(integer(key, value, 64));
          if (file.ranks < 1) fail("ranks: must be at least 1");
        }
        else fail("unknown header field '" + key + "'");
      }
      header = true;
      continue;
    }
    if (file.rays.size() >= kMaxKeptFailures) fail("more than " + std::to_string(kMaxKeptFailures) + " rays");
    FailedRay r;
    const size_t whatAt = line.find(" what=");
    if (whatAt == std::string::npos) fail("no 'what=' field");
    r.what = line.substr(whatAt + 6);
    std::istringstream fields(line.substr(0, whatAt));
    std::string test;
    fields >> test;
    if (test == "parity") r.test = FailedRay::Test::Parity;
    else if (test == "inside") r.test = FailedRay::Test::Inside;
    else if (test == "shadow") r.test = FailedRay::Test::Shadow;
    else fail("unknown test '" + test + "' (parity, inside, shadow)");
    std::set<std::string> seen;
    for (std::string field; fields >> field;) {
      const size_t eq = field.find('=');
      if (eq == std::string::npos) fail("expected KEY=VALUE, got '" + field + "'");
      const std::string key = field.substr(0, eq), value = field.substr(eq + 1);
      if (!seen.insert(key).second) fail("'" + key + "' given twice");
      if (key == "volume") r.volume = int(integer(key, value, 1 << 20));
      else if (key == "surface") r.surface = int(integer(key, value, 1 << 20));
      else if (key == "index") r.index = integer(key, value, uint64_t(1) << 62);
      else if (key == "org") r.org = Vec3f(three(key, value));
      else if (key == "dir") r.dir = Vec3f(three(key, value));
      else if (key == "tfar") r.tfar = float(number64(key, value));
      else if (key == "margin") r.margin = number64(key, value);
      else if (key == "start") r.startInside = integer(key, value, 1) == 1;
      else if (key == "endclass") r.endInside = integer(key, value, 1) == 1;
      else if (key == "occluded") r.occluded = integer(key, value, 1) == 1;
      else if (key == "hits") r.hits = list(key, value);
      else if (key == "reference") r.reference = list(key, value);
      else fail("unknown field '" + key + "'");
    }
    for (const char* key : {"volume", "surface", "org", "dir", "tfar"})
      if (!seen.count(key)) fail(std::string("no '") + key + "' field");
    file.rays.push_back(std::move(r));
  }
  if (!header) throw InputError(path, "", "empty: not an isotrace failure file");
  return file;
}

std::vector<FailedRay> replayFailures(const SceneDesc& scene, const IntersectorSpec& intersector, const Vec3d& offset, RayFlow flow,
                                      const std::vector<FailedRay>& rays) {
  return replayFailures(scene, intersector, offset, flow, rays, 1);
}

std::vector<FailedRay> replayFailures(const SceneDesc& scene, const IntersectorSpec& intersector, const Vec3d& offset, RayFlow flow,
                                      const std::vector<FailedRay>& rays, int ranks) {
  std::map<std::pair<int, int>, std::unique_ptr<AloneSurface>> surfaces;
  std::vector<FailedRay> out;
  for (const FailedRay& given : rays) {
    if (given.volume >= int(scene.volumes.size()) ||
        given.surface >= int(scene.volumes[size_t(given.volume)].isosurfaces.size()))
      throw InputError(scene.path, "", "the failure file names iso-surface " + std::to_string(given.surface) + " of volume " +
                                           std::to_string(given.volume) + ", which this scene does not have");
    auto& slot = surfaces[{given.volume, given.surface}];
    if (!slot)
      slot = std::make_unique<AloneSurface>(scene, size_t(given.volume), size_t(given.surface), intersector, offset, flow, ranks);
    FailedRay r = given;
    slot->checker->keepCountDifferences(given.countDifference());
    WatertightCounts counts;
    TraversalStats stats;
    std::vector<FailedRay> failed;
    slot->checker->judge(r, counts, stats, &failed);
    out.push_back(r);
  }
  return out;
}

}  // namespace iso
