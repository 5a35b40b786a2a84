// The visualisation integrators: shading normals, a headlight, ambient occlusion.
#include <cmath>
#include <stdexcept>

#include "integrators/integrator.h"
#include "integrators/path.h"

namespace iso {
namespace {

// The world-space shading normal, components in [-1, 1], exactly 0 where nothing is hit.
class NormalsIntegrator final : public Integrator {
 public:
  using Integrator::Integrator;
  void afterTrace(PathState& p, bool found, const Hit& hit, RayCounters& counters) const override {
    ++counters.camera;
    if (!found) return;
    recordFirstHit(p.ray, hit, p.out);
    p.out.L = hit.shading;
  }
  bool signedOutput() const override { return true; }
};

// A light at the eye: the material's base colour (textures included) times a Lambert term
// with the cosine to the viewer, both sides lit; emitters show their emission.
class EyelightIntegrator final : public Integrator {
 public:
  using Integrator::Integrator;
  void afterTrace(PathState& p, bool found, const Hit& hit, RayCounters& counters) const override {
    ++counters.camera;
    if (!found) return;
    recordFirstHit(p.ray, hit, p.out);
    const float cosine = std::fabs(dot(hit.shading, normalize(p.ray.dir)));
    p.out.L = m_world.albedo(hit) * (0.1f + 0.9f * cosine) + m_world.emitted(hit, -normalize(p.ray.dir));
  }
};

// Ambient occlusion: one cosine-weighted direction per sample around the shading normal on
// the viewer's side; 1 when nothing lies within `distance`, else 0.
class AmbientOcclusionIntegrator final : public Integrator {
 public:
  AmbientOcclusionIntegrator(const World& world, float distance) : Integrator(world), m_distance(distance) {}
  void afterTrace(PathState& p, bool found, const Hit& hit, RayCounters& counters) const override {
    ++counters.camera;
    if (!found) return;
    recordFirstHit(p.ray, hit, p.out);
    const Vec3f wo = -normalize(p.ray.dir);
    const Vec3f n = dot(hit.shading, wo) < 0 ? -hit.shading : hit.shading;
    const Frame frame = Frame::fromNormal(n, World::textureFrame(hit).dpdu);
    const float u0 = p.sampler.next(), u1 = p.sampler.next();
    const Vec3f wi = frame.toWorld(sampleCosineHemisphere(u0, u1));
    p.shadow = spawnRay(hit, wi);
    p.shadow.tfar = m_distance;
    p.shadowing = true;
    ++counters.shadow;
  }
  void afterShadow(PathState& p, bool blocked) const override {
    const float open = blocked ? 0.f : 1.f;
    p.out.L = {open, open, open};
  }

 private:
  float m_distance;
};

}  // namespace

void Integrator::Li(const Ray& ray, Sampler& sampler, RayCounters& counters, SampleResult& out) const {
  PathState p;
  p.begin(ray, sampler);
  start(p);
  while (p.tracing || p.shadowing) {
    if (p.shadowing) {
      p.shadowing = false;
      afterShadow(p, m_world.occluded(p.shadow, counters.traversal));
    }
    if (p.tracing) {
      p.tracing = false;
      Hit hit;
      const bool found = m_world.intersect(p.ray, hit, counters.traversal);
      afterTrace(p, found, hit, counters);
    }
  }
  finish(p);
  out = p.out;
  sampler = p.sampler;
}

std::unique_ptr<Integrator> makeIntegrator(const std::string& name, const World& world,
                                           const RenderSettings& settings) {
  if (name == "normals") return std::make_unique<NormalsIntegrator>(world);
  if (name == "eyelight") return std::make_unique<EyelightIntegrator>(world);
  if (name == "ao") return std::make_unique<AmbientOcclusionIntegrator>(world, float(settings.aoDistance));
  const float clamp = float(settings.clampIndirect);
  if (name == "direct") return std::make_unique<PathIntegrator>(world, 1, false, clamp);
  if (name == "path") return std::make_unique<PathIntegrator>(world, settings.maxDepth, false, clamp);
  if (name == "compare") return std::make_unique<PathIntegrator>(world, settings.maxDepth, true, clamp);
  throw std::logic_error("makeIntegrator: unknown integrator '" + name + "'");
}

}  // namespace iso
