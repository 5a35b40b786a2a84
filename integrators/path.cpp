#include "integrators/path.h"

#include <cmath>

namespace iso {

namespace {
float maxComponent(const Vec3f& v) { return std::max({v.x, v.y, v.z}); }
bool isBlack(const Vec3f& v) { return !(v.x > 0 || v.y > 0 || v.z > 0); }
}  // namespace

Vec3f PathIntegrator::sampleLight(const Hit& hit, const Bsdf& bsdf, const Vec3f& wo, Sampler& sampler,
                                  RayCounters& counters) const {
  const float uPick = sampler.next(), u0 = sampler.next(), u1 = sampler.next(), u2 = sampler.next();
  float pickPdf;
  const int index = m_world.pickLight(uPick, pickPdf);
  if (index < 0 || !(pickPdf > 0)) return {0, 0, 0};
  const Light& light = m_world.lights()[size_t(index)];
  LightSample ls;
  if (!light.sample(hit.position, u0, u1, u2, ls) || !(ls.pdf > 0)) return {0, 0, 0};
  if (!ls.traced && isBlack(ls.L)) return {0, 0, 0};
  // Opaque surfaces reflect only to the side wo is on: a light behind the geometric surface
  // is not seen through it, whatever the shading normal says.
  if (dot(ls.wi, hit.normal) * dot(wo, hit.normal) <= 0) return {0, 0, 0};
  const Vec3f f = bsdf.f(wo, ls.wi) * std::fabs(dot(ls.wi, bsdf.frame().n));
  if (isBlack(f)) return {0, 0, 0};
  ++counters.shadow;
  if (ls.traced) {
    // An iso-surface light: its radiance is what the ray finds first, if that is the light.
    Hit lit;
    Vec3f T;
    if (!m_world.intersectPastThin(spawnRay(hit, ls.wi), lit, T, counters.traversal) || m_world.lightOf(lit) != index)
      return {0, 0, 0};
    ls.L = m_world.emitted(lit, -ls.wi) * T;
    if (isBlack(ls.L)) return {0, 0, 0};
  } else {
    const Ray shadow = std::isinf(ls.distance) ? spawnRay(hit, ls.wi)
                                               : spawnRayTo(hit, hit.position + ls.wi * ls.distance);
    const Vec3f T = m_world.transmittance(shadow, counters.traversal);
    if (isBlack(T)) return {0, 0, 0};
    ls.L = ls.L * T;
  }
  const float lightPdf = ls.pdf * pickPdf;
  const float weight = ls.delta ? 1.f : powerHeuristic(lightPdf, bsdf.pdf(wo, ls.wi));
  return f * ls.L * (weight / lightPdf);
}

void PathIntegrator::Li(const Ray& cameraRay, Sampler& sampler, RayCounters& counters, SampleResult& out) const {
  const std::vector<Light>& lights = m_world.lights();
  Vec3f L{0, 0, 0}, direct{0, 0, 0}, beta{1, 1, 1};
  Ray ray = cameraRay;
  ray.dir = normalize(ray.dir);
  // The last bounce was a delta lobe (or there was none: the camera): no light sampling
  // competed with it.
  bool specular = true;
  float bsdfPdf = 0;
  Vec3f previous;  // the last scattering point, for the area light pdf
  // `bounce` counts scattering events so far: the ray being traced leaves vertex `bounce`. A
  // straight pass through a thin sheet is no scattering event (the path has not turned), so
  // a sheet does not use up depth; `segment` counts every ray traced.
  int bounce = 0;
  for (int segment = 0;; ++segment) {
    auto add = [&](const Vec3f& c) {
      L += c;
      if (bounce <= 1) direct += c;  // emission seen directly or from the first scattering
    };
    Hit hit;
    ++(segment == 0 ? counters.camera : counters.indirect);
    if (!m_world.intersect(ray, hit, counters.traversal)) {
      for (int i : m_world.environmentLights()) {
        const Vec3f Le = lights[i].environment(ray.dir);
        const float w =
            specular ? 1.f : powerHeuristic(bsdfPdf, m_world.lightProbability(i) * lights[i].pdfEnvironment(ray.dir));
        add(beta * Le * w);
      }
      break;
    }
    if (segment == 0) recordFirstHit(ray, hit, out);
    const Vec3f wo = -ray.dir;
    const Vec3f Le = m_world.emitted(hit, wo);
    if (!isBlack(Le)) {
      float w = 1;
      // Emitters are also reached by light sampling (from the previous vertex): weigh by MIS.
      const int light = m_world.lightOf(hit);
      if (!specular && light >= 0) {
        const Light& l = lights[size_t(light)];
        const float pdf = l.kind() == Light::Kind::IsoSurface ? l.pdfIsoSurface(previous, ray.dir)
                                                              : l.pdfArea(previous, hit.position, hit.normal);
        w = powerHeuristic(bsdfPdf, m_world.lightProbability(light) * pdf);
      }
      add(beta * Le * w);
    }
    // At the last scattering event the path ends, unless a thin sheet lets it go on straight.
    const Material& material = m_world.materials()[size_t(hit.material)];
    const bool last = bounce == m_maxDepth;
    if (last && !(material.thin && material.type == MaterialType::Dielectric)) break;
    const Bsdf bsdf = m_world.bsdf(hit);
    if (bsdf.isBlack()) break;
    if (!bsdf.isDelta()) {
      const Vec3f Ld = sampleLight(hit, bsdf, wo, sampler, counters);
      L += beta * Ld;
      if (bounce == 0) direct += beta * Ld;
    }
    const float u0 = sampler.next(), u1 = sampler.next(), u2 = sampler.next();
    BsdfSample bs;
    if (!bsdf.sample(wo, u0, u1, u2, bs) || (last && !bs.straight)) break;
    // A reflection must leave on wo's side of the geometric surface, a transmission on the
    // other; otherwise the shading normal has bent it through the surface.
    const bool sameSide = dot(bs.wi, hit.normal) * dot(wo, hit.normal) > 0;
    if (sameSide == bs.transmission) break;
    beta = beta * bs.f * (std::fabs(dot(bs.wi, bsdf.frame().n)) / bs.pdf);
    if (!(maxComponent(beta) > 0) || !std::isfinite(maxComponent(beta))) break;
    // Straight through a thin sheet the path has not turned: light sampling from the last real
    // scattering point saw through the sheet too, so the MIS state stays that point's.
    if (!bs.straight) {
      specular = bs.delta;
      bsdfPdf = bs.pdf;
      previous = hit.position;
    }
    ray = spawnRay(hit, bs.wi);
    if (bs.straight) continue;
    // Russian roulette after three bounces (pbrt-v4): survival in proportion to throughput.
    if (bounce++ >= 2) {
      const float q = std::max(0.05f, 1 - maxComponent(beta));
      if (sampler.next() < q) break;
      beta = beta / (1 - q);
    }
  }
  if (m_clamp > 0) {
    // Fireflies are rare paths of huge weight, almost always indirect (a diffuse bounce onto
    // a glossy reflection of a small light): clipping the indirect part removes them and
    // leaves direct light exact.
    const Vec3f indirect = L - direct;
    const float peak = maxComponent(indirect);
    if (peak > m_clamp) L = direct + indirect * (m_clamp / peak);
  }
  out.L = L;
  out.direct = direct;
}

}  // namespace iso
