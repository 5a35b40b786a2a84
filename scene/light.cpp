#include "scene/light.h"

#include <cmath>
#include <limits>

namespace iso {

namespace {
constexpr float kPi = float(M_PI);
}

Distribution1D::Distribution1D(const std::vector<float>& weights) : m_weights(weights) {
  m_cdf.resize(weights.size() + 1, 0);
  double sum = 0;
  for (size_t i = 0; i < weights.size(); ++i) {
    sum += std::max(0.f, weights[i]);
    m_cdf[i + 1] = sum;
  }
  m_total = float(sum);
}

int Distribution1D::pick(float u, float& pdf) const {
  const double target = double(u) * m_cdf.back();
  // The first bin whose cdf end exceeds the target; zero-weight bins are never chosen.
  size_t lo = 0, hi = m_weights.size() - 1;
  while (lo < hi) {
    const size_t mid = (lo + hi) / 2;
    if (m_cdf[mid + 1] <= target) lo = mid + 1;
    else hi = mid;
  }
  pdf = probability(int(lo));
  return int(lo);
}

int Distribution1D::sample(float u, float& pdf, float& remapped) const {
  const int bin = pick(u, pdf);
  const double target = double(u) * m_cdf.back();
  const size_t lo = size_t(bin);
  const double width = m_cdf[lo + 1] - m_cdf[lo];
  remapped = width > 0 ? float(std::clamp((target - m_cdf[lo]) / width, 0.0, 0x1.fffffep-1)) : 0.f;
  return bin;
}

Vec3f Light::directionFromLatLong(float u, float v) {
  const float phi = 2 * kPi * (u - 0.5f), theta = kPi * v;
  const float s = std::sin(theta);
  return {s * std::sin(phi), std::cos(theta), -s * std::cos(phi)};
}

void Light::latLongFromDirection(const Vec3f& d, float& u, float& v) {
  u = std::atan2(d.x, -d.z) / (2 * kPi) + 0.5f;
  // atan2 keeps theta accurate near the poles, where acos(d.y) loses it in float.
  v = std::clamp(std::atan2(std::sqrt(d.x * d.x + d.z * d.z), d.y) / kPi, 0.f, 1.f);
  u = u - std::floor(u);
}

Light Light::fromDesc(const LightDesc& d, const Texture* image) {
  Light l;
  l.m_position = Vec3f(d.position);
  l.m_direction = Vec3f(normalize(d.direction));
  switch (d.type) {
    case LightType::Point: l.m_kind = Kind::Point; l.m_power = Vec3f(d.intensity); break;
    case LightType::Spot:
      l.m_kind = Kind::Spot;
      l.m_power = Vec3f(d.intensity);
      l.m_cosInner = float(std::cos(d.innerAngle * M_PI / 180));
      l.m_cosOuter = float(std::cos(d.outerAngle * M_PI / 180));
      break;
    case LightType::Directional: l.m_kind = Kind::Directional; l.m_power = Vec3f(d.irradiance); break;
    case LightType::Environment: {
      l.m_kind = Kind::Environment;
      l.m_power = Vec3f(d.radiance);
      l.m_image = image;
      if (image) {
        // Importance by luminance times sin(theta), the lat-long map's area element.
        const int w = image->width(), h = image->height();
        std::vector<float> rowWeights(h);
        for (int y = 0; y < h; ++y) {
          const float sinTheta = std::sin(kPi * (y + 0.5f) / h);
          std::vector<float> cols(w);
          for (int x = 0; x < w; ++x) cols[x] = luminance(image->texel(x, y).rgb()) * sinTheta + 1e-8f;
          l.m_columns.emplace_back(cols);
          rowWeights[y] = l.m_columns.back().total();
        }
        l.m_rows = Distribution1D(rowWeights);
      }
      break;
    }
  }
  return l;
}

Light Light::area(std::vector<Vec3f> triangles, std::vector<Vec2f> uvs, const Material& material,
                  const std::vector<Texture>& textures) {
  Light l;
  l.m_kind = Kind::Area;
  l.m_material = &material;
  l.m_textures = &textures;
  std::vector<float> areas;
  for (size_t i = 0; i + 2 < triangles.size(); i += 3) {
    const Vec3f c = cross(triangles[i + 1] - triangles[i], triangles[i + 2] - triangles[i]);
    const float len = length(c);
    areas.push_back(0.5f * len);
    l.m_normals.push_back(len > 0 ? c / len : Vec3f{0, 0, 1});
  }
  l.m_triangles = std::move(triangles);
  l.m_uvs = std::move(uvs);
  l.m_areas = Distribution1D(areas);
  return l;
}

Light Light::isoSurface(int surface, std::vector<Vec3f> lower, std::vector<Vec3f> upper,
                        const std::vector<float>& weights, const Material& material, float area) {
  Light l;
  l.m_kind = Kind::IsoSurface;
  l.m_surface = surface;
  l.m_material = &material;
  l.m_boxLower = std::move(lower);
  l.m_boxUpper = std::move(upper);
  l.m_boxes = Distribution1D(weights);
  l.m_area = area;
  for (size_t b = 0; b < l.m_boxLower.size(); ++b) {
    const Vec3f e = l.m_boxUpper[b] - l.m_boxLower[b];
    const double volume = double(e.x) * e.y * e.z;
    for (int a = 0; a < 3; ++a) {
      l.m_slabLo[a].push_back(l.m_boxLower[b][a]);
      l.m_slabHi[a].push_back(l.m_boxUpper[b][a]);
    }
    l.m_boxScale.push_back(volume > 0 ? float(l.m_boxes.probability(int(b)) / (3 * volume)) : 0.f);
  }
  return l;
}

float Light::power(float sceneRadius) const {
  const float r2 = sceneRadius * sceneRadius;
  switch (m_kind) {
    case Kind::Point: return 4 * kPi * luminance(m_power);
    case Kind::Spot: return 2 * kPi * luminance(m_power) * (1 - 0.5f * (m_cosInner + m_cosOuter));
    case Kind::Directional: return kPi * r2 * luminance(m_power);
    case Kind::Environment: {
      float mean = 1;
      if (m_image) {
        // The image's mean luminance, each texel weighted by its solid angle (sin theta).
        double sum = 0, weight = 0;
        for (int y = 0; y < m_image->height(); ++y) {
          const double s = std::sin(kPi * (y + 0.5) / m_image->height());
          for (int x = 0; x < m_image->width(); ++x) sum += s * luminance(m_image->texel(x, y).rgb());
          weight += s * m_image->width();
        }
        mean = weight > 0 ? float(sum / weight) : 0.f;
      }
      return 4 * kPi * kPi * r2 * luminance(m_power) * mean;
    }
    case Kind::Area:
      return kPi * luminance(m_material->emission) * float(m_areas.total()) * (m_material->twoSided ? 2 : 1);
    case Kind::IsoSurface:
      return kPi * luminance(m_material->emission) * m_area * (m_material->twoSided ? 2 : 1);
  }
  return 0;
}

Vec3f Light::emitted(int tri, float b1, float b2, const Vec3f& w) const {
  const Material& m = *m_material;
  if (!m.twoSided && dot(w, m_normals[tri]) <= 0) return {0, 0, 0};
  Vec3f e = m.emission;
  if (m.emissionTexture >= 0 && !m_uvs.empty()) {
    const Vec2f* uv = &m_uvs[size_t(tri) * 3];
    const float b0 = 1 - b1 - b2;
    e = e * (*m_textures)[m.emissionTexture].lookup(b0 * uv[0].x + b1 * uv[1].x + b2 * uv[2].x,
                                                    b0 * uv[0].y + b1 * uv[1].y + b2 * uv[2].y).rgb();
  }
  return e;
}

Vec3f Light::environment(const Vec3f& dir) const {
  if (m_kind != Kind::Environment) return {0, 0, 0};
  if (!m_image) return m_power;
  float u, v;
  latLongFromDirection(dir, u, v);
  return m_power * m_image->lookup(u, v).rgb();
}

bool Light::sample(const Vec3f& p, float u0, float u1, float u2, LightSample& s) const {
  s.delta = isDelta();
  switch (m_kind) {
    case Kind::Point:
    case Kind::Spot: {
      const Vec3f d = m_position - p;
      const float d2 = dot(d, d);
      if (!(d2 > 0)) return false;
      s.distance = std::sqrt(d2);
      s.wi = d / s.distance;
      s.pdf = 1;
      s.L = m_power / d2;
      if (m_kind == Kind::Spot) {
        const float c = dot(-s.wi, m_direction);
        if (c <= m_cosOuter) return false;
        if (c < m_cosInner) {
          const float t = (c - m_cosOuter) / (m_cosInner - m_cosOuter);
          s.L = s.L * (t * t * (3 - 2 * t));  // smoothstep between the cones
        }
      }
      return true;
    }
    case Kind::Directional:
      s.wi = -m_direction;
      s.distance = std::numeric_limits<float>::infinity();
      s.pdf = 1;
      s.L = m_power;
      return true;
    case Kind::Environment: {
      s.distance = std::numeric_limits<float>::infinity();
      if (!m_image) {
        s.wi = sampleUniformSphere(u0, u1);
        s.pdf = 1 / (4 * kPi);
        s.L = m_power;
        return true;
      }
      float pRow, pCol, fy, fx;
      const int y = m_rows.sample(u0, pRow, fy);
      const int x = m_columns[y].sample(u1, pCol, fx);
      const float u = (x + fx) / m_image->width(), v = (y + fy) / m_image->height();
      s.wi = directionFromLatLong(u, v);
      const float sinTheta = std::sin(kPi * v);
      if (!(sinTheta > 0)) return false;
      s.pdf = pRow * pCol * m_image->width() * m_image->height() / (2 * kPi * kPi * sinTheta);
      s.L = environment(s.wi);
      return s.pdf > 0;
    }
    case Kind::IsoSurface: {
      // Towards a uniform point of a box chosen by weight (the first coordinate reuses the
      // remainder of the box choice).
      float pBox, ux;
      const int b = m_boxes.sample(u0, pBox, ux);
      const Vec3f lo = m_boxLower[size_t(b)], hi = m_boxUpper[size_t(b)];
      const Vec3f y{lo.x + (hi.x - lo.x) * ux, lo.y + (hi.y - lo.y) * u1, lo.z + (hi.z - lo.z) * u2};
      const Vec3f d = y - p;
      const float len = length(d);
      if (!(len > 0)) return false;
      s.wi = d / len;
      s.distance = std::numeric_limits<float>::infinity();
      s.traced = true;
      s.L = {0, 0, 0};
      s.pdf = pdfIsoSurface(p, s.wi);
      return s.pdf > 0 && std::isfinite(s.pdf);
    }
    case Kind::Area: {
      float pTri, bu;
      const int tri = m_areas.sample(u0, pTri, bu);
      // Uniform point in the triangle (the square-root parameterisation).
      const float r = std::sqrt(u1), b1 = 1 - r, b2 = r * u2;
      const Vec3f* v = &m_triangles[size_t(tri) * 3];
      const Vec3f y = v[0] * (1 - b1 - b2) + v[1] * b1 + v[2] * b2;
      const Vec3f d = y - p;
      const float d2 = dot(d, d);
      if (!(d2 > 0)) return false;
      s.distance = std::sqrt(d2);
      s.wi = d / s.distance;
      const float cosL = std::fabs(dot(s.wi, m_normals[tri]));
      if (!(cosL > 0)) return false;
      s.pdf = d2 / (cosL * m_areas.total());
      s.L = emitted(tri, b1, b2, -s.wi);
      return s.pdf > 0 && std::isfinite(s.pdf);
    }
  }
  return false;
}

float Light::pdfEnvironment(const Vec3f& wi) const {
  if (m_kind != Kind::Environment) return 0;
  if (!m_image) return 1 / (4 * kPi);
  float u, v;
  latLongFromDirection(wi, u, v);
  const int y = std::min(int(v * m_image->height()), m_image->height() - 1);
  const int x = std::min(int(u * m_image->width()), m_image->width() - 1);
  const float sinTheta = std::sin(kPi * v);
  if (!(sinTheta > 0)) return 0;
  return m_rows.probability(y) * m_columns[y].probability(x) * m_image->width() * m_image->height() /
         (2 * kPi * kPi * sinTheta);
}

// A point uniform in a box of volume V seen from p: along direction w the density per solid
// angle is the integral of t^2 / V over the part [t0, t1] of the ray inside the box, i.e.
// (t1^3 - t0^3) / (3 V) (the solid angle element at distance t covers t^2 of area).
float Light::pdfIsoSurface(const Vec3f& p, const Vec3f& wi) const {
  if (m_kind != Kind::IsoSurface || m_boxes.total() <= 0) return 0;
  // Slab tests with the reciprocal direction (an axis the ray does not move along gives
  // infinite slab distances of the right signs); boxes the ray misses add 0.
  const float ix = 1 / wi.x, iy = 1 / wi.y, iz = 1 / wi.z;
  const float *loX = m_slabLo[0].data(), *loY = m_slabLo[1].data(), *loZ = m_slabLo[2].data();
  const float *hiX = m_slabHi[0].data(), *hiY = m_slabHi[1].data(), *hiZ = m_slabHi[2].data();
  const float* scale = m_boxScale.data();
  float pdf = 0;
  for (size_t b = 0; b < m_boxScale.size(); ++b) {
    const float ax = (loX[b] - p.x) * ix, bx = (hiX[b] - p.x) * ix;
    const float ay = (loY[b] - p.y) * iy, by = (hiY[b] - p.y) * iy;
    const float az = (loZ[b] - p.z) * iz, bz = (hiZ[b] - p.z) * iz;
    const float t0 = std::max(std::max(0.f, std::min(ax, bx)), std::max(std::min(ay, by), std::min(az, bz)));
    const float t1 = std::min(std::max(ax, bx), std::min(std::max(ay, by), std::max(az, bz)));
    pdf += t1 > t0 ? scale[b] * (t1 * t1 * t1 - t0 * t0 * t0) : 0.f;
  }
  return pdf;
}

float Light::pdfArea(const Vec3f& p, const Vec3f& y, const Vec3f& ny) const {
  const Vec3f d = y - p;
  const float d2 = dot(d, d);
  const float cosL = std::fabs(dot(normalize(d), ny));
  if (!(cosL > 0) || m_areas.total() <= 0) return 0;
  return d2 / (cosL * m_areas.total());
}

}  // namespace iso
