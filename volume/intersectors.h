#pragma once
// The five ray-cell intersectors. Each one looks at one CellSegment and answers two
// questions: where is the first crossing in s in [0, 1] (first), and is there one at all
// (any, for shadow rays). A crossing is a change of the class isInside(f) = f > 0; values
// exactly at the iso value count as outside, everywhere, so integer iso values on integer
// data (whole faces on the surface) are neither doubled nor lost.
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "volume/cell_cubic.h"

namespace iso {

template <typename Real>
struct Root {
  Real s = 0;          // position of the crossing on the segment
  Real sError = 0;     // |s - true root| <= sError (a bracket width; an estimate for schwarze)
  bool tangent = false;  // reference only: the cubic touches zero without a sign change
};

enum class IntersectorKind { Linear, Neubauer, Schwarze, Isolation, Reference };

struct IntersectorSpec {
  IntersectorKind kind = IntersectorKind::Isolation;
  int iterations = 8;  // refinement steps for neubauer (default 3) and isolation (default 8)
};

// "linear", "neubauer", "schwarze", "isolation", "reference", optionally ":N" for the
// iteration count of neubauer and isolation ("isolation:8"). False if unknown.
bool parseIntersector(const std::string& text, IntersectorSpec& spec, std::string& error);
std::string intersectorName(const IntersectorSpec& spec);
const char* intersectorList();

namespace detail {

// Roots of q0 + q1 s + q2 s^2 inside the open interval (0, 1), sorted; returns how many.
// The numerically stable form (Numerical Recipes 5.6) avoids cancellation.
template <typename Real>
inline int quadraticRootsInUnit(Real q0, Real q1, Real q2, Real out[2]) {
  int n = 0;
  auto keep = [&](Real s) { if (s > Real(0) && s < Real(1)) out[n++] = s; };
  if (q2 == Real(0)) {
    if (q1 != Real(0)) keep(-q0 / q1);
  } else {
    const Real disc = q1 * q1 - Real(4) * q2 * q0;
    if (disc >= Real(0)) {
      const Real q = Real(-0.5) * (q1 + std::copysign(std::sqrt(disc), q1));
      keep(q / q2);
      if (q != Real(0)) keep(q0 / q);
    }
  }
  if (n == 2 && out[0] > out[1]) std::swap(out[0], out[1]);
  return n;
}

// Splits [0, 1] at the extrema of the cubic: inside each piece the cubic is monotone, so it
// has at most one root there (Marmitt et al. 2004, "Isolation and Iterative Root Finding").
// Fills the knots s[] and values f[] (end values are the face-consistent f0, f1).
template <typename Real>
inline int isolate(const CellSegment<Real>& seg, const Cubic<Real>& cubic, Real s[4], Real f[4]) {
  Real e[2];
  const int n = quadraticRootsInUnit(cubic.c[1], Real(2) * cubic.c[2], Real(3) * cubic.c[3], e);
  s[0] = 0;
  f[0] = seg.f0;
  for (int i = 0; i < n; ++i) {
    s[i + 1] = e[i];
    f[i + 1] = cubic(e[i]);
  }
  s[n + 1] = 1;
  f[n + 1] = seg.f1;
  return n + 2;
}

// Illinois-modified regula falsi on a bracket whose ends differ in class. Plain regula falsi
// leaves one end fixed on convex pieces and stalls (DESIGN.md, "Known traps"); halving the
// stale end's value restores superlinear convergence at no extra evaluations.
//
// Returns the final bracket as the error; `provenError` gets the bracket between the last
// points whose value is farther from zero than the evaluation error `evalError` (their signs
// are proven, so the root lies between them).
template <typename Real, typename F>
inline Root<Real> refineBracket(Real lo, Real hi, Real flo, Real fhi, int iterations, F&& f,
                                Real evalError, Real* provenError = nullptr) {
  const bool loInside = isInside(flo);
  Real loSafe = lo, hiSafe = hi;
  int lastSide = 0;
  for (int i = 0; i < iterations && hi > lo; ++i) {
    Real s = lo + (hi - lo) * (flo / (flo - fhi));
    if (!(s > lo && s < hi)) s = lo + Real(0.5) * (hi - lo);
    if (!(s > lo && s < hi)) break;  // the bracket is down to adjacent floats
    const Real fs = f(s);
    const bool proven = std::fabs(fs) > evalError;
    if (isInside(fs) == loInside) {
      lo = s; flo = fs;
      if (proven) loSafe = s;
      if (lastSide == -1) fhi *= Real(0.5);
      lastSide = -1;
    } else {
      hi = s; fhi = fs;
      if (proven) hiSafe = s;
      if (lastSide == 1) flo *= Real(0.5);
      lastSide = 1;
    }
  }
  Real s = lo + (hi - lo) * (flo / (flo - fhi));
  if (!(s >= lo && s <= hi)) s = lo + Real(0.5) * (hi - lo);
  if (provenError) *provenError = std::max(s - loSafe, hiSafe - s);
  return {s, std::max(s - lo, hi - s), false};
}

// The absolute error of evaluating the cell's cubic: a few ulps of the corner magnitudes.
template <typename Real>
inline Real evaluationError(const CellSegment<Real>& seg) {
  Real scale = 0;
  for (Real g : seg.g) scale += std::fabs(g);
  return Real(32) * std::numeric_limits<Real>::epsilon() * scale;
}

// How far rounding can move a root: the cubic is evaluated with an absolute error of a few
// ulps of the corner magnitudes, and near a simple root that moves s by error / |f'(s)|
// (first order). A tangent-like root (f' ~ 0) honestly gets a large bound.
template <typename Real>
inline Real evaluationBound(const CellSegment<Real>& seg, const Cubic<Real>& cubic, Real s) {
  Real scale = 0;
  for (Real g : seg.g) scale += std::fabs(g);
  const Real slope = std::fabs((Real(3) * cubic.c[3] * s + Real(2) * cubic.c[2]) * s + cubic.c[1]);
  const Real bound = Real(32) * std::numeric_limits<Real>::epsilon() * scale / slope;
  return std::isfinite(bound) ? std::min(bound, Real(1)) : Real(1);
}

template <typename Real>
inline Root<Real> withEvaluationBound(Root<Real> root, const CellSegment<Real>& seg,
                                      const Cubic<Real>& cubic) {
  root.sError += evaluationBound(seg, cubic, root.s);
  return root;
}

// The error bound of isolation and reference: the final bracket plus the first-order
// evaluation bound (error / |f'(s)|), or the proven bracket if smaller. Both hold; the first
// is tight at simple roots, the second next to a near-double root, where error / |f'| explodes
// (a bound of a whole cell made restarts and spawned rays jump over the second root of a
// close pair: a parity error found by the stress suite).
template <typename Real>
inline Root<Real> refineWithBound(Real lo, Real hi, Real flo, Real fhi, int iterations,
                                  const CellSegment<Real>& seg, const Cubic<Real>& cubic) {
  Real proven = 0;
  const Root<Real> r = refineBracket(lo, hi, flo, fhi, iterations, cubic, evaluationError(seg), &proven);
  Root<Real> bounded = withEvaluationBound(r, seg, cubic);
  bounded.sError = std::min(bounded.sError, std::max(proven, r.sError));
  return bounded;
}

}  // namespace detail

// Linear: the field at entry and exit, interpolated linearly. Misses a ray that crosses twice.
struct LinearIntersector {
  bool first(const CellSegment<float>& seg, Root<float>& root) const {
    if (isInside(seg.f0) == isInside(seg.f1)) return false;
    const float s = std::clamp(seg.f0 / (seg.f0 - seg.f1), 0.f, 1.f);
    root = {s, std::max(s, 1 - s), false};  // all it knows is the bracket [0, 1]
    return true;
  }
  bool any(const CellSegment<float>& seg) const { return isInside(seg.f0) != isInside(seg.f1); }
};

// Neubauer et al. 2002: repeated linear interpolation (plain regula falsi) between the
// entry and exit values. Same holes as linear, since it starts from the same test.
struct NeubauerIntersector {
  int iterations = 3;
  bool first(const CellSegment<float>& seg, Root<float>& root) const {
    if (isInside(seg.f0) == isInside(seg.f1)) return false;
    const Cubic<float> cubic = cellCubic(seg);
    float lo = 0, hi = 1, flo = seg.f0, fhi = seg.f1;
    const bool loInside = isInside(flo);
    for (int i = 0; i < iterations; ++i) {
      const float s = lo + (hi - lo) * (flo / (flo - fhi));
      if (!(s > lo && s < hi)) break;
      const float fs = cubic(s);
      if (isInside(fs) == loInside) { lo = s; flo = fs; } else { hi = s; fhi = fs; }
    }
    float s = lo + (hi - lo) * (flo / (flo - fhi));
    if (!(s >= lo && s <= hi)) s = 0.5f * (lo + hi);
    root = detail::withEvaluationBound<float>({s, std::max(s - lo, hi - s), false}, seg, cubic);
    return true;
  }
  bool any(const CellSegment<float>& seg) const { return isInside(seg.f0) != isInside(seg.f1); }
};

// Schwarze, "Cubic and quartic roots", Graphics Gems I (1990), in float as published: the
// cubic is divided by its leading coefficient, so a zero or noise-level c3 (axis-parallel
// rays, smooth fields) yields garbage or no roots. Kept as the seed paper's counter-example.
struct SchwarzeIntersector {
  static int solveCubic(const float c[4], float roots[3]) {
    constexpr float kEps = 1e-9f;
    auto isZero = [&](float x) { return x > -kEps && x < kEps; };
    const float A = c[2] / c[3], B = c[1] / c[3], C = c[0] / c[3];
    const float sqA = A * A;
    const float p = 1.f / 3 * (-1.f / 3 * sqA + B);
    const float q = 1.f / 2 * (2.f / 27 * A * sqA - 1.f / 3 * A * B + C);
    const float cbP = p * p * p;
    const float D = q * q + cbP;
    int n;
    if (isZero(D)) {
      if (isZero(q)) { roots[0] = 0; n = 1; }
      else { const float u = std::cbrt(-q); roots[0] = 2 * u; roots[1] = -u; n = 2; }
    } else if (D < 0) {
      const float phi = 1.f / 3 * std::acos(-q / std::sqrt(-cbP));
      const float t = 2 * std::sqrt(-p);
      roots[0] = t * std::cos(phi);
      roots[1] = -t * std::cos(phi + float(M_PI) / 3);
      roots[2] = -t * std::cos(phi - float(M_PI) / 3);
      n = 3;
    } else {
      const float sqrtD = std::sqrt(D);
      roots[0] = std::cbrt(sqrtD - q) - std::cbrt(sqrtD + q);
      n = 1;
    }
    for (int i = 0; i < n; ++i) roots[i] -= 1.f / 3 * A;
    return n;
  }
  bool first(const CellSegment<float>& seg, Root<float>& root) const {
    const Cubic<float> cubic = cellCubic(seg);
    float r[3];
    const int n = solveCubic(cubic.c, r);
    float best = std::numeric_limits<float>::infinity();
    for (int i = 0; i < n; ++i)
      if (r[i] >= 0.f && r[i] <= 1.f) best = std::min(best, r[i]);  // NaN fails both tests
    if (!(best <= 1.f)) return false;
    // A Newton step's length as the error estimate: the method itself has no bound.
    const float d = (3 * cubic.c[3] * best + 2 * cubic.c[2]) * best + cubic.c[1];
    const float err = std::fabs(cubic(best) / d);
    root = {best, std::isfinite(err) ? err + 4 * std::numeric_limits<float>::epsilon() : 1.f, false};
    return true;
  }
  bool any(const CellSegment<float>& seg) const {
    Root<float> r;
    return first(seg, r);
  }
};

namespace detail {

// Whether the float solve cannot tell the class at an extremum inside the segment: the cubic's
// value there lies within seg.doubt (the rounding of the segment's end points and of the
// evaluation) of zero (f[1..n-2] from isolate). Such a segment is a near-tangent pass (a close
// pair of crossings, or none): float would lose or invent the pair by rounding alone.
inline bool unprovenExtremum(const CellSegment<float>& seg, int n, const float f[4]) {
  float scale = 0;
  for (float g : seg.g) scale += std::fabs(g);
  const float error = seg.doubt * scale;
  for (int i = 1; i + 1 < n; ++i)
    if (std::fabs(f[i]) <= error) return true;
  return false;
}

// The first crossing of the float segment decided in double: the same end values (the ends'
// classes are the walk's, shared with the neighbouring cells), the corners minus the iso value
// and the end points on the ray in double where the walk gave them (else the float ones: a float
// corner value subtracts the iso value rounded to float), the cubic and its extrema in
// double, refined to adjacent doubles. The root comes back as float, its bound grown by the
// rounding of s to float.
bool firstInDouble(const CellSegment<float>& seg, Root<float>& root);  // (intersectors.cpp: one instance for every caller)

}  // namespace detail

// Marmitt et al. 2004: split the segment at the cubic's extrema, take the first piece whose
// ends differ in class, refine there (Illinois regula falsi). Exact in which crossing it
// finds, approximate only in where, and that error is bounded by the final bracket. Where the
// class at an extremum is not proven in float (its value within the evaluation error of zero),
// the segment is decided in double instead (detail::firstInDouble): a near-tangent pass keeps
// or loses its pair of crossings as the double reference does, not by float rounding.
struct IsolationIntersector {
  int iterations = 8;
  bool first(const CellSegment<float>& seg, Root<float>& root) const {
    const Cubic<float> cubic = cellCubic(seg);
    float s[4], f[4];
    const int n = detail::isolate(seg, cubic, s, f);
    if (detail::unprovenExtremum(seg, n, f)) return detail::firstInDouble(seg, root);
    for (int i = 0; i + 1 < n; ++i) {
      if (isInside(f[i]) != isInside(f[i + 1])) {
        root = detail::refineWithBound(s[i], s[i + 1], f[i], f[i + 1], iterations, seg, cubic);
        return true;
      }
    }
    return false;
  }
  // Shadow rays stop at the first proven sign change and never refine.
  bool any(const CellSegment<float>& seg) const {
    if (isInside(seg.f0) != isInside(seg.f1)) return true;
    const Cubic<float> cubic = cellCubic(seg);
    float s[4], f[4];
    const int n = detail::isolate(seg, cubic, s, f);
    if (detail::unprovenExtremum(seg, n, f)) {
      Root<float> r;
      return detail::firstInDouble(seg, r);
    }
    for (int i = 1; i + 1 < n; ++i)
      if (isInside(f[i]) != isInside(f[0])) return true;
    return false;
  }
};

// The ground truth: isolation in double, refined until the bracket is two adjacent doubles,
// and a touching root (|f| at an extremum within rounding of zero, no sign change) is
// reported as a tangent hit.
struct ReferenceIntersector {
  bool first(const CellSegment<double>& seg, Root<double>& root) const {
    const Cubic<double> cubic = cellCubic(seg);
    double s[4], f[4];
    const int n = detail::isolate(seg, cubic, s, f);
    const double scale = std::fabs(cubic.c[0]) + std::fabs(cubic.c[1]) + std::fabs(cubic.c[2]) +
                         std::fabs(cubic.c[3]);
    const double touch = 16 * std::numeric_limits<double>::epsilon() * scale;
    for (int i = 0; i + 1 < n; ++i) {
      if (isInside(f[i]) != isInside(f[i + 1])) {
        root = detail::refineWithBound(s[i], s[i + 1], f[i], f[i + 1], 200, seg, cubic);
        return true;
      }
      if (i + 1 < n - 1 && std::fabs(f[i + 1]) <= touch) {
        root = {s[i + 1], 0.0, true};
        return true;
      }
    }
    return false;
  }
  bool any(const CellSegment<double>& seg) const {
    Root<double> r;
    return first(seg, r) && !r.tangent;
  }
};

}  // namespace iso
