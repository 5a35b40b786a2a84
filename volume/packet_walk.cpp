// The isolation intersector on 8 segments at once. Every lane runs the scalar code's operations
// (volume/intersectors.h, volume/cell_cubic.h) in the scalar code's order, written as straight
// loops over the lanes with selects instead of branches, so that the compiler turns each loop
// into 8-wide instructions. This file is built with -O3 (loop vectorisation) and
// -ffp-contract=off (a fused multiply-add would round differently from the scalar code), and
// its two entry points are compiled twice, for AVX2 and for the baseline, the CPU choosing at
// load time (GCC's target_clones).
#include "volume/packet_walk.h"

#include <cmath>
#include <limits>

namespace iso {
namespace {

constexpr int W = kPacketLanes;
constexpr float kEvalFactor = 32 * std::numeric_limits<float>::epsilon();  // evaluationError's

// The lanes' segments as structures of arrays, and what the scalar isolate() makes of them:
// the knots k[0..n+1] (0, the cubic's extrema inside (0, 1), 1) and the values there.
struct Lanes {
  float g[8][W];
  float a[3][W], b[3][W];
  float f0[W], f1[W];
  float c[4][W];      // the cubic
  int n[W];           // extrema inside (0, 1)
  float k[4][W];      // knots, padded with 1 past n + 1
  float fk[4][W];     // values at the knots, padded with f1
  float scale[W];     // sum of |g|, in the scalar order
};

inline bool inside(float f) { return f > 0.f; }

// Gathers the segments (lanes outside `mask` copy a lane inside it: all arithmetic stays finite
// where the data are) and runs cellCubic and isolate on every lane.
void prepare(const CellSegment<float>* const segs[W], uint32_t mask, Lanes& L) {
  const int any = __builtin_ctz(mask);
  for (int l = 0; l < W; ++l) {
    const CellSegment<float>& s = *segs[(mask >> l & 1) ? l : any];
    for (int i = 0; i < 8; ++i) L.g[i][l] = s.g[i];
    for (int i = 0; i < 3; ++i) {
      L.a[i][l] = s.a[i];
      L.b[i][l] = s.b[i];
    }
    L.f0[l] = s.f0;
    L.f1[l] = s.f1;
  }
  // cellCubic: along x (linear in s), then y (quadratic), then z (cubic).
  for (int l = 0; l < W; ++l) {
    const float ax = L.a[0][l], ay = L.a[1][l], az = L.a[2][l];
    const float dx = L.b[0][l] - ax, dy = L.b[1][l] - ay, dz = L.b[2][l] - az;
    float A[4], B[4];
    for (int e = 0; e < 4; ++e) {
      const float diff = L.g[2 * e + 1][l] - L.g[2 * e][l];
      A[e] = L.g[2 * e][l] + ax * diff;
      B[e] = dx * diff;
    }
    float h[2][3];
    for (int q = 0; q < 2; ++q) {
      const float P = A[2 * q + 1] - A[2 * q], Q = B[2 * q + 1] - B[2 * q];
      h[q][0] = A[2 * q] + ay * P;
      h[q][1] = B[2 * q] + ay * Q + dy * P;
      h[q][2] = dy * Q;
    }
    const float D0 = h[1][0] - h[0][0], D1 = h[1][1] - h[0][1], D2 = h[1][2] - h[0][2];
    L.c[0][l] = h[0][0] + az * D0;
    L.c[1][l] = h[0][1] + az * D1 + dz * D0;
    L.c[2][l] = h[0][2] + az * D2 + dz * D1;
    L.c[3][l] = dz * D2;
  }
  // isolate: the roots of the derivative c1 + 2 c2 s + 3 c3 s^2 inside (0, 1), as
  // quadraticRootsInUnit finds them (every candidate computed, the kept ones selected).
  for (int l = 0; l < W; ++l) {
    const float q0 = L.c[1][l], q1 = 2.f * L.c[2][l], q2 = 3.f * L.c[3][l];
    const float disc = q1 * q1 - 4.f * q2 * q0;
    const float q = -0.5f * (q1 + std::copysign(std::sqrt(std::max(disc, 0.f)), q1));
    const bool quadratic = q2 != 0.f;
    const bool real = disc >= 0.f;
    // First candidate: -q0 / q1 (linear) or q / q2; second: q0 / q (quadratic, q != 0).
    const float r0 = quadratic ? q / q2 : -q0 / q1;
    const float r1 = q0 / q;
    const bool keep0 = (quadratic ? real : q1 != 0.f) && r0 > 0.f && r0 < 1.f;
    const bool keep1 = quadratic && real && q != 0.f && r1 > 0.f && r1 < 1.f;
    const bool swap = keep0 && keep1 && r0 > r1;
    const float e0 = keep0 && !swap ? r0 : r1;
    const float e1 = swap ? r0 : r1;
    const int n = int(keep0) + int(keep1);
    L.n[l] = n;
    const float c0 = L.c[0][l], c1 = L.c[1][l], c2 = L.c[2][l], c3 = L.c[3][l];
    const float fe0 = ((c3 * e0 + c2) * e0 + c1) * e0 + c0;
    const float fe1 = ((c3 * e1 + c2) * e1 + c1) * e1 + c0;
    L.k[0][l] = 0.f;
    L.fk[0][l] = L.f0[l];
    L.k[1][l] = n >= 1 ? e0 : 1.f;
    L.fk[1][l] = n >= 1 ? fe0 : L.f1[l];
    L.k[2][l] = n == 2 ? e1 : 1.f;
    L.fk[2][l] = n == 2 ? fe1 : L.f1[l];
    L.k[3][l] = 1.f;
    L.fk[3][l] = L.f1[l];
  }
  for (int l = 0; l < W; ++l) {
    float scale = 0;
    for (int i = 0; i < 8; ++i) scale += std::fabs(L.g[i][l]);
    L.scale[l] = scale;
  }
}

__attribute__((target_clones("avx2", "default")))
uint32_t isolationFirst(const CellSegment<float>* const segs[W], uint32_t mask, int iterations, Root<float> roots[W]) {
  Lanes L;
  prepare(segs, mask, L);
  // The first piece whose ends differ in class.
  float lo[W], hi[W], flo[W], fhi[W];
  bool live[W];
  uint32_t found = 0;
  for (int l = 0; l < W; ++l) {
    const int n = L.n[l];
    const bool c01 = inside(L.fk[0][l]) != inside(L.fk[1][l]);
    const bool c12 = n >= 1 && inside(L.fk[1][l]) != inside(L.fk[2][l]);
    const bool c23 = n == 2 && inside(L.fk[2][l]) != inside(L.fk[3][l]);
    const int i = c01 ? 0 : c12 ? 1 : 2;
    lo[l] = L.k[i][l];
    hi[l] = L.k[i + 1][l];
    flo[l] = L.fk[i][l];
    fhi[l] = L.fk[i + 1][l];
    live[l] = (mask >> l & 1) && (c01 || c12 || c23);
    found |= uint32_t(live[l]) << l;
  }
  if (!found) return 0;
  // refineBracket: Illinois-modified regula falsi, lanes retiring as the scalar loop breaks.
  float loSafe[W], hiSafe[W], evalError[W];
  int lastSide[W];
  bool loInside[W];
  for (int l = 0; l < W; ++l) {
    loSafe[l] = lo[l];
    hiSafe[l] = hi[l];
    lastSide[l] = 0;
    loInside[l] = inside(flo[l]);
    evalError[l] = kEvalFactor * L.scale[l];
  }
  for (int it = 0; it < iterations; ++it) {
    bool any = false;
    for (int l = 0; l < W; ++l) {
      bool on = live[l] && hi[l] > lo[l];
      float s = lo[l] + (hi[l] - lo[l]) * (flo[l] / (flo[l] - fhi[l]));
      if (!(s > lo[l] && s < hi[l])) s = lo[l] + 0.5f * (hi[l] - lo[l]);
      on = on && s > lo[l] && s < hi[l];
      const float fs = ((L.c[3][l] * s + L.c[2][l]) * s + L.c[1][l]) * s + L.c[0][l];
      const bool proven = std::fabs(fs) > evalError[l];
      const bool toLo = inside(fs) == loInside[l];
      const bool moveLo = on && toLo, moveHi = on && !toLo;
      const float halfHi = lastSide[l] == -1 ? fhi[l] * 0.5f : fhi[l];
      const float halfLo = lastSide[l] == 1 ? flo[l] * 0.5f : flo[l];
      lo[l] = moveLo ? s : lo[l];
      loSafe[l] = moveLo && proven ? s : loSafe[l];
      hi[l] = moveHi ? s : hi[l];
      hiSafe[l] = moveHi && proven ? s : hiSafe[l];
      flo[l] = moveLo ? fs : moveHi ? halfLo : flo[l];
      fhi[l] = moveHi ? fs : moveLo ? halfHi : fhi[l];
      lastSide[l] = moveLo ? -1 : moveHi ? 1 : lastSide[l];
      live[l] = on;
      any = any || on;
    }
    if (!any) break;
  }
  // The root and its bound (refineBracket's end, withEvaluationBound, refineWithBound).
  for (int l = 0; l < W; ++l) {
    float s = lo[l] + (hi[l] - lo[l]) * (flo[l] / (flo[l] - fhi[l]));
    if (!(s >= lo[l] && s <= hi[l])) s = lo[l] + 0.5f * (hi[l] - lo[l]);
    const float proven = std::max(s - loSafe[l], hiSafe[l] - s);
    const float bracket = std::max(s - lo[l], hi[l] - s);
    const float slope = std::fabs((3.f * L.c[3][l] * s + 2.f * L.c[2][l]) * s + L.c[1][l]);
    const float bound = kEvalFactor * L.scale[l] / slope;
    const float evaluation = std::isfinite(bound) ? std::min(bound, 1.f) : 1.f;
    roots[l].s = s;
    roots[l].sError = std::min(bracket + evaluation, std::max(proven, bracket));
    roots[l].tangent = false;
  }
  return found;
}

__attribute__((target_clones("avx2", "default")))
uint32_t isolationAny(const CellSegment<float>* const segs[W], uint32_t mask) {
  Lanes L;
  prepare(segs, mask, L);
  uint32_t found = 0;
  for (int l = 0; l < W; ++l) {
    const bool in0 = inside(L.fk[0][l]);
    const int n = L.n[l];
    const bool yes = in0 != inside(L.f1[l]) || (n >= 1 && inside(L.fk[1][l]) != in0) ||
                     (n == 2 && inside(L.fk[2][l]) != in0);
    found |= uint32_t(yes && (mask >> l & 1)) << l;
  }
  return found;
}

}  // namespace

uint32_t IsolationPacket::first(const CellSegment<float>* const segs[kPacketLanes], uint32_t mask,
                                Root<float> roots[kPacketLanes]) const {
  return mask ? isolationFirst(segs, mask, iterations, roots) : 0;
}

uint32_t IsolationPacket::any(const CellSegment<float>* const segs[kPacketLanes], uint32_t mask) const {
  return mask ? isolationAny(segs, mask) : 0;
}

}  // namespace iso
