#pragma once
// The loaded scene: grids, their brick ranges and iso-surfaces, and one Embree scene that
// holds one user geometry per iso-surface.
#include <embree3/rtcore.h>

#include <memory>
#include <string>
#include <vector>

#include "scene/camera.h"
#include "scene/scene.h"
#include "volume/iso_surface.h"

namespace iso {

struct Hit {
  float t = 0;
  float tError = 0;
  Vec3f position;
  Vec3f normal;   // unit, world space
  int surface = -1;  // index into World::surfaces()
};

struct SurfaceInfo {
  int volume = 0;
  double iso = 0;
  Vec3f color{0.8f, 0.8f, 0.8f};
  std::unique_ptr<IsoSurface> surface;
};

struct VolumeInfo {
  std::string name;  // file or procedural field
  std::unique_ptr<Grid> grid;
  std::unique_ptr<BrickGrid> bricks;
};

class World {
 public:
  // Loads every volume of the scene and builds the Embree scene with `intersector`.
  World(const SceneDesc& scene, const IntersectorSpec& intersector);
  ~World();
  World(const World&) = delete;
  World& operator=(const World&) = delete;

  bool intersect(const Ray& ray, Hit& hit, TraversalStats& stats) const;
  bool occluded(const Ray& ray, TraversalStats& stats) const;

  const std::vector<VolumeInfo>& volumes() const { return m_volumes; }
  const std::vector<SurfaceInfo>& surfaces() const { return m_surfaces; }
  double loadSeconds() const { return m_loadSeconds; }
  double buildSeconds() const { return m_buildSeconds; }

 private:
  RTCDevice m_device = nullptr;
  RTCScene m_scene = nullptr;
  std::vector<VolumeInfo> m_volumes;
  std::vector<SurfaceInfo> m_surfaces;
  std::vector<int> m_geometryToSurface;
  double m_loadSeconds = 0, m_buildSeconds = 0;
};

// Loads one volume of a scene with its placement applied (file header, then scene keys).
Grid loadVolume(const VolumeDesc& desc);

}  // namespace iso
