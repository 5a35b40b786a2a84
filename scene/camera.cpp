#include "scene/camera.h"

#include <cmath>

namespace iso {

Camera::Camera(const CameraDesc& d, int width, int height)
    : m_origin(Vec3f(d.position)), m_width(width), m_height(height) {
  const Vec3d f = normalize(d.lookAt - d.position);
  const Vec3d r = normalize(cross(f, d.up));
  m_forward = Vec3f(f);
  m_right = Vec3f(r);
  m_up = Vec3f(cross(r, f));
  m_tanHalf = float(std::tan(d.fov * M_PI / 360));
  m_aspect = float(width) / float(height);
}

Ray Camera::generateRay(float x, float y) const {
  const float sx = (2 * x / m_width - 1) * m_tanHalf * m_aspect;
  const float sy = (1 - 2 * y / m_height) * m_tanHalf;
  Ray ray;
  ray.org = m_origin;
  ray.dir = normalize(m_forward + m_right * sx + m_up * sy);
  return ray;
}

}  // namespace iso
