#include "volume/clip.h"

#include <algorithm>
#include <cmath>

namespace iso {

void ClipRegion::addPlane(const Vec3d& point, const Vec3d& normal) {
  const Vec3d n = normalize(normal);
  m_planes.push_back({n, dot(n, point)});
}

void ClipRegion::addBox(const Vec3d& lo, const Vec3d& hi) {
  for (int a = 0; a < 3; ++a) {
    Vec3d n{0, 0, 0};
    n[a] = 1;
    m_planes.push_back({n, hi[a]});
    n[a] = -1;
    m_planes.push_back({n, -lo[a]});
  }
}

void ClipRegion::add(const ClipRegion& other) {
  m_planes.insert(m_planes.end(), other.m_planes.begin(), other.m_planes.end());
}

bool ClipRegion::operator==(const ClipRegion& o) const {
  if (m_planes.size() != o.m_planes.size()) return false;
  for (size_t i = 0; i < m_planes.size(); ++i)
    if (!(m_planes[i].normal == o.m_planes[i].normal) || m_planes[i].offset != o.m_planes[i].offset) return false;
  return true;
}

bool ClipRegion::keeps(const Vec3d& p) const {
  for (const ClipPlane& c : m_planes)
    if (!(dot(c.normal, p) <= c.offset)) return false;
  return true;
}

double ClipRegion::planeDistance(const Vec3d& p) const {
  double d = INFINITY;
  for (const ClipPlane& c : m_planes) d = std::min(d, std::fabs(dot(c.normal, p) - c.offset));
  return d;
}

ClipRegion ClipRegion::transformed(const Transform& to) const {
  ClipRegion r;
  for (const ClipPlane& c : m_planes) r.addPlane(to.point(c.normal * c.offset), to.normal(c.normal));
  return r;
}

void ClipRegion::extent(const Vec3d& o, const Vec3d& d, double& k0, double& k1, int& plane0, int& plane1) const {
  k0 = -INFINITY;
  k1 = INFINITY;
  plane0 = plane1 = -1;
  for (int i = 0; i < int(m_planes.size()); ++i) {
    const ClipPlane& c = m_planes[size_t(i)];
    const double nd = dot(c.normal, d), gap = c.offset - dot(c.normal, o);
    if (nd == 0) {
      if (!(gap >= 0)) k0 = INFINITY, k1 = -INFINITY, plane0 = plane1 = i;  // parallel and outside: nothing kept
      continue;
    }
    if (k0 > k1) continue;  // nothing kept already
    const double t = gap / nd;
    if (nd > 0) {
      if (t < k1) k1 = t, plane1 = i;
    } else if (t > k0) {
      k0 = t, plane0 = i;
    }
  }
}

ClipRegion::BoxSide ClipRegion::classify(const Vec3d& lo, const Vec3d& hi, double margin) const {
  bool kept = true;
  for (const ClipPlane& c : m_planes) {
    // The box's least and greatest value of dot(normal, p).
    double least = 0, most = 0;
    for (int a = 0; a < 3; ++a) {
      const double u = c.normal[a] * lo[a], v = c.normal[a] * hi[a];
      least += std::min(u, v);
      most += std::max(u, v);
    }
    if (least > c.offset + margin) return BoxSide::Cut;
    if (!(most < c.offset - margin)) kept = false;
  }
  return kept ? BoxSide::Kept : BoxSide::Boundary;
}

}  // namespace iso
