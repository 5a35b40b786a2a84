// The visualisation integrators: shading normals, and a headlight for a first look.
#include <cmath>
#include <stdexcept>

#include "integrators/integrator.h"

namespace iso {
namespace {

// The world-space shading normal, components in [-1, 1], exactly 0 where nothing is hit.
class NormalsIntegrator final : public Integrator {
 public:
  using Integrator::Integrator;
  Vec3f Li(const Ray& ray, Sampler&, RayCounters& counters) const override {
    ++counters.camera;
    Hit hit;
    if (!m_world.intersect(ray, hit, counters.traversal)) return {0, 0, 0};
    return hit.shading;
  }
  bool signedOutput() const override { return true; }
};

// A light at the eye: the material's base colour (textures included) times a Lambert term
// with the cosine to the viewer, both sides lit; emitters show their emission.
class EyelightIntegrator final : public Integrator {
 public:
  using Integrator::Integrator;
  Vec3f Li(const Ray& ray, Sampler&, RayCounters& counters) const override {
    ++counters.camera;
    Hit hit;
    if (!m_world.intersect(ray, hit, counters.traversal)) return {0, 0, 0};
    const float cosine = std::fabs(dot(hit.shading, ray.dir));
    return m_world.albedo(hit) * (0.1f + 0.9f * cosine) + m_world.emitted(hit, -ray.dir);
  }
};

}  // namespace

std::unique_ptr<Integrator> makeIntegrator(const std::string& name, const World& world) {
  if (name == "normals") return std::make_unique<NormalsIntegrator>(world);
  if (name == "eyelight") return std::make_unique<EyelightIntegrator>(world);
  throw std::logic_error("makeIntegrator: unknown integrator '" + name + "'");
}

}  // namespace iso
