#pragma once
// The loaded scene: glTF meshes and built-in shapes, grids with their brick ranges and
// iso-surfaces, materials, textures and lights, in one Embree scene. Meshes used once are
// baked into world space; a glTF mesh used by several nodes and a transformed volume are
// Embree instances. Only what the scene uses is loaded or built.
#include <embree3/rtcore.h>

#include <array>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "scene/camera.h"
#include "scene/gltf.h"
#include "scene/light.h"
#include "scene/material.h"
#include "scene/scene.h"
#include "volume/iso_surface.h"
#include "volume/packet_walk.h"
#include "volume/partition.h"

namespace iso {

// (A new field must be written by both World::fillHit (iso-surfaces) and World::fillTriangleHit,
// which fill a Hit without clearing it first.) What only shading reads of a triangle hit (its
// texture coordinates and tangents: World::textureFrame) is not built with it.
struct Hit {
  float t = 0;
  float tError = 0;   // |t - true t| <= tError (iso-surfaces; 0 for triangles)
  Vec3f position;
  Vec3d position64;   // the same in double: iso-surface hits are located to double precision
  Vec3f pError;       // per-axis bound on the error of `position64` (and of `position` to
                      // within float rounding)
  Vec3f normal;       // geometric, unit, world space, pointing out of the solid
  Vec3f shading;      // interpolated shading normal (before normal mapping), unit
  int material = 0;   // index into World::materials()
  int surface = -1;   // iso-surface index, or -1 for a triangle
  int mesh = -1;      // scene mesh index, or -1 for an iso-surface
  int light = -1;     // area light index of an emissive triangle, or -1
  int triangle = -1;  // triangle index inside that area light
  int slice = -1;     // a slice plane (World::slices()), or -1
  float b1 = 0, b2 = 0;  // barycentrics of a triangle hit
  // A triangle hit: its mesh (object space), the triangle, and the mesh's placement (null: the
  // mesh is stored in world space). Null for iso-surfaces.
  const TriangleMesh* triangles = nullptr;
  unsigned prim = 0;
  const Transform* toWorld = nullptr;
  float spawnOffset = 0;  // iso-surfaces: how far a ray leaving the hit starts off it
  Vec3f incoming;        // direction of the ray that made the hit
  bool insideAfter = false;  // iso-surfaces: the ray is inside (value > iso) just past the hit
  bool cap = false;          // iso-surfaces: a cap, where a clip plane cuts the solid open
};

// A hit's texture coordinates and the surface tangents along them (World::textureFrame).
struct TextureFrame {
  Vec2f uv;          // a triangle's barycentrics (b1, b2) where its mesh has no texture coordinates
  Vec3f dpdu, dpdv;  // world space; 0 without texture coordinates (and for iso-surfaces)
};

struct SurfaceInfo {
  int volume = 0;
  double iso = 0;
  int material = 0;
  bool solidAbove = true;
  bool smoothNormals = true;
  int light = -1;  // index into World::lights() when the surface emits
  std::unique_ptr<IsoSurface> surface;
  // "color_by": the base colour from a colour map of a field at the hit (World::albedo).
  std::optional<ColorByDesc> colorBy;
  Vec3f nanColor;  // colorBy->nanColor in linear light
  // "cap_color_by": the same for the surface's caps (default: colorBy).
  std::optional<ColorByDesc> capColorBy;
  Vec3f capNanColor;
};

// A slice plane of a volume as built: its polygon inside the grid is a mesh in the scene.
struct SliceInfo {
  int volume = 0;
  ColorMap map;
  double lo = 0, hi = 1;
  bool emit = false;
  size_t triangles = 0;
};

struct VolumeInfo {
  std::string name;  // file or procedural field
  std::shared_ptr<const Grid> grid;  // shared with a World built from it (sameVolumes)
  std::shared_ptr<const BrickGrid> bricks;
  Transform transform;             // grid space -> world: the file's affine, then the scene's
  Transform toObject;              // its inverse: world -> the grid's object space
  std::string format;              // the file's format ("procedural" for a built-in field)
  std::vector<std::string> notes;  // what the file said about itself (VolumeFile::notes)
  std::string source;              // what was loaded (volumeSourceKey): a later World reuses it when equal
  // The cells [ownLo, ownHi) of the rank's own box of a volume split over data-parallel ranks
  // (volume/partition.h), the part of the volume it answers for, and [heldLo, heldHi), the cells
  // it holds ("replicate": its box and copies of its neighbours' bricks around it). The whole
  // grid's cells when the volume is not split.
  Vec3i ownLo, ownHi, heldLo, heldHi;
};

// How a World gets a volume's samples: nothing (loadVolume reads it), or a function that may hand
// over one read ahead (a time series' next step, read while a frame renders).
using VolumeLoader = std::function<VolumeFile(size_t volume, const VolumeDesc& desc)>;

struct MeshInfo {
  std::string name;            // file or built-in shape
  size_t meshes = 0;           // glTF meshes (or 1 for a shape)
  size_t uniqueTriangles = 0;  // stored
  size_t triangles = 0;        // in the world, counting every instance
  size_t instances = 0;        // placements of glTF meshes (nodes with a mesh)
  size_t embreeInstances = 0;  // of those, traced as Embree instances (mesh used more than once)
  size_t cameras = 0, lights = 0, materials = 0, textures = 0, images = 0;
  Vec3d lower{1e300, 1e300, 1e300}, upper{-1e300, -1e300, -1e300};  // world-space bounds
};

// The 8 corners of a volume's grid box in world space (corner c: bit 0 x, bit 1 y, bit 2 z at
// the grid's far side).
std::array<Vec3d, 8> gridBoxCorners(const VolumeInfo& volume);

class World {
 public:
  // Loads and builds everything the scene needs for intersector `intersector`. `sameVolumes`:
  // a World of a scene whose volumes load alike (only their iso-surfaces, materials and the
  // rest may differ, as in `isotrace view` or an iso sweep): its grids and brick ranges are
  // shared instead of read and built again, each volume whose source (volumeSourceKey: a time
  // series' step) is the same. `load`: how the others are read (default loadVolume).
  World(const SceneDesc& scene, const IntersectorSpec& intersector, const World* sameVolumes = nullptr,
        const VolumeLoader& load = {});
  ~World();
  World(const World&) = delete;
  World& operator=(const World&) = delete;

  // Geometry masks (Ray::mask): triangle meshes (and their instances), and the rest: iso-surfaces.
  static constexpr unsigned kMeshMask = 1u, kVolumeMask = ~1u;
  // An upper bound on the world-space length of any cell's diagonal of those volumes (0: none).
  double largestCell() const;
  bool intersect(const Ray& ray, Hit& hit, TraversalStats& stats) const;
  bool occluded(const Ray& ray, TraversalStats& stats) const;
  // Up to kPacket rays traced together (Embree's 8-wide packets, rtcIntersect8 / rtcOccluded8):
  // found[i] and hits[i] (blocked[i]) are what intersect() (occluded()) gives for rays[i] alone,
  // bit for bit (tests/world_test.cpp: Packets.*). Coherent rays (a camera's 4x2 pixels, rays
  // towards one light) share the BVH traversal. Where Embree has no native 8-wide packets (a
  // CPU without AVX: it would split them, and the iso-surfaces' lanes would not follow), each
  // ray is traced alone, with the same results.
  static constexpr int kPacket = 8;
  void intersectPacket(const Ray* rays, int n, Hit* hits, bool* found, TraversalStats& stats) const;
  void occludedPacket(const Ray* rays, int n, bool* blocked, TraversalStats& stats) const;
  // What of a shadow ray's light arrives: 1 if nothing is in the way, 0 if something opaque
  // (or refracting) is; thin dielectrics ("thin": true) let it through, tinted by their colour
  // and their thin-sheet transmission at each crossing. Without thin materials it is occluded().
  Vec3f transmittance(const Ray& ray, TraversalStats& stats) const;
  // No thin dielectric in the scene: transmittance() is 1 or 0, i.e. occluded().
  bool opaqueShadows() const { return !m_hasThin; }
  // The first hit that is not a thin dielectric, and in T what the thin ones before it let
  // through (1 without thin materials: then it is intersect()).
  bool intersectPastThin(const Ray& ray, Hit& hit, Vec3f& T, TraversalStats& stats) const;

  // Shading at a hit: the BSDF (textures and normal map applied) seen from `wo`, the base colour,
  // and the radiance emitted towards `wo` (unit, pointing away from the surface).
  Bsdf bsdf(const Hit& hit, const Vec3f& wo) const;
  Vec3f albedo(const Hit& hit) const;
  // The hit's texture coordinates and tangents, computed on demand: only shading reads them.
  static TextureFrame textureFrame(const Hit& hit);
  // The value "color_by" maps at an iso-surface hit (NaN where its field has none).
  // `ownVolume`: the surface's own volume (for "gradient_magnitude").
  double colorValue(const ColorByDesc& c, int ownVolume, const Vec3d& world) const;
  Vec3f emitted(const Hit& hit, const Vec3f& wo) const;
  // Radiance from the environment lights along `dir` (a ray that escaped).
  Vec3f environment(const Vec3f& dir) const;

  const CameraDesc& camera() const { return m_camera; }
  // The bounds of what this World holds (Embree's scene bounds; none: lower > upper).
  Vec3d lower() const { return m_lower; }
  Vec3d upper() const { return m_upper; }
  // What depends on the scene's bounds (the framing camera, distant lights' power) from other
  // bounds: a data-parallel rank's World holds part of the scene, and takes the union of all
  // ranks' bounds, which is the whole scene's (SceneDesc::dataPart).
  void setSceneBounds(const SceneDesc& scene, const Vec3d& lower, const Vec3d& upper);
  const std::vector<VolumeInfo>& volumes() const { return m_volumes; }
  const std::vector<SurfaceInfo>& surfaces() const { return m_surfaces; }
  const std::vector<MeshInfo>& meshes() const { return m_meshInfo; }
  const std::vector<Material>& materials() const { return m_materials; }
  const std::vector<Texture>& textures() const { return m_textures; }
  const std::vector<Light>& lights() const { return m_lights; }
  const std::vector<int>& environmentLights() const { return m_environmentLights; }
  // Light selection by power (pbrt-v4's PowerLightSampler): a light index for u in [0, 1)
  // with its probability, and the probability of a given light. -1 when there is no light.
  int pickLight(float u, float& probability) const;
  float lightProbability(int light) const { return m_lightPick.probability(light); }
  // The light whose emission a hit shows (an emissive triangle or iso-surface), or -1.
  const std::vector<SliceInfo>& slices() const { return m_slices; }
  int lightOf(const Hit& hit) const { return hit.surface >= 0 ? m_surfaces[hit.surface].light : hit.light; }
  const std::vector<std::string>& warnings() const { return m_warnings; }
  double loadSeconds() const { return m_loadSeconds; }
  double buildSeconds() const { return m_buildSeconds; }
  // The ray as its queries trace it: a ray spawned from an iso-surface hit whose origin the
  // offset pushed out of that volume's box starts back on the box (world.cpp says where).
  Ray startInsideVolume(const Ray& ray) const;

 private:
  struct GeometryRecord {
    const TriangleMesh* mesh = nullptr;  // null: an iso-surface or an instance
    int surface = -1;
    int material = 0;
    int meshDesc = -1;
    int light = -1;
    int instance = -1;  // index into m_instanceRecords for an Embree instance
    int slice = -1;     // index into m_slices
    Transform toWorld;  // of the instance (mesh stored in object space)
    bool identity = true;
  };
  struct PendingAreaLight {
    std::vector<Vec3f> triangles;  // world space, three per triangle
    std::vector<Vec2f> uvs;
    int material = 0;
  };

  void release();
  void loadMeshes(const SceneDesc& scene);
  void buildVolumes(const SceneDesc& scene, const IntersectorSpec& intersector, const World* sameVolumes,
                    const VolumeLoader& load);
  void buildSlices(const SceneDesc& scene);
  // Embree triangles of `mesh`; `clipped`: hits outside the scene's clip region are ignored.
  RTCGeometry triangleGeometry(const TriangleMesh& mesh, bool clipped = false) const;
  // A world point in volume `volume`'s grid coordinates; false if it lies outside the grid
  // (beyond rounding of the point).
  bool gridCoordinates(int volume, const Vec3d& world, Vec3d& g) const;
  // A slice's map of its volume's value at a slice hit.
  Vec3f sliceColor(const Hit& hit) const;
  void buildLights(const SceneDesc& scene);
  void addIsoSurfaceLight(int surface);
  int materialFor(const SceneDesc& scene, const std::string& name);
  int gltfMaterial(size_t model, int index);
  int textureFor(size_t model, const GltfTextureRef& ref, bool srgb);
  unsigned attach(RTCScene scene, RTCGeometry geometry, std::vector<GeometryRecord>& table,
                  const GeometryRecord& record);
  const GeometryRecord& recordOf(const RTCHit& hit) const;
  // albedo() with the hit's texture frame, where the caller has built it already (nullptr: not).
  Vec3f albedo(const Hit& hit, const TextureFrame* frame) const;
  void fillHit(const Ray& ray, const RTCRayHit& rh, const IsoRayLane& lane, Hit& hit) const;
  void fillTriangleHit(const Ray& ray, const RTCRayHit& rh, const GeometryRecord& rec, Hit& hit) const;
  // Whether a ray needs its lane (IsoRayLane: the world ray in double, its start class) for the
  // callbacks Embree may call: the iso-surfaces', and the clip filter of meshes a scene clip cuts
  // (which reads the lane's world ray). Otherwise (meshes only, unclipped) rays are traced
  // without one. (Not decided by the ray's mask: no ray is mesh-only, and Embree may be built
  // without mask tests, calling the callbacks for every lane.)
  bool needsLanes() const { return !m_surfaces.empty() || !m_sceneClip.empty(); }
  // The lanes of a packet being traced (World::packRays fills the rays Embree is to see).
  struct PacketLanes {
    const Ray* start[kPacket];  // each ray as traced: the caller's, or moved onto its volume's box in `moved`
    LaneSlots<Ray> moved;
    LaneSlots<Vec3d> origin;
    LaneSlots<IsoRayLane> lanes;
    alignas(32) int valid[kPacket];
  };
  bool packRays(const Ray* rays, int n, Hit* hits, bool* done, TraversalStats& stats, PacketLanes& p,
                RTCRay8& packet) const;
  void fillIsoHit(const Ray& ray, int surface, double t, float tError, Vec3d normal, bool insideAfter, bool cap,
                  const Transform* toWorld, Hit& hit) const;
  bool crossesAtInactiveStart(const Ray& ray, Hit* hit, TraversalStats& stats) const;
  bool trace(const Ray& ray, Hit& hit, TraversalStats& stats) const;  // intersect() through Embree
  bool traceShadow(const Ray& ray, TraversalStats& stats) const;      // occluded() through Embree

  RTCDevice m_device = nullptr;
  bool m_nativePackets = true;  // Embree traces 8-wide packets natively (intersectPacket)
  RTCScene m_scene = nullptr;
  std::vector<RTCScene> m_subScenes;
  CameraDesc m_camera, m_unframedCamera;
  Vec3d m_lower, m_upper;
  std::vector<GltfModel> m_models;
  std::vector<std::vector<int>> m_modelMaterials;  // [model][glTF material] -> material, -1 unbuilt
  std::vector<std::unique_ptr<TriangleMesh>> m_meshStore;
  std::vector<MeshInfo> m_meshInfo;
  std::vector<VolumeInfo> m_volumes;
  std::vector<SurfaceInfo> m_surfaces;
  std::vector<SliceInfo> m_slices;
  ClipRegion m_sceneClip;  // the scene's "clip" (world space): meshes and every volume
  std::vector<Material> m_materials;
  std::vector<Texture> m_textures;
  std::vector<std::tuple<size_t, int, bool>> m_textureKeys;  // (model, glTF texture, sRGB)
  std::vector<std::unique_ptr<Texture>> m_environmentImages;
  std::vector<PendingAreaLight> m_pendingAreaLights;  // become the first lights
  std::vector<Light> m_lights;
  std::vector<int> m_environmentLights;
  Distribution1D m_lightPick;
  std::vector<GeometryRecord> m_top;
  std::vector<std::vector<GeometryRecord>> m_instanceRecords;
  std::vector<std::string> m_warnings;
  double m_loadSeconds = 0, m_buildSeconds = 0;
  bool m_hasThin = false;  // a thin dielectric is in the scene: shadow rays go through it
};

// Rays leaving a hit (pbrt-v4's OffsetRayOrigin): for triangles the origin moves along the
// geometric normal by the hit's position error bound projected on it (from the barycentric
// interpolation), to the side the ray leaves to, and is then rounded away from the surface.
// For iso-surfaces it moves along the incoming ray, forward if the new ray goes through the
// surface and back if it turns back, by Hit::spawnOffset (the intersector's error bound on t,
// capped at the rounding of the float traversal's grid coordinates, see World::fillIsoHit): on
// that line the crossing and its class were decided, while the normal is one cell's gradient
// and can point across a bend of the surface at a cell face.
// A ray leaving an iso-surface also carries the class it starts in (Ray::fromSurface): the
// class the hit's crossing led to if it goes on through the surface (to the side of the
// normal the incoming ray was heading to), else the class it came from. Next to a close pair
// of crossings the offset can step over the second one, or the field at the origin is below
// rounding; with the class given, the query reports such a crossing at the origin instead.
Vec3d offsetRayOrigin(const Hit& hit, const Vec3f& w);
Ray spawnRay(const Hit& hit, const Vec3f& dir);
// A shadow ray to `target` that stops just short of it (1 - 1e-4 of the way, pbrt's
// ShadowEpsilon, so that an area light's own surface is not an occluder).
Ray spawnRayTo(const Hit& hit, const Vec3f& target);

// A camera that sees the whole box [lower, upper] (a scene file without a camera).
CameraDesc frameBounds(const Vec3d& lower, const Vec3d& upper, double fov = 40);

// Loads one volume of a scene with its placement applied: the file's origin, spacing and affine,
// then the scene's keys ("origin" and "spacing" replace the file's; "transform" comes after its
// affine). The result's toWorld is the whole grid-space-to-world placement.
VolumeFile loadVolume(const VolumeDesc& desc);
// A volume's placement from its description (origin, spacing, transform), after loading.
void placeVolume(const VolumeDesc& desc, VolumeFile& volume);
// The camera's rays through a 32 x 18 grid over the image, in volume v's index space, from which
// a data-parallel render chooses the axes it cuts the volume along (partitionBricks): if both are
// known before the volume's samples are read — `camera` is the scene file's or a glTF node's (null
// when the camera frames the scene, which needs every volume's bounds) and the volume is a
// procedural field, an array, or a file whose header says where its samples lie (raw, NRRD,
// MetaImage, binary VTK, NIfTI) — else none (the longest axis is cut). `isotrace info --ranks`
// uses the same rays.
CutRays cameraCutRays(const SceneDesc& scene, const CameraDesc* camera, size_t v);
// The iso values of a volume's iso-surfaces, in order (what its bricks are weighed by when it is
// split over ranks: activeBrickWeights).
std::vector<double> isoValuesOf(const VolumeDesc& desc);
// What a data-parallel render ("distribution": "data") cannot do yet, as an InputError naming the
// place: queries the ranks would each answer for their own part only (colour by data, emissive or
// clipped iso-surfaces, thin sheets' transmission, slices) and adaptive sampling.
void checkDataParallel(const SceneDesc& scene);

}  // namespace iso
