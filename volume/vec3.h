#pragma once
// Small 3-vector used everywhere. Templated so that the double-precision reference path
// and the float fast path share one implementation.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace iso {

template <typename T>
struct Vec3 {
  T x = 0, y = 0, z = 0;
  constexpr Vec3() = default;
  constexpr Vec3(T x_, T y_, T z_) : x(x_), y(y_), z(z_) {}
  template <typename U>
  constexpr explicit Vec3(const Vec3<U>& o) : x(T(o.x)), y(T(o.y)), z(T(o.z)) {}

  constexpr T operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  T& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }

  constexpr Vec3 operator+(const Vec3& o) const { return {x + o.x, y + o.y, z + o.z}; }
  constexpr Vec3 operator-(const Vec3& o) const { return {x - o.x, y - o.y, z - o.z}; }
  constexpr Vec3 operator*(const Vec3& o) const { return {x * o.x, y * o.y, z * o.z}; }
  constexpr Vec3 operator/(const Vec3& o) const { return {x / o.x, y / o.y, z / o.z}; }
  constexpr Vec3 operator*(T s) const { return {x * s, y * s, z * s}; }
  constexpr Vec3 operator/(T s) const { return {x / s, y / s, z / s}; }
  constexpr Vec3 operator-() const { return {-x, -y, -z}; }
  Vec3& operator+=(const Vec3& o) { x += o.x; y += o.y; z += o.z; return *this; }
  Vec3& operator*=(T s) { x *= s; y *= s; z *= s; return *this; }
  constexpr bool operator==(const Vec3& o) const { return x == o.x && y == o.y && z == o.z; }
};

template <typename T> constexpr Vec3<T> operator*(T s, const Vec3<T>& v) { return v * s; }
template <typename T> constexpr T dot(const Vec3<T>& a, const Vec3<T>& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
template <typename T> constexpr Vec3<T> cross(const Vec3<T>& a, const Vec3<T>& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
template <typename T> T length(const Vec3<T>& v) { return std::sqrt(dot(v, v)); }
template <typename T> Vec3<T> normalize(const Vec3<T>& v) { return v / length(v); }
template <typename T> Vec3<T> min(const Vec3<T>& a, const Vec3<T>& b) {
  return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)};
}
template <typename T> Vec3<T> max(const Vec3<T>& a, const Vec3<T>& b) {
  return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)};
}
template <typename T> bool isFinite(const Vec3<T>& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

using Vec3f = Vec3<float>;
using Vec3d = Vec3<double>;
using Vec3i = Vec3<int>;

// std::nextafter(v, +-infinity) without the library call (pbrt-v4's NextFloatUp/Down): the same
// bits for every float, signed zeros and infinities included (Vec3.NextFloatMatchesNextafter).
inline float nextFloatUp(float v) {
  if (std::isinf(v) && v > 0) return v;
  if (v == -0.f) v = 0.f;
  uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  bits = v >= 0 ? bits + 1 : bits - 1;
  std::memcpy(&v, &bits, sizeof bits);
  return v;
}
inline float nextFloatDown(float v) { return -nextFloatUp(-v); }

// Where the line o + t d lies in the box [lo, hi] (slabs): t in [t0, t1]; false if it misses
// (a line parallel to a face, outside its slab, misses).
inline bool lineInBox(const Vec3d& o, const Vec3d& d, const Vec3d& lo, const Vec3d& hi, double& t0, double& t1) {
  t0 = -INFINITY;
  t1 = INFINITY;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0) {
      if (o[a] < lo[a] || o[a] > hi[a]) return false;
      continue;
    }
    const double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
    t0 = std::max(t0, std::min(ta, tb));
    t1 = std::min(t1, std::max(ta, tb));
  }
  return t0 <= t1;
}

}  // namespace iso
