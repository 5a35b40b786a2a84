// Building the World: loading meshes and volumes, brick ranges and iso-surfaces, slices, materials
// and lights into one Embree scene. Its ray queries and shading are in world_trace.cpp.
#include "scene/world.h"

#include "scene/texture.h"
#include "scene/time_series.h"

#include <algorithm>
#include <filesystem>
#include <chrono>
#include <cstdlib>
#include <cmath>
#include <cstdio>
#include <map>
#include <stdexcept>
#include <tuple>

#include "volume/input_error.h"
#include "volume/partition.h"
#include "volume/procedural.h"

namespace iso {
namespace {

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

const char* shapeName(MeshShape s) { return s == MeshShape::Sphere ? "sphere" : "quad"; }

// The triangles of a mesh in world space, three vertices each (for area lights).
void worldTriangles(const TriangleMesh& m, const Transform& t, bool identity, std::vector<Vec3f>& tris,
                    std::vector<Vec2f>& uvs) {
  for (size_t i = 0; i < m.indices.size(); ++i) {
    const Vec3f p = m.positions[m.indices[i]];
    tris.push_back(identity ? p : Vec3f(t.point(Vec3d(p))));
    if (!m.uvs.empty()) uvs.push_back(m.uvs[m.indices[i]]);
  }
}

}  // namespace

VolumeFile loadVolume(const VolumeDesc& desc) {
  VolumeFile v;
  if (desc.array) {
    v.grid = *desc.array;  // the samples are shared, not copied
    v.format = "array";
  } else if (desc.field) {
    v.grid = makeProceduralGrid(*desc.field, desc.resolution);
    v.format = "procedural";
  } else {
    v = readVolumeFile(desc.file, desc.layout, desc.part);
  }
  placeVolume(desc, v);
  return v;
}

namespace {
// The scene's keys applied to a file's placement: "origin" and "spacing" replace the file's,
// "transform" comes after its affine.
FilePlacement placed(const VolumeDesc& desc, FilePlacement p) {
  if (desc.origin) p.origin = *desc.origin;
  if (desc.spacing) p.spacing = *desc.spacing;
  p.toWorld = desc.transform * p.toWorld;
  return p;
}
}  // namespace

void placeVolume(const VolumeDesc& desc, VolumeFile& v) {
  const FilePlacement p = placed(desc, {v.grid.origin(), v.grid.spacing(), v.toWorld});
  v.grid.setOrigin(p.origin);
  v.grid.setSpacing(p.spacing);
  v.toWorld = p.toWorld;
}

namespace {
constexpr double kMaxCoordinate = 1e15;

bool isObjFile(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  return ext == ".obj";
}

// The camera, wherever it came from (scene file, glTF node, framing), must give finite rays
// that Embree accepts.
void checkCamera(const CameraDesc& c, const SceneDesc& scene) {
  const std::string where = scene.camera.gltfCamera.empty() ? "/camera" : "/camera/gltf_camera";
  const Vec3d forward = c.lookAt - c.position;
  for (const Vec3d& p : {c.position, c.lookAt, c.up})
    for (int a = 0; a < 3; ++a)
      if (!std::isfinite(p[a]))
        throw InputError(scene.path, where, "the camera has no view direction (its placement is not finite: a node scaled to 0?)");
  for (const Vec3d& p : {c.position, c.lookAt})
    for (int a = 0; a < 3; ++a)
      if (!(std::fabs(p[a]) <= kMaxCoordinate))
        throw InputError(scene.path, where, "camera coordinate " + std::to_string(p[a]) + " is beyond +-1e15");
  const double f = length(forward), u = length(c.up);
  if (!(f > 0) || !std::isfinite(f)) throw InputError(scene.path, where, "the camera has no view direction");
  if (!(u > 0) || !(length(cross(forward / f, c.up / u)) > 1e-6))
    throw InputError(scene.path, where, "the camera's up direction is zero or parallel to the view direction");
  if (!(c.fov > 0 && c.fov < 180)) throw InputError(scene.path, where, "field of view " + std::to_string(c.fov) + " is not in (0, 180)");
}
}  // namespace

CameraDesc frameBounds(const Vec3d& lower, const Vec3d& upper, double fov) {
  // From the front (+z, the side glTF's default camera looks from), a little to the right and
  // above, far enough for the bounding sphere to fit the vertical field of view (the narrower
  // one of a landscape image).
  CameraDesc c;
  c.fov = fov;
  c.lookAt = (lower + upper) * 0.5;
  const double radius = std::max(0.5 * length(upper - lower), 1e-6);
  const double distance = radius / std::sin(0.5 * fov * M_PI / 180) * 1.05;
  c.position = c.lookAt + normalize(Vec3d{0.45, 0.35, 1}) * distance;
  return c;
}

World::World(const SceneDesc& scene, const IntersectorSpec& intersector, const World* sameVolumes,
             const VolumeLoader& load) {
  m_camera = scene.camera;
  m_sceneClip = scene.clip;
  Material fallback;
  fallback.name = "default";
  m_materials.push_back(fallback);
  // ISOTRACE_EMBREE_CONFIG (e.g. "isa=avx2"): Embree's device configuration, to run the kernels
  // another CPU would pick (Embree chooses by the CPU it runs on); unset, Embree's defaults.
  const char* embreeConfig = std::getenv("ISOTRACE_EMBREE_CONFIG");
  m_device = rtcNewDevice(embreeConfig);
  if (!m_device && embreeConfig)  // (Embree ignores keys it does not know, and an unknown isa)
    throw InputError("ISOTRACE_EMBREE_CONFIG", "", std::string("Embree refused the device configuration '") +
                                                       embreeConfig + "'");
  if (!m_device) throw std::runtime_error("cannot create the Embree device");
  m_nativePackets = rtcGetDeviceProperty(m_device, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED) != 0;
  m_scene = rtcNewScene(m_device);
  rtcSetSceneFlags(m_scene, RTC_SCENE_FLAG_ROBUST);
  try {
    loadMeshes(scene);
    buildVolumes(scene, intersector, sameVolumes, load);
    buildSlices(scene);
    buildLights(scene);
    // The GGX albedo table (~8e7 instructions, built once per process on first use) is built
    // here rather than inside the first tile a thread renders, where it held the other threads
    // up and counted as render time (and in every instruction count of a small render).
    ggx::averageAlbedo(0.5f);
    const auto commitStart = std::chrono::steady_clock::now();
    for (RTCScene sub : m_subScenes) rtcCommitScene(sub);
    rtcCommitScene(m_scene);
    m_buildSeconds += secondsSince(commitStart);
    RTCBounds b;
    rtcGetSceneBounds(m_scene, &b);
    m_lower = {b.lower_x, b.lower_y, b.lower_z};
    m_upper = {b.upper_x, b.upper_y, b.upper_z};
    m_unframedCamera = m_camera;  // the scene's, or a glTF node's
    setSceneBounds(scene, m_lower, m_upper);
  } catch (...) {
    release();
    throw;
  }
}

double World::largestCell() const {
  double largest = 0;
  for (const SurfaceInfo& s : m_surfaces) {
    const VolumeInfo& vol = m_volumes[size_t(s.volume)];
    const Vec3d stretch = vol.transform.absRowSums();  // bounds how far the transform moves a unit step
    largest = std::max(largest, length(vol.grid->spacing()) * std::max({stretch.x, stretch.y, stretch.z}));
  }
  return largest;
}

void World::setSceneBounds(const SceneDesc& scene, const Vec3d& lower, const Vec3d& upper) {
  const bool bounded = lower.x <= upper.x;
  // Embree asserts on rays that start beyond ~1.8e18 (and float precision is long gone far
  // before): coordinates are bounded well inside that, for geometry and the camera.
  for (const double c : {lower.x, lower.y, lower.z, upper.x, upper.y, upper.z})
    if (bounded && !(std::fabs(c) <= kMaxCoordinate))
      throw InputError(scene.path, "", "the scene reaches coordinate " + std::to_string(c) +
                                           ": coordinates beyond +-1e15 are not supported");
  m_camera = m_unframedCamera;
  if (m_camera.frameScene && bounded) m_camera = frameBounds(lower, upper);
  checkCamera(m_camera, scene);
  // Lights are chosen by power; distant ones by what falls on the scene (its bounding
  // sphere). Without any power (black lights) the choice is uniform.
  const float radius = bounded ? float(0.5 * length(upper - lower)) : 1.f;
  std::vector<float> powers;
  double total = 0;
  for (const Light& l : m_lights) {
    const float p = l.power(radius);
    powers.push_back(std::isfinite(p) && p > 0 ? p : 0.f);
    total += powers.back();
  }
  if (!(total > 0)) std::fill(powers.begin(), powers.end(), 1.f);
  m_lightPick = Distribution1D(powers);
}

World::~World() { release(); }

void World::release() {
  for (RTCScene sub : m_subScenes) rtcReleaseScene(sub);
  m_subScenes.clear();
  if (m_scene) rtcReleaseScene(m_scene);
  if (m_device) rtcReleaseDevice(m_device);
  m_scene = nullptr;
  m_device = nullptr;
}

unsigned World::attach(RTCScene scene, RTCGeometry geometry, std::vector<GeometryRecord>& table,
                       const GeometryRecord& record) {
  rtcCommitGeometry(geometry);
  const unsigned id = rtcAttachGeometry(scene, geometry);
  rtcReleaseGeometry(geometry);
  if (table.size() <= id) table.resize(id + 1);
  table[id] = record;
  return id;
}

int World::materialFor(const SceneDesc& scene, const std::string& name) {
  for (size_t i = 1; i < m_materials.size(); ++i)
    if (m_materials[i].name == name) return int(i);
  const MaterialDesc& d = scene.materials.at(name);
  Material m;
  m.name = name;
  m.type = d.type;
  m.color = Vec3f(d.color);
  m.metallic = float(d.metallic);
  m.roughness = float(d.roughness);
  m.ior = float(d.ior);
  m.thin = d.thin;
  m_hasThin = m_hasThin || d.thin;
  m.emission = Vec3f(d.emission);
  m.twoSided = d.twoSided;
  m_materials.push_back(m);
  return int(m_materials.size() - 1);
}

// Decodes a glTF texture the first time a used material needs it.
int World::textureFor(size_t model, const GltfTextureRef& ref, bool srgb) {
  if (ref.texture < 0) return -1;
  for (size_t i = 0; i < m_textureKeys.size(); ++i)
    if (m_textureKeys[i] == std::make_tuple(model, ref.texture, srgb)) return int(i);
  const GltfModel& g = m_models[model];
  const GltfTexture& t = g.textures[ref.texture];
  const std::string at = "/textures/" + std::to_string(ref.texture);
  if (t.image < 0 || size_t(t.image) >= g.images.size())
    throw InputError(g.path, at + "/source", "image " + std::to_string(t.image) + " does not exist");
  const GltfImage& image = g.images[t.image];
  if (image.encoded.empty()) throw InputError(g.path, "/images/" + std::to_string(t.image), "image has no data");
  m_textures.push_back(Texture::decode(image.encoded, g.path + ": " + image.name, srgb, t.wrapS, t.wrapT, t.nearest));
  m_textureKeys.emplace_back(model, ref.texture, srgb);
  return int(m_textures.size() - 1);
}

int World::gltfMaterial(size_t model, int index) {
  if (index < 0) return 0;
  int& slot = m_modelMaterials[model][index];
  if (slot >= 0) return slot;
  const GltfMaterial& g = m_models[model].materials[index];
  Material m;
  m.name = g.name.empty() ? m_models[model].path + " material " + std::to_string(index) : g.name;
  m.type = g.type;
  m.color = g.baseColor;
  m.metallic = g.metallic;
  m.roughness = g.roughness;
  m.emission = g.emissive;
  m.twoSided = g.doubleSided;
  m.normalScale = g.normalScale;
  m.colorTexture = textureFor(model, g.baseColorTexture, true);
  m.metallicRoughnessTexture = textureFor(model, g.metallicRoughnessTexture, false);
  m.normalTexture = textureFor(model, g.normalTexture, false);
  m.emissionTexture = textureFor(model, g.emissiveTexture, true);
  m_materials.push_back(m);
  slot = int(m_materials.size() - 1);
  return slot;
}

namespace {

// Hits on a clipped mesh outside the clip region (the geometry's user data) do not count. The
// point is taken on the world ray in double (the iso-surface lanes carry it), at the hit's t,
// which an instance's transform does not change.
void clipFilter(const RTCFilterFunctionNArguments* args) {
  const auto* clip = static_cast<const ClipRegion*>(args->geometryUserPtr);
  const auto* context = reinterpret_cast<const IsoRayContext*>(args->context);
  for (unsigned i = 0; i < std::min(args->N, unsigned(kPacketLanes)); ++i) {
    if (args->valid[i] == 0) continue;
    const IsoRayLane& lane = context->lanes[args->N == 1 ? 0 : i];
    if (!lane.origin) continue;
    const double t = RTCRayN_tfar(args->ray, args->N, i);
    if (!clip->keeps(*lane.origin + lane.direction * t)) args->valid[i] = 0;
  }
}

}  // namespace

RTCGeometry World::triangleGeometry(const TriangleMesh& mesh, bool clipped) const {
  RTCGeometry geometry = rtcNewGeometry(m_device, RTC_GEOMETRY_TYPE_TRIANGLE);
  rtcSetGeometryMask(geometry, kMeshMask);
  if (clipped) {
    rtcSetGeometryUserData(geometry, const_cast<ClipRegion*>(&m_sceneClip));
    rtcSetGeometryIntersectFilterFunction(geometry, clipFilter);
    rtcSetGeometryOccludedFilterFunction(geometry, clipFilter);
  }
  auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                        3 * sizeof(float), mesh.positions.size()));
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    v[3 * i] = mesh.positions[i].x; v[3 * i + 1] = mesh.positions[i].y; v[3 * i + 2] = mesh.positions[i].z;
  }
  auto* idx = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                             3 * sizeof(unsigned), mesh.triangleCount()));
  std::copy(mesh.indices.begin(), mesh.indices.end(), idx);
  return geometry;
}

void World::loadMeshes(const SceneDesc& scene) {
  std::vector<PendingAreaLight>& pending = m_pendingAreaLights;
  for (size_t d = 0; d < scene.meshes.size(); ++d) {
    const MeshDesc& desc = scene.meshes[d];
    const auto loadStart = std::chrono::steady_clock::now();
    GltfModel model;
    if (desc.shape != MeshShape::None) {
      model.path = shapeName(desc.shape);
      model.meshes.push_back({desc.shape == MeshShape::Sphere ? makeSphereMesh() : makeQuadMesh()});
      model.meshNames.push_back(model.path);
      model.instances.push_back({0, Transform(), "shape"});
    } else {
      model = isObjFile(desc.file) ? loadObj(desc.file) : loadGltf(desc.file);
      for (const std::string& w : model.warnings) m_warnings.push_back(desc.file + ": " + w);
    }
    m_loadSeconds += secondsSince(loadStart);
    const auto buildStart = std::chrono::steady_clock::now();
    const size_t modelIndex = m_models.size();
    m_models.push_back(std::move(model));
    const GltfModel& g = m_models.back();
    m_modelMaterials.emplace_back(g.materials.size(), -1);

    MeshInfo info;
    info.name = desc.shape != MeshShape::None ? g.path : desc.file;
    info.meshes = g.meshes.size();
    info.instances = g.instances.size();
    info.cameras = g.cameras.size();
    info.lights = g.lights.size();
    info.materials = g.materials.size();
    info.textures = g.textures.size();
    info.images = g.images.size();
    std::vector<int> uses(g.meshes.size(), 0);
    for (const GltfInstance& inst : g.instances) ++uses[inst.mesh];
    std::vector<RTCScene> shared(g.meshes.size(), nullptr);
    std::vector<std::vector<const TriangleMesh*>> stored(g.meshes.size());
    for (size_t m = 0; m < g.meshes.size(); ++m)
      for (const TriangleMesh& prim : g.meshes[m]) info.uniqueTriangles += uses[m] ? prim.triangleCount() : 0;

    auto materialOf = [&](const TriangleMesh& prim) {
      return desc.material.empty() ? gltfMaterial(modelIndex, prim.material) : materialFor(scene, desc.material);
    };
    // The scene's clip region cuts meshes (no caps: a mesh is not a solid), except lights (their
    // triangles are sampled whole) and meshes it keeps whole (a filter costs on every hit).
    auto clipsMesh = [&](int material, const std::vector<Vec3d>& worldPoints) {
      if (m_sceneClip.empty() || m_materials[size_t(material)].emits() || worldPoints.empty()) return false;
      Vec3d lo = worldPoints[0], hi = worldPoints[0];
      for (const Vec3d& p : worldPoints) lo = min(lo, p), hi = max(hi, p);
      return m_sceneClip.classify(lo, hi, 0) != ClipRegion::BoxSide::Kept;
    };
    // The world positions of a mesh's every placement in the file.
    auto placements = [&](size_t mesh, const TriangleMesh& prim) {
      std::vector<Vec3d> points;
      for (const GltfInstance& other : g.instances)
        if (size_t(other.mesh) == mesh) {
          const Transform t = desc.transform * other.toFile;
          for (const Vec3f& p : prim.positions) points.push_back(t.point(Vec3d(p)));
        }
      return points;
    };

    for (const GltfInstance& inst : g.instances) {
      const Transform toWorld = desc.transform * inst.toFile;
      const std::vector<TriangleMesh>& prims = g.meshes[inst.mesh];
      for (const TriangleMesh& prim : prims)
        for (const Vec3f& p : prim.positions) {
          const Vec3d w = toWorld.point(Vec3d(p));
          info.lower = min(info.lower, w);
          info.upper = max(info.upper, w);
        }
      info.triangles += [&] { size_t n = 0; for (auto& p : prims) n += p.triangleCount(); return n; }();
      if (uses[inst.mesh] == 1) {
        // Used once: bake into world space (a flatter BVH, and error bounds in world space).
        for (const TriangleMesh& prim : prims) {
          auto baked = std::make_unique<TriangleMesh>(prim);
          for (Vec3f& p : baked->positions) p = Vec3f(toWorld.point(Vec3d(p)));
          for (Vec3f& n : baked->normals)
            if (length(n) > 0) n = Vec3f(normalize(toWorld.normal(Vec3d(n))));
          for (const Vec3f& p : baked->positions)
            if (!isFinite(p)) throw InputError(desc.file.empty() ? scene.path : desc.file, inst.node, "transformed vertex is not finite");
          GeometryRecord rec;
          rec.mesh = baked.get();
          rec.material = materialOf(prim);
          rec.meshDesc = int(d);
          if (m_materials[rec.material].emits()) {
            rec.light = int(pending.size());
            pending.push_back({});
            worldTriangles(*baked, Transform(), true, pending.back().triangles, pending.back().uvs);
            pending.back().material = rec.material;
          }
          std::vector<Vec3d> points(baked->positions.begin(), baked->positions.end());
          attach(m_scene, triangleGeometry(*baked, clipsMesh(rec.material, points)), m_top, rec);
          m_meshStore.push_back(std::move(baked));
        }
        continue;
      }
      // Used by several nodes: one shared object-space scene, one Embree instance per node.
      if (!shared[inst.mesh]) {
        shared[inst.mesh] = rtcNewScene(m_device);
        m_subScenes.push_back(shared[inst.mesh]);
        for (const TriangleMesh& prim : prims) {
          m_meshStore.push_back(std::make_unique<TriangleMesh>(prim));
          stored[inst.mesh].push_back(m_meshStore.back().get());
          RTCGeometry geometry = triangleGeometry(prim, clipsMesh(materialOf(prim), placements(size_t(inst.mesh), prim)));
          rtcCommitGeometry(geometry);
          rtcAttachGeometry(shared[inst.mesh], geometry);
          rtcReleaseGeometry(geometry);
        }
      }
      std::vector<GeometryRecord> records;
      for (size_t k = 0; k < prims.size(); ++k) {
        GeometryRecord rec;
        rec.mesh = stored[inst.mesh][k];
        rec.material = materialOf(prims[k]);
        rec.meshDesc = int(d);
        rec.toWorld = toWorld;
        rec.identity = false;
        if (m_materials[rec.material].emits()) {
          rec.light = int(pending.size());
          pending.push_back({});
          worldTriangles(prims[k], toWorld, false, pending.back().triangles, pending.back().uvs);
          pending.back().material = rec.material;
        }
        records.push_back(rec);
      }
      RTCGeometry instance = rtcNewGeometry(m_device, RTC_GEOMETRY_TYPE_INSTANCE);
      rtcSetGeometryMask(instance, kMeshMask);
      rtcSetGeometryInstancedScene(instance, shared[inst.mesh]);
      float xfm[12];
      toWorld.toColumnMajor(xfm);
      rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, xfm);
      GeometryRecord top;
      top.instance = int(m_instanceRecords.size());
      top.meshDesc = int(d);
      m_instanceRecords.push_back(std::move(records));
      attach(m_scene, instance, m_top, top);
      ++info.embreeInstances;
    }
    m_meshInfo.push_back(info);
    m_buildSeconds += secondsSince(buildStart);
  }
}

void checkDataParallel(const SceneDesc& scene) {
  auto refuse = [&](const std::string& where, const std::string& what) {
    throw InputError(scene.path, where, what + " is not supported with \"distribution\": \"data\" (--data-parallel) yet");
  };
  if (scene.settings.noiseThreshold > 0) refuse("/integrator/noise_threshold", "adaptive sampling");
  if (!scene.clip.empty()) refuse("/clip", "clipping");
  for (const auto& [name, m] : scene.materials)
    if (m.thin && m.type == MaterialType::Dielectric) refuse("/materials/" + name, "a thin dielectric (light through it)");
  for (const VolumeDesc& v : scene.volumes) {
    if (!v.clip.empty()) refuse(v.where + "/clip", "clipping");
    if (!v.slices.empty()) refuse(v.where + "/slices", "a slice plane");
    for (size_t k = 0; k < v.isosurfaces.size(); ++k) {
      const IsoSurfaceDesc& iso = v.isosurfaces[k];
      const std::string where = v.where + "/isosurfaces/" + std::to_string(k);
      if (iso.colorBy || iso.capColorBy) refuse(where, "colouring by data");
      const auto m = scene.materials.find(iso.material);
      if (m != scene.materials.end() && (m->second.emission.x > 0 || m->second.emission.y > 0 || m->second.emission.z > 0))
        refuse(where, "an emissive iso-surface");
    }
  }
}

CutRays cameraCutRays(const SceneDesc& scene, const CameraDesc* camera, size_t v) {
  CutRays rays;
  const VolumeDesc& desc = scene.volumes[v];
  if (!camera) return rays;
  std::optional<FilePlacement> file;  // (before the scene's keys)
  if (desc.array)
    file = FilePlacement{desc.array->origin(), desc.array->spacing(), Transform()};
  else if (desc.field)
    file = FilePlacement{{-1, -1, -1}, proceduralSpacing(desc.resolution), Transform()};
  else
    file = filePlacement(desc.file, desc.layout, desc.part);
  if (!file) return rays;
  const FilePlacement p = placed(desc, *file);
  if (!p.toWorld.isFiniteInvertible() || !(p.spacing.x > 0 && p.spacing.y > 0 && p.spacing.z > 0)) return rays;
  const Transform toIndex = worldToIndex(p.origin, p.spacing, p.toWorld.inverse());
  const int w = std::max(scene.settings.width, 1), h = std::max(scene.settings.height, 1);
  const Camera eye(*camera, w, h);
  constexpr int kAcross = 32, kDown = 18;
  for (int j = 0; j < kDown; ++j)
    for (int i = 0; i < kAcross; ++i) {
      const Ray r = eye.generateRay((float(i) + 0.5f) * float(w) / kAcross, (float(j) + 0.5f) * float(h) / kDown);
      rays.org.push_back(toIndex.point(Vec3d(r.org)));
      rays.dir.push_back(toIndex.vector(Vec3d(r.dir)));
    }
  return rays;
}

std::vector<double> isoValuesOf(const VolumeDesc& desc) {
  std::vector<double> values;
  for (const IsoSurfaceDesc& iso : desc.isosurfaces) values.push_back(iso.value);
  return values;
}

namespace {
// This rank's box of volume v (SceneDesc::dataPart) from the ranges of its bricks: boxes of
// whole bricks balanced by the bricks active for the volume's iso values, cut where the fewest of
// the camera's rays (`camera`, cameraCutRays) and of the rays leaving the surfaces pass, the same
// on every rank; and the box it holds, with the copies of its neighbours' bricks "replicate" allows.
struct RankPart {
  RankBox own, held;
};
RankPart rankPart(const SceneDesc& scene, size_t v, const BrickGrid& bricks, const CutRays& camera) {
  const VolumeDesc& desc = scene.volumes[v];
  const std::vector<double> weights = activeBrickWeights(bricks, isoValuesOf(desc));
  const RankBox own = partitionBricks(bricks, weights, scene.dataPart.ranks, scene.path + ": " + desc.where,
                                      &camera)[size_t(scene.dataPart.rank)];
  return {own, heldBox(own, bricks, scene.settings.replicate)};
}

// This rank's window of volume v. A procedural field is evaluated twice, once for its bricks'
// ranges (nothing kept) and once for the window; a file whose samples lie in runs of bytes (raw,
// NRRD, MetaImage, binary VTK, NIfTI, DICOM: fileBrickRanges) is read twice, for the ranges and for the window: the rank
// never holds more than its window (and a compressed file's compressed bytes). Other files are
// read whole and the window cut from them (docs/distributed.md).
// (`part`: the boxes it answers for and holds.)
VolumeFile loadRankVolume(const SceneDesc& scene, size_t v, const CameraDesc* camera, RankPart& part) {
  const VolumeDesc& desc = scene.volumes[v];
  const CutRays rays = cameraCutRays(scene, camera, v);
  VolumeFile f;
  if (desc.field && !desc.array) {
    const Vec3i n = desc.resolution;
    part = rankPart(scene, v, proceduralBrickRanges(*desc.field, n), rays);
    f.grid = makeProceduralWindow(*desc.field, n, part.held.windowFirst(), part.held.windowExtent(n));
    f.format = "procedural";
    placeVolume(desc, f);
    return f;
  }
  if (!desc.array && !desc.field) {
    // Its bricks' ranges first (the files read or inflated in order, a layer at a time), then
    // only the window's samples.
    if (const std::optional<BrickGrid> ranges = fileBrickRanges(desc.file, desc.layout, desc.part)) {
      part = rankPart(scene, v, *ranges, rays);
      const SampleWindow window{part.held.windowFirst(), part.held.windowExtent(ranges->dims())};
      f = readVolumeFile(desc.file, desc.layout, desc.part, &window);
      placeVolume(desc, f);
      return f;
    }
  }
  f = loadVolume(desc);
  if (f.grid.sparse())
    throw InputError(scene.path, desc.where, "a sparse (OpenVDB) volume cannot be split over ranks yet (\"distribution\": \"data\")");
  part = rankPart(scene, v, BrickGrid(f.grid), rays);
  f.grid = windowOf(f.grid, part.held.windowFirst(), part.held.windowExtent(f.grid.dims()));
  return f;
}
}  // namespace

void World::buildVolumes(const SceneDesc& scene, const IntersectorSpec& intersector, const World* sameVolumes,
                         const VolumeLoader& load) {
  for (size_t v = 0; v < scene.volumes.size(); ++v) {
    const VolumeDesc& desc = scene.volumes[v];
    const auto loadStart = std::chrono::steady_clock::now();
    VolumeInfo info;
    const std::string source = volumeSourceKey(desc);
    const bool shared = sameVolumes && v < sameVolumes->m_volumes.size() && sameVolumes->m_volumes[v].source == source;
    if (shared) {
      info = sameVolumes->m_volumes[v];  // the grid and brick ranges are shared, not copied
    } else {
      info.name = desc.array ? "array" : desc.field ? "procedural" : desc.file;
      info.source = source;
      const bool split = scene.dataPart.ranks > 1 && !desc.isosurfaces.empty();
      RankPart part;
      VolumeFile file = split ? loadRankVolume(scene, v, scene.camera.frameScene ? nullptr : &m_camera, part) : load ? load(v, desc) : loadVolume(desc);
      if (split) {
        info.ownLo = part.own.cellLo, info.ownHi = part.own.cellHi;
        info.heldLo = part.held.cellLo, info.heldHi = part.held.cellHi;
      } else {
        info.ownLo = info.heldLo = {0, 0, 0};
        info.ownHi = info.heldHi = file.grid.dims() - Vec3i{1, 1, 1};
      }
      info.grid = std::make_shared<const Grid>(std::move(file.grid));
      info.transform = file.toWorld;
      info.toObject = info.transform.inverse();
      info.format = file.format;
      info.notes = std::move(file.notes);
    }
    m_loadSeconds += secondsSince(loadStart);

    const auto buildStart = std::chrono::steady_clock::now();
    if (!shared) info.bricks = std::make_shared<const BrickGrid>(*info.grid);
    m_volumes.push_back(std::move(info));
    const VolumeInfo& vol = m_volumes.back();
    // (A volume without iso-surfaces is a data field for "color_by": nothing to trace.)
    const bool instanced = !vol.transform.isIdentity() && !desc.isosurfaces.empty();
    RTCScene target = m_scene;
    std::vector<GeometryRecord> records;
    if (instanced) {
      target = rtcNewScene(m_device);
      rtcSetSceneFlags(target, RTC_SCENE_FLAG_ROBUST);
      m_subScenes.push_back(target);
    }
    // The scene's and the volume's clip regions, in the grid's object space.
    ClipRegion objectClip = scene.clip;
    objectClip.add(desc.clip);
    if (!vol.transform.isIdentity()) objectClip = objectClip.transformed(vol.toObject);
    for (size_t k = 0; k < desc.isosurfaces.size(); ++k) {
      const IsoSurfaceDesc& isoDesc = desc.isosurfaces[k];
      SurfaceInfo s;
      s.volume = int(v);
      s.iso = isoDesc.value;
      s.solidAbove = isoDesc.solidAbove;
      s.smoothNormals = isoDesc.smoothNormals;
      s.colorBy = isoDesc.colorBy;
      if (s.colorBy) {
        const Vec3d n = s.colorBy->nanColor;
        s.nanColor = {srgbToLinear(float(n.x)), srgbToLinear(float(n.y)), srgbToLinear(float(n.z))};
      }
      if (!isoDesc.material.empty()) {
        s.material = materialFor(scene, isoDesc.material);
      } else if (isoDesc.color) {
        // A colour without a material is shorthand for a diffuse material of that colour.
        Material m;
        m.name = desc.where + "/isosurfaces/" + std::to_string(k) + "/color";
        m.color = Vec3f(*isoDesc.color);
        m_materials.push_back(m);
        s.material = int(m_materials.size() - 1);
      }
      if (isoDesc.capColorBy) {
        s.capColorBy = isoDesc.capColorBy;
        const Vec3d n = s.capColorBy->nanColor;
        s.capNanColor = {srgbToLinear(float(n.x)), srgbToLinear(float(n.y)), srgbToLinear(float(n.z))};
      } else if (s.colorBy) {
        s.capColorBy = s.colorBy;
        s.capNanColor = s.nanColor;
      }
      s.surface = std::make_unique<IsoSurface>(*vol.grid, *vol.bricks, isoDesc.value, intersector, objectClip,
                                               isoDesc.solidAbove);
      s.surface->setOrder(int(m_surfaces.size()));
      if (!s.surface->clip().empty() && s.material >= 0 && m_materials[size_t(s.material)].emits())
        throw InputError(scene.path, desc.where + "/isosurfaces/" + std::to_string(k),
                         "an emissive iso-surface cannot be clipped (its light would be sampled where it is cut away)");
      if (s.surface->activeBricks().empty()) {
        char line[256];
        const double lo = vol.bricks->minValue(), hi = vol.bricks->maxValue();
        std::snprintf(line, sizeof line, "iso value %g %s the volume's values %g to %g: the surface is empty",
                      isoDesc.value, isoDesc.value < lo || isoDesc.value > hi ? "lies outside" : "has no crossing among",
                      lo, hi);
        m_warnings.push_back(scene.path + ": " + desc.where + "/isosurfaces/" + std::to_string(k) + ": " + line);
      }
      if (instanced) s.surface->setWorldToObject(vol.toObject);
      // A surface with no active brick holds no primitive: nothing for Embree to build.
      if (!s.surface->activeBricks().empty()) {
        GeometryRecord rec;
        rec.surface = int(m_surfaces.size());
        rec.material = s.material;
        rec.toWorld = vol.transform;
        rec.identity = !instanced;
        attach(target, s.surface->createGeometry(m_device), instanced ? records : m_top, rec);
      }
      m_surfaces.push_back(std::move(s));
    }
    if (instanced) {
      RTCGeometry instance = rtcNewGeometry(m_device, RTC_GEOMETRY_TYPE_INSTANCE);
      rtcSetGeometryInstancedScene(instance, target);
      float xfm[12];
      vol.transform.toColumnMajor(xfm);
      rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, xfm);
      GeometryRecord top;
      top.instance = int(m_instanceRecords.size());
      m_instanceRecords.push_back(std::move(records));
      attach(m_scene, instance, m_top, top);
    }
    m_buildSeconds += secondsSince(buildStart);
  }
}

void World::buildLights(const SceneDesc& scene) {
  // Area lights first, so that a triangle record's light index is its place in m_lights.
  for (PendingAreaLight& p : m_pendingAreaLights)
    m_lights.push_back(Light::area(std::move(p.triangles), std::move(p.uvs), m_materials[p.material], m_textures));
  m_pendingAreaLights.clear();
  auto add = [&](const LightDesc& d) {
    const Texture* image = nullptr;
    if (d.type == LightType::Environment && !d.file.empty()) {
      const auto start = std::chrono::steady_clock::now();
      m_environmentImages.push_back(std::make_unique<Texture>(Texture::loadFile(d.file)));
      image = m_environmentImages.back().get();
      m_loadSeconds += secondsSince(start);
    }
    if (d.type == LightType::Environment) m_environmentLights.push_back(int(m_lights.size()));
    m_lights.push_back(Light::fromDesc(d, image));
  };
  for (const LightDesc& d : scene.lights) add(d);
  for (size_t s = 0; s < m_surfaces.size(); ++s)
    if (m_materials[m_surfaces[s].material].emits() && !m_surfaces[s].surface->activeBricks().empty())
      addIsoSurfaceLight(int(s));
  int cameraIndex = 0;
  bool cameraFound = scene.camera.gltfCamera.empty();
  std::string cameraNames;
  for (size_t m = 0; m < m_models.size(); ++m) {
    const Transform& t = scene.meshes[m].transform;
    for (LightDesc d : m_models[m].lights) {
      d.position = t.point(d.position);
      d.direction = normalize(t.vector(d.direction));
      add(d);
    }
    for (const GltfCamera& c : m_models[m].cameras) {
      const std::string& want = scene.camera.gltfCamera;
      cameraNames += (cameraNames.empty() ? "" : ", ") + c.name;
      if (!cameraFound && (want == c.name || want == "#" + std::to_string(cameraIndex))) {
        m_camera.position = t.point(c.desc.position);
        m_camera.lookAt = m_camera.position + normalize(t.vector(c.desc.lookAt - c.desc.position));
        m_camera.up = normalize(t.vector(c.desc.up));
        m_camera.fov = c.desc.fov;
        cameraFound = true;
      }
      ++cameraIndex;
    }
  }
  if (!cameraFound)
    throw InputError(scene.path, "/camera/gltf_camera",
                     "no glTF camera '" + scene.camera.gltfCamera + "' (cameras: " +
                         (cameraNames.empty() ? "none" : cameraNames) + "; \"#N\" picks the N-th)");
}

// An emissive iso-surface as a light: its active bricks grouped into at most 64 boxes (bricks
// of one group of g^3, g doubling until the groups are few enough), each weighted by the
// surface cells it holds. Few boxes keep the pdf of a direction (a sum over all boxes the
// ray crosses) cheap; tight boxes keep the sampled directions on the surface.
void World::addIsoSurfaceLight(int index) {
  constexpr size_t kMaxBoxes = 64;
  SurfaceInfo& info = m_surfaces[size_t(index)];
  const IsoSurface& surface = *info.surface;
  const VolumeInfo& volume = m_volumes[size_t(info.volume)];
  const std::vector<uint32_t>& active = surface.activeBricks();
  std::map<std::tuple<int, int, int>, size_t> groupOf;
  std::vector<Vec3d> lower, upper;
  std::vector<float> weights;
  for (int g = 1;; g *= 2) {
    groupOf.clear();
    lower.clear(), upper.clear(), weights.clear();
    for (uint32_t i = 0; i < active.size(); ++i) {
      const Vec3i c = volume.bricks->cellBegin(active[i]);
      const auto key = std::make_tuple(c.x / (BrickGrid::kCells * g), c.y / (BrickGrid::kCells * g), c.z / (BrickGrid::kCells * g));
      auto [it, added] = groupOf.emplace(key, lower.size());
      float lo[3], hi[3];
      surface.primitiveBounds(i, lo, hi);
      if (added) {
        lower.push_back({lo[0], lo[1], lo[2]});
        upper.push_back({hi[0], hi[1], hi[2]});
        weights.push_back(0);
      }
      Vec3d& l = lower[it->second];
      Vec3d& u = upper[it->second];
      l = min(l, Vec3d{lo[0], lo[1], lo[2]});
      u = max(u, Vec3d{hi[0], hi[1], hi[2]});
      weights[it->second] += float(surface.surfaceCells(i));
    }
    if (lower.size() <= kMaxBoxes) break;
  }
  // World-space boxes around the object-space ones (their 8 corners transformed).
  const Transform& t = volume.transform;
  std::vector<Vec3f> worldLower, worldUpper;
  for (size_t b = 0; b < lower.size(); ++b) {
    Vec3d lo{INFINITY, INFINITY, INFINITY}, hi = -lo;
    for (int c = 0; c < 8; ++c) {
      const Vec3d p = t.point({c & 1 ? upper[b].x : lower[b].x, c & 2 ? upper[b].y : lower[b].y,
                               c & 4 ? upper[b].z : lower[b].z});
      lo = min(lo, p);
      hi = max(hi, p);
    }
    worldLower.push_back(Vec3f(lo));
    worldUpper.push_back(Vec3f(hi));
  }
  // The area, roughly: about 0.6 of a cell face per cell the surface passes through (a plane
  // through a cubic grid), scaled by the transform.
  double cells = 0;
  for (float w : weights) cells += w;
  const Vec3d s = volume.grid->spacing();
  const double face = (s.x * s.y + s.y * s.z + s.z * s.x) / 3;
  const double area = 0.6 * cells * face * std::pow(std::fabs(t.determinant()), 2.0 / 3.0);
  info.light = int(m_lights.size());
  m_lights.push_back(Light::isoSurface(index, std::move(worldLower), std::move(worldUpper), weights,
                                       m_materials[size_t(info.material)], float(area)));
}

int World::pickLight(float u, float& probability) const {
  probability = 0;
  if (m_lights.empty()) return -1;
  return m_lightPick.pick(u, probability);
}

void World::buildSlices(const SceneDesc& scene) {
  for (size_t v = 0; v < scene.volumes.size(); ++v)
    for (const SliceDesc& desc : scene.volumes[v].slices) {
      const VolumeInfo& vol = m_volumes[v];
      const std::array<Vec3d, 8> corner = gridBoxCorners(vol);
      double d[8];
      for (int c = 0; c < 8; ++c) d[c] = dot(corner[c] - desc.point, desc.normal);
      std::vector<Vec3d> points;
      for (int c = 0; c < 8; ++c)
        if (d[c] == 0) points.push_back(corner[c]);
      for (int c = 0; c < 8; ++c)
        for (int bit : {1, 2, 4})
          if (!(c & bit) && ((d[c] < 0 && d[c | bit] > 0) || (d[c] > 0 && d[c | bit] < 0)))
            points.push_back(corner[c] + (corner[c | bit] - corner[c]) * (d[c] / (d[c] - d[c | bit])));
      if (points.size() < 3) throw InputError(scene.path, desc.where, "the plane does not cut the volume's grid");
      Vec3d centre{0, 0, 0};
      for (const Vec3d& p : points) centre = centre + p;
      centre = centre / double(points.size());
      // Order by angle in the plane (u, v: any basis of it).
      const Vec3d n = desc.normal;
      const Vec3d u = normalize(std::fabs(n.x) < 0.9 ? cross(n, Vec3d{1, 0, 0}) : cross(n, Vec3d{0, 1, 0}));
      const Vec3d w = cross(n, u);
      std::sort(points.begin(), points.end(), [&](const Vec3d& a, const Vec3d& b) {
        return std::atan2(dot(a - centre, w), dot(a - centre, u)) < std::atan2(dot(b - centre, w), dot(b - centre, u));
      });
      auto mesh = std::make_unique<TriangleMesh>();
      mesh->positions.push_back(Vec3f(centre));
      for (const Vec3d& p : points) mesh->positions.push_back(Vec3f(p));
      for (uint32_t i = 0; i < points.size(); ++i)
        mesh->indices.insert(mesh->indices.end(), {0u, 1 + i, 1 + uint32_t((i + 1) % points.size())});
      SliceInfo info;
      info.volume = int(v);
      info.map = desc.map;
      info.lo = desc.lo ? *desc.lo : double(vol.bricks->minValue());
      info.hi = desc.hi ? *desc.hi : double(vol.bricks->maxValue());
      if (!(info.hi > info.lo)) info.hi = info.lo + 1;  // a constant volume: one colour
      info.emit = desc.emit;
      info.triangles = mesh->triangleCount();
      Material m;
      m.name = desc.where;
      m.type = desc.emit ? MaterialType::Emissive : MaterialType::Diffuse;
      m.twoSided = true;
      m.emission = {1, 1, 1};  // stands for the map's colour (World::emitted)
      m_materials.push_back(m);
      GeometryRecord rec;
      rec.mesh = mesh.get();
      rec.material = int(m_materials.size() - 1);
      rec.slice = int(m_slices.size());
      attach(m_scene, triangleGeometry(*mesh), m_top, rec);
      m_meshStore.push_back(std::move(mesh));
      m_slices.push_back(std::move(info));
    }
}

std::array<Vec3d, 8> gridBoxCorners(const VolumeInfo& volume) {
  const Grid& grid = *volume.grid;
  const Vec3d extent = Vec3d(grid.dims() - Vec3i{1, 1, 1}) * grid.spacing();
  std::array<Vec3d, 8> corners;
  for (int c = 0; c < 8; ++c)
    corners[size_t(c)] =
        volume.transform.point(grid.origin() + Vec3d{c & 1 ? extent.x : 0, c & 2 ? extent.y : 0, c & 4 ? extent.z : 0});
  return corners;
}

}  // namespace iso
