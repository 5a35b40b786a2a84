#pragma once
// Ray traversal of a box of cells (one brick, or the whole grid): slab clipping, then a
// 3D-DDA (Amanatides & Woo 1987) that skips cells whose corners all lie on one side.
//
// Why no cracks: every segment boundary is a plane crossing t = planeT(axis, k), computed by
// one function, so the exit t of a cell (or brick) is the entry t of the next bit for bit.
// At that t the coordinate on the crossed axis is set exactly to the face (0 or 1), the others
// are computed from t the same way on both sides, and trilinear() at local 0 and 1 reduces
// exactly to the shared face's bilinear value. So f1 of one cell is f0 of the next, each
// crossing is counted in exactly one cell, and the sign sequence along a ray telescopes.
#include <cmath>
#include <type_traits>
#include <limits>

#include "volume/grid.h"
#include "volume/intersectors.h"

// The cell walk's steps are inlined into the loop that drives them (traverseCells, traversePacket):
// called out of line from two places, GCC stopped inlining them, and the scalar walk lost ~15%.
#define ISO_INLINE [[gnu::always_inline]] inline

namespace iso {

// A ray in grid coordinates (sample (i, j, k) at point (i, j, k)); t is the world ray's t.
template <typename Real>
struct GridRay {
  Vec3<Real> org, dir, invDir;
  GridRay() = default;
  GridRay(const Vec3<Real>& o, const Vec3<Real>& d)
      : org(o), dir(d), m_valid(isFinite(o) && isFinite(d) && !(d == Vec3<Real>{0, 0, 0})) {
    for (int a = 0; a < 3; ++a) invDir[a] = Real(1) / d[a];
  }
  Real planeT(int axis, int k) const { return (Real(k) - org[axis]) * invDir[axis]; }
  // Finite, with a direction: decided once per ray (a query per brick only reads it).
  bool valid() const { return m_valid; }

 private:
  bool m_valid = false;
};

// Maps a world-space ray to grid coordinates. Done in double so that a grid placed far from
// the origin (1e5) keeps its local precision once the origin is subtracted.
template <typename Real>
inline GridRay<Real> toGridRay(const Grid& grid, const Vec3d& org, const Vec3d& dir) {
  const Vec3d o = (org - grid.origin()) / grid.spacing();
  const Vec3d d = dir / grid.spacing();
  return GridRay<Real>(Vec3<Real>(o), Vec3<Real>(d));
}

// The query's ray in double (grid coordinates, as GridRay<double> holds it), its extent and the
// iso value in double. A float traversal takes the class at the ends of the ray's extent in
// the grid from it (see exactEndClass): where the ray starts inside the grid without a given
// class, enters the grid through its boundary, leaves it through its boundary, or ends at
// tfar. Faces between cells keep the float values both cells compute alike.
struct ExactEnds {
  Vec3d org, dir;
  double iso = 0, tnear = 0, tfar = 0;
};

struct TraversalStats {
  uint64_t cellsVisited = 0;  // cells the DDA stepped through
  uint64_t cellsSolved = 0;   // cells whose corners straddle the iso value
  uint64_t rootsRefined = 0;  // crossings located (closest-hit queries only)
  // Packet queries (volume/packet_walk.h): brick queries of a packet, their lanes, steps (every
  // live lane on to its next cell to solve; `lockstepSteps`, named when a step was one cell per
  // lane), and the steps with cells to solve and how many lanes solved in them: how full the
  // lanes the vector code works on are.
  uint64_t packetQueries = 0, packetLanes = 0, lockstepSteps = 0, solveSteps = 0, solveLanes = 0;
  // Every counter, in order (to sum or send them all).
  static constexpr int kFields = 8;
  template <typename F>
  void forEach(F&& f) {
    for (uint64_t* v : {&cellsVisited, &cellsSolved, &rootsRefined, &packetQueries, &packetLanes, &lockstepSteps,
                        &solveSteps, &solveLanes})
      f(*v);
  }
  // (Written out: every ray's query adds its counters, and the generic loop cost ~50
  // instructions a ray.)
  void add(const TraversalStats& o) {
    cellsVisited += o.cellsVisited;
    cellsSolved += o.cellsSolved;
    rootsRefined += o.rootsRefined;
    packetQueries += o.packetQueries;
    packetLanes += o.packetLanes;
    lockstepSteps += o.lockstepSteps;
    solveSteps += o.solveSteps;
    solveLanes += o.solveLanes;
  }
};

template <typename Real>
struct CellHit {
  Real t = 0;
  Real tError = 0;
  Vec3i cell;
  Vec3<Real> local;   // cell-local hit coordinates
  bool tangent = false;
  bool insideAfter = false;  // the class (value > iso) the ray is in just past the hit
  Real segmentStart = 0;     // t where the hit's cell segment begins
};

// The class a query starts in when the caller knows it. A ray that continues from a hit on
// this surface (a spawned ray, or a restart past the hit) is in the class the hit's crossing
// led to, or back in the one it came from (a reflection). Evaluating the field at the new
// origin instead is unreliable exactly where it matters: next to a close pair of crossings the
// values there are below rounding, and a spawn offset can step over the second crossing. With
// the class given, a query that finds the field on the other side right at its start reports
// a crossing there (t ~ tnear), so the classes along a chain of rays telescope like those
// along one ray: the number of hits has the parity of the classes at the chain's two ends.
enum class StartClass : signed char { Unknown = 0, Outside = -1, Inside = 1 };

// The class of every cell of one brick (BrickGrid::kCells^3 cells): bit (y * 8 + x) of word z
// of `positive` / `negative` is set when all 8 corners of cell (x, y, z) of the brick lie
// strictly above / below the iso value, in float and in double alike. The traversal steps over
// such a cell on two bit tests, without loading its corners; every other cell takes the full
// path, so the answers are the same bits as without the table.
struct CellClasses {
  uint64_t positive[8] = {};
  uint64_t negative[8] = {};
};

// The class table of the brick being traversed, if any: +1 all corners strictly inside, -1
// all strictly outside, 0 unknown (load them).
struct BrickClassLookup {
  const CellClasses* classes = nullptr;  // of the brick whose first cell is `classOrigin`
  Vec3i classOrigin;
  int uniformClass(const Vec3i& c) const {
    if (!classes) return 0;
    const int x = c.x - classOrigin.x, y = c.y - classOrigin.y, z = c.z - classOrigin.z;
    const uint64_t bit = uint64_t(1) << (y * 8 + x);
    return (classes->positive[z] & bit) ? 1 : (classes->negative[z] & bit) ? -1 : 0;
  }
};

// A dense grid's cells read in its own sample type (a template parameter, so that the fetch of
// the 8 corners is inlined into the traversal, without a switch per cell).
template <typename Sample>
struct CellAccess : BrickClassLookup {
  const Sample* data = nullptr;
  Vec3i dims;             // the whole grid's
  size_t ey = 0;          // samples held along y (a window's, Grid::windowExtent)
  size_t sy = 0, sz = 0;  // strides of y and z, in samples
  size_t shift = 0;       // the index the window's first sample would have without the window

  CellAccess(const Grid& grid, const Sample* samples, const CellClasses* brickClasses = nullptr,
             Vec3i brickOrigin = {})
      : BrickClassLookup{brickClasses, brickOrigin}, data(samples), dims(grid.dims()),
        ey(size_t(grid.windowExtent().y)), sy(size_t(grid.windowExtent().x)), sz(sy * ey),
        shift((size_t(grid.windowFirst().z) * ey + size_t(grid.windowFirst().y)) * sy + size_t(grid.windowFirst().x)) {}

  // Corner c = bit0 x, bit1 y, bit2 z; values minus the iso value. Every sample type converts
  // to float exactly, and float to double, so all precisions see the same corner values.
  template <typename Real>
  void load(const Vec3i& c, Real iso, Real g[8]) const {
    const Sample* p = data + ((size_t(c.z) * ey + size_t(c.y)) * sy + size_t(c.x) - shift);
    g[0] = Real(float(p[0])) - iso;
    g[1] = Real(float(p[1])) - iso;
    g[2] = Real(float(p[sy])) - iso;
    g[3] = Real(float(p[sy + 1])) - iso;
    g[4] = Real(float(p[sz])) - iso;
    g[5] = Real(float(p[sz + 1])) - iso;
    g[6] = Real(float(p[sz + sy])) - iso;
    g[7] = Real(float(p[sz + sy + 1])) - iso;
  }
};

// A sparse grid's cells: the 8 corners from the cell's brick block (or its one value), the
// same bits a dense copy of the grid would give.
struct SparseCellAccess : BrickClassLookup {
  const SparseSamples* sparse;
  Vec3i dims;

  SparseCellAccess(const Grid& grid, const CellClasses* brickClasses = nullptr, Vec3i brickOrigin = {})
      : BrickClassLookup{brickClasses, brickOrigin}, sparse(grid.sparse()), dims(grid.dims()) {}

  template <typename Real>
  void load(const Vec3i& c, Real iso, Real g[8]) const {
    constexpr size_t k = SparseSamples::kBlock;
    const int32_t slot = sparse->slotOf(c.x >> 3, c.y >> 3, c.z >> 3);
    if (slot < 0) {
      const Real v = Real(sparse->uniformValue(slot)) - iso;
      for (int i = 0; i < 8; ++i) g[i] = v;
      return;
    }
    const float* p = sparse->block(slot) + (size_t(c.z & 7) * k + size_t(c.y & 7)) * k + size_t(c.x & 7);
    g[0] = Real(p[0]) - iso;
    g[1] = Real(p[1]) - iso;
    g[2] = Real(p[k]) - iso;
    g[3] = Real(p[k + 1]) - iso;
    g[4] = Real(p[k * k]) - iso;
    g[5] = Real(p[k * k + 1]) - iso;
    g[6] = Real(p[k * k + k]) - iso;
    g[7] = Real(p[k * k + k + 1]) - iso;
  }
};

// Calls f(cells) with the grid's cell access (CellAccess<its sample type>, or SparseCellAccess):
// the one switch per query.
template <typename F>
inline decltype(auto) withCellAccess(const Grid& grid, const CellClasses* classes, Vec3i origin, F&& f) {
  if (grid.sparse()) return f(SparseCellAccess(grid, classes, origin));
  return grid.visitSamples([&](const auto* samples) { return f(CellAccess(grid, samples, classes, origin)); });
}

// Where a segment's cubic ends exactly at zero (s = 1), the side it comes from: the sign of
// the first non-zero of -df, d2f, -d3f at s = 1; `flat` if the cubic is constant there. The
// cell's corner values `g` bound the field: a side they rule out (no corner above the iso value,
// yet "from inside"; none below, yet "from outside") is rounding noise in the coefficients, and
// counts as flat. Without that, two walks could decide the class at the same exact zero
// differently: one stepping over the cell on its corners alone, the next brick re-deriving it
// from a noise-level cubic (a root counted twice at 1e7 rays on hydrogen at iso 20,
// tests/data/exactness/real_hydrogen_20.failures.txt).
template <typename Real>
inline Real approachSide(const Cubic<Real>& c, const Real g[8], Real flat) {
  const Real d1 = c.c[1] + Real(2) * c.c[2] + Real(3) * c.c[3];
  const Real d2 = Real(2) * c.c[2] + Real(6) * c.c[3];
  const Real side = d1 != Real(0) ? -d1 : d2 != Real(0) ? d2 : c.c[3] != Real(0) ? -c.c[3] : flat;
  bool above = false, below = false;
  for (int i = 0; i < 8; ++i) {
    above = above || g[i] > Real(0);
    below = below || g[i] < Real(0);
  }
  if ((side > Real(0) && !above) || (side < Real(0) && !below)) return flat;
  return side;
}

// The class (+1 inside, -1 outside) where the ray crosses the grid plane `face` on `axis`, a seam
// between two bricks' boxes at which the float walk found the field exactly on the surface, or 0
// if the field is exactly on the surface there in double too. A brick's walk leaving through the
// seam and the next brick's walk entering through it are separate queries that must agree on the
// class there, or a crossing is counted twice or not at all. The float point cannot decide it:
// rounded onto an edge of exact zeros (integer data, an integer iso value) it no longer says
// which side of the edge the ray passes (a hole found at 1e7 rays, hydrogen iso 20 at 1e5). So
// both take it from the ray in double (`org`, `dir` in grid coordinates), in the cell on the
// plane's upper side whichever side they are on, and get the same bits. Where the double point
// is on the surface too (a face of exact zeros the ray runs through or touches), the convention
// holds: the class the ray had before stands (0: the walks decide as without this, the leaving
// one by the side its segment approaches from, the entering one by classBehindEntry).
template <typename Cells>
int seamClass(const Cells& cells, const Vec3d& org, const Vec3d& dir, double iso, int axis, int face) {
  const double t = (double(face) - org[axis]) / dir[axis];
  Vec3i cell;
  Vec3d p;
  for (int a = 0; a < 3; ++a) {
    if (a == axis) {
      cell[a] = std::clamp(face, 0, cells.dims[a] - 2);
      p[a] = double(face - cell[a]);
    } else {
      const double x = org[a] + t * dir[a];
      cell[a] = int(std::clamp(std::floor(x), 0.0, double(cells.dims[a] - 2)));
      p[a] = std::clamp(x - double(cell[a]), 0.0, 1.0);
    }
  }
  double g[8];
  cells.load(cell, iso, g);
  const double f = trilinear(g, p);
  return f > 0 ? 1 : f < 0 ? -1 : 0;
}

// Entering a box through a face exactly on the surface (a brick seam, a restart at a face) where
// the ray in double is on the surface too (seamClass 0), the class is the one the ray had in the
// cell behind that face, as a traversal through it would have carried it: the side the cubic of
// that cell's segment (ending at the face point `entry`, local to `cell`) approaches zero from.
// Otherwise, or at the grid's boundary, `carried`. (A function rather than a lambda of the
// traversal: it runs at most once per query.)
template <typename Real, typename Cells>
Real classBehindEntry(const Cells& cells, Real iso, const GridRay<Real>& ray, Vec3i cell, int entryAxis,
                      int entryStep, const Vec3<Real>& entry, const Real g[8], Real carried) {
  Vec3i prev = cell;
  prev[entryAxis] -= entryStep;
  if (prev[entryAxis] < 0 || prev[entryAxis] > cells.dims[entryAxis] - 2) return carried;
  if (trilinear(g, entry) != Real(0)) return carried;
  CellSegment<Real> behind;
  cells.load(prev, iso, behind.g);
  behind.b = entry;
  behind.b[entryAxis] = Real(1) - entry[entryAxis];
  behind.a = behind.b - ray.dir;
  const Real tiny = std::numeric_limits<Real>::denorm_min();
  return approachSide(cellCubic(behind), behind.g, carried) > Real(0) ? tiny : -tiny;
}

// The class (+1 inside, -1 outside, 0 exactly on the surface) of the field of `cell` in double,
// at the ray's point at t (faceAxis < 0), or where the ray meets the grid's face `face` on
// `faceAxis` (its t found in double too). This is what the double-precision reference, and
// any check in double, sees at the ends of the ray's extent in the grid; a float traversal
// that decided them from its float positions (off by float rounding, 1e-6 cells at the far
// side of a 100-cell grid) could put a crossing within that distance of an end on the other
// side of it: a hole or a double hit (found at 1e7 rays, bench/exactness.sh).
template <typename Cells>
int exactEndClass(const Cells& cells, const ExactEnds& e, const Vec3i& cell, double t, int faceAxis, int face) {
  double g[8];
  cells.load(cell, e.iso, g);
  if (faceAxis >= 0) t = (double(face) - e.org[faceAxis]) / e.dir[faceAxis];
  Vec3d p;
  for (int a = 0; a < 3; ++a)
    p[a] = a == faceAxis ? double(face - cell[a]) : std::clamp(e.org[a] + t * e.dir[a] - double(cell[a]), 0.0, 1.0);
  const double f = trilinear(g, p);
  return f > 0 ? 1 : f < 0 ? -1 : 0;
}

// One ray's walk through the cells [lo, hi) with t in [tnear, tfar], a cell at a time: the
// 3D-DDA and everything a cell decides except the solve of its cubic. traverseCells drives one
// walk with a scalar intersector; a packet query (volume/packet_walk.h) drives up to 8 together
// and solves their cells together, so both run this same code for everything else and
// give the same bits. `start` applies where the walk starts at tnear inside the box (not at a
// face of it).
template <typename Real, typename Cells>
class CellWalk {
 public:
  // What a cell asks of the caller.
  enum class Visit {
    Pass,           // nothing to solve: advance()
    Solve,          // segment() may hold a crossing: solve it; none found: advance()
    StartCrossing,  // the field is on the other side of the given start class: startHit()
  };

  CellWalk() = default;
  // `tstop`: the walk may stop before a cell that begins past it (a closest hit is known there);
  // the cells before it are cut at tfar as always, so a hit does not depend on tstop.
  // `startCell` (a clipped surface's walk from where the ray enters the kept region): the walk
  // starts at tnear in that cell of the box, with `start` given, whatever the box's faces say.
  CellWalk(const Cells& cells, Real iso, const GridRay<Real>& ray, Vec3i lo, Vec3i hi, Real tnear, Real tfar,
           StartClass start, const ExactEnds* exact, Real tstop = std::numeric_limits<Real>::infinity(),
           const Vec3i* startCell = nullptr)
      : m_cells(&cells), m_ray(&ray), m_exact(exact), m_startCell(startCell), m_iso(iso), m_tnear(tnear),
        m_tfar(tfar), m_tstop(tstop), m_lo(lo), m_hi(hi), m_start(start) {}

  // Clips the ray to the box and finds its first cell; false if it has none.
  ISO_INLINE bool begin() {
    const GridRay<Real>& ray = *m_ray;
    if (!ray.valid() || !(m_tnear <= m_tfar)) return false;
    const Vec3i lo = m_lo, hi = m_hi;
    Real t0 = m_tnear, t1 = m_tfar;
    int entryAxis = -1;
    for (int a = 0; a < 3; ++a) {
      if (ray.dir[a] == Real(0)) {
        if (ray.org[a] < Real(lo[a]) || ray.org[a] > Real(hi[a])) return false;
        continue;
      }
      const bool pos = ray.dir[a] > Real(0);
      const Real tl = ray.planeT(a, pos ? lo[a] : hi[a]);
      const Real th = ray.planeT(a, pos ? hi[a] : lo[a]);
      if (tl > t0) { t0 = tl; entryAxis = a; }
      t1 = std::min(t1, th);
    }
    if (entryAxis < 0 && m_exact && !m_startCell) {
      // A float start inside the box (or on its boundary) whose exact start lies beyond one of
      // its faces between bricks, heading away: float rounded the origin onto that face, and
      // the box holds none of the exact ray (the brick beyond starts it). Walked here, its
      // zero-length segment compared the given class with the face's class where the exact ray
      // crosses that plane, behind its origin: a crossing at the start where there is none, and
      // another from the next spawned ray (extra pairs on hydrogen, HeadMR, lidc2, smoke,
      // example4d). (An exact start behind a face heading in is left to both bricks, as before:
      // the one behind compares the given class with that face's, ahead of the origin.)
      for (int a = 0; a < 3; ++a) {
        const double p = m_exact->org[a] + m_exact->tnear * m_exact->dir[a], d = m_exact->dir[a];
        const bool pastLoSeam = p < double(lo[a]) && lo[a] > 0 && !(d > 0);
        const bool pastHiSeam = p > double(hi[a]) && hi[a] < m_cells->dims[a] - 1 && !(d < 0);
        if (pastLoSeam || pastHiSeam) return false;
      }
    }
    if (m_startCell) {
      // (Rounding can put the box's entry just past tnear, or its exit just before it: the cell
      // holds tnear by the caller's decision, and its segment is then of zero length.)
      t0 = m_tnear;
      entryAxis = -1;
      t1 = std::max(t1, t0);
    }
    if (!(t0 <= t1)) {
      // A ray continuing from a hit may start on the box's boundary heading out (IsoSurface moves
      // starts that left the box onto it), where rounding in planeT can put t1 just below t0.
      // Its one zero-length segment still compares the given class with the field there.
      const Real eps = Real(4) * std::numeric_limits<Real>::epsilon();
      if (m_start == StartClass::Unknown || entryAxis >= 0 || !(t0 - t1 <= eps * (std::fabs(t0) + Real(1))))
        return false;
      for (int a = 0; a < 3; ++a) {
        const Real p = ray.org[a] + t0 * ray.dir[a];
        const Real tol = eps * (std::fabs(p) + Real(1));
        if (!(p >= Real(lo[a]) - tol && p <= Real(hi[a]) + tol)) return false;
      }
      t1 = t0;
    }
    const Real inf = std::numeric_limits<Real>::infinity();
    for (int a = 0; a < 3; ++a) {
      const bool pos = ray.dir[a] > Real(0);
      if (m_startCell) {
        m_cell[a] = (*m_startCell)[a];
      } else if (a == entryAxis) {
        m_cell[a] = pos ? lo[a] : hi[a] - 1;
      } else if (entryAxis < 0 && m_exact) {
        // A ray that starts inside the box starts in the cell of its exact origin. The float
        // origin can round onto a face the exact one lies just short of (a spawned ray 2e-6
        // below z = 87, where float's spacing is 7.6e-6): its walk began in the cell beyond,
        // with a zero-length segment whose face took its class where the exact ray crosses that
        // plane, behind its origin: a crossing at the start where there is none, and another
        // from the next ray (lidc2 at iso 18, extra pairs).
        const double p = m_exact->org[a] + m_exact->tnear * m_exact->dir[a];
        m_cell[a] = int(std::clamp(p, double(lo[a]), double(hi[a] - 1)));
      } else {
        const Real p = ray.org[a] + t0 * ray.dir[a];
        // Clamped first, then truncated: the same cell as floor-then-clamp (lo >= 0), cheaper, and
        // no out-of-range conversion for a far origin whose p carries a large rounding error.
        m_cell[a] = int(std::clamp(p, Real(lo[a]), Real(hi[a] - 1)));
      }
      m_step[a] = ray.dir[a] == Real(0) ? 0 : (pos ? 1 : -1);
      m_tNext[a] = m_step[a] == 0 ? inf : ray.planeT(a, m_cell[a] + (pos ? 1 : 0));
    }
    m_t0 = t0;
    m_t1 = t1;
    m_ta = t0;
    for (int a = 0; a < 3; ++a) m_absOrg[a] = std::fabs(ray.org[a]);
    m_entryAxis = m_enterAxis = entryAxis;
    // Exact zeros (a face or edge whose value is exactly the iso value, common with integer
    // data and integer iso values) take the class the ray had just before them: a crossing is
    // a change between strictly inside and strictly outside. Without this, a ray that touches
    // such a face from inside counts one crossing (inside -> zero) where there are zero or two,
    // and neither a restart nor a spawned ray can recover the pairing (DESIGN.md, "Known
    // traps"). `carried` stands in for an exact zero at the start of the next segment; a ray
    // starts outside, by the convention that zero is not inside.
    m_carried = -kTiny;
    // Entering through a face exactly on the surface, the class at that seam (without it a
    // crossing through an exact zero on a brick seam was seen by neither brick). Only the first
    // cell needs it, and only if it is not of one strict sign: see seamClass.
    m_entryPending = entryAxis >= 0;
    // A given start class stands for the first segment's f0, whatever the field says there.
    m_startGiven = entryAxis < 0 && m_start != StartClass::Unknown;
    if (m_startGiven) m_carried = m_start == StartClass::Inside ? kTiny : -kTiny;
    m_firstSegment = true;
    return true;
  }

  // The current cell: steps over it, or prepares its segment for a solve.
  ISO_INLINE Visit visit(TraversalStats& stats) {
    const Cells& cells = *m_cells;
    ++stats.cellsVisited;
    int m = 0;
    if (m_tNext[1] < m_tNext[m]) m = 1;
    if (m_tNext[2] < m_tNext[m]) m = 2;
    m_m = m;
    // Either the cell is left through a face (pinned) or the ray ends inside it at tfar.
    m_throughFace = m_tNext[m] <= m_t1;
    m_tb = std::max(m_ta, m_throughFace ? m_tNext[m] : m_t1);
    const int leaveAxis = m_throughFace ? m : -1;

    CellSegment<Real>& seg = m_seg;
    int positive = 0, negative = 0;
    if (const int uniform = cells.uniformClass(m_cell)) {
      (uniform > 0 ? positive : negative) = 8;
    } else {
      cells.load(m_cell, m_iso, seg.g);
      for (int i = 0; i < 8; ++i) {
        positive += seg.g[i] > Real(0);
        negative += seg.g[i] < Real(0);
      }
    }
    // Cells that cannot change the class are stepped over: one strict sign, or zeros with
    // values only on the side the ray is already on.
    if (m_entryPending) {
      // Entering through a seam exactly on the surface (the cell behind is not of one strict
      // class, so it is another brick's): the class there is seamClass's, or where that is 0,
      // the one the ray had in the cell behind (classBehindEntry).
      m_entryPending = false;
      if (positive != 8 && negative != 8 && !atGridFace(m_entryAxis, true)) {
        const Vec3<Real> entry = localAt(m_t0, m_entryAxis, faceValue(m_entryAxis, true));
        if (trilinear(seg.g, entry) == Real(0)) {
          const int c = seamClassAt(m_entryAxis, gridFace(m_entryAxis, true));
          m_carried = c != 0 ? (c > 0 ? kTiny : -kTiny)
                             : classBehindEntry(cells, m_iso, *m_ray, m_cell, m_entryAxis, m_step[m_entryAxis], entry,
                                                seg.g, m_carried);
        }
      }
    }
    // Leaving through a seam exactly on the surface: the next brick's walk starts in
    // seamClass's class, so this one ends in it, with a crossing in this cell if it differs
    // (seamClass 0: as any exact zero at a segment's end).
    m_seamExit = 0;
    if (positive != 8 && negative != 8 && m_throughFace && leavesBox(m) && !atGridFace(m, false) &&
        trilinear(seg.g, localAt(m_tb, m, faceValue(m, false))) == Real(0))
      m_seamExit = seamClassAt(m, gridFace(m, false));
    const bool carriedIn = m_carried > Real(0);
    if (m_startGiven && ((positive == 8 && !carriedIn) || (negative == 8 && carriedIn))) {
      // The field is strictly on the other side all over the first cell: the crossing lies
      // between the hit the ray continues from and its origin (the spawn offset stepped
      // over it). It is reported at the start, where its bound is the rounding of t alone.
      return Visit::StartCrossing;
    }
    if (positive == 8) {
      m_carried = kTiny;
      return Visit::Pass;
    }
    if (negative == 8) {
      m_carried = -kTiny;
      return Visit::Pass;
    }
    if (((negative == 0 && (positive == 0 || carriedIn)) || (positive == 0 && !carriedIn)) &&
        (m_seamExit == 0 || (m_seamExit > 0) == carriedIn))
      return Visit::Pass;  // the carried class stands
    ++stats.cellsSolved;
    const int enterAxis = m_enterAxis;
    seg.a = localAt(m_ta, enterAxis, enterAxis >= 0 ? faceValue(enterAxis, true) : Real(0));
    seg.b = localAt(m_tb, leaveAxis, leaveAxis >= 0 ? faceValue(leaveAxis, false) : Real(0));
    seg.f0 = trilinear(seg.g, seg.a);
    seg.f1 = trilinear(seg.g, seg.b);
    // A face between cells whose float value lies within the rounding of its point (the float
    // ray's position in the grid, ~eps |p|, times the face's slope) of zero: its class in double,
    // at the exact ray's crossing of the face. Both cells of the face (and both bricks' walks at
    // a seam) compute the same float value, the same doubt and the same double class, so they
    // agree; without it a near-tangent pass straddling a face lost or gained its pair of
    // crossings by rounding (on lidc2 at iso 18, ~27 lost and ~45 extra per 1e7 crossings).
    // A float value of exactly 0 is in doubt too: the exact-zero rule below (the class the ray
    // had) is for faces on the surface in double as well (integer data, corners at the iso
    // value); a float point that rounded onto a zero line of the face the exact ray passes
    // 1e-6 from takes the exact ray's class (a lost pair each on lidc2 at iso 18, 1e6 rays).
    if constexpr (std::is_same_v<Real, float>) {
      if (const ExactEnds* exact = m_exact) {
        // The ray's extent at the segment's two ends, for the doubt of the segment and of its two
        // faces (the end one is the next cell's start one: kept while the walk solves cells in a row).
        const Real extentA = m_ta == m_extentT ? m_extentAtT : extentAt(m_ta);
        const Real extentB = extentAt(m_tb);
        m_extentT = m_tb;
        m_extentAtT = extentB;
        exactSegment(*exact, enterAxis, leaveAxis, std::max(extentA, extentB), seg);
        if (enterAxis >= 0 && !m_startGiven && !atGridFace(enterAxis, true) &&
            faceInDoubt(seg.f0, seg.g, enterAxis, seg.a[enterAxis], extentA)) {
          const int c = exactEndClass(cells, *exact, m_cell, 0, enterAxis, gridFace(enterAxis, true));
          if (c != 0 && (seg.f0 == Real(0) || (c > 0) != (seg.f0 > Real(0)))) seg.f0 = c > 0 ? kTiny : -kTiny;
        }
        if (m_throughFace && !atGridFace(leaveAxis, false) &&
            faceInDoubt(seg.f1, seg.g, leaveAxis, seg.b[leaveAxis], extentB)) {
          const int c = exactEndClass(cells, *exact, m_cell, 0, leaveAxis, gridFace(leaveAxis, false));
          if (c != 0 && (seg.f1 == Real(0) || (c > 0) != (seg.f1 > Real(0)))) seg.f1 = c > 0 ? kTiny : -kTiny;
        }
      }
    }
    if (seg.f0 == Real(0) || m_startGiven) seg.f0 = m_carried;
    // At an end of the ray's extent in the grid, the class in double (exactEndClass) where
    // float says otherwise: the first segment of a ray that starts here without a given
    // class or enters through the grid's boundary; the last one that ends at tfar or leaves
    // through the grid's boundary.
    if (const ExactEnds* exact = m_exact) {
      if (m_firstSegment && !m_startGiven && (enterAxis < 0 || atGridFace(enterAxis, true))) {
        const int c = enterAxis < 0 ? exactEndClass(cells, *exact, m_cell, exact->tnear, -1, 0)
                                    : exactEndClass(cells, *exact, m_cell, 0, enterAxis, gridFace(enterAxis, true));
        if (c != 0 && (c > 0) != (seg.f0 > Real(0))) seg.f0 = c > 0 ? kTiny : -kTiny;
      }
      if ((!m_throughFace && m_t1 == m_tfar) || (m_throughFace && atGridFace(leaveAxis, false))) {
        const int c = m_throughFace ? exactEndClass(cells, *exact, m_cell, 0, leaveAxis, gridFace(leaveAxis, false))
                                    : exactEndClass(cells, *exact, m_cell, exact->tfar, -1, 0);
        if (c != 0 && (c > 0) != (seg.f1 > Real(0))) seg.f1 = c > 0 ? kTiny : -kTiny;
      }
    }
    if (m_seamExit != 0) seg.f1 = m_seamExit > 0 ? kTiny : -kTiny;
    if (seg.f1 == Real(0)) seg.f1 = approachSide(cellCubic(seg), seg.g, seg.f0) > Real(0) ? kTiny : -kTiny;
    m_carried = seg.f1 > Real(0) ? kTiny : -kTiny;
    return Visit::Solve;
  }

  // The segment of the cell visit() returned Solve for.
  ISO_INLINE const CellSegment<Real>& segment() const { return m_seg; }

  // The crossing at the start (after Visit::StartCrossing).
  ISO_INLINE void startHit(CellHit<Real>& hit, TraversalStats& stats) const {
    ++stats.rootsRefined;
    hit.t = m_ta;
    hit.segmentStart = m_ta;
    hit.tError = roundingOfT(m_ta, Real(0));
    hit.cell = m_cell;
    hit.local = localAt(m_ta, -1, Real(0));
    hit.tangent = false;
    hit.insideAfter = !(m_carried > Real(0));
  }

  // The crossing at `root` of the segment (after Visit::Solve).
  ISO_INLINE void hitAt(const Root<Real>& root, CellHit<Real>& hit, TraversalStats& stats) const {
    ++stats.rootsRefined;
    const Real len = m_tb - m_ta;
    // Never past the segment's end (ta + 1 * len can round above tb): a crossing at the end of
    // a brick's last cell then ties with, and is ordered before, one at the start of the next
    // brick (SurfaceHit::segmentStart).
    hit.t = std::min(m_ta + root.s * len, m_tb);
    hit.segmentStart = m_ta;
    hit.tError = root.sError * len + roundingOfT(hit.t, len);
    hit.cell = m_cell;
    hit.local = m_seg.a + (m_seg.b - m_seg.a) * root.s;
    hit.tangent = root.tangent;
    // The first change of class on the segment leaves the class of f0 (a tangent root
    // changes nothing).
    hit.insideAfter = root.tangent ? isInside(m_seg.f0) : !isInside(m_seg.f0);
  }

  // After advance() returned false: +1 (-1) if the walk ended at tfar inside its box (not
  // leaving it through a face, not stopped at tstop) in the class value > iso (< iso), else 0.
  ISO_INLINE int endClass() const {
    return m_throughFace || !(m_t1 == m_tfar) ? 0 : m_carried > Real(0) ? 1 : -1;
  }

  // On to the next cell; false when the walk is over (no crossing).
  ISO_INLINE bool advance() {
    m_startGiven = false;
    m_firstSegment = false;
    if (!m_throughFace) return false;
    const int m = m_m;
    m_cell[m] += m_step[m];
    if (m_cell[m] < m_lo[m] || m_cell[m] >= m_hi[m]) return false;
    m_ta = m_tb;
    if (m_ta > m_tstop) return false;
    m_enterAxis = m;
    m_tNext[m] = m_ray->planeT(m, m_cell[m] + (m_step[m] > 0 ? 1 : 0));
    return true;
  }

 private:
  static constexpr Real kTiny = std::numeric_limits<Real>::denorm_min();

  // Local coordinate on `axis` at t, with the crossed face pinned exactly.
  ISO_INLINE Vec3<Real> localAt(Real t, int faceAxis, Real faceValue) const {
    Vec3<Real> p;
    for (int a = 0; a < 3; ++a)
      p[a] = a == faceAxis ? faceValue
                           : std::clamp(m_ray->org[a] + t * m_ray->dir[a] - Real(m_cell[a]), Real(0), Real(1));
    return p;
  }
  // The segment's end points on the ray in double (the faces' coordinates exact), and its
  // doubt (CellSegment::doubt): a and b are the float ray's points, each within ~4 eps of the
  // grid coordinates' magnitude (and t's rounding) of the exact ones; the field's slope in a
  // cell is at most ~3.5 times the sum of |g|; plus the evaluation error.
  // `extent`: the largest of extentAt(m_ta) and extentAt(m_tb), which is max over the axes of
  // |org| + max(|ta dir|, |tb dir|) bit for bit (rounding is monotone: |o| + max(x, y) rounds to
  // the larger of |o| + x and |o| + y).
  ISO_INLINE void exactSegment(const ExactEnds& e, int enterAxis, int leaveAxis, Real extent, CellSegment<Real>& seg) const {
    seg.hasExact = true;
    seg.exactCorners = [](const void* cells, const Vec3i& cell, double iso, double g[8]) {
      static_cast<const Cells*>(cells)->load(cell, iso, g);
    };
    seg.exactCells = m_cells;
    seg.exactCell = m_cell;
    seg.exactIso = e.iso;
    // The ends on the exact ray: what CellSegment::exactEnd needs, not the points themselves (a
    // segment is solved in double only where the float cubic is in doubt).
    seg.exactOrg = &e.org;
    seg.exactDir = &e.dir;
    seg.exactAxis[0] = enterAxis;
    seg.exactAxis[1] = leaveAxis;
    seg.exactT[0] = double(m_ta);
    seg.exactT[1] = double(m_tb);
    seg.doubt = (Real(32) + Real(16) * (extent + Real(1))) * std::numeric_limits<Real>::epsilon();
  }
  // Whether the float value f at a face (local coordinate `side` on `axis`, at t) may have the
  // wrong sign: |f| within the rounding of the face point (a few eps of its grid coordinates)
  // times the face's corners, plus their evaluation error. The face's four corners in index
  // order, and the ray's extent at the face's t (extentAt): the same bits in both cells of the face.
  ISO_INLINE bool faceInDoubt(Real f, const Real g[8], int axis, Real side, Real extent) const {
    // The face's corners are those whose index has `side` in bit `axis`: i0 + {0, s1, s2, s1 + s2}
    // for the other two axes' index steps, summed in index order as a loop over all 8 would
    // (no branch per corner: this runs at every face a walk looks at twice).
    const int bit = side == Real(1) ? 1 : 0;
    const int i0 = bit << axis;
    const int s1 = axis == 0 ? 2 : 1, s2 = axis == 2 ? 2 : 4;
    const Real corners = ((std::fabs(g[i0]) + std::fabs(g[i0 + s1])) + std::fabs(g[i0 + s2])) + std::fabs(g[i0 + s1 + s2]);
    return std::fabs(f) <= Real(8) * std::numeric_limits<Real>::epsilon() * (extent + Real(2)) * corners;
  }
  // The largest over the axes of |org| + |t dir|: the magnitude of the ray's grid coordinates at t,
  // which their rounding scales with.
  ISO_INLINE Real extentAt(Real t) const {
    Real extent = 0;
    for (int a = 0; a < 3; ++a) extent = std::max(extent, m_absOrg[a] + std::fabs(t * m_ray->dir[a]));
    return extent;
  }
  ISO_INLINE Real faceValue(int axis, bool entering) const {
    const bool pos = m_ray->dir[axis] > Real(0);
    return Real(pos == entering ? 0 : 1);
  }
  // The grid coordinate of the face the ray enters (leaves) the current cell through on
  // `axis`, and whether that face is on the grid's boundary.
  ISO_INLINE bool leavesBox(int axis) const {
    const int next = m_cell[axis] + m_step[axis];
    return next < m_lo[axis] || next >= m_hi[axis];
  }
  // seamClass of the ray in double: the exact ray if the walk has it, else its own.
  int seamClassAt(int axis, int face) const {
    if (m_exact) return seamClass(*m_cells, m_exact->org, m_exact->dir, m_exact->iso, axis, face);
    return seamClass(*m_cells, Vec3d(m_ray->org), Vec3d(m_ray->dir), double(m_iso), axis, face);
  }
  ISO_INLINE int gridFace(int axis, bool entering) const { return m_cell[axis] + int(faceValue(axis, entering)); }
  ISO_INLINE bool atGridFace(int axis, bool entering) const {
    if (axis < 0) return false;
    const int f = gridFace(axis, entering);
    return f == 0 || f == m_cells->dims[axis] - 1;
  }
  // Rounding in a hit's t: of the ray's origin in grid coordinates (it moves the ray by
  // eps |org|, i.e. t by that over the speed), and of t and the segment length themselves.
  ISO_INLINE Real roundingOfT(Real t, Real len) const {
    const GridRay<Real>& ray = *m_ray;
    const Real originScale =
        std::max({std::fabs(ray.org.x), std::fabs(ray.org.y), std::fabs(ray.org.z)}) / length(ray.dir);
    return Real(2) * std::numeric_limits<Real>::epsilon() * (originScale + std::fabs(t) + len);
  }

  const Cells* m_cells = nullptr;
  const GridRay<Real>* m_ray = nullptr;
  const ExactEnds* m_exact = nullptr;
  const Vec3i* m_startCell = nullptr;
  Real m_iso = 0, m_tnear = 0, m_tfar = 0, m_tstop = 0;
  Vec3i m_lo, m_hi;
  StartClass m_start = StartClass::Unknown;
  // The DDA: the current cell, its steps and the t of the next face on each axis.
  Vec3i m_cell, m_step;
  Vec3<Real> m_tNext;
  Real m_t0 = 0, m_t1 = 0;  // the clipped extent
  Real m_ta = 0, m_tb = 0;  // the current cell's segment
  int m_entryAxis = -1, m_enterAxis = -1, m_m = 0;
  bool m_throughFace = false;
  Real m_carried = 0;
  bool m_entryPending = false, m_startGiven = false, m_firstSegment = true;
  int m_seamExit = 0;  // this cell leaves through a seam exactly on the surface: seamClass there, else 0
  Vec3<Real> m_absOrg;  // |ray.org| per axis
  // extentAt(m_extentT), of the last solved segment's end (NaN: none yet).
  Real m_extentT = std::numeric_limits<Real>::quiet_NaN(), m_extentAtT = 0;
  CellSegment<Real> m_seg;
};

// First crossing of the ray with the iso-surface inside the cells [lo, hi) and t in
// [tnear, tfar]. AnyHit (shadow rays) returns at the first cell with a proven crossing.
// `start` applies where the query starts at tnear inside the box (not at a face of it).
template <bool AnyHit, typename Real, typename Intersector, typename Cells>
bool traverseCells(const Cells& cells, Real iso, const GridRay<Real>& ray, Vec3i lo, Vec3i hi,
                   Real tnear, Real tfar, const Intersector& solver, CellHit<Real>& hit,
                   TraversalStats& stats, StartClass start = StartClass::Unknown,
                   const ExactEnds* exact = nullptr, Real tstop = std::numeric_limits<Real>::infinity(),
                   const Vec3i* startCell = nullptr, int* endClass = nullptr) {
  CellWalk<Real, Cells> walk(cells, iso, ray, lo, hi, tnear, tfar, start, exact, tstop, startCell);
  if (endClass) *endClass = 0;
  if (!walk.begin()) return false;
  do {
    switch (walk.visit(stats)) {
      case CellWalk<Real, Cells>::Visit::StartCrossing:
        if constexpr (!AnyHit) walk.startHit(hit, stats);
        return true;
      case CellWalk<Real, Cells>::Visit::Solve:
        if constexpr (AnyHit) {
          if (solver.any(walk.segment())) return true;
        } else {
          Root<Real> root;
          if (solver.first(walk.segment(), root)) {
            walk.hitAt(root, hit, stats);
            return true;
          }
        }
        break;
      case CellWalk<Real, Cells>::Visit::Pass:
        break;
    }
  } while (walk.advance());
  if (endClass) *endClass = walk.endClass();
  return false;
}

}  // namespace iso
