// `isotrace mesh`: one iso-surface as a glTF triangle mesh in world space.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <filesystem>
#include <memory>

#include "renderer/commands.h"
#include "scene/gltf.h"
#include "scene/world.h"
#include "volume/input_error.h"
#include "volume/iso_mesh.h"

namespace iso {
namespace {

struct MeshFlags {
  std::string scene, output;
  int volume = 0, surface = 0;
  SceneOverrides overrides;
};

}  // namespace

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
  const VolumeFile volume = loadVolume(desc);
  const Grid& grid = volume.grid;
  const Transform& toWorld = volume.toWorld;
  const IsoMesh mesh = extractIsoMesh(grid, surface.value);
  const std::string where = desc.where + "/isosurfaces/" + std::to_string(surfaceIndex);
  if (mesh.indices.empty()) {
    float lo, hi;
    grid.range(lo, hi);
    throw InputError(scene.path, where + "/value",
                     "iso value " + jsonNumber(surface.value) + " gives no surface (the volume's values span " +
                         jsonNumber(lo) + " to " + jsonNumber(hi) + ")");
  }
  GltfMeshOut out;
  out.name = std::filesystem::path(scene.path).stem().string() + where;
  // Grid coordinates -> the volume's space -> world; normals out of the solid.
  const Vec3d origin = grid.origin(), spacing = grid.spacing();
  const double side = surface.solidAbove ? -1 : 1;
  out.positions.reserve(mesh.positions.size());
  out.normals.reserve(mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    out.positions.push_back(Vec3f(toWorld.point(origin + mesh.positions[i] * spacing)));
    const Vec3d n = toWorld.normal(mesh.gradients[i] / spacing) * side;
    const double len = length(n);
    out.normals.push_back(len > 0 && std::isfinite(len) ? Vec3f(n / len) : Vec3f{0, 0, 1});
  }
  out.indices = mesh.indices;
  // The mesh is wound counter-clockwise seen from lower values; glTF's front is the solid's
  // outside, which is the higher side for a solid below the iso value; a mirroring transform
  // flips the winding once more.
  if (!surface.solidAbove != (toWorld.determinant() < 0))
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
  return out;
}

namespace {

// `isotrace mesh`: one iso-surface as triangles in world space, with the surface's material.
int exportMesh(const MeshFlags& flags) {
  const SceneDesc scene = parseSceneFile(flags.scene, flags.overrides);
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
  addSceneOverrides(cmd, f.overrides);
  return {cmd, [flags] { return exportMesh(*flags); }};
}

}  // namespace iso
