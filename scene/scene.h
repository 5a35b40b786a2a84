#pragma once
// The scene description as read from a scene file: what to load and how to render it.
// Nothing is loaded here; World (world.h) turns this into grids and an Embree scene.
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "scene/colormap.h"

#include "volume/clip.h"
#include "volume/grid.h"
#include "volume/transform.h"

#include "volume/intersectors.h"
#include "volume/loaders.h"
#include "volume/procedural.h"

namespace iso {

struct CameraDesc {
  Vec3d position{0, 0, 4};
  Vec3d lookAt{0, 0, 0};
  Vec3d up{0, 1, 0};
  double fov = 40;  // vertical, degrees
  // Take the camera from a glTF file of the scene instead: a camera name, or "#N" for the
  // N-th camera over all meshes in scene order. Resolved when the meshes are loaded.
  std::string gltfCamera;
  // The scene file has no camera: World frames everything the scene holds (frameBounds).
  bool frameScene = false;
};

// A named material of the scene file (materials of glTF files are read from the file).
enum class MaterialType { Diffuse, MetallicRoughness, Conductor, Dielectric, Emissive };

struct MaterialDesc {
  std::string where;
  MaterialType type = MaterialType::Diffuse;
  Vec3d color{0.8, 0.8, 0.8};  // albedo / base colour / F0 / transmission tint
  double metallic = 0;
  double roughness = 0.5;
  double ior = 1.5;
  Vec3d emission{0, 0, 0};  // radiance of an emissive material
  bool twoSided = false;    // emission from both sides
  bool thin = false;        // dielectric: a thin sheet (straight transmission, shadows pass)
};

// "color_by": the surface's base colour from a colour map of a scalar at the hit.
struct ColorByDesc {
  int volume = -1;        // the scene's volume sampled (trilinear, in its own placement); -1: the
                          // gradient magnitude of the surface's own volume
  std::string fieldName;  // as written: a volume's "name", or "gradient_magnitude"
  ColorMap map;
  double lo = 0, hi = 1;  // the range mapped onto the map; values outside clamp
  Vec3d nanColor{0.5, 0.5, 0.5};  // sRGB, where the field has no value (outside its grid)
};

// A slice plane through a volume ("slices"): the part of the plane inside the grid, an opaque
// surface coloured by a colour map of the volume's values there.
struct SliceDesc {
  std::string where;      // JSON path, for messages
  Vec3d point, normal;    // world space; the normal is not zero
  ColorMap map;
  std::optional<double> lo, hi;  // the range mapped; default: the volume's value range
  bool emit = false;      // an unlit slice: it emits the map's colour and reflects nothing
};

struct IsoSurfaceDesc {
  double value = 0;
  std::optional<Vec3d> color;  // shown by the eyelight integrator when there is no material
  std::string material;        // name in SceneDesc::materials; empty: default grey diffuse
  std::string materialWhere;   // JSON path of the reference, for messages
  bool solidAbove = true;      // the solid (e.g. glass) is where value > iso
  bool smoothNormals = true;   // shading normals from Grid::smoothGradient; false: the cell's own
  std::optional<ColorByDesc> colorBy;
  std::optional<ColorByDesc> capColorBy;  // "cap_color_by": of the caps clip planes cut (default: colorBy)
};

enum class MeshShape { None, Sphere, Quad };

struct MeshDesc {
  std::string where;
  std::string file;  // glTF (.gltf / .glb), resolved; empty for a built-in shape
  MeshShape shape = MeshShape::None;
  Transform transform;
  std::string material;  // overrides every material of the file when set
  std::string materialWhere;
};

// How the renderer traces rays (`--ray-flow`, the scene's "integrator": {"ray_flow": ...}):
// `wavefront` keeps a tile's paths in flight and traces their rays stage by stage in Embree
// packets; `scalar` traces each path's rays one at a time (the reference). Same image bits.
enum class RayFlow { Wavefront, Scalar };
const char* rayFlowName(RayFlow f);
bool parseRayFlow(const std::string& name, RayFlow& flow);

// The denoiser (`--denoise`, the scene's "film": {"denoise": ...}; renderer/denoise.h):
// `quality` (feature regression, NFOR-style), `fast` (a-trous, for previews) or `off`.
enum class DenoiseMode { Off, Quality, Fast };
const char* denoiseModeName(DenoiseMode mode);
bool parseDenoiseMode(const std::string& name, DenoiseMode& mode);
// The names parseDenoiseMode knows, for messages.
const char* denoiseModeList();

enum class LightType { Point, Spot, Directional, Environment };

struct LightDesc {
  std::string where;
  LightType type = LightType::Point;
  Vec3d position{0, 0, 0};
  Vec3d direction{0, -1, 0};       // the way the light travels (spot, directional)
  Vec3d intensity{1, 1, 1};        // W/sr (point, spot)
  Vec3d irradiance{1, 1, 1};       // W/m^2 on a surface facing the light (directional)
  Vec3d radiance{1, 1, 1};         // W/(sr m^2) (environment; multiplies the image)
  double innerAngle = 0, outerAngle = 45;  // spot cone half-angles, degrees
  std::string file;                // environment: lat-long image, resolved
};

struct VolumeDesc {
  std::string where;  // JSON path, for messages about this volume
  std::string file;   // absolute or relative to the working directory (already resolved)
  std::optional<Field> field;
  Vec3i resolution{64, 64, 64};
  RawLayout layout;
  VolumePart part;  // which series of a DICOM folder, which grid of a VDB file
  std::optional<Vec3d> origin, spacing;
  Transform transform;  // applied after origin/spacing place the grid
  std::string name;     // "name": how "color_by" refers to it (empty: none)
  std::vector<IsoSurfaceDesc> isosurfaces;  // none: a data field that colours others, not drawn
  std::vector<SliceDesc> slices;
  ClipRegion clip;  // "clip" (world space): its iso-surfaces are cut open and capped
  // "array": K, a grid handed to the parser (SceneArrays: the Python module's numpy volumes,
  // used in place); its samples, origin and spacing. Null for a file or a procedural field.
  std::shared_ptr<const Grid> array;
  // A volume that changes over time, one volume per time step: "file" as a list of files or a
  // pattern (* and ? in its last part, matches in natural order), "time": "all" on a file with a
  // time axis (a 4D NIfTI), or a list of arrays from Python. `file`, `part.time` and `array` above
  // hold the step being rendered (scene/time_series.h, selectTimeStep).
  struct TimeSeries {
    std::vector<std::string> files;                    // one per step (a list or a pattern's matches)
    std::vector<std::shared_ptr<const Grid>> arrays;   // one per step (Python)
    bool fileAxis = false;                             // "time": "all": the steps of `file`'s time axis
    int steps = 1;                                     // (a time axis's: known once resolveTimeSeries read the header)
    std::string where;                                 // JSON path of "file" or "time", for messages
    bool varying() const { return !files.empty() || !arrays.empty() || fileAxis; }
  } time;
};

struct RenderSettings {
  int width = 640;
  int height = 480;
  int spp = 4;
  int maxDepth = 5;
  double aoDistance = 1;
  std::string integrator = "eyelight";
  IntersectorSpec intersector;
  uint64_t seed = 0;
  int threads = 0;  // 0: all cores
  // Cycles' indirect clamp: a sample's indirect radiance is scaled down to at most this in
  // its largest component (0: off; it biases, darkening what it clips).
  double clampIndirect = 0;
  // Adaptive sampling: a pixel stops once the standard error of its mean luminance is at most
  // this share of the mean (0: off; every pixel takes spp).
  double noiseThreshold = 0;
  RayFlow rayFlow = RayFlow::Wavefront;
  DenoiseMode denoise = DenoiseMode::Off;
  // "distribution": "data" (--data-parallel): under MPI each rank holds only its part of each
  // volume (renderer/distributed.h); "image" (the default): every rank holds the whole scene.
  bool dataParallel = false;
  // "replicate" (--replicate): in a data-parallel render, the fraction of each volume's bricks a
  // rank may hold beyond its own box, as copies of its neighbours' bricks next to it (0 to 1;
  // volume/partition.h heldBox). More memory per rank, fewer rays asked of other ranks.
  double replicate = 0;
};

// The part of the scene's volumes this process holds in a data-parallel render: each volume with
// iso-surfaces is split into `ranks` boxes of whole bricks (volume/partition.h), and this process
// keeps the window of box `rank` (Grid's window). One rank: the whole volumes.
struct DataPart {
  int rank = 0, ranks = 1;
};

struct SceneDesc {
  std::string path;
  CameraDesc camera;
  RenderSettings settings;
  std::vector<MeshDesc> meshes;
  std::vector<VolumeDesc> volumes;
  std::map<std::string, MaterialDesc> materials;
  std::vector<LightDesc> lights;
  ClipRegion clip;  // the scene's "clip" (world space): every volume, and meshes that do not emit
  DataPart dataPart;  // set by the renderer under MPI with "distribution": "data"
  // The command line's changes to the file (SceneOverrides), as applied: "POINTER=VALUE", the
  // value as compact JSON, in the order given (--iso first). Images record them.
  std::vector<std::string> overrides;
};

// Changes to a scene file made on the command line, applied to its JSON before it is read, so
// that the parser validates them like the file itself.
struct SceneOverrides {
  // --set POINTER=VALUE: a JSON pointer (RFC 6901) to a place in the scene whose parent exists
  // (an object: the key is set or added; an array: an index it has), and a JSON value; a bare
  // word that is not JSON (path, ../ct.nrrd) is taken as a string.
  std::vector<std::string> set;
  // --iso S=V: the value of iso-surface S, counted over all volumes from 0 (as --iso-sweep).
  std::vector<std::string> iso;
  bool empty() const { return set.empty() && iso.empty(); }
};

// JSON text nested deeper than `limit` arrays and objects is refused (an InputError naming the
// byte) before any parser sees it: parsers and the code walking their trees recurse.
void checkJsonNesting(const std::string& text, const std::string& file, int limit = 128);
// A JSON library exception (not a syntax error) as one InputError: "FILE: JSON: what", without
// nlohmann's "[json.exception...]" prefix (e.g. a number beyond double: 1e400).
[[noreturn]] void throwJsonError(const std::string& file, const std::string& what);

// Reads and validates a scene file, with the command line's overrides applied. Any problem is an
// InputError naming the JSON path (or the flag, for an override that cannot be applied).
// Grids held in memory that volumes name by index ({"array": K}): the Python module's volumes.
// A scene file has none to name.
using SceneArrays = std::vector<std::shared_ptr<const Grid>>;
SceneDesc parseSceneFile(const std::string& path, const SceneOverrides& overrides = {});
SceneDesc parseSceneText(const std::string& text, const std::string& path, const SceneOverrides& overrides = {},
                         const SceneArrays* arrays = nullptr);
// The scene's JSON text with the overrides applied (for `isotrace view`, which edits the JSON);
// refuses what parseSceneText refuses about them.
std::string overriddenSceneText(const std::string& text, const std::string& path, const SceneOverrides& overrides);

const char* integratorList();
bool isKnownIntegrator(const std::string& name);

}  // namespace iso
