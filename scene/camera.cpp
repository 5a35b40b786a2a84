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

}  // namespace iso
