#pragma once
// An integrator answers one question per camera ray: the radiance along it, Li(ray, sampler).
// It is written as stages over a PathState (start, afterTrace, afterShadow, finish) so that two
// ray flows run the same code: Li() traces one path's rays one at a time (the reference,
// `--ray-flow scalar`), and the wavefront renderer (renderer/render.cpp) keeps many paths in
// flight and traces their rays stage by stage in packets (`--ray-flow wavefront`). Each path
// takes its random numbers and adds its radiance in the same order either way, so the two
// flows give the same image bits.
// Integrators are chosen by name (integratorList() in scene/scene.h):
//   normals   shading normal at the first hit (signed, 0 where nothing is hit)
//   eyelight  base colour lit from the eye, for a quick look
//   ao        ambient occlusion: the share of cosine-weighted directions free up to ao_distance
//   direct    emission seen directly + next-event estimation from every light, combined with
//             BSDF sampling by multiple importance sampling (= path with max_depth 1)
//   path      unidirectional path tracing with next-event estimation and MIS
//   compare   path, with the direct part (paths of depth 1) kept apart in the same samples
//
// max_depth convention (pbrt's): the number of scattering events whose light is gathered.
// max_depth 1 is direct lighting (emission seen directly, plus light reaching the first
// surface the camera sees); max_depth 2 adds one bounce of indirect light, and so on. In a
// closed diffuse sphere of albedo a around a light, depth d gives (1 - a^d) / (1 - a) times
// the direct value.
#include <cstdint>
#include <limits>
#include <memory>
#include <string>

#include "integrators/sampler.h"
#include "scene/world.h"

namespace iso {

// Per-thread counters, summed by the renderer after the frame ("Category/Name" in --stats).
struct RayCounters {
  uint64_t camera = 0;
  uint64_t shadow = 0;
  uint64_t indirect = 0;
  TraversalStats traversal;
  void add(const RayCounters& o) {
    camera += o.camera; shadow += o.shadow; indirect += o.indirect;
    traversal.add(o.traversal);
  }
};

// What one camera sample returns: radiance, the direct part of it (compare only), and the
// first hit's albedo, shading normal and distance for the AOV layers (and the denoiser; the path
// integrators take albedo and normal through perfect mirrors and glass, see PathIntegrator).
struct SampleResult {
  Vec3f L{0, 0, 0};
  Vec3f direct{0, 0, 0};
  Vec3f albedo{0, 0, 0};
  Vec3f normal{0, 0, 0};
  float depth = std::numeric_limits<float>::infinity();  // infinity where nothing is hit
};

// One camera sample in flight. After start() and after each stage, the path asks for its next
// ray (`tracing`: closest hit of `ray`) and/or a shadow ray (`shadowing`: is `shadow` blocked?);
// when a stage leaves both false the path is done and finish() writes `out`. A shadow ray asked
// for together with the next ray is answered first (afterShadow, then afterTrace), as the
// one-ray loop does it.
struct PathState {
  Ray ray;
  Ray shadow;
  bool tracing = false;
  bool shadowing = false;
  Sampler sampler{0, 0, 0, 0};
  SampleResult out;
  // The path integrator's own state (the others use `out` alone).
  Vec3f L{0, 0, 0}, direct{0, 0, 0}, beta{1, 1, 1};
  Vec3f previous;          // the last scattering point, for the area light pdf
  float bsdfPdf = 0;
  int bounce = 0;          // scattering events so far
  int segment = 0;         // rays traced so far (thin sheets do not scatter)
  bool specular = true;    // the last bounce was a delta lobe (or the camera)
  Vec3f unblocked{0, 0, 0};  // what the waiting shadow ray adds to L if nothing blocks it
  bool unblockedIsDirect = false;  // ... and to `direct`
  // The path integrator: the denoiser's features wait for the first hit that is not a perfect
  // mirror or glass (SampleResult::albedo and normal keep the last such hit's until then).
  bool featurePending = false;

  // A camera sample's fresh path: every field a stage reads before writing it is reset (the
  // wavefront flow reuses its paths from pass to pass; the rest is written before it is read).
  void begin(const Ray& camera, const Sampler& s) {
    ray = camera;
    sampler = s;
    tracing = shadowing = false;
    out = SampleResult();
    L = direct = {0, 0, 0};
    beta = {1, 1, 1};
    bsdfPdf = 0;
    bounce = segment = 0;
    specular = true;
    featurePending = false;
  }
};

class Integrator {
 public:
  explicit Integrator(const World& world) : m_world(world) {}
  virtual ~Integrator() = default;
  // The whole path of one camera sample, one ray at a time (the scalar ray flow).
  void Li(const Ray& ray, Sampler& sampler, RayCounters& counters, SampleResult& out) const;

  // The stages. start: `p.ray` holds the camera ray and `p.sampler` the sample's sampler.
  virtual void start(PathState& p) const { p.tracing = true; }
  // The closest hit of p.ray (found, hit); p.tracing is false on entry.
  virtual void afterTrace(PathState& p, bool found, const Hit& hit, RayCounters& counters) const = 0;
  // Whether p.shadow is blocked; p.shadowing is false on entry.
  virtual void afterShadow(PathState&, bool /*blocked*/) const {}
  virtual void finish(PathState&) const {}
  const World& world() const { return m_world; }
  // True when the output holds signed values (normals) rather than radiance; PNG output
  // then maps [-1, 1] to [0, 1] instead of tone mapping.
  virtual bool signedOutput() const { return false; }
  // True when SampleResult::direct is filled (the compare integrator).
  virtual bool splitsDirect() const { return false; }

 protected:
  void recordFirstHit(const Ray& ray, const Hit& hit, SampleResult& out) const {
    out.albedo = m_world.albedo(hit);
    out.normal = hit.shading;
    out.depth = hit.t * length(ray.dir);
  }

  const World& m_world;
};

// The power heuristic with beta = 2 (Veach 1997, 9.2.4): the weight of a sample drawn with
// density `pdfA` when the other strategy would have drawn it with density `pdfB`.
inline float powerHeuristic(float pdfA, float pdfB) {
  const float a = pdfA * pdfA, b = pdfB * pdfB;
  if (!(a > 0)) return 0;
  if (std::isinf(a)) return 1;
  return a / (a + b);
}

// Creates an integrator by name (validated by the caller) with the scene's settings.
std::unique_ptr<Integrator> makeIntegrator(const std::string& name, const World& world,
                                           const RenderSettings& settings = RenderSettings());

}  // namespace iso
