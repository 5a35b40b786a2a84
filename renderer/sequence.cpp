#include "renderer/sequence.h"

#include <cmath>
#include <sstream>

#include "scene/time_series.h"
#include "volume/input_error.h"

namespace iso {

IsoSurfaceDesc* FrameSequence::iso(SceneDesc& scene) const {
  int k = 0;
  for (VolumeDesc& v : scene.volumes)
    for (IsoSurfaceDesc& d : v.isosurfaces)
      if (k++ == surface) return &d;
  return nullptr;
}

bool FrameSequence::apply(SceneDesc& scene, int frame) const {
  bool changed = surface >= 0;
  for (VolumeDesc& v : scene.volumes) {
    if (!v.time.varying()) continue;
    const std::string before = volumeSourceKey(v);
    selectTimeStep(v, timeStepOfFrame(frame, frames, v.time.steps));
    changed = changed || volumeSourceKey(v) != before;
  }
  if (surface >= 0) iso(scene)->value = isoValue(frame);
  return changed;
}

CameraDesc FrameSequence::camera(const CameraDesc& c, int frame) const {
  const double turn = degrees(frame);
  if (turn == 0) return c;
  CameraDesc out = c;
  const Transform r = Transform::rotate(turn, c.up);
  out.position = c.lookAt + r.vector(c.position - c.lookAt);
  return out;
}

FrameSequence frameSequence(const SequenceRequest& request, SceneDesc& scene) {
  const bool cli = request.where.empty();
  auto fail = [&](const char* flag, const char* key, const std::string& message) -> InputError {
    return cli ? InputError(flag, "", message) : InputError(request.where, key, message);
  };
  const std::string sweepName = cli ? "--iso-sweep" : "iso_sweep", orbitName = cli ? "--orbit" : "orbit",
                    framesName = cli ? "--frames N" : "frames=N";
  FrameSequence seq;
  seq.steps = sceneTimeSteps(scene);
  seq.frames = request.frames ? *request.frames : seq.steps;
  if (request.frames && (*request.frames < 1 || *request.frames > 100000))
    throw fail("--frames", "frames", "expected 1 to 100000 frames");
  if (!request.isoSweep.empty()) {
    std::istringstream in(request.isoSweep);
    std::string index, from, to;
    if (!std::getline(in, index, ':') || !std::getline(in, from, ':') || !std::getline(in, to) ||
        index.find_first_not_of("0123456789") != std::string::npos || index.empty() || index.size() > 6)
      throw fail("--iso-sweep", "iso_sweep", cli ? "expected SURFACE:FROM:TO, e.g. 0:40:120 (SURFACE counts all iso-surfaces from 0)"
                                                : "expected (surface, from, to), e.g. (0, 40, 120) (surface counts all iso-surfaces from 0)");
    seq.surface = std::stoi(index);
    try {
      size_t used = 0;
      seq.from = std::stod(from, &used);
      if (used != from.size()) throw std::invalid_argument(from);
      seq.to = std::stod(to, &used);
      if (used != to.size()) throw std::invalid_argument(to);
    } catch (const std::exception&) {
      throw fail("--iso-sweep", "iso_sweep", "'" + from + "' and '" + to + "' must be numbers");
    }
    if (!std::isfinite(seq.from) || !std::isfinite(seq.to)) throw fail("--iso-sweep", "iso_sweep", "the iso values must be finite");
    if (!seq.iso(scene)) {
      size_t count = 0;
      for (const VolumeDesc& v : scene.volumes) count += v.isosurfaces.size();
      throw fail("--iso-sweep", "iso_sweep", "no iso-surface " + index + " (the scene has " + std::to_string(count) +
                                                 ", counted from 0 over all volumes)");
    }
  }
  if (request.orbit) {
    if (!std::isfinite(*request.orbit) || std::fabs(*request.orbit) > 36000)
      throw fail("--orbit", "orbit", "expected degrees in [-36000, 36000]");
    seq.orbit = *request.orbit;
  }
  if (seq.frames > 1 && seq.surface < 0 && !request.orbit && seq.steps == 1)
    throw fail("--frames", "frames", "a sequence needs " + sweepName + ", " + orbitName +
                                         " or a volume that changes over time (else every frame is the same)");
  if (seq.frames == 1 && (seq.surface >= 0 || request.orbit))
    throw fail("--frames", "frames", sweepName + " and " + orbitName + " make a sequence: give " + framesName + " (N >= 2)");
  return seq;
}

void TimeStepsAhead::startFrame(const FrameSequence& seq, const SceneDesc& scene, int next) {
  for (size_t v = 0; v < scene.volumes.size(); ++v) {
    if (!scene.volumes[v].time.varying()) continue;
    VolumeDesc step = scene.volumes[v];
    selectTimeStep(step, timeStepOfFrame(next, seq.frames, step.time.steps));
    if (volumeSourceKey(step) != volumeSourceKey(scene.volumes[v])) start(v, std::move(step));
  }
}

void TimeStepsAhead::start(size_t volume, VolumeDesc desc) {
  Pending& p = m_pending[volume];
  if (p.result.valid()) p.result.wait();  // (never two reads of one volume at once)
  p.key = volumeSourceKey(desc);
  p.result = std::async(std::launch::async, [desc = std::move(desc)] { return loadVolume(desc); });
}

VolumeFile TimeStepsAhead::take(size_t volume, const VolumeDesc& desc) {
  auto it = m_pending.find(volume);
  if (it == m_pending.end() || !it->second.result.valid() || it->second.key != volumeSourceKey(desc))
    return loadVolume(desc);
  VolumeFile f = it->second.result.get();
  m_pending.erase(it);
  return f;
}

TimeStepsAhead::~TimeStepsAhead() {
  for (auto& [v, p] : m_pending)
    if (p.result.valid()) p.result.wait();
}

}  // namespace iso
