#pragma once
// Lights. Units (radiometric, RGB): point and spot `intensity` in W/sr, directional
// `irradiance` in W/m^2 on a surface facing the light, environment and emissive surfaces
// `radiance` in W/(sr m^2). glTF punctual lights are read with candela as W/sr and lux as
// W/m^2 (no photometric conversion).
#include <memory>
#include <vector>

#include "scene/material.h"

namespace iso {

struct LightSample {
  Vec3f wi;           // unit, from the shading point towards the light
  Vec3f L;            // radiance (delta lights: the irradiance-like value to use as is)
  float pdf = 0;      // solid angle density; 1 for delta lights
  float distance = 0; // to the sampled point; infinity for distant lights
  bool delta = false;
  // Iso-surface lights sample a direction only: the radiance is what a ray along wi hits
  // first, if that is the light's surface (the caller traces it; L is not set).
  bool traced = false;
};

// A piecewise-constant 1D distribution (for triangle areas and environment rows/columns).
class Distribution1D {
 public:
  Distribution1D() = default;
  explicit Distribution1D(const std::vector<float>& weights);
  // Returns the bin; `pdf` is the bin's probability; `remapped` the position inside it in [0, 1).
  int sample(float u, float& pdf, float& remapped) const;
  // The bin alone (sample's, without the position inside it).
  int pick(float u, float& pdf) const;
  float probability(int bin) const { return m_total > 0 ? m_weights[bin] / m_total : 0; }
  float total() const { return m_total; }
  size_t size() const { return m_weights.size(); }

 private:
  std::vector<float> m_weights;
  std::vector<double> m_cdf;
  float m_total = 0;
};

class Light {
 public:
  enum class Kind { Point, Spot, Directional, Environment, Area, IsoSurface };

  static Light fromDesc(const LightDesc& desc, const Texture* environmentImage);
  // Emissive triangles (world space) with their material; `uvs` may be empty.
  static Light area(std::vector<Vec3f> triangles, std::vector<Vec2f> uvs, const Material& material,
                    const std::vector<Texture>& textures);
  // An emissive iso-surface (World surface `surface`), sampled by direction: a box is chosen
  // by `weights`, a point uniformly inside it, and the direction towards that point; the
  // boxes (world space) must hold the whole surface. `area`: an estimate of its area, for
  // the light's power only.
  static Light isoSurface(int surface, std::vector<Vec3f> lower, std::vector<Vec3f> upper,
                          const std::vector<float>& weights, const Material& material, float area);

  Kind kind() const { return m_kind; }
  bool isDelta() const { return m_kind == Kind::Point || m_kind == Kind::Spot || m_kind == Kind::Directional; }
  bool sample(const Vec3f& p, float u0, float u1, float u2, LightSample& s) const;
  // Solid-angle density of sample() choosing direction `wi` from `p`: environment (any wi),
  // area (the point `y` with normal `ny` that the ray reached).
  float pdfEnvironment(const Vec3f& wi) const;
  float pdfArea(const Vec3f& p, const Vec3f& y, const Vec3f& ny) const;
  // Iso-surface lights: the solid-angle density of sample() choosing `wi` from `p`, whatever
  // the ray along wi hits (the sum over the boxes it crosses).
  float pdfIsoSurface(const Vec3f& p, const Vec3f& wi) const;
  int surface() const { return m_surface; }
  // Total emitted power (luminance; pbrt-v4's Light::Phi) for choosing lights by power.
  // Distant lights count what falls on a disc of the scene's radius.
  float power(float sceneRadius) const;
  // Radiance arriving at the scene along -dir, i.e. seen by a ray that escapes in direction dir.
  Vec3f environment(const Vec3f& dir) const;
  size_t triangleCount() const { return m_triangles.size() / 3; }
  double area() const { return m_areas.total(); }
  // The radiance an area light emits at barycentrics of triangle `tri` towards `w` (unit).
  Vec3f emitted(int tri, float b1, float b2, const Vec3f& w) const;

  // Lat-long mapping of the environment (+y up, the image centre looks along -z).
  static Vec3f directionFromLatLong(float u, float v);
  static void latLongFromDirection(const Vec3f& d, float& u, float& v);

 private:
  Kind m_kind = Kind::Point;
  Vec3f m_position, m_direction;  // direction: the way the light travels
  Vec3f m_power;                  // intensity / irradiance / radiance
  float m_cosInner = 1, m_cosOuter = 0;
  // Environment image and its sampling distributions (rows, then columns per row).
  const Texture* m_image = nullptr;
  Distribution1D m_rows;
  std::vector<Distribution1D> m_columns;
  // Area light.
  std::vector<Vec3f> m_triangles, m_normals;
  std::vector<Vec2f> m_uvs;
  Distribution1D m_areas;
  const Material* m_material = nullptr;
  const std::vector<Texture>* m_textures = nullptr;
  // Iso-surface light: its surface, boxes and their distribution (the material is above).
  int m_surface = -1;
  std::vector<Vec3f> m_boxLower, m_boxUpper;
  Distribution1D m_boxes;
  // The same boxes by axis, with probability / (3 volume) each: pdfIsoSurface runs for every
  // light sample and every BSDF hit of the surface, over all boxes, so it is a flat loop.
  std::vector<float> m_slabLo[3], m_slabHi[3], m_boxScale;
  float m_area = 0;
};

}  // namespace iso
