#pragma once
// Pinhole camera: vertical field of view in degrees, image plane at distance 1.
#include <optional>

#include "scene/scene.h"

namespace iso {

struct Ray {
  Vec3f org, dir;
  float tnear = 0;
  float tfar = 3.4e38f;
  // The origin in double when it has more precision than `org` (rays spawned from iso-surface
  // hits); iso-surface queries start from it. Empty: `org` is exact.
  std::optional<Vec3d> org64;
  Vec3d origin() const { return org64 ? *org64 : Vec3d(org); }
  // A ray spawned from an iso-surface hit: that surface's index, and whether the ray starts
  // on its inside (value > iso). The surface's query takes that class as given at the origin
  // instead of evaluating the field there (StartClass, volume/traversal.h).
  int fromSurface = -1;
  bool fromInside = false;
  bool fromCap = false;  // it leaves a cap of that surface (its origin is on the clip region's boundary)
  // How far and which way the spawn offset moved the origin from its hit (origin() minus the
  // hit's position, in double; zero if not spawned from an iso-surface). An origin the offset
  // pushed out of the volume's box moves back along it, towards the hit (World::startInsideVolume).
  Vec3d fromOffset{0, 0, 0};
  // What the ray meets: every geometry, or only World::kVolumeMask (the iso-surfaces: a
  // data-parallel rank answering another rank's ray, whose meshes that rank traces itself).
  unsigned mask = ~0u;
};

class Camera {
 public:
  Camera(const CameraDesc& desc, int width, int height);
  // (x, y) in pixel units from the top-left corner of the image. (Inline: a wave starts
  // thousands of camera rays, each written straight into its path.)
  Ray generateRay(float x, float y) const {
    const float sx = (2 * x / m_width - 1) * m_tanHalf * m_aspect;
    const float sy = (1 - 2 * y / m_height) * m_tanHalf;
    Ray ray;
    ray.org = m_origin;
    ray.dir = normalize(m_forward + m_right * sx + m_up * sy);
    return ray;
  }

 private:
  Vec3f m_origin, m_forward, m_right, m_up;
  float m_tanHalf, m_aspect;
  int m_width, m_height;
};

}  // namespace iso
