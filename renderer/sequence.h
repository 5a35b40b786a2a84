#pragma once
// A sequence of frames (`isotrace render --frames`, Python's isotrace.render_sequence): frame f
// of N has iso-surface `surface` (counted over all volumes in scene order) at from + (to - from)
// f / (N - 1), the camera turned about its look-at point, around its up vector, by orbit f / N
// degrees (a full 360 turn does not repeat the first frame), and each time series at step
// timeStepOfFrame(f, N, its steps) (scene/time_series.h). N defaults to the longest series'
// steps: one frame a step.
#include <future>
#include <map>
#include <optional>
#include <string>

#include "scene/scene.h"
#include "scene/world.h"

namespace iso {

struct FrameSequence {
  int frames = 1;
  int steps = 1;     // the longest time series' (1: nothing changes over time)
  int surface = -1;  // swept surface, or -1
  double from = 0, to = 0;
  double orbit = 0;
  IsoSurfaceDesc* iso(SceneDesc& scene) const;
  double isoValue(int f) const { return frames == 1 ? from : from + (to - from) * double(f) / double(frames - 1); }
  // Sets `scene` to frame f: the swept iso value, each time series' step. True when its World must
  // be built again (an iso value or a step changed; a camera move alone needs none).
  bool apply(SceneDesc& scene, int frame) const;
  // The camera of frame f (the orbit's turn of `camera`, the World's).
  CameraDesc camera(const CameraDesc& camera, int frame) const;
  double degrees(int frame) const { return orbit * double(frame) / double(frames); }
};

// What a caller asks of a sequence; `where` names the caller in errors: "" for the command line
// (errors then name the flags: --frames, --iso-sweep, --orbit), else e.g.
// "isotrace.render_sequence" (errors name frames, iso_sweep, orbit).
struct SequenceRequest {
  std::optional<int> frames;  // none: one per time step (or 1)
  std::string isoSweep;       // "SURFACE:FROM:TO", or empty
  std::optional<double> orbit;
  std::string where;
};
// Checked against `scene` (an InputError for a bad request, or a sequence whose frames would all
// be the same).
FrameSequence frameSequence(const SequenceRequest& request, SceneDesc& scene);

// Time steps read ahead on a second thread: start() the next frame's step of a volume, and the next
// World take()s it (waiting for it) if it is the step that World asks for; otherwise it is read
// there. An error in a read ahead comes out of take(), where the frame that needs it is built.
// At most the current and the next step of a volume are held.
class TimeStepsAhead {
 public:
  // Starts reading what `scene`'s time series show at frame `next` of `seq`, where it differs
  // from what they show now.
  void startFrame(const FrameSequence& seq, const SceneDesc& scene, int next);
  void start(size_t volume, VolumeDesc desc);
  VolumeFile take(size_t volume, const VolumeDesc& desc);
  // A World's VolumeLoader that takes from here.
  VolumeLoader loader() {
    return [this](size_t v, const VolumeDesc& desc) { return take(v, desc); };
  }
  ~TimeStepsAhead();  // a read still under way (the sequence stopped or failed) is waited for

 private:
  struct Pending {
    std::string key;
    std::future<VolumeFile> result;
  };
  std::map<size_t, Pending> m_pending;
};

}  // namespace iso
