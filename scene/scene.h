#pragma once
// The scene description as read from a scene file: what to load and how to render it.
// Nothing is loaded here; World (world.h) turns this into grids and an Embree scene.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "volume/intersectors.h"
#include "volume/loaders.h"
#include "volume/procedural.h"

namespace iso {

struct CameraDesc {
  Vec3d position{0, 0, 4};
  Vec3d lookAt{0, 0, 0};
  Vec3d up{0, 1, 0};
  double fov = 40;  // vertical, degrees
};

struct IsoSurfaceDesc {
  double value = 0;
  std::optional<Vec3d> color;  // shown by the eyelight integrator
};

struct VolumeDesc {
  std::string where;  // JSON path, for messages about this volume
  std::string file;   // absolute or relative to the working directory (already resolved)
  std::optional<Field> field;
  Vec3i resolution{64, 64, 64};
  RawLayout layout;
  std::optional<Vec3d> origin, spacing;
  std::vector<IsoSurfaceDesc> isosurfaces;
};

struct RenderSettings {
  int width = 640;
  int height = 480;
  int spp = 4;
  std::string integrator = "eyelight";
  IntersectorSpec intersector;
  uint64_t seed = 0;
  int threads = 0;  // 0: all cores
};

struct SceneDesc {
  std::string path;
  CameraDesc camera;
  RenderSettings settings;
  std::vector<VolumeDesc> volumes;
};

// Reads and validates a scene file. Any problem is an InputError naming the JSON path.
SceneDesc parseSceneFile(const std::string& path);
SceneDesc parseSceneText(const std::string& text, const std::string& path);

const char* integratorList();
bool isKnownIntegrator(const std::string& name);

}  // namespace iso
