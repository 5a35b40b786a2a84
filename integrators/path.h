#pragma once
// Unidirectional path tracing with next-event estimation and multiple importance sampling
// (pbrt-v4's PathIntegrator, Veach 1997 ch. 9). `direct` is this with max_depth 1.
#include "integrators/integrator.h"

namespace iso {

class PathIntegrator final : public Integrator {
 public:
  // `splitDirect`: also return the direct part (paths of depth 1) in SampleResult::direct.
  // `clampIndirect` > 0: the indirect part of each sample (everything but paths of depth 1) is
  // scaled down to at most that in its largest component (Cycles' indirect clamp; biased).
  PathIntegrator(const World& world, int maxDepth, bool splitDirect, float clampIndirect = 0)
      : Integrator(world), m_maxDepth(maxDepth), m_split(splitDirect), m_clamp(clampIndirect) {}
  void start(PathState& p) const override;
  void afterTrace(PathState& p, bool found, const Hit& hit, RayCounters& counters) const override;
  void afterShadow(PathState& p, bool blocked) const override;
  void finish(PathState& p) const override;
  bool splitsDirect() const override { return m_split; }

 private:
  // One light chosen by power, one sample of it, a shadow ray (for an iso-surface light a
  // ray that must hit it); weighted against BSDF sampling by the power heuristic (delta
  // lights: weight 1). See path.cpp.
  void sampleLight(PathState& p, const Hit& hit, const Bsdf& bsdf, const Vec3f& wo, RayCounters& counters) const;

  // The denoiser's features (SampleResult::albedo, normal) from `hit` (its base colour `albedo`),
  // seen through the specular bounces so far.
  void recordFeatures(PathState& p, const Hit& hit, const Vec3f& albedo) const;

  int m_maxDepth;
  bool m_split;
  float m_clamp;
};

}  // namespace iso
