#pragma once
// Materials (what the scene file and glTF files say) and the BSDF built from one at a hit.
//
// BSDF conventions (pbrt-v4): directions point away from the surface; f() is the BSDF value
// without the cosine; pdf() is per unit solid angle; sample() returns f, pdf and wi with
// f * |cos(wi, n)| / pdf the path throughput weight. Delta lobes (mirror, smooth glass) have
// f() = pdf() = 0 and are reached only through sample(), which sets `delta`.
#include <string>
#include <vector>

#include "scene/mesh.h"
#include "scene/scene.h"
#include "scene/texture.h"

namespace iso {

struct Material {
  std::string name;
  MaterialType type = MaterialType::Diffuse;
  Vec3f color{0.8f, 0.8f, 0.8f};
  float metallic = 0, roughness = 0.5f, ior = 1.5f;
  Vec3f emission{0, 0, 0};
  bool twoSided = false;  // emits from both sides
  bool thin = false;      // dielectric only: a thin sheet (see Bsdf and World::transmittance)
  // Indices into the World's textures; -1: none.
  int colorTexture = -1, metallicRoughnessTexture = -1, normalTexture = -1, emissionTexture = -1;
  float normalScale = 1;
  bool emits() const { return emission.x > 0 || emission.y > 0 || emission.z > 0; }
};

// An orthonormal frame around a normal.
struct Frame {
  Vec3f s, t, n;
  static Frame fromNormal(const Vec3f& n, const Vec3f& hint);
  Vec3f toLocal(const Vec3f& v) const { return {dot(v, s), dot(v, t), dot(v, n)}; }
  Vec3f toWorld(const Vec3f& v) const { return s * v.x + t * v.y + n * v.z; }
};

struct BsdfSample {
  Vec3f wi;   // world space
  Vec3f f;    // BSDF value (for delta lobes: the value that makes f |cos| / pdf right)
  float pdf = 0;
  bool delta = false;
  bool transmission = false;
  bool straight = false;  // straight through a thin dielectric: the path has not turned
};

// The local-frame BSDF (z = shading normal, pointing out of the solid), seen from one outgoing
// direction. A path asks the BSDF at a hit several questions from the same wo (f and pdf towards
// a light, a sample): what depends on wo alone (its local direction, the GGX masking term, the
// layer's single-scattering albedo and the lobe-choice probability) and on the material alone
// (the multiple-scattering tint) is computed once, in setOutgoing, and every query reads it.
class Bsdf {
 public:
  Bsdf() = default;
  // `thin` (dielectric only): a thin sheet of that glass (pbrt-v4's ThinDielectricBxDF): it
  // reflects R + T^2 R / (1 - R^2) (the inner reflections summed) and transmits the rest
  // straight through, without refraction.
  Bsdf(MaterialType type, const Frame& frame, const Vec3f& color, float metallic, float roughness, float ior,
       bool thin = false);

  // The outgoing direction every query below is from (world space, unit, away from the surface).
  void setOutgoing(const Vec3f& wo) { setOutgoingLocal(m_frame.toLocal(wo)); }
  Vec3f f(const Vec3f& wi) const { return evaluateLocal(m_frame.toLocal(wi), nullptr); }
  float pdf(const Vec3f& wi) const;
  // f(wi), and pdf(wi) into *pdf when given: the two share their half vector and microfacet terms.
  Vec3f evaluate(const Vec3f& wi, float* pdf) const { return evaluateLocal(m_frame.toLocal(wi), pdf); }
  // u: three uniform numbers in [0, 1).
  bool sample(float u0, float u1, float u2, BsdfSample& out) const;
  // True when every lobe is a delta (no light sampling helps).
  bool isDelta() const { return m_delta; }
  bool isBlack() const { return m_type == MaterialType::Emissive; }
  const Vec3f& albedo() const { return m_color; }
  const Frame& frame() const { return m_frame; }

  // Local-frame queries from any wo, for tests (each sets a copy's outgoing direction).
  Vec3f fLocal(const Vec3f& wo, const Vec3f& wi) const;
  float pdfLocal(const Vec3f& wo, const Vec3f& wi) const;
  bool sampleLocal(const Vec3f& wo, float u0, float u1, float u2, BsdfSample& out) const;

 private:
  void setOutgoingLocal(const Vec3f& wo);
  Vec3f evaluateLocal(const Vec3f& wi, float* pdf) const;
  bool sampleOutgoing(float u0, float u1, float u2, BsdfSample& out) const;
  // The GGX layer's microfacet pdf of reflecting wo (flipped up) to wi through h, per solid angle of wi.
  float specularPdf(const Vec3f& h, float d) const;
  bool glossy() const { return m_type == MaterialType::Conductor || m_type == MaterialType::MetallicRoughness; }

  MaterialType m_type = MaterialType::Diffuse;
  Frame m_frame;
  Vec3f m_color{0.8f, 0.8f, 0.8f};
  float m_metallic = 0, m_alpha = 0, m_eta = 1.5f;
  float m_roughness = 0;  // sqrt(m_alpha): the energy tables' parameter (glossy types)
  bool m_thin = false;
  bool m_delta = false;
  // Set by setOutgoing. Opaque materials are two-sided: their queries mirror wo and wi to the
  // upper hemisphere (m_flip); glass keeps wo as it is (its side says entering or leaving).
  Vec3f m_woLocal{0, 0, 1};  // wo as given, in the local frame
  Vec3f m_wo{0, 0, 1};       // flipped up
  float m_flip = 1;
  // Glossy types, from wo: Smith's lambda(wo), 1 - E(wo) (the layer's lost energy, Kulla-Conty),
  // and the share of samples drawn from the specular lobe (1 - the multiple-scattering share
  // for conductors). From the material: f0, 1 - Eavg scaled by pi, and the returned energy's tint.
  float m_lambdaO = 0, m_lostO = 0, m_msDenominator = 0;
  float m_specularShare = 0, m_cosineShare = 0;  // pdf = specular share * its pdf + cosine share * cos / pi
  bool m_multipleScattering = false;  // Eavg < 1
  Vec3f m_f0{0, 0, 0}, m_tint{0, 0, 0};
};

// GGX (Trowbridge-Reitz) with the height-correlated Smith term; visible-normal sampling
// (Heitz 2018, "Sampling the GGX Distribution of Visible Normals").
namespace ggx {
float D(const Vec3f& h, float alpha);
float lambda(const Vec3f& w, float alpha);
Vec3f sampleVisibleNormal(const Vec3f& wo, float alpha, float u0, float u1);
// Multiple scattering (Kulla & Conty 2017, "Revisiting Physically Based Shading at
// Imageworks"): single-scattering GGX loses the light that bounces between microfacets (69%
// of it at grazing angles for roughness 1). E(mu, roughness) is the single-scattering albedo
// of a white lobe, Eavg its cosine-weighted mean; the lost energy returns as a diffuse-like
// lobe (1 - E(mu_o)) (1 - E(mu_i)) / (pi (1 - Eavg)), tinted by Fms below.
float albedo(float cosTheta, float roughness);
float averageAlbedo(float roughness);
// The colour of the returned energy for Schlick Fresnel with reflectance f0: the average
// Fresnel Favg = f0 + (1 - f0) / 21; Fms = Favg^2 Eavg / (1 - Favg (1 - Eavg)), 1 when white.
Vec3f multipleScatteringTint(const Vec3f& f0, float roughness);
}  // namespace ggx

// Exact Fresnel reflectance of a smooth dielectric; cosI > 0 on the side of the normal.
float fresnelDielectric(float cosI, float eta);
// Reflectance of a thin sheet of that dielectric, its inner reflections summed (pbrt-v4).
float thinDielectricReflectance(float cosI, float eta);

// Helpers shared by integrators and lights.
inline float luminance(const Vec3f& c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }
Vec3f sampleCosineHemisphere(float u0, float u1);
Vec3f sampleUniformSphere(float u0, float u1);

}  // namespace iso
