#include "scene/world.h"

#include <chrono>
#include <stdexcept>

#include "volume/input_error.h"

namespace iso {
namespace {

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Distinct colours for nested shells in the eyelight view.
Vec3f paletteColor(size_t i) {
  static const Vec3f palette[] = {{0.85f, 0.85f, 0.85f}, {0.9f, 0.55f, 0.35f}, {0.4f, 0.65f, 0.9f},
                                  {0.55f, 0.85f, 0.45f}, {0.9f, 0.8f, 0.35f}, {0.75f, 0.5f, 0.85f}};
  return palette[i % (sizeof(palette) / sizeof(palette[0]))];
}

}  // namespace

Grid loadVolume(const VolumeDesc& desc) {
  Grid grid = desc.field ? makeProceduralGrid(*desc.field, desc.resolution)
                         : loadVolumeFile(desc.file, desc.layout);
  if (desc.origin) grid.setOrigin(*desc.origin);
  if (desc.spacing) grid.setSpacing(*desc.spacing);
  return grid;
}

World::World(const SceneDesc& scene, const IntersectorSpec& intersector) {
  const auto loadStart = std::chrono::steady_clock::now();
  for (const VolumeDesc& desc : scene.volumes) {
    VolumeInfo info;
    info.name = desc.field ? "procedural" : desc.file;
    info.grid = std::make_unique<Grid>(loadVolume(desc));
    m_volumes.push_back(std::move(info));
  }
  m_loadSeconds = secondsSince(loadStart);

  const auto buildStart = std::chrono::steady_clock::now();
  m_device = rtcNewDevice(nullptr);
  if (!m_device) throw std::runtime_error("cannot create the Embree device");
  m_scene = rtcNewScene(m_device);
  rtcSetSceneFlags(m_scene, RTC_SCENE_FLAG_ROBUST);
  for (size_t v = 0; v < scene.volumes.size(); ++v) {
    m_volumes[v].bricks = std::make_unique<BrickGrid>(*m_volumes[v].grid);
    for (const IsoSurfaceDesc& isoDesc : scene.volumes[v].isosurfaces) {
      SurfaceInfo s;
      s.volume = int(v);
      s.iso = isoDesc.value;
      s.color = isoDesc.color ? Vec3f(*isoDesc.color) : paletteColor(m_surfaces.size());
      s.surface = std::make_unique<IsoSurface>(*m_volumes[v].grid, *m_volumes[v].bricks,
                                               isoDesc.value, intersector);
      // A surface with no active brick holds no primitive: nothing for Embree to build.
      if (!s.surface->activeBricks().empty()) {
        RTCGeometry geometry = s.surface->createGeometry(m_device);
        const unsigned id = rtcAttachGeometry(m_scene, geometry);
        rtcReleaseGeometry(geometry);
        if (m_geometryToSurface.size() <= id) m_geometryToSurface.resize(id + 1, -1);
        m_geometryToSurface[id] = int(m_surfaces.size());
      }
      m_surfaces.push_back(std::move(s));
    }
  }
  rtcCommitScene(m_scene);
  m_buildSeconds = secondsSince(buildStart);
}

World::~World() {
  if (m_scene) rtcReleaseScene(m_scene);
  if (m_device) rtcReleaseDevice(m_device);
}

bool World::intersect(const Ray& ray, Hit& hit, TraversalStats& stats) const {
  IsoRayContext context;
  RTCRayHit rh{};
  rh.ray.org_x = ray.org.x; rh.ray.org_y = ray.org.y; rh.ray.org_z = ray.org.z;
  rh.ray.dir_x = ray.dir.x; rh.ray.dir_y = ray.dir.y; rh.ray.dir_z = ray.dir.z;
  rh.ray.tnear = ray.tnear;
  rh.ray.tfar = ray.tfar;
  rh.ray.mask = 0xffffffff;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(m_scene, &context.embree, &rh);
  stats.cellsVisited += context.stats.cellsVisited;
  stats.cellsSolved += context.stats.cellsSolved;
  stats.rootsRefined += context.stats.rootsRefined;
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  hit.t = rh.ray.tfar;
  hit.tError = context.tError;
  hit.position = ray.org + ray.dir * hit.t;
  hit.normal = Vec3f{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
  hit.surface = m_geometryToSurface[rh.hit.geomID];
  return true;
}

bool World::occluded(const Ray& ray, TraversalStats& stats) const {
  IsoRayContext context;
  RTCRay r{};
  r.org_x = ray.org.x; r.org_y = ray.org.y; r.org_z = ray.org.z;
  r.dir_x = ray.dir.x; r.dir_y = ray.dir.y; r.dir_z = ray.dir.z;
  r.tnear = ray.tnear;
  r.tfar = ray.tfar;
  r.mask = 0xffffffff;
  rtcOccluded1(m_scene, &context.embree, &r);
  stats.cellsVisited += context.stats.cellsVisited;
  stats.cellsSolved += context.stats.cellsSolved;
  return r.tfar < 0;
}

}  // namespace iso
