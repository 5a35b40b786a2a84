// The isolation intersector on 8 segments at once. Every lane runs the scalar code's operations
// (volume/intersectors.h, volume/cell_cubic.h) in the scalar code's order, written as straight
// loops over the lanes with selects instead of branches, so that the compiler turns each loop
// into 8-wide instructions. This file is built with -O3 (loop vectorisation) and
// -ffp-contract=off (a fused multiply-add would round differently from the scalar code), and
// its two entry points are compiled twice, for AVX2 and for the baseline, the CPU choosing at
// load time (GCC's target_clones).
#include "volume/packet_walk.h"

#include <cmath>
#include <cstdint>
#include <limits>

namespace iso {
namespace {

// GCC's vector extensions: 8 floats, 8 ints (a comparison gives 0 or -1 per lane), with the
// usual operators; `m ? a : b` selects by lane. The baseline clone splits them into SSE halves.
typedef float F8 __attribute__((vector_size(32)));
typedef int32_t I8 __attribute__((vector_size(32)));

constexpr int W = kPacketLanes;
constexpr float kEvalFactor = 32 * std::numeric_limits<float>::epsilon();  // evaluationError's

// The helpers are macros: a function taking or returning a 32-byte vector by value changes the
// ABI of the baseline clone (GCC warns, clang refuses), even when it is always inlined.
// Arithmetic with a scalar operand broadcasts it to every lane.
#define FABS8(x) ((F8)((I8)(x) & 0x7fffffff))
#define COPYSIGN8(magnitude, sign) ((F8)(((I8)(magnitude) & 0x7fffffff) | ((I8)(sign) & int32_t(0x80000000u))))
// std::max and std::min as the scalar code calls them: (a < b) ? b : a and (b < a) ? b : a.
#define MAX8(a, b) ((a) < (b) ? (b) : (a))
#define MIN8(a, b) ((b) < (a) ? (b) : (a))
#define INSIDE8(f) ((f) > 0.f)
#define CUBIC8(c, s) ((((c)[3] * (s) + (c)[2]) * (s) + (c)[1]) * (s) + (c)[0])

inline uint32_t bits8(const I8& m) {
  uint32_t r = 0;
  for (int l = 0; l < W; ++l) r |= uint32_t(m[l] != 0) << l;
  return r;
}

// What the scalar isolate() makes of each lane's segment: the cubic, the knots k[0..n+1] (0,
// the extrema inside (0, 1), 1; padded with 1) and the values there (padded with f1), and the
// sum of |g| in the scalar order. Lanes outside `mask` copy a lane inside it.
struct Lanes {
  F8 c[4];
  I8 n1, n2;  // n >= 1, n == 2 (n: extrema inside (0, 1))
  F8 k[4], fk[4];
  F8 f0, f1;
  F8 scale;
  F8 doubt;  // CellSegment::doubt
};

inline void prepare(const CellSegment<float>* const segs[W], uint32_t mask, Lanes& L) {
  const int first = __builtin_ctz(mask);
  F8 g[8], a[3], b[3];
  for (int l = 0; l < W; ++l) {
    const CellSegment<float>& s = *segs[(mask >> l & 1) ? l : first];
    for (int i = 0; i < 8; ++i) g[i][l] = s.g[i];
    for (int i = 0; i < 3; ++i) {
      a[i][l] = s.a[i];
      b[i][l] = s.b[i];
    }
    L.f0[l] = s.f0;
    L.f1[l] = s.f1;
    L.doubt[l] = s.doubt;
  }
  // cellCubic: along x (linear in s), then y (quadratic), then z (cubic).
  const F8 d[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
  F8 A[4], B[4];
  for (int e = 0; e < 4; ++e) {
    const F8 diff = g[2 * e + 1] - g[2 * e];
    A[e] = g[2 * e] + a[0] * diff;
    B[e] = d[0] * diff;
  }
  F8 h[2][3];
  for (int q = 0; q < 2; ++q) {
    const F8 P = A[2 * q + 1] - A[2 * q], Q = B[2 * q + 1] - B[2 * q];
    h[q][0] = A[2 * q] + a[1] * P;
    h[q][1] = B[2 * q] + a[1] * Q + d[1] * P;
    h[q][2] = d[1] * Q;
  }
  const F8 D0 = h[1][0] - h[0][0], D1 = h[1][1] - h[0][1], D2 = h[1][2] - h[0][2];
  L.c[0] = h[0][0] + a[2] * D0;
  L.c[1] = h[0][1] + a[2] * D1 + d[2] * D0;
  L.c[2] = h[0][2] + a[2] * D2 + d[2] * D1;
  L.c[3] = d[2] * D2;
  // isolate: the roots of the derivative c1 + 2 c2 s + 3 c3 s^2 inside (0, 1), as
  // quadraticRootsInUnit finds them (every candidate computed, the kept ones selected).
  const F8 q0 = L.c[1], q1 = 2.f * L.c[2], q2 = 3.f * L.c[3];
  const F8 disc = q1 * q1 - 4.f * q2 * q0;
  F8 root;
  for (int l = 0; l < W; ++l) root[l] = std::sqrt(disc[l] >= 0.f ? disc[l] : 0.f);
  const F8 q = -0.5f * (q1 + COPYSIGN8(root, q1));
  const I8 quadratic = q2 != 0.f;
  const I8 real = disc >= 0.f;
  // First candidate: -q0 / q1 (linear) or q / q2; second: q0 / q (quadratic, q != 0).
  const F8 r0 = quadratic ? q / q2 : -q0 / q1;
  const F8 r1 = q0 / q;
  const I8 keep0 = (quadratic ? real : (q1 != 0.f)) & (r0 > 0.f) & (r0 < 1.f);
  const I8 keep1 = quadratic & real & (q != 0.f) & (r1 > 0.f) & (r1 < 1.f);
  const I8 swap = keep0 & keep1 & (r0 > r1);
  const F8 e0 = (keep0 & ~swap) ? r0 : r1;
  const F8 e1 = swap ? r0 : r1;
  L.n1 = keep0 | keep1;
  L.n2 = keep0 & keep1;
  L.k[0] = F8{};
  L.fk[0] = L.f0;
  L.k[1] = L.n1 ? e0 : F8{} + 1.f;
  L.fk[1] = L.n1 ? CUBIC8(L.c, e0) : L.f1;
  L.k[2] = L.n2 ? e1 : F8{} + 1.f;
  L.fk[2] = L.n2 ? CUBIC8(L.c, e1) : L.f1;
  L.k[3] = F8{} + 1.f;
  L.fk[3] = L.f1;
  F8 scale = {};
  for (int i = 0; i < 8; ++i) scale += FABS8(g[i]);
  L.scale = scale;
}

// The lanes of `mask` whose class at an extremum is not proven in float (detail::unprovenExtremum):
// the scalar intersector decides them in double.
inline uint32_t unprovenLanes(const Lanes& L, uint32_t mask) {
  const F8 evalError = L.doubt * L.scale;
  const I8 unproven = (L.n1 & (FABS8(L.fk[1]) <= evalError)) | (L.n2 & (FABS8(L.fk[2]) <= evalError));
  return bits8(unproven) & mask;
}

__attribute__((target_clones("avx2", "default")))
uint32_t isolationFirst(const CellSegment<float>* const segs[W], uint32_t mask, int iterations, Root<float> roots[W],
                        uint32_t* unproven) {
  Lanes L;
  prepare(segs, mask, L);
  *unproven = unprovenLanes(L, mask);
  mask &= ~*unproven;
  // The first piece whose ends differ in class.
  const I8 in0 = INSIDE8(L.fk[0]), in1 = INSIDE8(L.fk[1]), in2 = INSIDE8(L.fk[2]), in3 = INSIDE8(L.fk[3]);
  const I8 c01 = in0 != in1, c12 = L.n1 & (in1 != in2), c23 = L.n2 & (in2 != in3);
  I8 lanes;
  for (int l = 0; l < W; ++l) lanes[l] = (mask >> l & 1) ? -1 : 0;
  I8 live = lanes & (c01 | c12 | c23);
  const uint32_t found = bits8(live);
  if (!found) return 0;
  F8 lo = c01 ? L.k[0] : c12 ? L.k[1] : L.k[2];
  F8 hi = c01 ? L.k[1] : c12 ? L.k[2] : L.k[3];
  F8 flo = c01 ? L.fk[0] : c12 ? L.fk[1] : L.fk[2];
  F8 fhi = c01 ? L.fk[1] : c12 ? L.fk[2] : L.fk[3];
  // refineBracket: Illinois-modified regula falsi, lanes retiring as the scalar loop breaks.
  const F8 evalError = kEvalFactor * L.scale;
  const I8 loInside = INSIDE8(flo);
  F8 loSafe = lo, hiSafe = hi;
  I8 lastSide = {};
  for (int it = 0; it < iterations; ++it) {
    I8 on = live & (hi > lo);
    F8 s = lo + (hi - lo) * (flo / (flo - fhi));
    s = ((s > lo) & (s < hi)) ? s : lo + 0.5f * (hi - lo);
    on &= (s > lo) & (s < hi);
    if (!bits8(on)) break;
    const F8 fs = CUBIC8(L.c, s);
    const I8 proven = FABS8(fs) > evalError;
    const I8 toLo = INSIDE8(fs) == loInside;
    const I8 moveLo = on & toLo, moveHi = on & ~toLo;
    const F8 halfHi = lastSide == -1 ? fhi * 0.5f : fhi;
    const F8 halfLo = lastSide == 1 ? flo * 0.5f : flo;
    lo = moveLo ? s : lo;
    loSafe = (moveLo & proven) ? s : loSafe;
    hi = moveHi ? s : hi;
    hiSafe = (moveHi & proven) ? s : hiSafe;
    flo = moveLo ? fs : moveHi ? halfLo : flo;
    fhi = moveHi ? fs : moveLo ? halfHi : fhi;
    lastSide = moveLo ? I8{} - 1 : moveHi ? I8{} + 1 : lastSide;
    live = on;
  }
  // The root and its bound (refineBracket's end, withEvaluationBound, refineWithBound).
  F8 s = lo + (hi - lo) * (flo / (flo - fhi));
  s = ((s >= lo) & (s <= hi)) ? s : lo + 0.5f * (hi - lo);
  const F8 proven = MAX8(s - loSafe, hiSafe - s);
  const F8 bracket = MAX8(s - lo, hi - s);
  const F8 slope = FABS8((3.f * L.c[3] * s + 2.f * L.c[2]) * s + L.c[1]);
  const F8 bound = kEvalFactor * L.scale / slope;
  const F8 one = F8{} + 1.f;
  const F8 evaluation = (FABS8(bound) < std::numeric_limits<float>::infinity()) ? MIN8(bound, one) : one;
  const F8 error = MIN8(bracket + evaluation, MAX8(proven, bracket));
  for (int l = 0; l < W; ++l) {
    roots[l].s = s[l];
    roots[l].sError = error[l];
    roots[l].tangent = false;
  }
  return found;
}

__attribute__((target_clones("avx2", "default")))
uint32_t isolationAny(const CellSegment<float>* const segs[W], uint32_t mask, uint32_t* unproven) {
  Lanes L;
  prepare(segs, mask, L);
  const I8 in0 = INSIDE8(L.fk[0]);
  const I8 ends = in0 != INSIDE8(L.f1);
  // Ends of different classes cross whatever the extrema say; otherwise an unproven extremum decides in double.
  *unproven = unprovenLanes(L, mask) & ~bits8(ends);
  const I8 yes = ends | (L.n1 & (INSIDE8(L.fk[1]) != in0)) | (L.n2 & (INSIDE8(L.fk[2]) != in0));
  return bits8(yes) & mask & ~*unproven;
}

}  // namespace

// Fewer lanes than this to solve: lane by lane with the scalar intersector (the same bits; a
// vector solve costs the same whether one lane or eight use it).
constexpr int kVectorSolveLanes = 3;

uint32_t IsolationPacket::first(const CellSegment<float>* const segs[kPacketLanes], uint32_t mask,
                                Root<float> roots[kPacketLanes]) const {
  if (laneCount(mask) < kVectorSolveLanes) {
    const IsolationIntersector scalar{iterations};
    uint32_t found = 0;
    for (uint32_t rest = mask; rest; rest &= rest - 1) {
      const int l = __builtin_ctz(rest);
      if (scalar.first(*segs[l], roots[l])) found |= 1u << l;
    }
    return found;
  }
  uint32_t unproven = 0;
  uint32_t found = isolationFirst(segs, mask, iterations, roots, &unproven);
  for (uint32_t rest = unproven; rest; rest &= rest - 1) {
    const int l = __builtin_ctz(rest);
    if (detail::firstInDouble(*segs[l], roots[l])) found |= 1u << l;
  }
  return found;
}

uint32_t IsolationPacket::any(const CellSegment<float>* const segs[kPacketLanes], uint32_t mask) const {
  if (laneCount(mask) < kVectorSolveLanes) {
    const IsolationIntersector scalar{iterations};
    uint32_t found = 0;
    for (uint32_t rest = mask; rest; rest &= rest - 1) {
      const int l = __builtin_ctz(rest);
      if (scalar.any(*segs[l])) found |= 1u << l;
    }
    return found;
  }
  uint32_t unproven = 0;
  uint32_t found = isolationAny(segs, mask, &unproven);
  for (uint32_t rest = unproven; rest; rest &= rest - 1) {
    const int l = __builtin_ctz(rest);
    Root<float> root;
    if (detail::firstInDouble(*segs[l], root)) found |= 1u << l;
  }
  return found;
}

}  // namespace iso
