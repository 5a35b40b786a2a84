#include "scene/material.h"

#include <cmath>

namespace iso {

namespace {
constexpr float kPi = float(M_PI);
// Below this roughness^2 a GGX lobe is numerically a spike; conductors switch to a mirror
// and the glTF material keeps this floor (its spec has no delta lobe).
constexpr float kMinAlpha = 1e-3f;

Vec3f reflect(const Vec3f& w, const Vec3f& n) { return n * (2 * dot(w, n)) - w; }

Vec3f schlick(const Vec3f& f0, float cosine) {
  const float m = std::clamp(1 - cosine, 0.f, 1.f), m5 = m * m * m * m * m;
  return f0 + (Vec3f{1, 1, 1} - f0) * m5;
}
}  // namespace

Frame Frame::fromNormal(const Vec3f& n, const Vec3f& hint) {
  Frame f;
  f.n = n;
  // (A zero hint, as surfaces without texture coordinates give, always takes the fallback.)
  const bool noHint = hint.x == 0 && hint.y == 0 && hint.z == 0;
  Vec3f s = noHint ? Vec3f{0, 0, 0} : hint - n * dot(n, hint);
  float len = noHint ? 0.f : length(s);
  if (!(len > 1e-6f)) {
    // Duff et al. 2017, "Building an Orthonormal Basis, Revisited".
    const float sign = std::copysign(1.f, n.z), a = -1 / (sign + n.z), b = n.x * n.y * a;
    s = {1 + sign * n.x * n.x * a, sign * b, -sign * n.x};
    len = length(s);
  }
  f.s = s / len;
  f.t = cross(n, f.s);
  return f;
}

Vec3f sampleCosineHemisphere(float u0, float u1) {
  const float r = std::sqrt(u0), phi = 2 * kPi * u1;
  return {r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.f, 1 - u0))};
}

Vec3f sampleUniformSphere(float u0, float u1) {
  const float z = 1 - 2 * u0, r = std::sqrt(std::max(0.f, 1 - z * z)), phi = 2 * kPi * u1;
  return {r * std::cos(phi), r * std::sin(phi), z};
}

float fresnelDielectric(float cosI, float eta) {
  if (cosI < 0) {
    eta = 1 / eta;
    cosI = -cosI;
  }
  const float sin2T = (1 - cosI * cosI) / (eta * eta);
  if (sin2T >= 1) return 1;  // total internal reflection
  const float cosT = std::sqrt(1 - sin2T);
  const float rs = (cosI - eta * cosT) / (cosI + eta * cosT);
  const float rp = (eta * cosI - cosT) / (eta * cosI + cosT);
  return 0.5f * (rs * rs + rp * rp);
}

float thinDielectricReflectance(float cosI, float eta) {
  const float r = fresnelDielectric(std::fabs(cosI), eta);
  if (r >= 1) return 1;
  const float t = 1 - r;
  return r + t * t * r / (1 - r * r);
}

namespace ggx {
float D(const Vec3f& h, float alpha) {
  if (h.z <= 0) return 0;
  const float a2 = alpha * alpha, c2 = h.z * h.z, d = c2 * (a2 - 1) + 1;
  return a2 / (kPi * d * d);
}
float lambda(const Vec3f& w, float alpha) {
  const float c2 = w.z * w.z;
  if (c2 <= 0) return 1e30f;
  const float tan2 = std::max(0.f, 1 - c2) / c2;
  return 0.5f * (std::sqrt(1 + alpha * alpha * tan2) - 1);
}
Vec3f sampleVisibleNormal(const Vec3f& wo, float alpha, float u0, float u1) {
  // Stretch, sample the projected hemisphere, unstretch (Heitz 2018, listing 1).
  const Vec3f vh = normalize(Vec3f{alpha * wo.x, alpha * wo.y, wo.z});
  const float lensq = vh.x * vh.x + vh.y * vh.y;
  const Vec3f t1 = lensq > 0 ? Vec3f{-vh.y, vh.x, 0} / std::sqrt(lensq) : Vec3f{1, 0, 0};
  const Vec3f t2 = cross(vh, t1);
  const float r = std::sqrt(u0), phi = 2 * kPi * u1;
  const float p1 = r * std::cos(phi);
  float p2 = r * std::sin(phi);
  const float s = 0.5f * (1 + vh.z);
  p2 = (1 - s) * std::sqrt(std::max(0.f, 1 - p1 * p1)) + s * p2;
  const Vec3f nh = t1 * p1 + t2 * p2 + vh * std::sqrt(std::max(0.f, 1 - p1 * p1 - p2 * p2));
  return normalize(Vec3f{alpha * nh.x, alpha * nh.y, std::max(1e-7f, nh.z)});
}

namespace {
// E(mu, roughness) on a 32 x 32 grid (mu = cos theta and roughness each from 0 to 1), computed
// once on first use: per entry 16 x 16 stratified visible-normal samples, whose weight for a
// white lobe is G2(wo, wi) / G1(wo) (Heitz 2018). Eavg = 2 * integral of E(mu) mu dmu.
struct AlbedoTable {
  static constexpr int kSize = 32;
  float e[kSize][kSize];  // [roughness][mu]
  float average[kSize];
  AlbedoTable() {
    for (int r = 0; r < kSize; ++r) {
      const float roughness = float(r) / (kSize - 1);
      const float alpha = std::max(roughness * roughness, kMinAlpha);
      for (int m = 0; m < kSize; ++m) {
        const float mu = std::max(float(m) / (kSize - 1), 1e-3f);
        const Vec3f wo{std::sqrt(1 - mu * mu), 0, mu};
        const float g1 = 1 / (1 + lambda(wo, alpha));
        double sum = 0;
        constexpr int n = 16;
        for (int i = 0; i < n; ++i)
          for (int j = 0; j < n; ++j) {
            const Vec3f h = sampleVisibleNormal(wo, alpha, (i + 0.5f) / n, (j + 0.5f) / n);
            const Vec3f wi = reflect(wo, h);
            if (wi.z <= 0) continue;
            sum += (1 / (1 + lambda(wo, alpha) + lambda(wi, alpha))) / g1;
          }
        e[r][m] = float(std::min(1.0, sum / (n * n)));
      }
      double avg = 0;  // trapezoid rule over mu
      for (int m = 0; m + 1 < kSize; ++m) {
        const double m0 = double(m) / (kSize - 1), m1 = double(m + 1) / (kSize - 1);
        avg += (e[r][m] * m0 + e[r][m + 1] * m1) * (m1 - m0);
      }
      average[r] = float(std::min(avg, 1.0));
    }
  }
  static const AlbedoTable& get() {
    static const AlbedoTable table;
    return table;
  }
};
}  // namespace

float albedo(float cosTheta, float roughness) {
  const AlbedoTable& t = AlbedoTable::get();
  const float x = std::clamp(cosTheta, 0.f, 1.f) * (AlbedoTable::kSize - 1);
  const float y = std::clamp(roughness, 0.f, 1.f) * (AlbedoTable::kSize - 1);
  const int x0 = std::min(int(x), AlbedoTable::kSize - 2), y0 = std::min(int(y), AlbedoTable::kSize - 2);
  const float fx = x - x0, fy = y - y0;
  return (t.e[y0][x0] * (1 - fx) + t.e[y0][x0 + 1] * fx) * (1 - fy) +
         (t.e[y0 + 1][x0] * (1 - fx) + t.e[y0 + 1][x0 + 1] * fx) * fy;
}

float averageAlbedo(float roughness) {
  const AlbedoTable& t = AlbedoTable::get();
  const float y = std::clamp(roughness, 0.f, 1.f) * (AlbedoTable::kSize - 1);
  const int y0 = std::min(int(y), AlbedoTable::kSize - 2);
  const float fy = y - y0;
  return t.average[y0] * (1 - fy) + t.average[y0 + 1] * fy;
}

Vec3f multipleScatteringTint(const Vec3f& f0, float roughness) {
  const float eAvg = averageAlbedo(roughness);
  const Vec3f fAvg = f0 + (Vec3f{1, 1, 1} - f0) * (1.f / 21);
  Vec3f out;
  // A white lobe (Favg = 1) gives 1: it returns exactly the 1 - E(mu_o) single scattering lost.
  for (int c = 0; c < 3; ++c) out[c] = fAvg[c] * fAvg[c] * eAvg / (1 - fAvg[c] * (1 - eAvg));
  return out;
}

}  // namespace ggx

Bsdf::Bsdf(MaterialType type, const Frame& frame, const Vec3f& color, float metallic, float roughness, float ior,
           bool thin)
    : m_type(type), m_frame(frame), m_color(color), m_metallic(metallic), m_eta(ior),
      m_thin(thin && type == MaterialType::Dielectric) {
  m_alpha = std::max(roughness * roughness, kMinAlpha);
  if (glossy()) m_roughness = std::sqrt(m_alpha);
  m_delta = type == MaterialType::Dielectric || (type == MaterialType::Conductor && roughness * roughness < kMinAlpha);
}

void Bsdf::setOutgoingLocal(const Vec3f& wo) {
  m_woLocal = wo;
  m_flip = wo.z < 0 ? -1.f : 1.f;
  m_wo = {wo.x, wo.y, wo.z * m_flip};
  if (!glossy() || m_delta || !(m_wo.z >= 0)) return;
  m_lambdaO = ggx::lambda(m_wo, m_alpha);
  const float eAvg = ggx::averageAlbedo(m_roughness);
  m_multipleScattering = eAvg < 1;
  m_lostO = 1 - ggx::albedo(m_wo.z, m_roughness);
  m_msDenominator = kPi * (1 - eAvg);
  // glTF 2.0 Appendix B: the specular layer's Fresnel at normal incidence, 0.04 for the
  // dielectric part and the base colour for the metal part.
  m_f0 = m_type == MaterialType::Conductor ? m_color
                                           : Vec3f{0.04f, 0.04f, 0.04f} * (1 - m_metallic) + m_color * m_metallic;
  m_tint = ggx::multipleScatteringTint(m_f0, m_roughness);
  if (m_type == MaterialType::Conductor) {
    // Conductors send a share of samples to the multiple-scattering lobe (cosine-distributed).
    const float q = std::clamp(m_lostO, 0.f, 0.9f);
    m_specularShare = 1 - q;
    m_cosineShare = q;
  } else {
    // The glTF material's specular share: its Fresnel weight at wo against the diffuse albedo,
    // kept away from 0 and 1 so both lobes stay sampled.
    const float spec = luminance(schlick(m_f0, std::fabs(m_wo.z)));
    const float diff = luminance(m_color) * (1 - m_metallic) * (1 - spec);
    m_specularShare = diff <= 0 ? 1 : std::clamp(spec / (spec + diff), 0.1f, 0.9f);
    m_cosineShare = 1 - m_specularShare;
  }
}

float Bsdf::pdf(const Vec3f& wi) const {
  float p;
  evaluateLocal(m_frame.toLocal(wi), &p);
  return p;
}

bool Bsdf::sample(float u0, float u1, float u2, BsdfSample& out) const {
  if (!sampleOutgoing(u0, u1, u2, out)) return false;
  out.wi = m_frame.toWorld(out.wi);
  return true;
}

Vec3f Bsdf::fLocal(const Vec3f& wo, const Vec3f& wi) const {
  Bsdf b(*this);
  b.setOutgoingLocal(wo);
  return b.evaluateLocal(wi, nullptr);
}

float Bsdf::pdfLocal(const Vec3f& wo, const Vec3f& wi) const {
  Bsdf b(*this);
  b.setOutgoingLocal(wo);
  float p;
  b.evaluateLocal(wi, &p);
  return p;
}

bool Bsdf::sampleLocal(const Vec3f& wo, float u0, float u1, float u2, BsdfSample& out) const {
  Bsdf b(*this);
  b.setOutgoingLocal(wo);
  return b.sampleOutgoing(u0, u1, u2, out);
}

// Visible-normal sampling's density of h (Heitz 2018, eq. 3), D(h) given, turned into a density
// of the reflected direction (the 1 / (4 wo.h) Jacobian).
float Bsdf::specularPdf(const Vec3f& h, float d) const {
  const float pdfH = d / (1 + m_lambdaO) * std::max(0.f, dot(m_wo, h)) / m_wo.z;
  return pdfH / (4 * dot(m_wo, h));
}

Vec3f Bsdf::evaluateLocal(const Vec3f& wiIn, float* pdf) const {
  if (pdf) *pdf = 0;
  if (m_delta || m_type == MaterialType::Emissive) return {0, 0, 0};
  if (m_woLocal.z * wiIn.z <= 0) return {0, 0, 0};  // opaque: reflection only
  const Vec3f wi{wiIn.x, wiIn.y, wiIn.z * m_flip};
  const float cosine = wi.z / kPi;
  if (m_type == MaterialType::Diffuse) {
    if (pdf) *pdf = cosine;
    return m_color / kPi;
  }
  const Vec3f h = normalize(m_wo + wi);
  const float d = ggx::D(h, m_alpha);
  if (pdf) *pdf = m_specularShare * specularPdf(h, d) + m_cosineShare * cosine;
  const float G = 1 / (1 + m_lambdaO + ggx::lambda(wi, m_alpha));
  const float spec = d * G / (4 * m_wo.z * wi.z);
  // The energy single scattering loses, returned as a diffuse-like lobe (Kulla & Conty 2017).
  const Vec3f ms = m_multipleScattering
                       ? m_tint * (m_lostO * (1 - ggx::albedo(wi.z, m_roughness)) / m_msDenominator)
                       : Vec3f{0, 0, 0};
  if (m_type == MaterialType::Conductor) return schlick(m_color, dot(wi, h)) * spec + ms;
  // glTF 2.0 Appendix B: mix(dielectric_brdf, metal_brdf, metallic) with Schlick Fresnel,
  // the specular layer with its multiple scattering.
  const Vec3f F = schlick(m_f0, dot(wi, h));
  const Vec3f diffuse = (Vec3f{1, 1, 1} - F) * m_color * ((1 - m_metallic) / kPi);
  return diffuse + F * spec + ms;
}

bool Bsdf::sampleOutgoing(float u0, float u1, float u2, BsdfSample& out) const {
  const Vec3f& woIn = m_woLocal;
  if (m_type == MaterialType::Emissive || woIn.z == 0) return false;
  if (m_type == MaterialType::Dielectric) {
    // Smooth glass: the side of wo says whether the ray enters (wo.z > 0) or leaves. A thin
    // sheet reflects its inner reflections too and transmits straight through.
    const float F = m_thin ? thinDielectricReflectance(woIn.z, m_eta) : fresnelDielectric(woIn.z, m_eta);
    const float cosO = std::fabs(woIn.z);
    out.delta = true;
    if (u0 < F) {
      out.wi = {-woIn.x, -woIn.y, woIn.z};
      out.f = Vec3f{F, F, F} / cosO;
      out.pdf = F;
      out.transmission = false;
      return true;
    }
    if (m_thin) {
      out.wi = -woIn;
      out.f = m_color * ((1 - F) / cosO);
      out.pdf = 1 - F;
      out.transmission = out.straight = true;
      return out.pdf > 0;
    }
    const bool entering = woIn.z > 0;
    const float eta = entering ? m_eta : 1 / m_eta;  // eta_t / eta_i
    const float sin2T = (1 - woIn.z * woIn.z) / (eta * eta);
    const float cosT = std::sqrt(std::max(0.f, 1 - sin2T));
    out.wi = normalize(Vec3f{-woIn.x / eta, -woIn.y / eta, entering ? -cosT : cosT});
    // Radiance is compressed by 1/eta^2 on the way in (pbrt-v4, "non-symmetric scattering").
    out.f = m_color * ((1 - F) / (eta * eta) / std::fabs(out.wi.z));
    out.pdf = 1 - F;
    out.transmission = true;
    return out.pdf > 0;
  }
  const Vec3f& wo = m_wo;
  out.transmission = false;
  if (m_type == MaterialType::Conductor && m_delta) {
    out.wi = {-wo.x, -wo.y, wo.z * m_flip};
    out.f = schlick(m_color, wo.z) / wo.z;
    out.pdf = 1;
    out.delta = true;
    return true;
  }
  out.delta = false;
  Vec3f wi;
  if (m_type == MaterialType::Diffuse) {
    wi = sampleCosineHemisphere(u1, u2);
  } else if (u0 < m_specularShare) {
    wi = reflect(wo, ggx::sampleVisibleNormal(wo, m_alpha, u1, u2));
    if (wi.z <= 0) return false;
  } else {
    wi = sampleCosineHemisphere(u1, u2);
  }
  out.wi = {wi.x, wi.y, wi.z * m_flip};
  out.f = evaluateLocal(out.wi, &out.pdf);
  return out.pdf > 0;
}

}  // namespace iso
