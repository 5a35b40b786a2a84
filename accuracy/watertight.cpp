#include "accuracy/watertight.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <random>

#include "scene/world.h"

namespace iso {

void WatertightCounts::add(const WatertightCounts& o) {
  rays += o.rays;
  crossings += o.crossings;
  referenceCrossings += o.referenceCrossings;
  parityErrors += o.parityErrors;
  selfHits += o.selfHits;
  insideEscapes += o.insideEscapes;
  shadowMismatches += o.shadowMismatches;
}

namespace {

// The parameter range where the line o + t d lies in the box [0, hi]; false if it misses.
bool clipToBox(const Vec3d& o, const Vec3d& d, const Vec3d& hi, double& t0, double& t1) {
  t0 = -1e300;
  t1 = 1e300;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0) {
      if (o[a] < 0 || o[a] > hi[a]) return false;
      continue;
    }
    double ta = (0 - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  return t0 < t1;
}

class SurfaceChecker {
 public:
  SurfaceChecker(const World& world, const Transform& toWorld, double iso)
      : m_world(world), m_grid(*world.volumes()[0].grid), m_toWorld(toWorld), m_iso(iso),
        m_reference(m_grid, *world.volumes()[0].bricks, iso, IntersectorSpec{IntersectorKind::Reference, 8}) {
    // World -> grid coordinates: the inverse placement, then origin and spacing.
    m_toGrid = toWorld.inverse();
    const Vec3i d = m_grid.dims();
    m_hi = {double(d.x - 1), double(d.y - 1), double(d.z - 1)};
  }

  Vec3d toGrid(const Vec3d& world) const {
    return (m_toGrid.point(world) - m_grid.origin()) / m_grid.spacing();
  }
  Vec3d toWorldPoint(const Vec3d& grid) const { return m_toWorld.point(grid * m_grid.spacing() + m_grid.origin()); }
  bool inside(const Vec3d& grid) const { return m_grid.interpolate(grid) > m_iso; }

  // Crossings of the line o + t d, t in [t0, t1] (world space), by the reference intersector
  // in double, restarting just past each root.
  int referenceCrossings(const Vec3d& o, const Vec3d& d, double t0, double t1, TraversalStats& stats) const {
    const Vec3d oo = m_toGrid.point(o), dd = m_toGrid.vector(d);
    int n = 0;
    SurfaceHit h;
    double t = t0;
    while (n < 100000 && m_reference.intersect(oo, dd, t, t1, h, stats)) {
      ++n;
      t = h.t + std::max(h.tError, 1e-300);
    }
    return n;
  }

  // Hits from `ray` to its tfar, each next ray spawned from the last hit and continued to
  // the plane through `end` across the ray (the spawned origins leave the line by their
  // offsets), or without end if `end` is null; `last` gets the chain's last ray.
  int trace(Ray ray, const Vec3d* end, TraversalStats& stats, Ray* last = nullptr) const {
    Hit hit;
    int hits = 0;
    while (hits < 100000 && m_world.intersect(ray, hit, stats)) {
      ++hits;
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
    const Vec3d world = ray.origin();
    Vec3d o = toGrid(world);
    const Vec3d d = toGrid(world + Vec3d(ray.dir)) - o;
    if (spawned)
      for (int a = 0; a < 3; ++a) o[a] = std::clamp(o[a], 0.0, m_hi[a]);
    double t0, t1;
    if (clipToBox(o, d, m_hi, t0, t1) && t1 >= 0) {
      exit = o + d * t1;
      return true;
    }
    exit = o;
    return spawned;
  }

  void one(std::mt19937_64& rng, WatertightCounts& c, TraversalStats& stats) const {
    std::uniform_real_distribution<double> u(0, 1);
    auto randomPoint = [&] { return Vec3d{u(rng) * m_hi.x, u(rng) * m_hi.y, u(rng) * m_hi.z}; };
    auto randomDirection = [&] {
      const double z = 1 - 2 * u(rng), r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * M_PI * u(rng);
      return Vec3d{r * std::cos(phi), r * std::sin(phi), z};
    };
    ++c.rays;
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
          Ray ray;
          ray.org = Vec3f(wEntry - Vec3d(dir) * margin);
          ray.dir = dir;
          // The classes where the chain of rays enters and leaves the box: where this float ray
          // (not the double line) enters, and where the chain's last ray leaves (each spawned
          // ray starts off the line by its offset, so the chain drifts from it a little).
          const Vec3d o(ray.org), d(ray.dir);
          if (clipToBox(toGrid(o), toGrid(o + d) - toGrid(o), m_hi, t0, t1)) {
            ray.tfar = float(t1 + margin);
            Ray last;
            const int hits = trace(ray, nullptr, stats, &last);
            c.crossings += hits;
            const int expected = referenceCrossings(o, d, 0, t1 + margin, stats);
            c.referenceCrossings += expected;
            Vec3d exit;
            const bool leaves = exitPoint(last, hits > 0, exit);
            const double v0 = m_grid.interpolate(toGrid(o + d * t0)), v1 = leaves ? m_grid.interpolate(exit) : m_iso;
            const bool in0 = v0 > m_iso, in1 = v1 > m_iso;
            // An end exactly on the surface has no class: parity is undefined for that ray.
            const double tie = 1e-12 * (std::fabs(m_iso) + std::fabs(v0) + std::fabs(v1));
            const bool defined = std::fabs(v0 - m_iso) > tie && std::fabs(v1 - m_iso) > tie;
            if (defined && (hits % 2 == 1) != (in0 != in1)) {
              ++c.parityErrors;
              // Which way it went wrong: a root counted twice, or one missed (a hole).
              if (hits > expected) ++c.selfHits;
            }
          }
        }
      }
    }
    // Inside: from a random point, a ray that must cross must hit.
    {
      const Vec3d p = randomPoint();
      const Vec3d wp = toWorldPoint(p);
      Ray ray;
      ray.org = Vec3f(wp);
      ray.dir = Vec3f(randomDirection());
      const Vec3d o(ray.org), d(ray.dir);
      double t0, t1;
      if (clipToBox(toGrid(o), toGrid(o + d) - toGrid(o), m_hi, t0, t1) && t1 > 0) {
        const bool in0 = inside(toGrid(o)), in1 = inside(toGrid(o + d * t1));
        Hit hit;
        if (in0 != in1 && !m_world.intersect(ray, hit, stats)) ++c.insideEscapes;
      }
    }
    // Shadow: occlusion between two points against the crossings traced between them.
    {
      const Vec3d p = toWorldPoint(randomPoint()), q = toWorldPoint(randomPoint());
      Ray shadow;
      shadow.org = Vec3f(p);
      shadow.dir = Vec3f(q) - shadow.org;
      shadow.tfar = 1;
      if (length(shadow.dir) > 0) {
        const bool occluded = m_world.occluded(shadow, stats);
        // The same ray as the occlusion query (a normalised copy ends elsewhere by rounding).
        const Vec3d end = Vec3d(shadow.org) + Vec3d(shadow.dir);
        const int hits = trace(shadow, &end, stats);
        const bool differ = inside(toGrid(Vec3d(shadow.org))) != inside(toGrid(Vec3d(shadow.org) + Vec3d(shadow.dir)));
        if (occluded != (hits > 0 || differ)) ++c.shadowMismatches;
      }
    }
  }

 private:
  const World& m_world;
  const Grid& m_grid;
  Transform m_toWorld, m_toGrid;
  double m_iso;
  IsoSurface m_reference;
  Vec3d m_hi;
};

}  // namespace

std::vector<WatertightReport> checkWatertight(const SceneDesc& scene, const IntersectorSpec& intersector,
                                              const WatertightOptions& options) {
  std::vector<WatertightReport> reports;
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  for (size_t v = 0; v < scene.volumes.size(); ++v)
    for (size_t k = 0; k < scene.volumes[v].isosurfaces.size(); ++k) {
      // The iso-surface alone: no mesh, no other surface can hide a hole or add a hit.
      SceneDesc alone;
      alone.path = scene.path;
      VolumeDesc vd = scene.volumes[v];
      vd.transform = Transform::translate(options.offset) * vd.transform;
      vd.isosurfaces = {scene.volumes[v].isosurfaces[k]};
      vd.isosurfaces[0].material.clear();
      alone.volumes.push_back(vd);
      World world(alone, intersector);
      const SurfaceChecker checker(world, vd.transform, vd.isosurfaces[0].value);
      tbb::enumerable_thread_specific<WatertightCounts> counts;
      arena.execute([&] {
        tbb::parallel_for(tbb::blocked_range<int>(0, options.rays, 256), [&](const tbb::blocked_range<int>& r) {
          WatertightCounts& local = counts.local();
          TraversalStats stats;
          for (int i = r.begin(); i < r.end(); ++i) {
            // One generator per ray: the counts do not depend on the thread count.
            std::mt19937_64 rng(options.seed * 0x9e3779b97f4a7c15ull + uint64_t(i) * 0xbf58476d1ce4e5b9ull + v * 131 + k);
            checker.one(rng, local, stats);
          }
        });
      });
      WatertightReport report;
      report.volume = int(v);
      report.volumeName = vd.field ? "procedural" : vd.file;
      report.iso = vd.isosurfaces[0].value;
      report.intersector = intersectorName(intersector);
      for (const WatertightCounts& c : counts) report.counts.add(c);
      reports.push_back(report);
    }
  return reports;
}

}  // namespace iso
