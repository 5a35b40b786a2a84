#include "renderer/ask_filter.h"

#include <cfloat>
#include <cstdint>
#include <cstring>

namespace iso {
namespace {

// GCC's vector extensions, as in volume/packet_walk.cpp: 8 floats, 8 ints (a comparison gives 0
// or -1 per lane); a scalar operand is broadcast. The baseline clone splits them into SSE halves.
typedef float F8 __attribute__((vector_size(32)));
typedef int32_t I8 __attribute__((vector_size(32)));

// (Macros, not functions: a 32-byte vector passed by value changes the baseline clone's ABI.)
#define FABS8(x) ((F8)((I8)(x) & 0x7fffffff))
#define MAX8(a, b) ((a) < (b) ? (b) : (a))
#define MIN8(a, b) ((b) < (a) ? (b) : (a))

}  // namespace

void AskFilterRays::resize(size_t n) {
  // (Only ever grown: the arrays are reused from stage to stage, and growing them again after a
  // smaller stage would zero the new part each time.)
  const size_t padded = (n + 7) / 8 * 8;
  for (std::vector<float>* v : {&ox, &oy, &oz, &dx, &dy, &dz, &t0, &t1})
    if (v->size() < padded) v->resize(padded);
}

__attribute__((target_clones("avx2", "default")))
void filterAsks(const AskFilterRays& rays, size_t n, const AskFilterVolume& volume, unsigned char* settled) {
  const float big = FLT_MAX;
  auto load = [&](const std::vector<float>& v, size_t i, F8& out) { std::memcpy(&out, v.data() + i, sizeof out); };
  for (size_t i = 0; i < n; i += 8) {
    F8 o[3], d[3], t0, t1;
    load(rays.ox, i, o[0]);
    load(rays.oy, i, o[1]);
    load(rays.oz, i, o[2]);
    load(rays.dx, i, d[0]);
    load(rays.dy, i, d[1]);
    load(rays.dz, i, d[2]);
    load(rays.t0, i, t0);
    load(rays.t1, i, t1);
    const F8 reach = MAX8(MAX8(FABS8(o[0]), FABS8(o[1])), FABS8(o[2]));
    const F8 pad = 2.f * (volume.padPerReach * (2.f * reach) + volume.padFixed);
    // The lanes this test takes: a finite origin and pad, t0 <= t1, a finite direction on every axis.
    I8 ok = (reach <= big) & (pad <= big) & (t0 <= t1);
    F8 inv[3];
    for (int a = 0; a < 3; ++a) {
      inv[a] = 1.f / d[a];
      ok &= (d[a] != 0.f) & (FABS8(d[a]) <= big) & (FABS8(inv[a]) <= big);
    }
    // Both ends in the held box shrunk by the pad (t1 finite: its point then is).
    I8 held = ok;
    for (int a = 0; a < 3; ++a) {
      const F8 p0 = o[a] + d[a] * t0, p1 = o[a] + d[a] * t1;
      const F8 lo = volume.held.lo[a] + pad, hi = volume.held.hi[a] - pad;
      held &= (p0 >= lo) & (p0 <= hi) & (p1 >= lo) & (p1 <= hi);
    }
    // [t0, t1] outside every other rank's box grown by the pad (slabs).
    I8 missed = ok;
    for (const AskFilterBox& b : volume.others) {
      F8 a0 = t0, a1 = t1;
      for (int a = 0; a < 3; ++a) {
        const F8 ta = (b.lo[a] - pad - o[a]) * inv[a], tb = (b.hi[a] + pad - o[a]) * inv[a];
        a0 = MAX8(a0, MIN8(ta, tb));
        a1 = MIN8(a1, MAX8(ta, tb));
      }
      missed &= a0 > a1;
    }
    const I8 sure = held | missed;
    for (size_t l = 0; l < 8 && i + l < n; ++l)
      if (!sure[l]) settled[i + l] = 0;
  }
}

}  // namespace iso
