#include "volume/iso_surface.h"

#include <new>

#include "volume/packet_walk.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <type_traits>

namespace iso {
namespace {

// The ray of a query in grid coordinates. A ray with a given start class continues from a hit
// inside the grid's box, so its start belongs on the box. Where a restart by the hit's error
// bound went past the box's exit along the ray, the start moves back to that exit; where a
// spawn offset (or rounding) put it just beside the box, it moves onto the box (World moves
// spawned origins there already; this takes the rounding). Either way the class applies where
// the ray meets the field: left outside, the ray would enter through a face whose class is
// evaluated, or end without comparing its class with the field, and a chain of rays could
// change class without a hit.
template <typename Real>
GridRay<Real> queryRay(const Grid& grid, const Vec3d& org, const Vec3d& dir, double tnear, StartClass start) {
  if (start == StartClass::Unknown || !std::isfinite(tnear)) return toGridRay<Real>(grid, org, dir);
  Vec3d o = (org - grid.origin()) / grid.spacing();
  const Vec3d d = dir / grid.spacing();
  const Vec3d hi = Vec3d(grid.dims() - Vec3i{1, 1, 1});
  bool inBox = true;
  for (int a = 0; a < 3; ++a) {
    const double p = o[a] + tnear * d[a];
    inBox = inBox && p >= 0 && p <= hi[a];
  }
  if (inBox) return GridRay<Real>(Vec3<Real>(o), Vec3<Real>(d));
  double ta = -INFINITY, tb = INFINITY;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0) continue;
    const double t0 = -o[a] / d[a], t1 = (hi[a] - o[a]) / d[a];
    ta = std::max(ta, std::min(t0, t1));
    tb = std::min(tb, std::max(t0, t1));
  }
  if (ta <= tb && tnear > tb) o = o + d * (tb - tnear);
  for (int a = 0; a < 3; ++a) {
    const double p = o[a] + tnear * d[a];
    o[a] += std::clamp(p, 0.0, hi[a]) - p;
  }
  return GridRay<Real>(Vec3<Real>(o), Vec3<Real>(d));
}

}  // namespace

IsoSurface::IsoSurface(const Grid& grid, const BrickGrid& bricks, double iso, IntersectorSpec spec,
                       const ClipRegion& clip, bool solidAbove)
    : m_grid(grid), m_bricks(bricks), m_iso(iso), m_spec(spec), m_primitiveOf(bricks.size(), -1),
      m_air(solidAbove ? StartClass::Outside : StartClass::Inside) {
  // With a clip region: bricks wholly cut away hold nothing; bricks the region's boundary meets
  // (within a cell: the float ray's cell at a plane is off by far less) hold caps, so they are
  // primitives even where their field is uniformly solid, over their whole box (a cap can lie in
  // a uniform cell); bricks wholly kept are as without a clip.
  std::vector<bool> wholeBox;
  const float isoF = float(iso);
  if (!clip.empty()) {
    const Vec3d s = grid.spacing();
    const double margin = std::max({s.x, s.y, s.z});
    bool cutsSomething = false;
    for (uint32_t b = 0; b < bricks.size(); ++b) {
      const Vec3d lo = grid.origin() + Vec3d(bricks.cellBegin(b)) * s, hi = grid.origin() + Vec3d(bricks.cellEnd(b)) * s;
      const float bmin = bricks.brickMin(b), bmax = bricks.brickMax(b);
      const bool active = bmin <= isoF && bmax >= isoF && !(bmin == isoF && bmax == isoF);
      const bool held = bmin <= bmax;  // (a window of a grid holds only some bricks: BrickGrid)
      const bool solid = held && (solidAbove ? bmin > isoF : bmax < isoF);
      switch (clip.classify(lo, hi, margin)) {
        case ClipRegion::BoxSide::Kept:
          if (active) m_active.push_back(b), wholeBox.push_back(false);
          break;
        case ClipRegion::BoxSide::Cut:
          cutsSomething = true;
          break;
        case ClipRegion::BoxSide::Boundary:
          cutsSomething = true;
          if (active || solid) m_active.push_back(b), wholeBox.push_back(true);
          break;
      }
    }
    if (cutsSomething) {
      m_clip = clip;
    } else {
      m_active.clear();
      wholeBox.clear();
    }
  }
  if (m_clip.empty()) {
    m_active = bricks.activeBricks(isoF);
    wholeBox.assign(m_active.size(), false);
  }
  // The uniform cells of every active brick. A corner counts as strictly above (below) only if
  // it is in float and in double, so the table holds for the float and the double traversal.
  // The other cells span the brick's tight box: outside it every cell is of one strict class,
  // so a traversal of the box alone finds the same crossings (it enters the box through a face
  // whose class it evaluates, or takes from the ray in double where that face is exactly on the
  // surface, as at a brick seam: seamClass), and Embree culls rays that only cross the uniform part.
  m_primitives.resize(m_active.size());
  m_cellClasses.resize(m_active.size());
  withCellAccess(grid, nullptr, {}, [&](const auto& cells) {
    // Bricks are independent: in parallel, each writing only its own entries.
    tbb::parallel_for(size_t(0), m_active.size(), [&](size_t i) {
      const Vec3i c0 = bricks.cellBegin(m_active[i]), c1 = bricks.cellEnd(m_active[i]);
      CellClasses& classes = m_cellClasses[i];
      Vec3i lo = c1, hi = c0;
      uint32_t surfaceCells = 0;
      for (int z = c0.z; z < c1.z; ++z)
        for (int y = c0.y; y < c1.y; ++y)
          for (int x = c0.x; x < c1.x; ++x) {
            float v[8];
            cells.load(Vec3i{x, y, z}, 0.f, v);
            bool above = true, below = true;
            for (float f : v) {
              above = above && f > isoF && double(f) > iso;
              below = below && f < isoF && double(f) < iso;
            }
            const uint64_t bit = uint64_t(1) << ((y - c0.y) * 8 + (x - c0.x));
            if (above) classes.positive[z - c0.z] |= bit;
            if (below) classes.negative[z - c0.z] |= bit;
            if (!above && !below) {
              ++surfaceCells;
              lo = min(lo, Vec3i{x, y, z});
              hi = max(hi, Vec3i{x + 1, y + 1, z + 1});
            }
          }
      if (!(lo.x < hi.x) || wholeBox[i]) lo = c0, hi = c1;  // (the first cannot happen for an active brick)
      m_primitives[i] = {lo, hi, c0, surfaceCells};
    });
  });
  for (size_t i = 0; i < m_active.size(); ++i) m_primitiveOf[m_active[i]] = int32_t(i);
}

bool IsoSurface::floatQueryRay(const Vec3d& org, const Vec3d& dir, double tnear, double tfar, StartClass start,
                               GridRayCache& cache) const {
  if (cache.surface == this) return false;
  // The float ray is the double one rounded (what queryRay<float> gives); the double one
  // decides the classes at the ends of the ray's extent in the grid (ExactEnds).
  const GridRay<double> ray64 = queryRay<double>(m_grid, org, dir, tnear, start);
  cache.surface = this;
  new (&cache.ray) GridRay<float>(Vec3f(ray64.org), Vec3f(ray64.dir));
  new (&cache.exact) ExactEnds{ray64.org, ray64.dir, m_iso, tnear, tfar};
  return true;
}

// The clip region keeps [k0, k1] of the ray. A ray that starts in the solid (a given class) starts
// in the kept region, wherever rounding put its origin: it continues from a cap it went through
// or turned back at, a spawn offset away from the plane at most. Where it enters the kept region
// inside the grid, the class there is the field's, in double, in the cell the walk starts in (as
// the walk's begin() finds cells, on the walk's own ray), so the cap and the walk behind it agree.
template <typename Real, typename Cells>
ClipSpan IsoSurface::clipSpan(const Cells& cells, const GridRay<Real>& ray, const Vec3d& exactOrg,
                              const Vec3d& exactDir, const Vec3d& org, const Vec3d& dir, double tnear, double tfar,
                              StartClass start, bool onCap) const {
  ClipSpan span;
  double k0, k1;
  m_clip.extent(org, dir, k0, k1, span.plane0, span.plane1);
  span.tnear = tnear;
  span.tfar = tfar;
  if (start != StartClass::Unknown && start != m_air) {
    if (!(tnear <= k1)) {
      span.kind = ClipSpan::Kind::CrossAtStart;
      return span;
    }
    k0 = std::min(k0, tnear);
  }
  if (!(k0 <= k1) || !(k0 <= tfar) || !(k1 >= tnear) || !(tnear <= tfar)) {
    span.kind = ClipSpan::Kind::Empty;
    return span;
  }
  if (k1 < tfar) span.tfar = k1, span.leaves = true;
  // A ray leaving another surface's cap on this region's boundary, heading in: it enters the
  // region at its start (its origin is only a spawn offset inside).
  if (onCap && start == StartClass::Unknown && k0 < tnear) k0 = tnear;
  else if (!(k0 > tnear)) return span;
  span.tnear = k0;
  // Does the walk's ray meet the grid's box at k0 (its begin() would start inside, not at a face)?
  const Real tk = Real(k0);
  const Vec3i dims = m_grid.dims();
  for (int a = 0; a < 3; ++a) {
    const Real hi = Real(dims[a] - 1);
    if (ray.dir[a] == Real(0)) {
      if (ray.org[a] < Real(0) || ray.org[a] > hi) return span;
      continue;
    }
    const bool pos = ray.dir[a] > Real(0);
    if (ray.planeT(a, pos ? 0 : dims[a] - 1) > tk || ray.planeT(a, pos ? dims[a] - 1 : 0) < tk) return span;
  }
  span.enters = true;
  for (int a = 0; a < 3; ++a)
    span.startCell[a] = int(std::clamp(ray.org[a] + tk * ray.dir[a], Real(0), Real(dims[a] - 2)));
  const int c = exactEndClass(cells, ExactEnds{exactOrg, exactDir, m_iso, k0, k1}, span.startCell, k0, -1, 0);
  span.startClass = c > 0 ? StartClass::Inside : c < 0 ? StartClass::Outside : m_air;
  return span;
}

void IsoSurface::capHit(const Vec3d& org, const Vec3d& dir, double t, int plane, bool intoSolid, SurfaceHit& hit) const {
  hit = SurfaceHit();
  hit.t = t;
  // t = gap / (n . d) in double: a few roundings of the origin's and t's magnitude.
  const double originScale = std::max({std::fabs(org.x), std::fabs(org.y), std::fabs(org.z)}) / length(dir);
  hit.tError = 16 * 0x1p-52 * (originScale + std::fabs(t));
  // Out of the solid is out of the kept region: the plane's normal. (SurfaceHit's normal points
  // to lower values: out of the solid only when the solid lies above.)
  const Vec3d n = plane >= 0 ? m_clip.planes()[size_t(plane)].normal : -normalize(dir);
  hit.normal = Vec3f(m_air == StartClass::Outside ? n : -n);
  hit.insideAfter = intoSolid == (m_air == StartClass::Outside);
  hit.segmentStart = t;
  hit.cap = true;
}

template <typename Real, typename Cells>
void IsoSurface::surfaceHit(const Cells& cells, const CellHit<Real>& cellHit, const Vec3d& dir, SurfaceHit& hit) const {
  Real g[8];
  cells.load(cellHit.cell, Real(m_iso), g);
  const Vec3d grad = Vec3d(trilinearGradient(g, cellHit.local)) / m_grid.spacing();
  const double len = length(grad);
  // Without a gradient (a flat spot) the normal faces the ray; dir is scaled first so that
  // a tiny direction does not underflow to a NaN.
  const double dirScale = std::max({std::fabs(dir.x), std::fabs(dir.y), std::fabs(dir.z)});
  hit.normal = len > 0 && std::isfinite(len) ? Vec3f(-grad / len) : Vec3f(-normalize(dir / dirScale));
  hit.t = double(cellHit.t);
  hit.tError = double(cellHit.tError);
  hit.tangent = cellHit.tangent;
  hit.insideAfter = cellHit.insideAfter;
  hit.segmentStart = double(cellHit.segmentStart);
}

template <bool AnyHit>
bool IsoSurface::query(Vec3i lo, Vec3i hi, const CellClasses* classes, Vec3i classOrigin,
                       const Vec3d& org, const Vec3d& dir, double tnear, double tfar, SurfaceHit* hit,
                       TraversalStats& stats, StartClass start, GridRayCache* cache, double tstop) const {
  // Runs the traversal with the chosen intersector, in double for the reference and in
  // float otherwise, on the grid's own sample type, and converts the hit to world space.
  const bool onCap = cache && cache->capClip && !m_clip.empty() && m_order > cache->capOrder && *cache->capClip == m_clip;
  auto run = [&](auto real, const auto& solver) {
    using Real = decltype(real);
    return withCellAccess(m_grid, classes, classOrigin, [&](const auto& cells) {
      CellHit<Real> cellHit;
      std::optional<GridRayCache> local;  // made only for a float query without a cache of its own
      GridRay<double> ray64;
      const GridRay<Real>* ray;
      const ExactEnds* exact = nullptr;
      ClipSpan localSpan;
      const ClipSpan* span = nullptr;
      if constexpr (std::is_same_v<Real, float>) {
        GridRayCache& c = cache ? *cache : local.emplace();
        const bool fresh = floatQueryRay(org, dir, tnear, tfar, start, c);
        if (fresh && !m_clip.empty()) {
          new (&c.clip) ClipSpan(clipSpan(cells, c.ray, c.exact.org, c.exact.dir, org, dir, tnear, tfar, start, onCap));
          c.exact.tnear = c.clip.tnear;
          c.exact.tfar = c.clip.tfar;
        }
        ray = &c.ray;
        exact = &c.exact;
        if (!m_clip.empty()) span = &c.clip;
      } else {
        ray64 = queryRay<double>(m_grid, org, dir, tnear, start);
        ray = &ray64;
        if (!m_clip.empty()) {
          localSpan = clipSpan(cells, ray64, ray64.org, ray64.dir, org, dir, tnear, tfar, start, onCap);
          span = &localSpan;
        }
      }
      Real t0 = Real(tnear), t1 = Real(tfar);
      const Vec3i* startCell = nullptr;
      Vec3i c0;
      if (span) {
        // A clipped surface: caps where the ray enters or leaves the kept region in the solid,
        // the walk in between.
        switch (span->kind) {
          case ClipSpan::Kind::Empty: return false;
          case ClipSpan::Kind::CrossAtStart:
            if constexpr (!AnyHit) capHit(org, dir, tnear, span->plane1, false, *hit);
            return true;
          case ClipSpan::Kind::Walk: break;
        }
        t0 = Real(span->tnear);
        t1 = Real(span->tfar);
        if (span->enters) {
          // Only cells the walk from the start cell reaches: none behind it on an axis the ray moves along.
          c0 = span->startCell;
          const bool owner = c0.x >= lo.x && c0.y >= lo.y && c0.z >= lo.z && c0.x < hi.x && c0.y < hi.y && c0.z < hi.z;
          for (int a = 0; a < 3; ++a) {
            if (!(ray->dir[a] < Real(0))) lo[a] = std::max(lo[a], c0[a]);
            if (!(ray->dir[a] > Real(0))) hi[a] = std::min(hi[a], c0[a] + 1);
            if (lo[a] >= hi[a]) return false;
          }
          if (owner) {
            if (span->startClass != m_air) {  // the ray enters the solid through a cap
              if constexpr (!AnyHit) capHit(org, dir, span->tnear, span->plane0, true, *hit);
              return true;
            }
            startCell = &c0;
            start = span->startClass;
          } else {
            // Another brick: entered through a face, from the start cell's side.
            t0 = Real(tnear);
            start = StartClass::Unknown;
          }
        }
      }
      int endClass = 0;
      if (!traverseCells<AnyHit>(cells, Real(m_iso), *ray, lo, hi, t0, t1, solver, cellHit, stats, start, exact,
                                 Real(tstop), startCell, span && span->leaves ? &endClass : nullptr)) {
        // The walk reached the end of the kept region in the solid: the ray leaves through a cap.
        if (endClass == 0 || (endClass > 0 ? StartClass::Inside : StartClass::Outside) == m_air) return false;
        if constexpr (!AnyHit) capHit(org, dir, span->tfar, span->plane1, false, *hit);
        return true;
      }
      if constexpr (!AnyHit) surfaceHit(cells, cellHit, dir, *hit);
      return true;
    });
  };
  switch (m_spec.kind) {
    case IntersectorKind::Linear: return run(0.f, LinearIntersector{});
    case IntersectorKind::Neubauer: return run(0.f, NeubauerIntersector{m_spec.iterations});
    case IntersectorKind::Schwarze: return run(0.f, SchwarzeIntersector{});
    case IntersectorKind::Isolation: return run(0.f, IsolationIntersector{m_spec.iterations});
    case IntersectorKind::Reference: return run(0.0, ReferenceIntersector{});
  }
  return false;
}

template <bool AnyHit>
uint32_t IsoSurface::packetQuery(Vec3i lo, Vec3i hi, const CellClasses* classes, Vec3i classOrigin,
                                 const PacketLane* lanes, uint32_t mask, SurfaceHit* hits, TraversalStats& stats) const {
  uint32_t found = 0;
  // Double precision, or a clipped surface (whose caps and spans are the scalar query's): lane by lane.
  if (m_spec.kind == IntersectorKind::Reference || !m_clip.empty()) {
    for (uint32_t rest = mask; rest; rest &= rest - 1) {
      const int l = __builtin_ctz(rest);
      const PacketLane& r = lanes[l];
      const bool yes = query<AnyHit>(lo, hi, classes, classOrigin, r.org, r.dir, r.tnear, r.tfar,
                                     AnyHit ? nullptr : &hits[l], stats, r.start, r.cache, r.tstop);
      found |= uint32_t(yes) << l;
    }
    return found;
  }
  ++stats.packetQueries;
  stats.packetLanes += uint64_t(laneCount(mask));
  auto run = [&](const auto& solver) {
    return withCellAccess(m_grid, classes, classOrigin, [&](const auto& cells) {
      using Cells = std::decay_t<decltype(cells)>;
      LaneSlots<GridRayCache> local;  // for lanes without a cache of their own
      LaneSlots<CellWalk<float, Cells>> walks;
      LaneSlots<CellHit<float>> cellHits;
      uint32_t live = 0;
      for (uint32_t rest = mask; rest; rest &= rest - 1) {
        const int l = __builtin_ctz(rest);
        const PacketLane& r = lanes[l];
            GridRayCache& c = r.cache ? *r.cache : local.emplace(l);
        floatQueryRay(r.org, r.dir, r.tnear, r.tfar, r.start, c);
        CellWalk<float, Cells>& walk = walks.emplace(l, cells, float(m_iso), c.ray, lo, hi, float(r.tnear),
                                                     float(r.tfar), r.start, &c.exact, float(r.tstop));
        if (walk.begin()) {
          live |= 1u << l;
          cellHits.emplace(l);
        }
      }
      const uint32_t yes = traversePacket<AnyHit>(walks.data(), live, solver, cellHits.data(), stats);
      if constexpr (!AnyHit)
        for (uint32_t rest = yes; rest; rest &= rest - 1) {
          const int l = __builtin_ctz(rest);
          surfaceHit(cells, cellHits[l], lanes[l].dir, hits[l]);
        }
      return yes;
    });
  };
  switch (m_spec.kind) {
    case IntersectorKind::Linear: return run(LaneByLane<LinearIntersector>{{}});
    case IntersectorKind::Neubauer: return run(LaneByLane<NeubauerIntersector>{{m_spec.iterations}});
    case IntersectorKind::Schwarze: return run(LaneByLane<SchwarzeIntersector>{{}});
    case IntersectorKind::Isolation: return run(IsolationPacket{m_spec.iterations});
    case IntersectorKind::Reference: break;
  }
  return 0;
}

uint32_t IsoSurface::intersectBrickPacket(uint32_t primitive, const PacketLane* lanes, uint32_t mask, SurfaceHit* hits,
                                          TraversalStats& stats) const {
  const Primitive& p = m_primitives[primitive];
  return packetQuery<false>(p.lo, p.hi, &m_cellClasses[primitive], p.brickOrigin, lanes, mask, hits, stats);
}

uint32_t IsoSurface::occludedBrickPacket(uint32_t primitive, const PacketLane* lanes, uint32_t mask,
                                         TraversalStats& stats) const {
  const Primitive& p = m_primitives[primitive];
  return packetQuery<true>(p.lo, p.hi, &m_cellClasses[primitive], p.brickOrigin, lanes, mask, nullptr, stats);
}

bool IsoSurface::intersectBrick(uint32_t primitive, const Vec3d& org, const Vec3d& dir, double tnear,
                                double tfar, SurfaceHit& hit, TraversalStats& stats,
                                StartClass start, GridRayCache* cache, double tstop) const {
  const Primitive& p = m_primitives[primitive];
  return query<false>(p.lo, p.hi, &m_cellClasses[primitive], p.brickOrigin, org, dir,
                      tnear, tfar, &hit, stats, start, cache, tstop);
}

bool IsoSurface::occludedBrick(uint32_t primitive, const Vec3d& org, const Vec3d& dir, double tnear,
                               double tfar, TraversalStats& stats, StartClass start,
                               GridRayCache* cache) const {
  const Primitive& p = m_primitives[primitive];
  return query<true>(p.lo, p.hi, &m_cellClasses[primitive], p.brickOrigin, org, dir,
                     tnear, tfar, nullptr, stats, start, cache);
}

// Without Embree: one DDA over the whole grid. Cells are skipped by their corners alone, so
// this gives the same answers as the brick path (a test checks it bit for bit).
bool IsoSurface::intersect(const Vec3d& org, const Vec3d& dir, double tnear, double tfar,
                           SurfaceHit& hit, TraversalStats& stats, StartClass start) const {
  const Vec3i d = m_grid.dims();
  return query<false>({0, 0, 0}, {d.x - 1, d.y - 1, d.z - 1}, nullptr, {}, org, dir, tnear, tfar, &hit, stats, start);
}

uint32_t IsoSurface::intersectPacket(const PacketLane* lanes, uint32_t mask, SurfaceHit* hits,
                                     TraversalStats& stats) const {
  const Vec3i d = m_grid.dims();
  return packetQuery<false>({0, 0, 0}, {d.x - 1, d.y - 1, d.z - 1}, nullptr, {}, lanes, mask, hits, stats);
}

bool IsoSurface::occluded(const Vec3d& org, const Vec3d& dir, double tnear, double tfar,
                          TraversalStats& stats, StartClass start) const {
  const Vec3i d = m_grid.dims();
  return query<true>({0, 0, 0}, {d.x - 1, d.y - 1, d.z - 1}, nullptr, {}, org, dir, tnear, tfar, nullptr, stats, start);
}

bool IsoSurface::crossesAtInactiveStart(const Vec3d& org, const Vec3d& dir, double tnear,
                                        double tfar, StartClass start, SurfaceHit* hit,
                                        TraversalStats& stats) const {
  if (start == StartClass::Unknown || !(tnear <= tfar)) return false;
  if (!m_clip.empty()) {
    // A ray from the solid starts in the kept region (clipSpan), unless it lies past it: then it
    // leaves the solid at once. A ray from outside the solid that starts outside the region
    // meets the solid only at a cap, which the brick queries find.
    double k0, k1;
    int plane0, plane1;
    m_clip.extent(org, dir, k0, k1, plane0, plane1);
    if (start != m_air) {
      if (!(tnear <= k1)) {
        if (hit) capHit(org, dir, tnear, plane1, false, *hit);
        return true;
      }
    } else if (!(k0 <= tnear && tnear <= k1)) {
      return false;
    }
  }
  // The common case first, in double: a start well inside the tight box of an active brick
  // (a ray leaving the surface starts next to its hit, in a surface cell). Its margin is four
  // times the rounding of the float grid ray below, so that ray's start cell lies in that box
  // too, and the answer is the same.
  const Vec3d o = (org - m_grid.origin()) / m_grid.spacing(), d = dir / m_grid.spacing();
  const Vec3d p = o + d * tnear;
  const Vec3i dims = m_grid.dims();
  if (p.x >= 0 && p.y >= 0 && p.z >= 0 && p.x < dims.x - 1 && p.y < dims.y - 1 && p.z < dims.z - 1) {
    const double margin = 1e-6 * (std::max({std::fabs(o.x), std::fabs(o.y), std::fabs(o.z)}) +
                                  std::fabs(tnear) * std::max({std::fabs(d.x), std::fabs(d.y), std::fabs(d.z)}) + 1);
    const int32_t primitive = m_primitiveOf[m_bricks.brickOf(Vec3i{int(p.x), int(p.y), int(p.z)})];
    if (primitive >= 0 && m_primitives[primitive].holds(p, margin)) return false;
  }
  // The start cell as the traversal finds it: the cell of the start in double, in both
  // precisions (the float walk starts in its exact origin's cell, and a brick whose face its
  // float origin rounded onto but its exact one lies beyond does not start it: CellWalk::begin).
  const GridRay<double> ray = queryRay<double>(m_grid, org, dir, tnear, start);
  if (!ray.valid()) return false;
  Vec3i cell;
  bool inGrid = true;
  for (int a = 0; a < 3; ++a) {
    const double q = ray.org[a] + tnear * ray.dir[a];
    inGrid = inGrid && q >= 0 && q <= double(dims[a] - 1);
    if (inGrid) cell[a] = std::min(int(std::floor(q)), dims[a] - 2);
  }
  // Covered when the cell lies in the tight box of an active brick (Embree calls that
  // primitive for a ray starting inside its box); every other cell is seen by no query.
  if (!inGrid) return false;
  const uint32_t brick = m_bricks.brickOf(cell);
  const int32_t primitive = m_primitiveOf[brick];
  if (primitive >= 0 && m_primitives[primitive].contains(cell)) return false;
  // A window of the grid (a data-parallel rank's part) answers only in the bricks it holds (of
  // the others it has no range, BrickGrid): the rank holding the start cell's brick answers, as
  // the single process would.
  if (!(m_bricks.brickMin(brick) <= m_bricks.brickMax(brick))) return false;
  const Vec3i next{cell.x + 1, cell.y + 1, cell.z + 1};
  return hit ? query<false>(cell, next, nullptr, {}, org, dir, tnear, tfar, hit, stats, start)
             : query<true>(cell, next, nullptr, {}, org, dir, tnear, tfar, nullptr, stats, start);
}

void IsoSurface::setWorldToObject(const Transform& t) {
  m_worldToObject = t;
  m_instanced = !t.isIdentity();
  if (!m_instanced) {
    m_boundsPad = 0;
    return;
  }
  // The grid's corners in world space bound the magnitude of world coordinates near it; a
  // float rounds them by 2^-24 of that (several times over in Embree's transform), and the
  // object-space size of such an error is at most that times the inverse's row sums.
  const Transform toWorld = t.inverse();
  const Vec3i d = m_grid.dims();
  double worldScale = 0;
  for (int c = 0; c < 8; ++c) {
    const Vec3d corner = m_grid.origin() + Vec3d{double(c & 1 ? d.x - 1 : 0), double(c & 2 ? d.y - 1 : 0),
                                                 double(c & 4 ? d.z - 1 : 0)} * m_grid.spacing();
    const Vec3d w = toWorld.point(corner);
    worldScale = std::max({worldScale, std::fabs(w.x), std::fabs(w.y), std::fabs(w.z)});
  }
  const Vec3d rows = t.absRowSums();
  m_boundsPad = 16 * 0x1p-24 * worldScale * std::max({rows.x, rows.y, rows.z});
}

void IsoSurface::primitiveBounds(uint32_t primitive, float lower[3], float upper[3]) const {
  const Vec3i c0 = m_primitives[primitive].lo, c1 = m_primitives[primitive].hi;
  const Vec3d o = m_grid.origin(), s = m_grid.spacing();
  for (int a = 0; a < 3; ++a) {
    const double lo = o[a] + c0[a] * s[a], hi = o[a] + c1[a] * s[a];
    // Outward by a relative margin: Embree's box tests are not exact, the brick clip is.
    const double pad = 1e-5 * (hi - lo) + 1e-6 * std::max(std::fabs(lo), std::fabs(hi)) + m_boundsPad;
    lower[a] = std::nextafter(float(lo - pad), -INFINITY);
    upper[a] = std::nextafter(float(hi + pad), INFINITY);
  }
}

namespace {

void boundsCallback(const RTCBoundsFunctionArguments* args) {
  const auto* surface = static_cast<const IsoSurface*>(args->geometryUserPtr);
  float lo[3], hi[3];
  surface->primitiveBounds(args->primID, lo, hi);
  args->bounds_o->lower_x = lo[0]; args->bounds_o->lower_y = lo[1]; args->bounds_o->lower_z = lo[2];
  args->bounds_o->upper_x = hi[0]; args->bounds_o->upper_y = hi[1]; args->bounds_o->upper_z = hi[2];
}

// Embree calls these with the rays of one query: N = 1 for rtcIntersect1 / rtcOccluded1, and
// for rtcIntersect8 / rtcOccluded8 the whole packet (N = 8, lane i of the context for ray i,
// inactive lanes cleared in `valid`). Each lane is walked by the same scalar query as a single
// ray, so a ray's answer does not depend on the packet it travels in.
// A lane's ray as the iso-surface queries take it: in object space, in double, from the world
// ray World put in the lane, with the lane's own far end.
IsoSurface::PacketLane packetLane(const IsoSurface& surface, IsoRayLane& lane, RTCRayN* rays, unsigned N, unsigned i) {
  IsoSurface::PacketLane r;
  r.org = lane.origin ? surface.objectOrigin(*lane.origin)
                      : Vec3d{RTCRayN_org_x(rays, N, i), RTCRayN_org_y(rays, N, i), RTCRayN_org_z(rays, N, i)};
  r.dir = lane.origin ? surface.objectDirection(lane.direction)
                      : Vec3d{RTCRayN_dir_x(rays, N, i), RTCRayN_dir_y(rays, N, i), RTCRayN_dir_z(rays, N, i)};
  r.tnear = RTCRayN_tnear(rays, N, i);
  r.tfar = lane.tfar;
  r.start = lane.startSurface == &surface ? lane.start : StartClass::Unknown;
  r.cache = &lane.gridRay;
  return r;
}

// Embree calls these with the rays of one query: N = 1 for rtcIntersect1 / rtcOccluded1, and
// for rtcIntersect8 / rtcOccluded8 the whole packet (N = 8, lane i of the context for ray i,
// inactive lanes cleared in `valid`), whose lanes are walked together (intersectBrickPacket).
// A lane gets the answer its ray would get alone.
void intersectCallback(const RTCIntersectFunctionNArguments* args) {
  const auto* surface = static_cast<const IsoSurface*>(args->geometryUserPtr);
  auto* context = reinterpret_cast<IsoRayContext*>(args->context);
  const unsigned N = args->N;
  RTCRayN* rays = RTCRayHitN_RayN(args->rayhit, N);
  RTCHitN* hits = RTCRayHitN_HitN(args->rayhit, N);
  LaneSlots<IsoSurface::PacketLane> lanes;
  LaneSlots<SurfaceHit> found;
  uint32_t mask = 0;
  for (unsigned i = 0; i < std::min(N, unsigned(kPacketLanes)); ++i) {  // World traces 1 or 8 rays at once
    if (!args->valid[i]) continue;
    lanes.emplace(int(i), packetLane(*surface, context->lanes[i], rays, N, i)).tstop = RTCRayN_tfar(rays, N, i);
    found.emplace(int(i));
    mask |= 1u << i;
  }
  if (N == 1) {
    mask = mask && surface->intersectBrick(args->primID, lanes[0].org, lanes[0].dir, lanes[0].tnear, lanes[0].tfar,
                                           found[0], context->stats, lanes[0].start, lanes[0].cache, lanes[0].tstop);
  } else {
    mask = surface->intersectBrickPacket(args->primID, lanes.data(), mask, found.data(), context->stats);
  }
  for (; mask; mask &= mask - 1) {
    const unsigned i = unsigned(__builtin_ctz(mask));
    const SurfaceHit& hit = found[i];
    float& tfar = RTCRayN_tfar(rays, N, i);
    const float t = float(hit.t);
    if (!(t >= RTCRayN_tnear(rays, N, i) && t <= tfar)) continue;
    IsoRayLane& lane = context->lanes[i];
    // A tie in float t (a close pair of crossings on both sides of a brick seam, each brick
    // reporting one at the seam): the hit of the cell first along the ray wins, whatever order
    // Embree visits the bricks in. Keeping the later one carried the wrong class past the pair
    // (a parity error at 1e6 rays, tests/data/exactness/real_example4d.failures.txt).
    // (Caps of several surfaces on one plane tie in t and segment start: the lowest order wins.)
    if (t == tfar && !(hit.segmentStart < lane.segmentStart ||
                       (hit.segmentStart == lane.segmentStart && surface->order() < lane.order)))
      continue;
    tfar = t;
    RTCHitN_Ng_x(hits, N, i) = hit.normal.x;
    RTCHitN_Ng_y(hits, N, i) = hit.normal.y;
    RTCHitN_Ng_z(hits, N, i) = hit.normal.z;
    RTCHitN_u(hits, N, i) = 0;
    RTCHitN_v(hits, N, i) = 0;
    RTCHitN_primID(hits, N, i) = args->primID;
    RTCHitN_geomID(hits, N, i) = args->geomID;
    for (unsigned l = 0; l < RTC_MAX_INSTANCE_LEVEL_COUNT; ++l)
      RTCHitN_instID(hits, N, i, l) = args->context->instID[l];
    // float(t) rounds; the bound must cover that too. The double t keeps the precise hit.
    lane.tError = float(hit.tError + std::fabs(hit.t - double(t))) * (1 + 1e-6f);
    lane.t = hit.t;
    lane.insideAfter = hit.insideAfter;
    lane.segmentStart = hit.segmentStart;
    lane.cap = hit.cap;
    lane.order = surface->order();
  }
}

void occludedCallback(const RTCOccludedFunctionNArguments* args) {
  const auto* surface = static_cast<const IsoSurface*>(args->geometryUserPtr);
  auto* context = reinterpret_cast<IsoRayContext*>(args->context);
  const unsigned N = args->N;
  RTCRayN* rays = args->ray;
  LaneSlots<IsoSurface::PacketLane> lanes;
  uint32_t mask = 0;
  for (unsigned i = 0; i < std::min(N, unsigned(kPacketLanes)); ++i) {  // World traces 1 or 8 rays at once
    if (!args->valid[i]) continue;
    lanes.emplace(int(i), packetLane(*surface, context->lanes[i], rays, N, i));
    mask |= 1u << i;
  }
  if (N == 1) {
    mask = mask && surface->occludedBrick(args->primID, lanes[0].org, lanes[0].dir, lanes[0].tnear, lanes[0].tfar,
                                          context->stats, lanes[0].start, lanes[0].cache);
  } else {
    mask = surface->occludedBrickPacket(args->primID, lanes.data(), mask, context->stats);
  }
  for (; mask; mask &= mask - 1) RTCRayN_tfar(rays, N, unsigned(__builtin_ctz(mask))) = -INFINITY;
}

}  // namespace

RTCGeometry IsoSurface::createGeometry(RTCDevice device) const {
  RTCGeometry geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
  rtcSetGeometryUserPrimitiveCount(geometry, unsigned(m_active.size()));
  rtcSetGeometryUserData(geometry, const_cast<IsoSurface*>(this));
  rtcSetGeometryBoundsFunction(geometry, boundsCallback, nullptr);
  rtcSetGeometryIntersectFunction(geometry, intersectCallback);
  rtcSetGeometryOccludedFunction(geometry, occludedCallback);
  rtcCommitGeometry(geometry);
  return geometry;
}

}  // namespace iso
