#include "scene/world.h"


#include "scene/texture.h"

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

// pbrt's gamma(n): a bound on the relative error of n float operations.
constexpr float gamma(int n) {
  constexpr float eps = 0x1p-24f;
  return n * eps / (1 - n * eps);
}

template <typename T>
Vec3<T> absv(const Vec3<T>& v) { return {std::fabs(v.x), std::fabs(v.y), std::fabs(v.z)}; }

// Iso-surface queries start from the ray's origin in double (World::intersect and occluded
// pass it in the IsoRayContext): for an instance, Embree's own object-space origin carries
// the float rounding of the world origin and of the transform.
RTCRay toEmbree(const Ray& ray) {
  RTCRay r{};
  r.org_x = ray.org.x; r.org_y = ray.org.y; r.org_z = ray.org.z;
  r.dir_x = ray.dir.x; r.dir_y = ray.dir.y; r.dir_z = ray.dir.z;
  r.tnear = ray.tnear;
  r.tfar = ray.tfar;
  r.mask = ray.mask;
  return r;
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

void placeVolume(const VolumeDesc& desc, VolumeFile& v) {
  if (desc.origin) v.grid.setOrigin(*desc.origin);
  if (desc.spacing) v.grid.setSpacing(*desc.spacing);
  v.toWorld = desc.transform * v.toWorld;
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

World::World(const SceneDesc& scene, const IntersectorSpec& intersector, const World* sameVolumes) {
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
    buildVolumes(scene, intersector, sameVolumes);
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

void World::volumeBounds(Vec3d& lower, Vec3d& upper) const {
  lower = {INFINITY, INFINITY, INFINITY};
  upper = -lower;
  for (const SurfaceInfo& s : m_surfaces) {
    const VolumeInfo& vol = m_volumes[size_t(s.volume)];
    const Grid& g = *vol.grid;
    const Vec3i first = g.windowFirst(), last = first + g.windowExtent() - Vec3i{1, 1, 1};
    for (int c = 0; c < 8; ++c) {
      const Vec3d corner{double(c & 1 ? last.x : first.x), double(c & 2 ? last.y : first.y), double(c & 4 ? last.z : first.z)};
      const Vec3d p = vol.transform.point(g.origin() + corner * g.spacing());
      lower = min(lower, p);
      upper = max(upper, p);
    }
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

namespace {
// This rank's box of volume v (SceneDesc::dataPart) from the ranges of its bricks: boxes of
// whole bricks balanced by the bricks active for the volume's iso values, the same on every rank.
RankBox rankBox(const SceneDesc& scene, size_t v, const BrickGrid& bricks) {
  const VolumeDesc& desc = scene.volumes[v];
  std::vector<double> weights(bricks.size(), 0.0);
  for (const IsoSurfaceDesc& iso : desc.isosurfaces)
    for (uint32_t b : bricks.activeBricks(float(iso.value))) weights[b] = 1;
  return partitionBricks(bricks, weights, scene.dataPart.ranks, scene.path + ": " + desc.where)[size_t(scene.dataPart.rank)];
}

// This rank's window of volume v. A procedural field is evaluated twice, once for its bricks'
// ranges (nothing kept) and once for the window; a file whose samples lie in runs of bytes (raw,
// NRRD, MetaImage, binary VTK, NIfTI, DICOM: fileBrickRanges) is read twice, for the ranges and for the window: the rank
// never holds more than its window (and a compressed file's compressed bytes). Other files are
// read whole and the window cut from them (docs/distributed.md).
VolumeFile loadRankVolume(const SceneDesc& scene, size_t v) {
  const VolumeDesc& desc = scene.volumes[v];
  VolumeFile f;
  if (desc.field && !desc.array) {
    const Vec3i n = desc.resolution;
    const RankBox box = rankBox(scene, v, proceduralBrickRanges(*desc.field, n));
    f.grid = makeProceduralWindow(*desc.field, n, box.windowFirst(), box.windowExtent(n));
    f.format = "procedural";
    placeVolume(desc, f);
    return f;
  }
  if (!desc.array && !desc.field) {
    // Its bricks' ranges first (the files read or inflated in order, a layer at a time), then
    // only the window's samples.
    if (const std::optional<BrickGrid> ranges = fileBrickRanges(desc.file, desc.layout, desc.part)) {
      const RankBox box = rankBox(scene, v, *ranges);
      const SampleWindow window{box.windowFirst(), box.windowExtent(ranges->dims())};
      f = readVolumeFile(desc.file, desc.layout, desc.part, &window);
      placeVolume(desc, f);
      return f;
    }
  }
  f = loadVolume(desc);
  if (f.grid.sparse())
    throw InputError(scene.path, desc.where, "a sparse (OpenVDB) volume cannot be split over ranks yet (\"distribution\": \"data\")");
  const RankBox box = rankBox(scene, v, BrickGrid(f.grid));
  f.grid = windowOf(f.grid, box.windowFirst(), box.windowExtent(f.grid.dims()));
  return f;
}
}  // namespace

void World::buildVolumes(const SceneDesc& scene, const IntersectorSpec& intersector, const World* sameVolumes) {
  for (size_t v = 0; v < scene.volumes.size(); ++v) {
    const VolumeDesc& desc = scene.volumes[v];
    const auto loadStart = std::chrono::steady_clock::now();
    VolumeInfo info;
    const bool shared = sameVolumes && v < sameVolumes->m_volumes.size();
    if (shared) {
      info = sameVolumes->m_volumes[v];  // the grid and brick ranges are shared, not copied
    } else {
      info.name = desc.array ? "array" : desc.field ? "procedural" : desc.file;
      VolumeFile file =
          scene.dataPart.ranks > 1 && !desc.isosurfaces.empty() ? loadRankVolume(scene, v) : loadVolume(desc);
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
  float remapped;
  return m_lightPick.sample(u, probability, remapped);
}

const World::GeometryRecord& World::recordOf(const RTCHit& hit) const {
  if (hit.instID[0] != RTC_INVALID_GEOMETRY_ID) return m_instanceRecords[m_top[hit.instID[0]].instance][hit.geomID];
  return m_top[hit.geomID];
}

namespace {

StartClass startClassOf(const Ray& ray) { return ray.fromInside ? StartClass::Inside : StartClass::Outside; }

void startFromSurface(const Ray& ray, const std::vector<SurfaceInfo>& surfaces, IsoRayLane& lane) {
  if (ray.fromSurface < 0) return;
  lane.startSurface = surfaces[ray.fromSurface].surface.get();
  lane.start = startClassOf(ray);
  if (ray.fromCap) {
    lane.gridRay.capClip = &lane.startSurface->clip();
    lane.gridRay.capOrder = lane.startSurface->order();
  }
}

// Lane i of an Embree packet of width N as a single ray and hit (Embree's rtcGetRayHitFromRayHitN,
// with the float fields only).
RTCRayHit laneOf(const RTCRayHit8& packet, unsigned i) {
  RTCRayHit rh{};
  rh.ray.tfar = packet.ray.tfar[i];
  rh.hit.Ng_x = packet.hit.Ng_x[i]; rh.hit.Ng_y = packet.hit.Ng_y[i]; rh.hit.Ng_z = packet.hit.Ng_z[i];
  rh.hit.u = packet.hit.u[i]; rh.hit.v = packet.hit.v[i];
  rh.hit.primID = packet.hit.primID[i];
  rh.hit.geomID = packet.hit.geomID[i];
  for (unsigned l = 0; l < RTC_MAX_INSTANCE_LEVEL_COUNT; ++l) rh.hit.instID[l] = packet.hit.instID[l][i];
  return rh;
}

// What the iso-surface callbacks need of `ray` (its world origin in double, held by the caller in
// `origin`): the lane's ray in double, its far end and its start class.
void setLane(const Ray& ray, const Vec3d& origin, const std::vector<SurfaceInfo>& surfaces, IsoRayLane& lane) {
  lane.origin = &origin;
  lane.direction = Vec3d(ray.dir);
  lane.tfar = ray.tfar;
  startFromSurface(ray, surfaces, lane);
}

// Lane i of an 8-ray Embree packet set to `ray`.
void packLane(const Ray& ray, int i, RTCRay8& packet) {
  const RTCRay r = toEmbree(ray);
  packet.org_x[i] = r.org_x; packet.org_y[i] = r.org_y; packet.org_z[i] = r.org_z;
  packet.dir_x[i] = r.dir_x; packet.dir_y[i] = r.dir_y; packet.dir_z[i] = r.dir_z;
  packet.tnear[i] = r.tnear;
  packet.tfar[i] = r.tfar;
  packet.mask[i] = r.mask;
  packet.time[i] = 0;
  packet.flags[i] = 0;
}

}  // namespace

// The iso-surface hit at `t` on `ray`; `normal` in the surface's object space.
void World::fillIsoHit(const Ray& ray, int surface, double t, float tError, Vec3d normal,
                       bool insideAfter, bool cap, const Transform* toWorld, Hit& hit) const {
  const SurfaceInfo& info = m_surfaces[surface];
  hit.t = float(t);
  hit.material = info.material;
  hit.surface = surface;
  hit.tError = tError;
  hit.insideAfter = insideAfter;
  hit.cap = cap;
  // In double from the double origin: the bound is the intersector's, plus double rounding.
  const Vec3d org = ray.origin(), dir(ray.dir);
  hit.position64 = org + dir * t;
  hit.position = Vec3f(hit.position64);
  const Vec3d a = absv(hit.position64);
  const double rounding = 4 * 0x1p-52 * (std::max({a.x, a.y, a.z}) + length(dir) * std::fabs(t));
  hit.pError = Vec3f(absv(dir) * double(tError) + Vec3d(rounding, rounding, rounding));
  if (toWorld) normal = toWorld->normal(normal);
  hit.normal = Vec3f(normalize(normal));
  // The spawn offset. pbrt's (the error bound projected on the normal) is wide at a near-
  // tangent hit, where the bound is a bracket of values below rounding, and a ray spawned that
  // far off steps over a pair of crossings close behind (33 per million lost on the real
  // volumes). A ray leaving an iso-surface carries its class, so a crossing it steps over is
  // found anyway; the offset only has to clear the rounding of the float traversal's grid
  // coordinates, or the hit is found again at t = 0 by its own ray, over and over.
  const Grid& grid = *m_volumes[info.volume].grid;
  const Vec3d gridCoord = (info.surface->objectOrigin(hit.position64) - grid.origin()) / grid.spacing();
  const Vec3d g = absv(gridCoord);
  const Vec3d s = grid.spacing();
  double scale = std::max({s.x, s.y, s.z});
  if (toWorld) {
    const Vec3d rows = toWorld->absRowSums();
    scale *= std::max({rows.x, rows.y, rows.z});
  }
  const double gridRounding = 8 * 0x1p-24 * (std::max({g.x, g.y, g.z}) + 1) * scale;
  hit.spawnOffset = float(std::min(dot(absv(Vec3d(hit.normal)), Vec3d(hit.pError)), gridRounding));
  // A cap is exact to double rounding; a ray leaving it starts off its plane along the normal by
  // the float traversal's rounding, far enough that its own clip extent is decided on its side.
  if (cap) hit.spawnOffset = float(gridRounding);
  if (!info.solidAbove) hit.normal = -hit.normal;
  // The shading normal: the smooth gradient at the hit (the cell's own gradient jumps across
  // cell faces, which shades in facets). It only shades; orientation, spawning and the class
  // stay with the exact surface's geometric normal, which it may not contradict.
  hit.shading = hit.normal;
  if (info.smoothNormals && !cap) {  // (a cap is flat)
    Vec3d n = -grid.smoothGradient(gridCoord) / grid.spacing();
    if (toWorld) n = toWorld->normal(n);
    if (!info.solidAbove) n = -n;
    const double len = length(n);
    if (len > 0 && std::isfinite(len) && dot(n, Vec3d(hit.normal)) > 0) hit.shading = Vec3f(n / len);
  }
}

// A ray leaving an iso-surface whose origin lies in an inactive brick of that surface: no
// brick query sees that cell (IsoSurface::crossesAtInactiveStart).
bool World::crossesAtInactiveStart(const Ray& ray, Hit* hit, TraversalStats& stats) const {
  if (ray.fromSurface < 0) return false;
  const IsoSurface& surface = *m_surfaces[ray.fromSurface].surface;
  const Vec3d org = surface.objectOrigin(ray.origin());
  const Vec3d dir = surface.objectDirection(Vec3d(ray.dir));
  SurfaceHit sh;
  if (!surface.crossesAtInactiveStart(org, dir, ray.tnear, ray.tfar, startClassOf(ray), hit ? &sh : nullptr, stats))
    return false;
  if (hit) {
    *hit = Hit();
    hit->incoming = ray.dir;
    const Transform& toWorld = m_volumes[m_surfaces[ray.fromSurface].volume].transform;
    fillIsoHit(ray, ray.fromSurface, sh.t, float(sh.tError), Vec3d(sh.normal), sh.insideAfter, sh.cap,
               toWorld.isIdentity() ? nullptr : &toWorld, *hit);
  }
  return true;
}

// A ray leaving an iso-surface hit near its volume's box can start just outside the box (the
// spawn offset points out of it). Its start class applies where it meets the field, so its
// origin moves back onto the box: to where the line of the offset (through the hit and the
// origin: the incoming ray, on which the crossing and its class were decided), followed from
// the hit towards the origin, leaves the box. The crossing lies in the box, so that point is
// on the side of it the ray's class names, even where rounding put the hit itself outside.
// Moving each coordinate onto the box alone would step sideways off that line, and where the
// surface meets the box face within that step, onto its other side: an extra pair of hits at
// the box face (11 in 3e8 rays on a rough field). Embree then traces the same line as the
// iso-surface queries (IsoSurface moves what rounding leaves outside).
Ray World::startInsideVolume(const Ray& ray) const {
  if (ray.fromSurface < 0) return ray;
  const SurfaceInfo& info = m_surfaces[ray.fromSurface];
  const VolumeInfo& volume = m_volumes[info.volume];
  const Grid& grid = *volume.grid;
  const Vec3d world = ray.origin();
  const Vec3d o = info.surface->objectOrigin(world);
  const Vec3d lo = grid.origin();
  const Vec3d hi = lo + Vec3d(grid.dims() - Vec3i{1, 1, 1}) * grid.spacing();
  auto clampToBox = [&](const Vec3d& p) {
    return Vec3d{std::clamp(p.x, lo.x, hi.x), std::clamp(p.y, lo.y, hi.y), std::clamp(p.z, lo.z, hi.z)};
  };
  Vec3d c = clampToBox(o);
  if (c == o || !isFinite(o)) return ray;
  // The line from + s (o - from): where it is in the box, s in [enter, leave].
  const Vec3d from = info.surface->objectOrigin(world - ray.fromOffset);  // the hit
  double enter, leave;
  if (isFinite(from) && lineInBox(from, o - from, lo, hi, enter, leave) && leave < 1)
    c = clampToBox(from + (o - from) * leave);  // the clamp: rounding only
  Ray moved = ray;
  moved.org64 = volume.transform.isIdentity() ? c : volume.transform.point(c);
  moved.org = Vec3f(*moved.org64);
  return moved;
}

bool World::intersect(const Ray& ray, Hit& hit, TraversalStats& stats) const {
  if (ray.fromSurface < 0) return trace(ray, hit, stats);
  const Ray start = startInsideVolume(ray);
  return crossesAtInactiveStart(start, &hit, stats) || trace(start, hit, stats);
}

bool World::trace(const Ray& ray, Hit& hit, TraversalStats& stats) const {
  IsoRayLane lane;
  IsoRayContext context(&lane);
  const Vec3d origin = ray.origin();
  setLane(ray, origin, m_surfaces, lane);
  RTCRayHit rh{};
  rh.ray = toEmbree(ray);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(m_scene, &context.embree, &rh);
  stats.add(context.stats);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  fillHit(ray, rh, lane, hit);
  return true;
}

// What intersect() and occluded() do before Embree, for each ray of a packet: a ray leaving an
// iso-surface starts on its volume's box, and may cross at once where its start cell is seen by
// no brick query (done[i], with hits[i] filled if `hits` is given); every other ray becomes a
// valid lane of `packet` with its iso-surface data. False if no ray is left for Embree.
bool World::packRays(const Ray* rays, int n, Hit* hits, bool* done, TraversalStats& stats, PacketLanes& p,
                     RTCRay8& packet) const {
  if (n < 1 || n > kPacket) throw std::logic_error("World::intersectPacket/occludedPacket: 1 to 8 rays");
  for (int i = 0; i < kPacket; ++i) {
    p.valid[i] = 0;
    packet.tnear[i] = 0;
    packet.tfar[i] = -INFINITY;
  }
  bool any = false;
  for (int i = 0; i < n; ++i) {
    const Ray& start = p.start.emplace(i, startInsideVolume(rays[i]));
    done[i] = rays[i].fromSurface >= 0 && crossesAtInactiveStart(start, hits ? &hits[i] : nullptr, stats);
    if (done[i]) continue;
    setLane(start, p.origin.emplace(i, start.origin()), m_surfaces, p.lanes.emplace(i));
    packLane(start, i, packet);
    p.valid[i] = -1;
    any = true;
  }
  return any;
}

void World::intersectPacket(const Ray* rays, int n, Hit* hits, bool* found, TraversalStats& stats) const {
  if (!m_nativePackets) {
    for (int i = 0; i < n; ++i) found[i] = intersect(rays[i], hits[i], stats);
    return;
  }
  PacketLanes p;
  alignas(32) RTCRayHit8 packet;
  for (int i = 0; i < kPacket; ++i) {
    packet.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
    packet.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
  }
  if (!packRays(rays, n, hits, found, stats, p, packet.ray)) return;
  IsoRayContext context(p.lanes.data());
  rtcIntersect8(p.valid, m_scene, &context.embree, &packet);
  stats.add(context.stats);
  for (int i = 0; i < n; ++i) {
    if (!p.valid[i] || packet.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
    fillHit(p.start[i], laneOf(packet, unsigned(i)), p.lanes[i], hits[i]);
    found[i] = true;
  }
}

void World::occludedPacket(const Ray* rays, int n, bool* blocked, TraversalStats& stats) const {
  if (!m_nativePackets) {
    for (int i = 0; i < n; ++i) blocked[i] = occluded(rays[i], stats);
    return;
  }
  PacketLanes p;
  alignas(32) RTCRay8 packet;
  if (!packRays(rays, n, nullptr, blocked, stats, p, packet)) return;
  IsoRayContext context(p.lanes.data());
  rtcOccluded8(p.valid, m_scene, &context.embree, &packet);
  stats.add(context.stats);
  for (int i = 0; i < n; ++i)
    if (p.valid[i] && packet.tfar[i] < 0) blocked[i] = true;
}

// The hit Embree found for `ray` (in `rh`), with the lane's iso-surface result.
[[gnu::always_inline]] inline void World::fillHit(const Ray& ray, const RTCRayHit& rh, const IsoRayLane& lane, Hit& hit) const {
  const GeometryRecord& rec = recordOf(rh.hit);
  hit = Hit();
  hit.incoming = ray.dir;
  if (!rec.mesh) {
    // Iso-surface: the intersector's bound on t becomes a bound on the position.
    fillIsoHit(ray, rec.surface, lane.t, lane.tError, Vec3d{rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z},
               lane.insideAfter, lane.cap, rec.identity ? nullptr : &rec.toWorld, hit);
    return;
  }
  hit.t = rh.ray.tfar;
  hit.material = rec.material;
  // Triangle: position from barycentrics with pbrt-v4's bound (Pharr et al., 6.8.5).
  const TriangleMesh& m = *rec.mesh;
  const unsigned prim = rh.hit.primID;
  const uint32_t i0 = m.indices[3 * prim], i1 = m.indices[3 * prim + 1], i2 = m.indices[3 * prim + 2];
  const float b1 = rh.hit.u, b2 = rh.hit.v, b0 = 1 - b1 - b2;
  const Vec3f p0 = m.positions[i0], p1 = m.positions[i1], p2 = m.positions[i2];
  const Vec3f pObj = p0 * b0 + p1 * b1 + p2 * b2;
  const Vec3f errObj = (absv(p0 * b0) + absv(p1 * b1) + absv(p2 * b2)) * gamma(7);
  Vec3f ng = cross(p1 - p0, p2 - p0);
  hit.mesh = rec.meshDesc;
  hit.slice = rec.slice;
  hit.light = rec.light;
  hit.triangle = rec.light >= 0 ? int(prim) : -1;
  hit.b1 = b1;
  hit.b2 = b2;
  Vec3f ns = m.normals.empty() ? Vec3f{0, 0, 0} : m.normals[i0] * b0 + m.normals[i1] * b1 + m.normals[i2] * b2;
  Vec2f uv{b1, b2};
  Vec3f dpdu, dpdv;
  if (!m.uvs.empty()) {
    const Vec2f t0 = m.uvs[i0], t1 = m.uvs[i1], t2 = m.uvs[i2];
    uv = {t0.x * b0 + t1.x * b1 + t2.x * b2, t0.y * b0 + t1.y * b1 + t2.y * b2};
    const float du1 = t1.x - t0.x, dv1 = t1.y - t0.y, du2 = t2.x - t0.x, dv2 = t2.y - t0.y;
    const float det = du1 * dv2 - dv1 * du2;
    if (std::fabs(det) > 1e-12f) {
      dpdu = ((p1 - p0) * dv2 - (p2 - p0) * dv1) / det;
      dpdv = ((p2 - p0) * du1 - (p1 - p0) * du2) / det;
    }
  }
  if (rec.identity) {
    hit.position = pObj;
    hit.pError = errObj;
    hit.position64 = Vec3d(pObj);
  } else {
    const Transform& t = rec.toWorld;
    hit.position = Vec3f(t.point(Vec3d(pObj)));
    const Vec3d rows = t.absRowSums(), trans{t.m[0][3], t.m[1][3], t.m[2][3]};
    const float e = std::max({errObj.x, errObj.y, errObj.z});
    const Vec3f pAbs = absv(pObj);
    const float pMax = std::max({pAbs.x, pAbs.y, pAbs.z});
    hit.pError = Vec3f(rows * double(e)) + (Vec3f(rows * double(pMax)) + absv(Vec3f(trans)) + absv(hit.position)) * gamma(3);
    hit.position64 = Vec3d(hit.position);
    ng = Vec3f(t.normal(Vec3d(ng)));
    if (length(ns) > 0) ns = Vec3f(t.normal(Vec3d(ns)));
    dpdu = Vec3f(t.vector(Vec3d(dpdu)));
    dpdv = Vec3f(t.vector(Vec3d(dpdv)));
  }
  const float ngLen = length(ng);
  hit.normal = ngLen > 0 ? ng * (1 / ngLen) : -ray.dir;
  const float nsLen = length(ns);
  hit.shading = nsLen > 0 && std::isfinite(nsLen) ? ns * (1 / nsLen) : hit.normal;
  // The geometric normal follows the shading normals' side (pbrt's convention): vertex
  // normals say which way is out even where the winding disagrees.
  if (dot(hit.normal, hit.shading) < 0) hit.normal = -hit.normal;
  hit.uv = uv;
  hit.dpdu = dpdu;
  hit.dpdv = dpdv;
}

bool World::occluded(const Ray& ray, TraversalStats& stats) const {
  if (ray.fromSurface < 0) return traceShadow(ray, stats);
  const Ray start = startInsideVolume(ray);
  return crossesAtInactiveStart(start, nullptr, stats) || traceShadow(start, stats);
}

Vec3f World::transmittance(const Ray& shadow, TraversalStats& stats) const {
  if (!m_hasThin) return occluded(shadow, stats) ? Vec3f{0, 0, 0} : Vec3f{1, 1, 1};
  Hit hit;
  Vec3f T;
  return intersectPastThin(shadow, hit, T, stats) ? Vec3f{0, 0, 0} : T;
}

bool World::intersectPastThin(const Ray& first, Hit& hit, Vec3f& T, TraversalStats& stats) const {
  T = {1, 1, 1};
  if (!m_hasThin) return intersect(first, hit, stats);
  // Hit by hit: each thin crossing scales the light. A ray to a point (spawnRayTo) keeps its
  // target; any other ray its direction.
  const bool toPoint = first.tfar < 1;
  const Vec3f target = Vec3f(first.origin() + Vec3d(first.dir));
  const Vec3f dir = normalize(first.dir);
  Ray ray = first;
  for (int crossing = 0; crossing < 64; ++crossing) {
    if (!intersect(ray, hit, stats)) return false;
    const Material& m = m_materials[size_t(hit.material)];
    if (!(m.type == MaterialType::Dielectric && m.thin)) return true;
    T = T * albedo(hit) * (1 - thinDielectricReflectance(dot(dir, hit.normal), m.ior));
    if (!(std::max({T.x, T.y, T.z}) > 0)) return true;  // nothing passes: as good as opaque
    ray = toPoint ? spawnRayTo(hit, target) : spawnRay(hit, first.dir);
  }
  return true;
}

bool World::traceShadow(const Ray& ray, TraversalStats& stats) const {
  IsoRayLane lane;
  IsoRayContext context(&lane);
  const Vec3d origin = ray.origin();
  setLane(ray, origin, m_surfaces, lane);
  RTCRay r = toEmbree(ray);
  rtcOccluded1(m_scene, &context.embree, &r);
  stats.add(context.stats);
  return r.tfar < 0;
}

// Each slice's polygon: the plane cut through the volume's grid box (a parallelepiped in world
// space), its corners in order around their centre, as a triangle fan in world space.
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

bool World::gridCoordinates(int volume, const Vec3d& world, Vec3d& g) const {
  const VolumeInfo& vol = m_volumes[size_t(volume)];
  const Grid& grid = *vol.grid;
  g = ((vol.transform.isIdentity() ? world : vol.toObject.point(world)) - grid.origin()) / grid.spacing();
  const Vec3d hi = Vec3d(grid.dims() - Vec3i{1, 1, 1});
  const double slack = 1e-9 * (std::max({std::fabs(g.x), std::fabs(g.y), std::fabs(g.z)}) + 1);
  for (int a = 0; a < 3; ++a)
    if (!(g[a] >= -slack && g[a] <= hi[a] + slack)) return false;
  return true;
}

double World::colorValue(const ColorByDesc& c, int ownVolume, const Vec3d& world) const {
  const int volume = c.volume >= 0 ? c.volume : ownVolume;
  Vec3d g;
  if (!gridCoordinates(volume, world, g)) return NAN;
  const VolumeInfo& vol = m_volumes[size_t(volume)];
  if (c.volume >= 0) return vol.grid->interpolate(g);
  // The gradient's magnitude in world units: per grid step to per object unit, then the
  // inverse transpose of the volume's placement.
  const Vec3d d = vol.grid->smoothGradient(g) / vol.grid->spacing();
  if (vol.transform.isIdentity()) return length(d);
  const Transform& inv = vol.toObject;
  Vec3d worldGradient;
  for (int i = 0; i < 3; ++i) worldGradient[i] = inv.m[0][i] * d.x + inv.m[1][i] * d.y + inv.m[2][i] * d.z;
  return length(worldGradient);
}

Vec3f World::sliceColor(const Hit& hit) const {
  const SliceInfo& s = m_slices[size_t(hit.slice)];
  Vec3d g;
  gridCoordinates(s.volume, hit.position64, g);  // on the slice's polygon: inside (the value clamps)
  return s.map.linear(m_volumes[size_t(s.volume)].grid->interpolate(g), s.lo, s.hi);
}

Vec3f World::albedo(const Hit& hit) const {
  if (hit.slice >= 0)  // a slice: its map of the volume's value, or black if it only emits
    return m_slices[size_t(hit.slice)].emit ? Vec3f{0, 0, 0} : sliceColor(hit);
  if (hit.surface >= 0) {
    const SurfaceInfo& s = m_surfaces[size_t(hit.surface)];
    if (const std::optional<ColorByDesc>& by = hit.cap ? s.capColorBy : s.colorBy) {
      const double v = colorValue(*by, s.volume, hit.position64);
      return std::isfinite(v) ? by->map.linear(v, by->lo, by->hi) : hit.cap ? s.capNanColor : s.nanColor;
    }
  }
  const Material& m = m_materials[hit.material];
  Vec3f c = m.color;
  if (m.colorTexture >= 0) c = c * m_textures[m.colorTexture].lookup(hit.uv.x, hit.uv.y).rgb();
  return c;
}

Bsdf World::bsdf(const Hit& hit) const {
  const Material& m = m_materials[hit.material];
  float metallic = m.metallic, roughness = m.roughness;
  if (m.metallicRoughnessTexture >= 0) {
    // glTF: roughness in green, metalness in blue, both linear.
    const Vec4f mr = m_textures[m.metallicRoughnessTexture].lookup(hit.uv.x, hit.uv.y);
    roughness *= mr.y;
    metallic *= mr.z;
  }
  Vec3f n = hit.shading;
  if (m.normalTexture >= 0 && length(hit.dpdu) > 0) {
    // Tangent space of the texture: x along +u, y towards the image top (-v), z the normal.
    const Vec4f c = m_textures[m.normalTexture].lookup(hit.uv.x, hit.uv.y);
    const Vec3f local{(2 * c.x - 1) * m.normalScale, (2 * c.y - 1) * m.normalScale, 2 * c.z - 1};
    const Vec3f t = normalize(hit.dpdu - n * dot(n, hit.dpdu));
    Vec3f b = cross(n, t);
    if (dot(b, hit.dpdv) > 0) b = -b;
    const Vec3f mapped = t * local.x + b * local.y + n * local.z;
    if (length(mapped) > 0 && std::isfinite(length(mapped))) n = normalize(mapped);
  }
  return Bsdf(m.type, Frame::fromNormal(n, hit.dpdu), albedo(hit), metallic, roughness, m.ior, m.thin);
}

Vec3f World::emitted(const Hit& hit, const Vec3f& wo) const {
  const Material& m = m_materials[hit.material];
  if (!m.emits()) return {0, 0, 0};
  if (hit.slice >= 0) return sliceColor(hit);  // an unlit slice shows its map on both sides
  if (hit.surface < 0 && hit.light >= 0) return m_lights[hit.light].emitted(hit.triangle, hit.b1, hit.b2, wo);
  // Emissive iso-surfaces: front side is out of the solid.
  if (!m.twoSided && dot(wo, hit.normal) <= 0) return {0, 0, 0};
  return m.emission;
}

namespace {

// Whether a ray leaving an iso-surface hit in direction w goes on through the surface: when w
// heads to the same side of the normal as the incoming ray (w = incoming, the watertight
// check's case, always does); one of them in the plane decides by w against the incoming ray.
bool goesThrough(const Hit& hit, const Vec3f& w) {
  const float a = dot(w, hit.normal), b = dot(hit.incoming, hit.normal);
  return a != 0 && b != 0 ? (a > 0) == (b > 0) : dot(w, hit.incoming) > 0;
}

}  // namespace

Vec3d offsetRayOrigin(const Hit& hit, const Vec3f& w) {
  const Vec3d n(dot(w, hit.normal) < 0 ? -hit.normal : hit.normal);  // towards the leaving side
  const Vec3d p = hit.position64;
  const Vec3d a = absv(p);
  // pbrt rejects hits at t = 0, Embree accepts them (t >= tnear = 0): an origin must lie
  // strictly on the leaving side even where the bound is 0 (a hit on the plane y = 0 has no
  // error in y). For triangles, which Embree intersects in float, the floor is one float
  // spacing at the point's magnitude (a representable move, never a denormal, which Embree
  // flushes to zero); iso-surfaces are intersected from the double origin, so theirs is
  // one double spacing.
  const double spacing = hit.surface >= 0 ? 0x1p-52 : 0x1p-23;
  const double floor = std::max(std::max({a.x, a.y, a.z}) * spacing, 1e-20);
  const double d = std::max(hit.surface >= 0 ? double(hit.spawnOffset) : dot(absv(n), Vec3d(hit.pError)), floor);
  if (hit.surface >= 0 && !hit.cap && length(Vec3d(hit.incoming)) > 0) {
    // An iso-surface's origin moves along the incoming ray, on whose line the crossing and its
    // class were decided: forward past the hit for a ray that goes through, back for one that
    // turns back. Along the normal it could land on the wrong side where the hit sits on a
    // cell face: the normal is the gradient of one cell, and the surface bends at the face
    // (a double count found at 1e7 rays: the next ray started on the old side with the new
    // class and reported the same crossing again).
    const Vec3d in = normalize(Vec3d(hit.incoming));
    return p + in * (goesThrough(hit, w) ? d : -d);
  }
  Vec3d po = p + n * d;
  if (hit.surface < 0) {
    // Round away from the surface in float, where Embree will see it.
    Vec3f pf(po);
    for (int i = 0; i < 3; ++i) {
      if (n[i] > 0) pf[i] = std::nextafter(pf[i], INFINITY);
      else if (n[i] < 0) pf[i] = std::nextafter(pf[i], -INFINITY);
    }
    po = Vec3d(pf);
  }
  return po;
}

namespace {

Ray leaving(const Hit& hit, const Vec3f& w) {
  Ray r;
  const Vec3d o = offsetRayOrigin(hit, w);
  r.org = Vec3f(o);
  r.tnear = 0;
  if (hit.surface >= 0) {
    r.org64 = o;
    r.fromOffset = o - hit.position64;
    r.fromSurface = hit.surface;
    r.fromCap = hit.cap;
    r.fromInside = goesThrough(hit, w) ? hit.insideAfter : !hit.insideAfter;
  }
  return r;
}

}  // namespace

Ray spawnRay(const Hit& hit, const Vec3f& dir) {
  Ray r = leaving(hit, dir);
  r.dir = dir;
  return r;
}

Ray spawnRayTo(const Hit& hit, const Vec3f& target) {
  Ray r = leaving(hit, target - hit.position);
  r.dir = Vec3f(Vec3d(target) - r.origin());
  r.tfar = 1 - 1e-4f;
  return r;
}

Vec3f World::environment(const Vec3f& dir) const {
  Vec3f sum{0, 0, 0};
  for (int i : m_environmentLights) sum += m_lights[i].environment(dir);
  return sum;
}

}  // namespace iso
