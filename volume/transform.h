#pragma once
// Affine transforms of scene objects (meshes, volumes, glTF nodes) and of instanced
// iso-surfaces, kept in double so that
// composing a glTF hierarchy with a scene transform does not lose precision.
#include <cmath>
#include <limits>

#include "volume/vec3.h"

namespace iso {

class Transform {
 public:
  Transform() = default;  // identity
  // Row-major 3x4: the rotation/scale in columns 0..2, the translation in column 3.
  static Transform fromRows(const double r[12]) {
    Transform t;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 4; ++j) t.m[i][j] = r[i * 4 + j];
    return t;
  }
  static Transform translate(const Vec3d& v) {
    Transform t;
    t.m[0][3] = v.x; t.m[1][3] = v.y; t.m[2][3] = v.z;
    return t;
  }
  static Transform scale(const Vec3d& s) {
    Transform t;
    t.m[0][0] = s.x; t.m[1][1] = s.y; t.m[2][2] = s.z;
    return t;
  }
  // Rotation by `degrees` about `axis` (right-handed).
  static Transform rotate(double degrees, const Vec3d& axis) {
    const Vec3d a = normalize(axis);
    const double th = degrees * M_PI / 180, c = std::cos(th), s = std::sin(th), k = 1 - c;
    Transform t;
    t.m[0][0] = a.x * a.x * k + c;       t.m[0][1] = a.x * a.y * k - a.z * s; t.m[0][2] = a.x * a.z * k + a.y * s;
    t.m[1][0] = a.y * a.x * k + a.z * s; t.m[1][1] = a.y * a.y * k + c;       t.m[1][2] = a.y * a.z * k - a.x * s;
    t.m[2][0] = a.z * a.x * k - a.y * s; t.m[2][1] = a.z * a.y * k + a.x * s; t.m[2][2] = a.z * a.z * k + c;
    return t;
  }
  // A unit quaternion (x, y, z, w), as glTF stores rotations.
  static Transform quaternion(double x, double y, double z, double w) {
    Transform t;
    t.m[0][0] = 1 - 2 * (y * y + z * z); t.m[0][1] = 2 * (x * y - z * w);     t.m[0][2] = 2 * (x * z + y * w);
    t.m[1][0] = 2 * (x * y + z * w);     t.m[1][1] = 1 - 2 * (x * x + z * z); t.m[1][2] = 2 * (y * z - x * w);
    t.m[2][0] = 2 * (x * z - y * w);     t.m[2][1] = 2 * (y * z + x * w);     t.m[2][2] = 1 - 2 * (x * x + y * y);
    return t;
  }

  Transform operator*(const Transform& o) const {
    Transform r;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 4; ++j) {
        double v = j == 3 ? m[i][3] : 0;
        for (int k = 0; k < 3; ++k) v += m[i][k] * o.m[k][j];
        r.m[i][j] = v;
      }
    return r;
  }
  Vec3d point(const Vec3d& p) const {
    return {m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z + m[0][3],
            m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z + m[1][3],
            m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z + m[2][3]};
  }
  Vec3d vector(const Vec3d& v) const {
    return {m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z, m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
            m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z};
  }
  // Normals transform with the inverse transpose: the cofactor matrix does that up to a
  // positive scale for any invertible matrix (and keeps orientation for mirrored ones).
  Vec3d normal(const Vec3d& n) const {
    const Vec3d c0 = cross(col(1), col(2)), c1 = cross(col(2), col(0)), c2 = cross(col(0), col(1));
    const double sign = determinant() < 0 ? -1 : 1;
    // M^-T n = (n.x (c1 x c2) + n.y (c2 x c0) + n.z (c0 x c1)) / det.
    return (c0 * n.x + c1 * n.y + c2 * n.z) * sign;
  }
  // The maximum over rows of sum |m_ij| (j < 3): bounds |M v| in each coordinate by |v|_inf.
  Vec3d absRowSums() const {
    return {std::fabs(m[0][0]) + std::fabs(m[0][1]) + std::fabs(m[0][2]),
            std::fabs(m[1][0]) + std::fabs(m[1][1]) + std::fabs(m[1][2]),
            std::fabs(m[2][0]) + std::fabs(m[2][1]) + std::fabs(m[2][2])};
  }
  // The inverse (the caller checks isFiniteInvertible()).
  Transform inverse() const {
    const Vec3d c0 = col(0), c1 = col(1), c2 = col(2);
    const double det = dot(c0, cross(c1, c2));
    const Vec3d r0 = cross(c1, c2) / det, r1 = cross(c2, c0) / det, r2 = cross(c0, c1) / det;
    const double rows[12] = {r0.x, r0.y, r0.z, 0, r1.x, r1.y, r1.z, 0, r2.x, r2.y, r2.z, 0};
    Transform inv = fromRows(rows);
    const Vec3d t = inv.vector({m[0][3], m[1][3], m[2][3]});
    inv.m[0][3] = -t.x;
    inv.m[1][3] = -t.y;
    inv.m[2][3] = -t.z;
    return inv;
  }
  Vec3d col(int j) const { return {m[0][j], m[1][j], m[2][j]}; }
  double determinant() const { return dot(col(0), cross(col(1), col(2))); }
  bool isIdentity() const {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 4; ++j)
        if (m[i][j] != (i == j ? 1.0 : 0.0)) return false;
    return true;
  }
  bool isFiniteInvertible() const {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 4; ++j)
        if (!std::isfinite(m[i][j])) return false;
    const double scale = length(col(0)) * length(col(1)) * length(col(2));
    return std::fabs(determinant()) > 1e-12 * scale && scale > 0;
  }
  // Embree's RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR.
  void toColumnMajor(float out[12]) const {
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 3; ++i) out[j * 3 + i] = float(m[i][j]);
  }

  double m[3][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}};
};

// World space to a grid's index space (sample (i, j, k) at (i, j, k)), for a grid whose sample
// (i, j, k) lies at origin + (i, j, k) * spacing in its own space, and `toObject` taking world
// points to that space.
inline Transform worldToIndex(const Vec3d& origin, const Vec3d& spacing, const Transform& toObject) {
  return Transform::scale({1 / spacing.x, 1 / spacing.y, 1 / spacing.z}) * Transform::translate(-origin) * toObject;
}

}  // namespace iso
