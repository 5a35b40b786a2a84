#include "accuracy/stress.h"

#include <cmath>
#include <limits>
#include <random>

#include "volume/bricks.h"
#include "volume/iso_surface.h"
#include "volume/procedural.h"

namespace iso {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

Grid floatGrid(Vec3i n, const std::vector<float>& v, Vec3d origin = {0, 0, 0}, Vec3d spacing = {1, 1, 1}) {
  return Grid(n, Grid::Storage(v), origin, spacing);
}

Vec3d randomUnit(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  const double z = 1 - 2 * u(rng), r = std::sqrt(std::max(0.0, 1 - z * z)), phi = 2 * M_PI * u(rng);
  return {r * std::cos(phi), r * std::sin(phi), z};
}

// Rays from outside a grid's box towards random points inside it (camera-like).
std::vector<StressRay> raysInto(const Grid& g, int count, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  const Vec3d size = Vec3d(double(g.dims().x - 1), double(g.dims().y - 1), double(g.dims().z - 1)) * g.spacing();
  std::vector<StressRay> rays;
  for (int i = 0; i < count; ++i) {
    const Vec3d target = g.origin() + Vec3d{u(rng), u(rng), u(rng)} * size;
    const Vec3d dir = randomUnit(rng);
    rays.push_back({target - dir * (2 * length(size)), dir});
  }
  return rays;
}

std::vector<float> sphereValues(int n, double scale) {
  std::vector<float> v;
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        const Vec3d p = Vec3d{double(x), double(y), double(z)} * (2.0 / (n - 1)) - Vec3d{1, 1, 1};
        v.push_back(float(length(p) * scale));
      }
  return v;
}

}  // namespace

std::vector<StressCase> stressCases() {
  std::vector<StressCase> cases;
  std::mt19937_64 rng(20261122);
  std::uniform_real_distribution<double> u(0, 1);
  const int n = 2000;

  {  // Tangent: rays passing the sphere of radius 0.5 at distance 0.5 + delta (double roots).
    StressCase c{"tangent", "rays tangent to a sphere (double roots) and just inside/outside it",
                 makeProceduralGrid(Field::Sphere, {17, 17, 17}), 0.5, {}};
    const double deltas[] = {-1e-3, -1e-5, -1e-7, 0, 1e-7, 1e-5};
    for (int i = 0; i < n; ++i) {
      const Vec3d d = randomUnit(rng);
      Vec3d perp = normalize(cross(d, randomUnit(rng)));
      const Vec3d closest = perp * (0.5 + deltas[i % 6]);
      c.rays.push_back({closest - d * 3.0, d});
    }
    cases.push_back(std::move(c));
  }
  {  // Two crossings inside one cell: enters and leaves outside, positive in the middle.
    std::vector<float> v(8);
    for (int k = 0; k < 8; ++k) v[k] = (k == 0 || k == 7) ? 0.f : 100.f;
    StressCase c{"two_crossings_in_a_cell", "a ray enters and leaves a cell on the same side but crosses twice",
                 floatGrid({2, 2, 2}, v), 50, {}};
    for (int i = 0; i < n; ++i) {
      const Vec3d a = Vec3d{u(rng), u(rng), u(rng)} * 0.1, b = Vec3d{1, 1, 1} - Vec3d{u(rng), u(rng), u(rng)} * 0.1;
      const Vec3d d = normalize(b - a);
      c.rays.push_back({a - d * 2.0, d});
    }
    cases.push_back(std::move(c));
  }
  // A small random field with values 0..4, for rays that follow the grid's structure.
  std::vector<float> integers(8 * 8 * 8);
  for (float& x : integers) x = float(int(u(rng) * 5));
  {  // Along faces, edges and through vertices.
    StressCase c{"faces_edges_vertices", "rays in cell faces, along cell edges and through grid vertices",
                 floatGrid({8, 8, 8}, integers), 2.37, {}};  // not 2.5: with data 0..4 that gives exact double roots on diagonals
    for (int i = 0; i < n; ++i) {
      const int kind = i % 3;
      const Vec3d p{double(1 + i % 6), double(1 + (i / 6) % 6), double(1 + (i / 36) % 6)};
      Vec3d d;
      if (kind == 0) d = normalize(Vec3d{u(rng) - 0.5, u(rng) - 0.5, 0});           // in the face z = p.z
      else if (kind == 1) d = Vec3d{0, 0, 0}, d[i % 3 == 1 ? (i / 3) % 3 : 0] = 1;   // along an edge
      else d = normalize(Vec3d{1, 1, 1} + Vec3d{u(rng), u(rng), u(rng)} * 0.0);      // through vertices
      if (u(rng) < 0.5) d = -d;
      c.rays.push_back({p - d * 20.0, d});
    }
    cases.push_back(std::move(c));
  }
  {  // Axis-parallel rays on a smooth field: the cubic's leading coefficient is zero.
    StressCase c{"axis_parallel", "axis-parallel rays through a gyroid (leading coefficient 0)",
                 makeProceduralGrid(Field::Gyroid, {32, 32, 32}), 0, {}};
    for (int i = 0; i < n; ++i) {
      Vec3d d{0, 0, 0};
      d[i % 3] = i % 2 ? 1 : -1;
      Vec3d p{u(rng) * 2 - 1, u(rng) * 2 - 1, u(rng) * 2 - 1};
      p[i % 3] = -3 * d[i % 3];
      c.rays.push_back({p, d});
    }
    cases.push_back(std::move(c));
  }
  {  // Rays that clip a cell's corner over a tiny segment.
    std::vector<float> v(8 * 8 * 8);
    for (float& x : v) x = float(u(rng));
    StressCase c{"corner_clips", "rays passing within 1e-6 of grid vertices, clipping corners of cells",
                 floatGrid({8, 8, 8}, v), 0.5, {}};
    for (int i = 0; i < n; ++i) {
      const Vec3d vert{double(1 + int(u(rng) * 6)), double(1 + int(u(rng) * 6)), double(1 + int(u(rng) * 6))};
      const Vec3d d = randomUnit(rng);
      const Vec3d perp = normalize(cross(d, randomUnit(rng)));
      c.rays.push_back({vert + perp * 1e-6 - d * 20.0, d});
    }
    cases.push_back(std::move(c));
  }
  {  // Far from the origin.
    Grid g = makeProceduralGrid(Field::Sphere, {33, 33, 33});
    g.setOrigin({1e5, -1e5, 1e5});
    StressCase c{"far_from_origin", "a sphere at (1e5, -1e5, 1e5), spacing 1/16", std::move(g), 0.6, {}};
    c.rays = raysInto(c.grid, n, rng);
    cases.push_back(std::move(c));
  }
  for (double spacing : {1e-6, 1e6}) {  // Tiny and huge spacing.
    Grid g = makeProceduralGrid(Field::Torus, {24, 24, 24});
    g.setSpacing({spacing, spacing, spacing});
    g.setOrigin({-12 * spacing, -12 * spacing, -12 * spacing});
    StressCase c{spacing < 1 ? "tiny_spacing" : "huge_spacing",
                 spacing < 1 ? "a torus with spacing 1e-6" : "a torus with spacing 1e6", std::move(g), 0.25, {}};
    c.rays = raysInto(c.grid, n, rng);
    cases.push_back(std::move(c));
  }
  for (double scale : {1e30, 1e-30}) {  // Values near the ends of float's range.
    StressCase c{scale > 1 ? "values_1e30" : "values_1e-30",
                 scale > 1 ? "a sphere field scaled to values near 1e30" : "a sphere field scaled to values near 1e-30",
                 floatGrid({17, 17, 17}, sphereValues(17, scale), {-1, -1, -1}, {0.125, 0.125, 0.125}), 0.5 * scale, {}};
    c.rays = raysInto(c.grid, n, rng);
    cases.push_back(std::move(c));
  }
  {  // Iso values equal to the data: whole faces and edges lie on the surface.
    StressCase c{"iso_equals_data", "integer data 0..4 and the iso value 2: corners exactly on the surface",
                 floatGrid({8, 8, 8}, integers), 2, {}};
    c.rays = raysInto(c.grid, n, rng);
    cases.push_back(std::move(c));
  }
  {  // Constant cells equal to the iso value.
    std::vector<float> v;
    for (int z = 0; z < 8; ++z)
      for (int y = 0; y < 8; ++y)
        for (int x = 0; x < 8; ++x) v.push_back(x < 3 ? 0.f : x <= 5 ? 1.f : 2.f);
    StressCase c{"plateau_at_iso", "a slab of cells whose every corner equals the iso value",
                 floatGrid({8, 8, 8}, v), 1, {}};
    c.rays = raysInto(c.grid, n, rng);
    cases.push_back(std::move(c));
  }
  {  // NaN and Inf in the data (the loaders refuse these; the core must still not fail).
    std::vector<float> v = sphereValues(17, 1);
    for (size_t k = 0; k < v.size(); ++k) {
      const double r = u(rng);
      if (r < 0.03) v[k] = std::numeric_limits<float>::quiet_NaN();
      else if (r < 0.05) v[k] = std::numeric_limits<float>::infinity();
      else if (r < 0.07) v[k] = -std::numeric_limits<float>::infinity();
    }
    StressCase c{"nan_inf_data", "a sphere field with 3% NaN, 2% +Inf and 2% -Inf samples",
                 floatGrid({17, 17, 17}, v, {-1, -1, -1}, {0.125, 0.125, 0.125}), 0.5, {}};
    c.rays = raysInto(c.grid, n, rng);
    c.checkParity = false;
    cases.push_back(std::move(c));
  }
  {  // Broken rays.
    StressCase c{"bad_rays", "NaN, Inf and zero directions and origins",
                 makeProceduralGrid(Field::Sphere, {17, 17, 17}), 0.5, {}};
    const Vec3d bad[] = {{kNaN, 0, 1}, {0, kInf, 0}, {0, 0, 0}, {-kInf, kInf, 0}, {kNaN, kNaN, kNaN}, {1e-20, 0, 0}};
    for (int i = 0; i < 600; ++i) {
      const Vec3d d = bad[i % 6];
      c.rays.push_back({Vec3d{-3, 0.1, 0.2}, d});
      c.rays.push_back({i % 2 ? Vec3d{kNaN, 0, 0} : Vec3d{kInf, 0, 0}, Vec3d{1, 0, 0}});
    }
    cases.push_back(std::move(c));
  }
  return cases;
}

StressResult runStress(const StressCase& c, const IntersectorSpec& spec) {
  const BrickGrid bricks(c.grid);
  const IsoSurface tested(c.grid, bricks, c.iso, spec);
  const IsoSurface reference(c.grid, bricks, c.iso, IntersectorSpec{IntersectorKind::Reference, 8});
  const Vec3i dims = c.grid.dims();
  const Vec3d hi{double(dims.x - 1), double(dims.y - 1), double(dims.z - 1)};
  const double cell = std::min({c.grid.spacing().x, c.grid.spacing().y, c.grid.spacing().z});
  StressResult r;
  TraversalStats stats;
  for (const StressRay& ray : c.rays) {
    ++r.rays;
    SurfaceHit h, ref;
    const bool got = tested.intersect(ray.org, ray.dir, 0, kInf, h, stats);
    if (got && (!std::isfinite(h.t) || !std::isfinite(h.tError) || !isFinite(h.normal))) {
      ++r.nans;
      continue;
    }
    const bool refGot = reference.intersect(ray.org, ray.dir, 0, kInf, ref, stats);
    if (refGot && !ref.tangent) {
      ++r.referenceHits;
      const double slack = h.tError + ref.tError + 1e-9 * cell / std::max(length(ray.dir), 1e-300);
      if (!got || h.t > ref.t + slack) ++r.misses;
      else if (h.t < ref.t - slack) ++r.wrongRoots;
    } else if (!refGot && got) {
      ++r.wrongRoots;
    }
    // Parity: restart past each root to the end of the grid, against the classes at the ends.
    if (!c.checkParity || !isFinite(ray.org) || !isFinite(ray.dir) || length(ray.dir) == 0) continue;
    const Vec3d o = (ray.org - c.grid.origin()) / c.grid.spacing(), d = ray.dir / c.grid.spacing();
    double t0 = 0, t1 = kInf;
    bool inBox = true;
    for (int a = 0; a < 3 && inBox; ++a) {
      if (d[a] == 0) {
        inBox = o[a] >= 0 && o[a] <= hi[a];
        continue;
      }
      double ta = -o[a] / d[a], tb = (hi[a] - o[a]) / d[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    if (!inBox || !(t0 < t1)) continue;
    // An end on the surface (to rounding) has no class (zeros take the class of the ray before
    // them, see volume/traversal.h): parity is undefined there.
    const double v0 = c.grid.interpolate(o + d * t0), v1 = c.grid.interpolate(o + d * t1);
    const double tie = 1e-12 * (std::fabs(c.iso) + std::fabs(v0) + std::fabs(v1));
    if (std::fabs(v0 - c.iso) <= tie || std::fabs(v1 - c.iso) <= tie) continue;
    const bool in0 = v0 > c.iso, in1 = v1 > c.iso;
    // Each restart starts in the class the last crossing led to, as a spawned ray does.
    int crossings = 0;
    double t = 0;
    StartClass start = StartClass::Unknown;
    SurfaceHit k;
    while (crossings < 100000 && tested.intersect(ray.org, ray.dir, t, kInf, k, stats, start)) {
      ++crossings;
      const double next = k.t + std::max(k.tError, std::fabs(k.t) * 1e-15 + 1e-300);
      if (!(next > t)) break;
      t = next;
      start = k.insideAfter ? StartClass::Inside : StartClass::Outside;
    }
    if ((crossings % 2 == 1) != (in0 != in1)) ++r.parityErrors;
  }
  return r;
}

}  // namespace iso
