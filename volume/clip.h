#pragma once
// A clip region: the points kept by a list of half-spaces (their intersection, a convex region).
// A scene's "clip" entries (planes, boxes = six planes) become one of these per volume, in the
// volume's object space, where its iso-surfaces are queried (IsoSurface) and where a ray's kept
// extent is one interval [k0, k1] (extent()).
#include <vector>

#include "volume/transform.h"
#include "volume/vec3.h"

namespace iso {

struct ClipPlane {
  Vec3d normal;       // unit; points out of what is kept
  double offset = 0;  // keeps p with dot(normal, p) <= offset
};

class ClipRegion {
 public:
  // Keeps p with (p - point) . normal <= 0 (the normal points towards the part cut away).
  void addPlane(const Vec3d& point, const Vec3d& normal);
  // Keeps [lo, hi] on every axis.
  void addBox(const Vec3d& lo, const Vec3d& hi);
  void add(const ClipRegion& other);

  bool empty() const { return m_planes.empty(); }
  bool operator==(const ClipRegion& o) const;
  const std::vector<ClipPlane>& planes() const { return m_planes; }
  bool keeps(const Vec3d& p) const;
  // The distance from p to the nearest of the planes (infinity without planes).
  double planeDistance(const Vec3d& p) const;

  // The same region in the space `to` maps into (a point p kept here is kept there as to(p)).
  ClipRegion transformed(const Transform& to) const;

  // The extent [k0, k1] of the ray o + t d kept (k0 > k1: none), and the planes that bound it
  // (-1: unbounded on that side).
  void extent(const Vec3d& o, const Vec3d& d, double& k0, double& k1, int& plane0, int& plane1) const;

  // How a box [lo, hi] lies: wholly kept, wholly cut away, or met by the boundary, each plane
  // widened by `margin` (a box within the margin of the boundary counts as met by it).
  enum class BoxSide { Kept, Cut, Boundary };
  BoxSide classify(const Vec3d& lo, const Vec3d& hi, double margin) const;

 private:
  std::vector<ClipPlane> m_planes;
};

}  // namespace iso
