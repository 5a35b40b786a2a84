#pragma once
// An integrator answers one question per camera ray: the radiance along it, Li(ray, sampler).
#include <cstdint>
#include <memory>
#include <string>

#include "renderer/sampler.h"
#include "scene/world.h"

namespace iso {

// Per-thread counters, summed by the renderer after the frame.
struct RayCounters {
  uint64_t camera = 0;
  uint64_t shadow = 0;
  uint64_t indirect = 0;
  TraversalStats traversal;
  void add(const RayCounters& o) {
    camera += o.camera; shadow += o.shadow; indirect += o.indirect;
    traversal.cellsVisited += o.traversal.cellsVisited;
    traversal.cellsSolved += o.traversal.cellsSolved;
    traversal.rootsRefined += o.traversal.rootsRefined;
  }
};

class Integrator {
 public:
  explicit Integrator(const World& world) : m_world(world) {}
  virtual ~Integrator() = default;
  virtual Vec3f Li(const Ray& ray, Sampler& sampler, RayCounters& counters) const = 0;
  // True when the output holds signed values (normals) rather than radiance; PNG output
  // then maps [-1, 1] to [0, 1] instead of tone mapping.
  virtual bool signedOutput() const { return false; }

 protected:
  const World& m_world;
};

// Creates an integrator by name; InputError-free: the name was validated by the caller.
std::unique_ptr<Integrator> makeIntegrator(const std::string& name, const World& world);

}  // namespace iso
