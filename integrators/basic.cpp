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
  void Li(const Ray& ray, Sampler&, RayCounters& counters, SampleResult& out) const override {
    Hit hit;
    if (!traceCameraRay(ray, hit, counters, out)) return;
    out.L = hit.shading;
  }
  bool signedOutput() const override { return true; }
};

// A light at the eye: the material's base colour (textures included) times a Lambert term
// with the cosine to the viewer, both sides lit; emitters show their emission.
class EyelightIntegrator final : public Integrator {
 public:
  using Integrator::Integrator;
  void Li(const Ray& ray, Sampler&, RayCounters& counters, SampleResult& out) const override {
    Hit hit;
    if (!traceCameraRay(ray, hit, counters, out)) return;
    const float cosine = std::fabs(dot(hit.shading, normalize(ray.dir)));
    out.L = m_world.albedo(hit) * (0.1f + 0.9f * cosine) + m_world.emitted(hit, -normalize(ray.dir));
  }
};

// Ambient occlusion: one cosine-weighted direction per sample around the shading normal on
// the viewer's side; 1 when nothing lies within `distance`, else 0.
class AmbientOcclusionIntegrator final : public Integrator {
 public:
  AmbientOcclusionIntegrator(const World& world, float distance) : Integrator(world), m_distance(distance) {}
  void Li(const Ray& ray, Sampler& sampler, RayCounters& counters, SampleResult& out) const override {
    Hit hit;
    if (!traceCameraRay(ray, hit, counters, out)) return;
    const Vec3f wo = -normalize(ray.dir);
    const Vec3f n = dot(hit.shading, wo) < 0 ? -hit.shading : hit.shading;
    const Frame frame = Frame::fromNormal(n, hit.dpdu);
    const float u0 = sampler.next(), u1 = sampler.next();
    const Vec3f wi = frame.toWorld(sampleCosineHemisphere(u0, u1));
    Ray shadow = spawnRay(hit, wi);
    shadow.tfar = m_distance;
    ++counters.shadow;
    const float open = m_world.occluded(shadow, counters.traversal) ? 0.f : 1.f;
    out.L = {open, open, open};
  }

 private:
  float m_distance;
};

}  // namespace

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
