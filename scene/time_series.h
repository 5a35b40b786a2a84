#pragma once
// Volumes that change over time: one volume per time step, from a list of files, a file pattern,
// a file's time axis (a 4D NIfTI) or a list of arrays (Python). A sequence of frames steps
// through them (renderer/command_render.cpp, `--frames`); each frame's World loads the steps it
// shows. The scene format is in docs/scene-format.md ("Time series").
#include <string>
#include <vector>

#include "scene/scene.h"
#include "volume/loaders.h"

namespace iso {

// Whether a "file" is a pattern: `*` or `?` in its last part (folders are named as they are).
bool isFilePattern(const std::string& file);
// The files (or folders: DICOM series) a pattern matches, in natural order ("t2" before "t10");
// an InputError naming `sceneFile` and `where` when it matches none.
std::vector<std::string> expandFilePattern(const std::string& pattern, const std::string& sceneFile,
                                           const std::string& where);
// What the parser leaves to be read: the steps of a time axis (its header), then every step checked
// before any frame is rendered: each file there (a missing one named with its index) and, where a
// header tells it without reading the samples (raw, NRRD, MetaImage, VTK, NIfTI), the same shape
// and type as step 0; a time axis of one step is an error. Other formats' shapes are checked as
// their steps load (checkSameShape).
void resolveTimeSeries(SceneDesc& scene);
// The longest time series' steps (1: nothing in the scene changes over time).
int sceneTimeSteps(const SceneDesc& scene);
// The step of a series of `steps` that frame `frame` of `frames` shows: the series stretched over
// the frames (frames == steps: frame f shows step f; more frames hold a step, fewer skip some).
int timeStepOfFrame(int frame, int frames, int steps);
// Sets the volume's file, time point or array to step `step` (clamped to its last).
void selectTimeStep(VolumeDesc& v, int step);
// The step a volume shows (0 when it does not change).
int currentTimeStep(const VolumeDesc& v);
// What a volume loads, as a key (file, time point, series, grid, layout; or the array): a World
// reuses the previous World's volume when the key is the same.
std::string volumeSourceKey(const VolumeDesc& v);
// A loaded step of a series must have step 0's dims and type: an InputError naming the step's
// file (or array) and its index otherwise.
void checkSameShape(const SceneDesc& scene, const VolumeDesc& v, const VolumeShape& first, const Grid& step);

}  // namespace iso
