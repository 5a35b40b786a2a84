#include "integrators/path.h"

#include <cmath>

namespace iso {

namespace {
float maxComponent(const Vec3f& v) { return std::max({v.x, v.y, v.z}); }
bool isBlack(const Vec3f& v) { return !(v.x > 0 || v.y > 0 || v.z > 0); }
}  // namespace

// Next-event estimation at `hit`: one light chosen by power, one sample of it. What the light
// brings if nothing blocks it goes to p.unblocked, and the shadow ray to p.shadow (p.shadowing);
// an iso-surface light (a ray that must hit it) and shadow rays through thin sheets are
// answered here at once, into p.L. The random numbers are drawn here either way.
void PathIntegrator::sampleLight(PathState& p, const Hit& hit, const Bsdf& bsdf, const Vec3f& wo,
                                 RayCounters& counters) const {
  Sampler& sampler = p.sampler;
  const float uPick = sampler.next(), u0 = sampler.next(), u1 = sampler.next(), u2 = sampler.next();
  float pickPdf;
  const int index = m_world.pickLight(uPick, pickPdf);
  if (index < 0 || !(pickPdf > 0)) return;
  const Light& light = m_world.lights()[size_t(index)];
  LightSample ls;
  if (!light.sample(hit.position, u0, u1, u2, ls) || !(ls.pdf > 0)) return;
  if (!ls.traced && isBlack(ls.L)) return;
  // Opaque surfaces reflect only to the side wo is on: a light behind the geometric surface
  // is not seen through it, whatever the shading normal says.
  if (dot(ls.wi, hit.normal) * dot(wo, hit.normal) <= 0) return;
  // (The BSDF's pdf only weighs a light that BSDF sampling could also reach.)
  float bsdfPdf = 0;
  const Vec3f f = bsdf.evaluate(ls.wi, ls.delta ? nullptr : &bsdfPdf) * std::fabs(dot(ls.wi, bsdf.frame().n));
  if (isBlack(f)) return;
  ++counters.shadow;
  const float lightPdf = ls.pdf * pickPdf;
  const float weight = ls.delta ? 1.f : powerHeuristic(lightPdf, bsdfPdf);
  const bool isDirect = p.bounce == 0;
  auto add = [&](const Vec3f& Ld) {
    p.L += p.beta * Ld;
    if (isDirect) p.direct += p.beta * Ld;
  };
  if (ls.traced) {
    // An iso-surface light: its radiance is what the ray finds first, if that is the light.
    Hit lit;
    Vec3f T;
    if (!m_world.intersectPastThin(spawnRay(hit, ls.wi), lit, T, counters.traversal) || m_world.lightOf(lit) != index)
      return;
    ls.L = m_world.emitted(lit, -ls.wi) * T;
    if (isBlack(ls.L)) return;
    add(f * ls.L * (weight / lightPdf));
    return;
  }
  const Ray shadow = std::isinf(ls.distance) ? spawnRay(hit, ls.wi) : spawnRayTo(hit, hit.position + ls.wi * ls.distance);
  if (!m_world.opaqueShadows()) {
    const Vec3f T = m_world.transmittance(shadow, counters.traversal);
    if (isBlack(T)) return;
    ls.L = ls.L * T;
    add(f * ls.L * (weight / lightPdf));
    return;
  }
  // Opaque occluders only: the light arrives whole or not at all (afterShadow).
  const Vec3f Ld = f * ls.L * (weight / lightPdf);
  p.unblocked = p.beta * Ld;
  p.unblockedIsDirect = isDirect;
  p.shadow = shadow;
  p.shadowing = true;
}

void PathIntegrator::recordFeatures(PathState& p, const Hit& hit, const Vec3f& albedo) const {
  p.featurePending = false;
  p.out.albedo = albedo * p.beta;
  p.out.normal = hit.shading;
}

void PathIntegrator::start(PathState& p) const {
  p.ray.dir = normalize(p.ray.dir);
  p.tracing = true;
}

void PathIntegrator::afterShadow(PathState& p, bool blocked) const {
  if (blocked) return;
  p.L += p.unblocked;
  if (p.unblockedIsDirect) p.direct += p.unblocked;
}

void PathIntegrator::afterTrace(PathState& p, bool found, const Hit& hit, RayCounters& counters) const {
  const std::vector<Light>& lights = m_world.lights();
  const Ray& ray = p.ray;
  const int segment = p.segment++;
  auto add = [&](const Vec3f& c) {
    p.L += c;
    if (p.bounce <= 1) p.direct += c;  // emission seen directly or from the first scattering
  };
  ++(segment == 0 ? counters.camera : counters.indirect);
  if (!found) {
    for (int i : m_world.environmentLights()) {
      const Vec3f Le = lights[i].environment(ray.dir);
      const float w =
          p.specular ? 1.f : powerHeuristic(p.bsdfPdf, m_world.lightProbability(i) * lights[i].pdfEnvironment(ray.dir));
      add(p.beta * Le * w);
    }
    return;
  }
  if (segment == 0) {
    recordFirstHit(ray, hit, p.out);
    p.featurePending = true;
  }
  const Vec3f wo = -ray.dir;
  const Vec3f Le = m_world.emitted(hit, wo);
  if (!isBlack(Le)) {
    float w = 1;
    // Emitters are also reached by light sampling (from the previous vertex): weigh by MIS.
    const int light = m_world.lightOf(hit);
    if (!p.specular && light >= 0) {
      const Light& l = lights[size_t(light)];
      const float pdf = l.kind() == Light::Kind::IsoSurface ? l.pdfIsoSurface(p.previous, ray.dir)
                                                            : l.pdfArea(p.previous, hit.position, hit.normal);
      w = powerHeuristic(p.bsdfPdf, m_world.lightProbability(light) * pdf);
    }
    add(p.beta * Le * w);
  }
  // At the last scattering event the path ends, unless a thin sheet lets it go on straight.
  const Material& material = m_world.materials()[size_t(hit.material)];
  const bool last = p.bounce == m_maxDepth;
  if (last && !(material.thin && material.type == MaterialType::Dielectric)) {
    if (p.featurePending) recordFeatures(p, hit, m_world.albedo(hit));
    return;
  }
  const Bsdf bsdf = m_world.bsdf(hit, wo);
  // The denoiser's albedo and normal: those of the first surface that is not a perfect mirror or
  // glass, tinted by what the specular bounces before it passed (a glass skin over bone gives the
  // bone's), so that what is seen through glass keeps its edges.
  if (p.featurePending && (!bsdf.isDelta() || bsdf.isBlack())) recordFeatures(p, hit, bsdf.albedo());
  if (bsdf.isBlack()) return;
  if (!bsdf.isDelta()) sampleLight(p, hit, bsdf, wo, counters);
  Sampler& sampler = p.sampler;
  const float u0 = sampler.next(), u1 = sampler.next(), u2 = sampler.next();
  BsdfSample bs;
  if (!bsdf.sample(u0, u1, u2, bs) || (last && !bs.straight)) return;
  // A reflection must leave on wo's side of the geometric surface, a transmission on the
  // other; otherwise the shading normal has bent it through the surface.
  const bool sameSide = dot(bs.wi, hit.normal) * dot(wo, hit.normal) > 0;
  if (sameSide == bs.transmission) return;
  p.beta = p.beta * bs.f * (std::fabs(dot(bs.wi, bsdf.frame().n)) / bs.pdf);
  if (!(maxComponent(p.beta) > 0) || !std::isfinite(maxComponent(p.beta))) return;
  // Straight through a thin sheet the path has not turned: light sampling from the last real
  // scattering point saw through the sheet too, so the MIS state stays that point's.
  if (!bs.straight) {
    p.specular = bs.delta;
    p.bsdfPdf = bs.pdf;
    p.previous = hit.position;
  }
  p.ray = spawnRay(hit, bs.wi);
  if (!bs.straight) {
    // Russian roulette after three bounces (pbrt-v4): survival in proportion to throughput.
    if (p.bounce++ >= 2) {
      const float q = std::max(0.05f, 1 - maxComponent(p.beta));
      if (sampler.next() < q) return;
      p.beta = p.beta / (1 - q);
    }
  }
  p.tracing = true;
}

void PathIntegrator::finish(PathState& p) const {
  Vec3f L = p.L;
  if (m_clamp > 0) {
    // Fireflies are rare paths of huge weight, almost always indirect (a diffuse bounce onto
    // a glossy reflection of a small light): clipping the indirect part removes them and
    // leaves direct light exact.
    const Vec3f indirect = L - p.direct;
    const float peak = maxComponent(indirect);
    if (peak > m_clamp) L = p.direct + indirect * (m_clamp / peak);
  }
  p.out.L = L;
  p.out.direct = p.direct;
}

}  // namespace iso
