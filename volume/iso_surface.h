#pragma once
// One iso-surface of one grid: the active bricks, ray queries with any intersector, and the
// Embree user geometry whose primitives are those bricks.
#include <embree3/rtcore.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "volume/bricks.h"
#include "volume/clip.h"
#include "volume/transform.h"
#include "volume/traversal.h"

namespace iso {

struct SurfaceHit {
  double t = 0;
  double tError = 0;   // |t - true t| <= tError (see Root::sError)
  Vec3f normal;        // world space, unit, pointing to lower values (out of "inside")
  bool tangent = false;
  bool insideAfter = false;  // the class (value > iso) just past the hit, along the ray
  // Where the hit's cell segment begins (t along the ray): of two hits at the same float t
  // (a close pair on both sides of a brick seam), the one from the earlier cell comes first.
  double segmentStart = 0;
  bool cap = false;  // a clipped surface's cap: the hit lies on a clip plane (the normal is its normal)
};

// A clipped surface's view of one ray (IsoSurface::clipSpan): the extent of the query the clip
// region keeps, and where the ray enters that region inside the grid, the class there. Every
// brick query of the ray reads the same span, so they all agree on where caps are.
struct ClipSpan {
  enum class Kind : signed char {
    Empty,         // nothing of the query's extent is kept (and it does not start in the solid)
    CrossAtStart,  // the ray starts in the solid but past the kept region: it leaves the solid at tnear
    Walk,          // walk [tnear, tfar]
  };
  Kind kind = Kind::Walk;
  double tnear = 0, tfar = 0;
  // The ray enters the kept region at tnear inside the grid: its walk starts in `startCell`
  // in `startClass` (the field's class there, in double), with a cap there if that is the solid.
  bool enters = false;
  Vec3i startCell;
  StartClass startClass = StartClass::Unknown;
  // The kept region ends at tfar before the query's end: a cap there if the walk reaches it in
  // the solid.
  bool leaves = false;
  int plane0 = -1, plane1 = -1;  // the clip planes at tnear (enters) and tfar (leaves, CrossAtStart)
};

class IsoSurface;
// The ray of one Embree query in a surface's grid coordinates: the same for every brick of that
// surface the query visits (its origin, direction, extent and start class do not change), so it
// is computed once per ray instead of once per brick, and the brick walks read it in place.
struct GridRayCache {
  // The three below are left unwritten until IsoSurface::floatQueryRay sets `surface` and writes
  // them (clip where the surface is clipped): a lane is set up for every ray traced in a scene
  // with iso-surfaces, and most rays never reach a brick.
  GridRayCache() {}
  const IsoSurface* surface = nullptr;  // the surface whose grid the rest is in; none yet: null
  union { GridRay<float> ray; };        // what the float traversal walks
  union { ExactEnds exact; };  // the same ray in double with its extent: the float traversal's exact ends
  union { ClipSpan clip; };    // a clipped surface's span of the ray
  // A ray leaving a cap: the clip region whose boundary its origin lies on (a spawn offset
  // inside it). Another surface clipped by the same region that the ray meets in its solid
  // right there has its cap at the start too (two solids cut by one plane: the ray that goes
  // through the first one's cap, a thin sheet, enters the second one's solid there).
  const ClipRegion* capClip = nullptr;
  int capOrder = -1;  // IsoSurface::order() of the surface whose cap the ray leaves
};
// What the iso-surface callbacks know of one ray of a query, and what they write back: lane i
// of a packet traced by rtcIntersect8 / rtcOccluded8 (World::intersectPacket), or the one ray
// of rtcIntersect1. Embree carries no per-hit error bound, so rays are traced with an extended
// context (Embree's documented pattern for passing data to callbacks) holding these lanes.
struct IsoRayLane {
  // The ray in world space, in double (set by World for every ray it traces): rays spawned from
  // an iso-surface hit far from the world origin keep the precision a float origin would lose
  // (at 1e5 a float is exact to 1/128 only); queries map it to object space themselves, in
  // double, so that they depend neither on Embree's float instance transform nor on how its
  // packet and single-ray kernels round it.
  const Vec3d* origin = nullptr;
  Vec3d direction;
  // The ray's far end as traced. Every brick's cells are cut at it, not at the closest hit found
  // so far, so that a hit (its t, its error bound, its normal) does not depend on the order in
  // which Embree visits bricks and triangles, which differs between packets and single rays.
  float tfar = INFINITY;
  // A ray spawned from a hit on `startSurface` starts in the class `start` there (StartClass in
  // volume/traversal.h).
  const IsoSurface* startSurface = nullptr;
  StartClass start = StartClass::Unknown;
  double t = 0;       // the accepted iso-surface hit, in double
  float tError = 0;
  bool insideAfter = false;
  // Where the accepted hit's cell segment begins: bricks are visited in Embree's order, and of
  // two hits at the same float t the one of the cell first along the ray is kept (see
  // SurfaceHit::segmentStart). None yet: infinity.
  double segmentStart = INFINITY;
  bool cap = false;
  int order = std::numeric_limits<int>::max();  // IsoSurface::order() of the accepted hit
  GridRayCache gridRay;
};
struct IsoRayContext {
  RTCIntersectContext embree;
  IsoRayLane* lanes;  // as many as the query's rays
  TraversalStats stats;
  explicit IsoRayContext(IsoRayLane* laneData) : lanes(laneData) { rtcInitIntersectContext(&embree); }
};

class IsoSurface {
 public:
  // `clip` (in the grid's object space, the space of its origin and spacing): the surface is the
  // boundary of the solid (value > iso if `solidAbove`, else value < iso) within the clip region,
  // closed by caps on the clip planes where they pass through the solid. A region that keeps
  // the whole grid is dropped (it costs nothing).
  IsoSurface(const Grid& grid, const BrickGrid& bricks, double iso, IntersectorSpec spec,
             const ClipRegion& clip = {}, bool solidAbove = true);

  double iso() const { return m_iso; }
  const IntersectorSpec& intersector() const { return m_spec; }
  const Grid& grid() const { return m_grid; }
  const std::vector<uint32_t>& activeBricks() const { return m_active; }
  const ClipRegion& clip() const { return m_clip; }
  // The surface's place in its scene (World sets it): of hits at the same t from the same cell
  // segment start (caps of several surfaces on one clip plane), the lowest order wins, and a
  // ray leaving a cap meets the caps there of the surfaces after it only (GridRayCache::capClip).
  void setOrder(int order) { m_order = order; }
  int order() const { return m_order; }
  bool solidAbove() const { return m_air == StartClass::Outside; }
  size_t totalBricks() const { return m_bricks.size(); }

  // Queries on a world-space ray over the whole grid, without Embree (tests, benchmarks,
  // the reference path). `start`: the class at tnear when the ray continues from a hit of
  // this surface (a restart past the hit: StartClass of hit.insideAfter).
  bool intersect(const Vec3d& org, const Vec3d& dir, double tnear, double tfar, SurfaceHit& hit,
                 TraversalStats& stats, StartClass start = StartClass::Unknown) const;
  bool occluded(const Vec3d& org, const Vec3d& dir, double tnear, double tfar,
                TraversalStats& stats, StartClass start = StartClass::Unknown) const;
  // The same on one active brick, activeBricks()[primitive], as Embree calls it.
  // `cache`, if given, holds the float grid ray of the same query across bricks.
  // `tstop` (closest hits): a hit past it is of no use (a closer one is known); the walk may end
  // there, the hit it finds before it is the same.
  bool intersectBrick(uint32_t primitive, const Vec3d& org, const Vec3d& dir, double tnear,
                      double tfar, SurfaceHit& hit, TraversalStats& stats,
                      StartClass start = StartClass::Unknown, GridRayCache* cache = nullptr,
                      double tstop = INFINITY) const;
  bool occludedBrick(uint32_t primitive, const Vec3d& org, const Vec3d& dir, double tnear,
                     double tfar, TraversalStats& stats, StartClass start = StartClass::Unknown,
                     GridRayCache* cache = nullptr) const;
  // Lanes of an Embree packet on one brick (the callbacks with N > 1): for each lane l in `mask`
  // (at most 8 lanes), what intersectBrick / occludedBrick give that lane alone, bit for bit; bit
  // l of the result is set when lane l found a crossing. The lanes are walked together, each to
  // its next cell to solve, and those cells solved together (volume/packet_walk.h).
  struct PacketLane {
    Vec3d org, dir;
    double tnear = 0, tfar = 0;
    double tstop = INFINITY;  // as intersectBrick's
    StartClass start = StartClass::Unknown;
    GridRayCache* cache = nullptr;
  };
  uint32_t intersectBrickPacket(uint32_t primitive, const PacketLane* lanes, uint32_t mask, SurfaceHit* hits,
                                TraversalStats& stats) const;
  uint32_t occludedBrickPacket(uint32_t primitive, const PacketLane* lanes, uint32_t mask, TraversalStats& stats) const;
  // The same over the whole grid without Embree (as intersect()): `isotrace bench --ray-flow wavefront`.
  uint32_t intersectPacket(const PacketLane* lanes, uint32_t mask, SurfaceHit* hits, TraversalStats& stats) const;
  // With bricks, a ray that starts in an inactive brick has its first cell seen by no brick
  // query (inactive bricks are no Embree primitives). When its start class is given and that
  // brick lies strictly on the other side, the crossing is at the start: true, and `hit` (if
  // not null) is that crossing at tnear.
  bool crossesAtInactiveStart(const Vec3d& org, const Vec3d& dir, double tnear, double tfar,
                              StartClass start, SurfaceHit* hit, TraversalStats& stats) const;

  // Where the surface is placed when its geometry is instanced: world -> object space, for
  // the double-precision origin of IsoRayContext. Identity by default.
  // It also widens the brick bounds: Embree transforms the float world ray into object space,
  // carrying the rounding of world coordinates (about 1e-7 of their size: 0.008 at 1e5)
  // into bricks whose own coordinates are small.
  void setWorldToObject(const Transform& t);
  Vec3d objectOrigin(const Vec3d& world) const { return m_instanced ? m_worldToObject.point(world) : world; }
  Vec3d objectDirection(const Vec3d& world) const { return m_instanced ? m_worldToObject.vector(world) : world; }

  // A user geometry (one primitive per active brick) attached to nothing; the caller owns it.
  RTCGeometry createGeometry(RTCDevice device) const;
  // World-space bounds of primitive `primitive` (the tight box of activeBricks()[primitive]),
  // rounded outwards.
  void primitiveBounds(uint32_t primitive, float lower[3], float upper[3]) const;
  // Cells of primitive `primitive` that are not uniform: each holds a piece of the surface
  // (light sampling weighs the bricks of an emissive surface by it).
  uint32_t surfaceCells(uint32_t primitive) const { return m_primitives[primitive].surfaceCells; }
  // Memory of the primitives' records and class tables (Embree's BVH comes on top).
  size_t bytes() const {
    return m_primitives.size() * (sizeof(Primitive) + sizeof(CellClasses)) + m_primitiveOf.size() * sizeof(int32_t);
  }

 private:
  template <bool AnyHit>
  bool query(Vec3i lo, Vec3i hi, const CellClasses* classes, Vec3i classOrigin, const Vec3d& org,
             const Vec3d& dir, double tnear, double tfar, SurfaceHit* hit, TraversalStats& stats,
             StartClass start, GridRayCache* cache = nullptr, double tstop = INFINITY) const;
  template <bool AnyHit>
  uint32_t packetQuery(Vec3i lo, Vec3i hi, const CellClasses* classes, Vec3i classOrigin, const PacketLane* lanes,
                       uint32_t mask, SurfaceHit* hits, TraversalStats& stats) const;
  // The float grid ray of a query and the double one's ends, in `cache` (unless it holds them):
  // true if it was computed now.
  bool floatQueryRay(const Vec3d& org, const Vec3d& dir, double tnear, double tfar, StartClass start,
                     GridRayCache& cache) const;
  // A clipped surface's span of a query (`ray`: the grid ray the walk takes; `exactOrg`/`exactDir`:
  // the same in double).
  // `onCap`: the ray leaves a cap of another surface clipped by this one's region (GridRayCache::capClip).
  template <typename Real, typename Cells>
  ClipSpan clipSpan(const Cells& cells, const GridRay<Real>& ray, const Vec3d& exactOrg, const Vec3d& exactDir,
                    const Vec3d& org, const Vec3d& dir, double tnear, double tfar, StartClass start, bool onCap) const;
  // A cap at t on clip plane `plane`, leaving the ray in the solid (`intoSolid`) or out of it.
  void capHit(const Vec3d& org, const Vec3d& dir, double t, int plane, bool intoSolid, SurfaceHit& hit) const;
  // A cell hit as a world-space SurfaceHit (the normal from the cell's gradient).
  template <typename Real, typename Cells>
  void surfaceHit(const Cells& cells, const CellHit<Real>& cellHit, const Vec3d& dir, SurfaceHit& hit) const;

  const Grid& m_grid;
  const BrickGrid& m_bricks;
  double m_iso;
  IntersectorSpec m_spec;
  // Per active brick: the box of its cells that are not uniform (the only cells that can hold
  // or touch the surface), its first cell, and which of its cells are uniform.
  struct Primitive {
    Vec3i lo, hi;  // tight box: cells [lo, hi)
    Vec3i brickOrigin;
    uint32_t surfaceCells = 0;
    bool contains(const Vec3i& c) const {
      return c.x >= lo.x && c.y >= lo.y && c.z >= lo.z && c.x < hi.x && c.y < hi.y && c.z < hi.z;
    }
    // A point of grid space at least `margin` inside the box.
    bool holds(const Vec3d& p, double margin) const {
      for (int a = 0; a < 3; ++a)
        if (!(p[a] >= lo[a] + margin && p[a] <= hi[a] - margin)) return false;
      return true;
    }
  };
  std::vector<uint32_t> m_active;
  std::vector<int32_t> m_primitiveOf;  // per brick: index into m_primitives, or -1
  std::vector<Primitive> m_primitives;
  std::vector<CellClasses> m_cellClasses;
  ClipRegion m_clip;
  StartClass m_air = StartClass::Outside;  // the class outside the solid (and the clip region)
  int m_order = 0;
  Transform m_worldToObject;
  bool m_instanced = false;
  double m_boundsPad = 0;  // extra object-space padding of brick bounds for instances
};

}  // namespace iso
