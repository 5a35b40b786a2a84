// `isotrace mesh`: one iso-surface as a glTF triangle mesh in world space.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>

#include "renderer/commands.h"
#include "scene/gltf.h"
#include "scene/texture.h"
#include "scene/time_series.h"
#include "scene/world.h"
#include "volume/input_error.h"
#include "volume/clip.h"
#include "volume/iso_mesh.h"

namespace iso {
namespace {

struct MeshFlags {
  std::string scene, output;
  int volume = 0, surface = 0, time = 0;
  SceneOverrides overrides;
};

}  // namespace

namespace {

// The clipped solid as one field over the volume's samples, for a closed mesh of it: the solid
// (f above or below the iso value) intersected with the kept half-spaces is where
//   g = min(+-(f - iso) / slope, -(signed distance outside the kept region, in samples)) > 0,
// so g's zero set is the surface where it is kept and the cut (a plane) where the solid is cut:
// volumeToMesh then meshes both, joined, and the mesh stays closed. `slope` (the field's change
// per sample across the surface) makes both terms distances in samples, so that neither rounds
// the crease where surface and cap meet by more than about a cell.
struct ClippedField {
  std::vector<ClipPlane> planes;  // in grid coordinates (sample (i, j, k) at (i, j, k))
  double side = 1, iso = 0, slope = 1;
  double outside(const Vec3d& p) const {  // > 0 outside the kept region
    double d = -INFINITY;
    for (const ClipPlane& c : planes) d = std::max(d, dot(c.normal, p) - c.offset);
    return d;
  }
  double solid(double f) const { return side * (f - iso) / slope; }
};

// The field's mean change per sample across the iso value, over the x edges that cross it.
double crossingSlope(const Grid& grid, double iso) {
  const Vec3i n = grid.dims();
  double sum = 0;
  size_t count = 0;
  for (int z = 0; z < n.z; ++z)
    for (int y = 0; y < n.y; ++y)
      for (int x = 0; x + 1 < n.x; ++x) {
        const double a = grid.value(x, y, z) - iso, b = grid.value(x + 1, y, z) - iso;
        if ((a < 0) != (b < 0)) sum += std::fabs(b - a), ++count;
      }
  return count > 0 && sum > 0 ? sum / double(count) : 1;
}

Grid clippedGrid(const Grid& grid, const ClippedField& c) {
  const Vec3i n = grid.dims();
  auto samples = std::shared_ptr<float[]>(new float[size_t(n.x) * n.y * n.z]);
  for (int z = 0; z < n.z; ++z)
    for (int y = 0; y < n.y; ++y)
      for (int x = 0; x < n.x; ++x)
        samples[(size_t(z) * n.y + y) * n.x + x] =
            float(std::min(c.solid(grid.value(x, y, z)), -c.outside(Vec3d{double(x), double(y), double(z)})));
  return Grid(n, ScalarType::Float32, std::shared_ptr<const void>(samples, samples.get()));
}

}  // namespace

void selectMeshTimeStep(SceneDesc& scene, int step, const std::string& flag) {
  const int steps = sceneTimeSteps(scene);
  if (step < 0 || step >= steps)
    throw InputError(flag, "", steps == 1 ? "no volume of the scene changes over time (only step 0)"
                                          : "expected a time step from 0 to " + std::to_string(steps - 1));
  for (VolumeDesc& v : scene.volumes) selectTimeStep(v, timeStepOfFrame(step, steps, v.time.steps));
}

GltfMeshOut surfaceMesh(const SceneDesc& scene, int volumeIndex, int surfaceIndex, const std::string& volumeFlag,
                        const std::string& surfaceFlag) {
  if (scene.volumes.empty()) throw InputError(scene.path, "/volumes", "the scene has no volume");
  if (volumeIndex < 0 || size_t(volumeIndex) >= scene.volumes.size())
    throw InputError(volumeFlag, "", "no volume " + std::to_string(volumeIndex) + " (the scene has " +
                                         std::to_string(scene.volumes.size()) + ", counted from 0)");
  const VolumeDesc& desc = scene.volumes[size_t(volumeIndex)];
  if (surfaceIndex < 0 || size_t(surfaceIndex) >= desc.isosurfaces.size())
    throw InputError(surfaceFlag, "", "no iso-surface " + std::to_string(surfaceIndex) + " in " + desc.where +
                                          " (it has " + std::to_string(desc.isosurfaces.size()) + ", counted from 0)");
  const IsoSurfaceDesc& surface = desc.isosurfaces[size_t(surfaceIndex)];
  // Colouring by data samples other volumes as the render does: through a World of the scene
  // (whose copy of this volume is the one meshed). Without colours the volume alone is read.
  const bool coloured = surface.colorBy || surface.capColorBy;
  std::unique_ptr<World> world;
  std::shared_ptr<const Grid> loaded;
  Transform toWorld;
  if (coloured) {
    world = std::make_unique<World>(scene, scene.settings.intersector);
    loaded = world->volumes()[size_t(volumeIndex)].grid;
    toWorld = world->volumes()[size_t(volumeIndex)].transform;
  } else {
    VolumeFile volume = loadVolume(desc);
    loaded = std::make_shared<const Grid>(std::move(volume.grid));
    toWorld = volume.toWorld;
  }
  const Grid& grid = *loaded;
  const Vec3d origin = grid.origin(), spacing = grid.spacing();
  // Grid coordinates -> the volume's space -> world.
  const Transform gridToWorld = toWorld * Transform::translate(origin) * Transform::scale(spacing);
  ClipRegion clip = scene.clip;
  clip.add(desc.clip);
  ClippedField field;
  field.side = surface.solidAbove ? 1 : -1;
  field.iso = surface.value;
  field.planes = clip.transformed(gridToWorld.inverse()).planes();
  const bool clipped = !field.planes.empty();
  if (clipped) field.slope = crossingSlope(grid, surface.value);
  // Clipped: the field g above, whose solid is where g > 0 (so meshed as a solid above 0).
  const IsoMesh mesh = clipped ? extractIsoMesh(clippedGrid(grid, field), 0) : extractIsoMesh(grid, surface.value);
  const bool solidAbove = clipped || surface.solidAbove;
  const std::string where = desc.where + "/isosurfaces/" + std::to_string(surfaceIndex);
  if (mesh.indices.empty()) {
    float lo, hi;
    grid.range(lo, hi);
    throw InputError(scene.path, clipped ? where : where + "/value",
                     "iso value " + jsonNumber(surface.value) + " gives no surface (the volume's values span " +
                         jsonNumber(lo) + " to " + jsonNumber(hi) + (clipped ? "; or the clip cuts it all away)" : ")"));
  }
  GltfMeshOut out;
  out.name = std::filesystem::path(scene.path).stem().string() + where;
  // Normals out of the solid.
  const double side = solidAbove ? -1 : 1;
  out.positions.reserve(mesh.positions.size());
  out.normals.reserve(mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    out.positions.push_back(Vec3f(gridToWorld.point(mesh.positions[i])));
    const Vec3d n = toWorld.normal(mesh.gradients[i] / spacing) * side;
    const double len = length(n);
    out.normals.push_back(len > 0 && std::isfinite(len) ? Vec3f(n / len) : Vec3f{0, 0, 1});
  }
  out.indices = mesh.indices;
  // The mesh is wound counter-clockwise seen from lower values; glTF's front is the solid's
  // outside, which is the higher side for a solid below the iso value; a mirroring transform
  // flips the winding once more.
  if (!solidAbove != (toWorld.determinant() < 0))
    for (size_t t = 0; t < out.indices.size(); t += 3) std::swap(out.indices[t + 1], out.indices[t + 2]);
  if (!surface.material.empty()) {
    const MaterialDesc& m = scene.materials.at(surface.material);
    out.color = Vec3f(m.color);
    out.metallic = m.type == MaterialType::Conductor ? 1.f : float(m.metallic);
    out.roughness = float(m.roughness);
  } else if (surface.color) {
    out.color = Vec3f(*surface.color);
    out.roughness = 1;
  }
  if (coloured) {
    // Each vertex's colour as the render's albedo there: the map of the field's value, the NaN
    // colour where the field has none; a vertex on a cut (where the plane term of g is the
    // smaller) takes the cap's colouring (by default the surface's; a surface coloured only on its
    // caps keeps its material's colour elsewhere). glTF multiplies COLOR_0 by the base colour,
    // which becomes white.
    auto linear = [](const Vec3d& srgb) {
      return Vec3f{srgbToLinear(float(srgb.x)), srgbToLinear(float(srgb.y)), srgbToLinear(float(srgb.z))};
    };
    out.colors.reserve(out.positions.size());
    for (size_t i = 0; i < mesh.positions.size(); ++i) {
      const Vec3d p = mesh.positions[i];
      const bool cap = clipped && -field.outside(p) <= field.solid(grid.interpolate(p));
      const ColorByDesc* by = cap && surface.capColorBy ? &*surface.capColorBy : surface.colorBy ? &*surface.colorBy : nullptr;
      if (!by) {
        out.colors.push_back(out.color);
        continue;
      }
      const double v = world->colorValue(*by, volumeIndex, gridToWorld.point(p));
      out.colors.push_back(std::isfinite(v) ? by->map.linear(v, by->lo, by->hi) : linear(by->nanColor));
    }
    out.color = {1, 1, 1};
  }
  return out;
}

namespace {

// `isotrace mesh`: one iso-surface as triangles in world space, with the surface's material.
int exportMesh(const MeshFlags& flags) {
  SceneDesc scene = parseSceneFile(flags.scene, flags.overrides);
  selectMeshTimeStep(scene, flags.time, "--time");
  if (flags.output.empty()) throw InputError("-o", "", "an output file is needed (-o NAME.glb or NAME.gltf)");
  const std::string ext = std::filesystem::path(flags.output).extension().string();
  if (ext != ".glb" && ext != ".gltf") throw InputError(flags.output, "", "the mesh output must be .glb or .gltf");
  const GltfMeshOut out = surfaceMesh(scene, flags.volume, flags.surface, "--volume", "--surface");
  saveGltfMesh(flags.output, out);
  std::printf("%s\n", flags.output.c_str());
  std::fprintf(stderr, "isotrace: %s: %zu triangles, %zu vertices\n", out.name.c_str(), out.indices.size() / 3,
               out.positions.size());
  return 0;
}

}  // namespace

Command addMeshCommand(CLI::App& app) {
  auto flags = std::make_shared<MeshFlags>();
  MeshFlags& f = *flags;
  CLI::App* cmd = app.add_subcommand("mesh", "write one iso-surface as a triangle mesh (glTF, world space)");
  cmd->add_option("scene", f.scene, "scene file (JSON)")->required();
  cmd->add_option("-o,--output", f.output, "output mesh, .glb or .gltf")->required();
  cmd->add_option("--volume", f.volume, "volume index in the scene, from 0 (default 0)");
  cmd->add_option("--surface", f.surface, "iso-surface index in that volume, from 0 (default 0)");
  cmd->add_option("--time", f.time, "the time step of volumes that change over time, from 0 (default 0)");
  addSceneOverrides(cmd, f.overrides);
  return {cmd, [flags] { return exportMesh(*flags); }};
}

}  // namespace iso
