#pragma once
// The trilinear field along a ray segment inside one cell is a cubic (Marmitt et al. 2004,
// "Fast and Accurate Ray-Voxel Intersection Techniques for Iso-Surface Ray Tracing", eq. 1-3).
// Everything is parameterised over the segment, s in [0, 1], in cell-local coordinates, so
// the coefficients are of the size of the corner values whatever the world scale is.
#include <limits>

#include "volume/vec3.h"

namespace iso {

// Corner c of a cell is (c & 1, (c >> 1) & 1, (c >> 2) & 1) in local coordinates.
template <typename Real>
struct CellSegment {
  Real g[8];       // corner values minus the iso value: inside means g > 0
  Vec3<Real> a;    // local coordinates at s = 0
  Vec3<Real> b;    // local coordinates at s = 1
  Real f0 = 0;     // field at s = 0 and s = 1, evaluated with trilinear() so that the
  Real f1 = 0;     // neighbouring cell computes the same bits at the shared face
  // A float walk that has the ray in double (ExactEnds) adds the segment's end points on it
  // (exact), and `doubt`: times the sum of |g|, how far the float cubic can be from the one
  // of the exact segment (rounding of a and b, and of the evaluation). Where the cubic's value
  // at an extremum is that close to zero, the isolation intersector decides in double.
  // And how to load the cell's corners minus the iso value in double, for the rare segment
  // solved in double (g subtracts the iso value rounded to float, 0.97 by 2.9e-8: enough to put
  // a near-tangent pass on the wrong side of zero): exactCorners(exactCells, exactCell, exactIso, g).
  bool hasExact = false;
  // The segment's ends on the exact ray are computed only for a segment solved in double
  // (exactEnd): from the exact ray (exactOrg + t exactDir, grid coordinates), the walk's t at
  // each end and the axis of the face each end lies on (-1: none; the end's local coordinate on
  // it is a's or b's).
  const Vec3<double>* exactOrg = nullptr;
  const Vec3<double>* exactDir = nullptr;
  int exactAxis[2] = {-1, -1};
  double exactT[2] = {0, 0};
  // End `end` (0: s = 0, 1: s = 1) in cell-local coordinates in double, on the exact ray.
  Vec3<double> exactEnd(int end) const {
    const int axis = exactAxis[end];
    const double side = axis >= 0 ? double((end == 0 ? a : b)[axis]) : 0.0;
    const Vec3<double>& o = *exactOrg;
    const Vec3<double>& d = *exactDir;
    const double te = axis >= 0 ? (double(exactCell[axis]) + side - o[axis]) / d[axis] : exactT[end];
    Vec3<double> p;
    for (int a = 0; a < 3; ++a)
      p[a] = a == axis ? side : std::clamp(o[a] + te * d[a] - double(exactCell[a]), 0.0, 1.0);
    return p;
  }
  void (*exactCorners)(const void* cells, const Vec3i& cell, double iso, double g[8]) = nullptr;
  const void* exactCells = nullptr;
  Vec3i exactCell;
  double exactIso = 0;
  Real doubt = Real(32) * std::numeric_limits<Real>::epsilon();
};

template <typename Real>
inline bool isInside(Real f) { return f > Real(0); }

// (1 - t) a + t b rather than a + t (b - a): exact at t = 0 and t = 1, and a sum of
// non-negative weights times the corners, so it never changes the sign class of corners
// that agree. That is what makes shared faces and skipped cells consistent.
template <typename Real>
inline Real lerp(Real a, Real b, Real t) { return (Real(1) - t) * a + t * b; }

template <typename Real>
inline Real trilinear(const Real g[8], const Vec3<Real>& p) {
  const Real e00 = lerp(g[0], g[1], p.x), e10 = lerp(g[2], g[3], p.x);
  const Real e01 = lerp(g[4], g[5], p.x), e11 = lerp(g[6], g[7], p.x);
  return lerp(lerp(e00, e10, p.y), lerp(e01, e11, p.y), p.z);
}

// The exact gradient of the trilinear interpolant, in cell-local units.
template <typename Real>
inline Vec3<Real> trilinearGradient(const Real g[8], const Vec3<Real>& p) {
  const Real u = p.x, v = p.y, w = p.z;
  const Real dx = lerp(lerp(g[1] - g[0], g[3] - g[2], v), lerp(g[5] - g[4], g[7] - g[6], v), w);
  const Real dy = lerp(lerp(g[2] - g[0], g[3] - g[1], u), lerp(g[6] - g[4], g[7] - g[5], u), w);
  const Real dz = lerp(lerp(g[4] - g[0], g[5] - g[1], u), lerp(g[6] - g[2], g[7] - g[3], u), v);
  return {dx, dy, dz};
}

template <typename Real>
struct Cubic {
  Real c[4];  // c0 + c1 s + c2 s^2 + c3 s^3
  Real operator()(Real s) const { return ((c[3] * s + c[2]) * s + c[1]) * s + c[0]; }
};

// Coefficients of f(s) = trilinear(g, a + s (b - a)): interpolate along x (linear in s),
// then y (quadratic), then z (cubic), carrying polynomials instead of values.
template <typename Real>
inline Cubic<Real> cellCubic(const CellSegment<Real>& seg) {
  const Vec3<Real> a = seg.a, d = seg.b - seg.a;
  const Real* g = seg.g;
  Real A[4], B[4];  // edge (j, k) along x: A + B s
  for (int e = 0; e < 4; ++e) {
    const Real diff = g[2 * e + 1] - g[2 * e];
    A[e] = g[2 * e] + a.x * diff;
    B[e] = d.x * diff;
  }
  Real h[2][3];  // face k along y: h0 + h1 s + h2 s^2
  for (int k = 0; k < 2; ++k) {
    const Real P = A[2 * k + 1] - A[2 * k], Q = B[2 * k + 1] - B[2 * k];
    h[k][0] = A[2 * k] + a.y * P;
    h[k][1] = B[2 * k] + a.y * Q + d.y * P;
    h[k][2] = d.y * Q;
  }
  const Real D0 = h[1][0] - h[0][0], D1 = h[1][1] - h[0][1], D2 = h[1][2] - h[0][2];
  return {{h[0][0] + a.z * D0, h[0][1] + a.z * D1 + d.z * D0, h[0][2] + a.z * D2 + d.z * D1,
           d.z * D2}};
}

}  // namespace iso
