// `isotrace info`: what a scene holds, what will be built and what is skipped.
#include <CLI/CLI.hpp>

#include <cmath>
#include <cstdio>
#include <memory>

#include "renderer/commands.h"
#include "scene/world.h"
#include "volume/input_error.h"
#include "volume/partition.h"

namespace iso {
namespace {

const char* materialTypeName(MaterialType t) {
  switch (t) {
    case MaterialType::Diffuse: return "diffuse";
    case MaterialType::MetallicRoughness: return "metallic_roughness";
    case MaterialType::Conductor: return "conductor";
    case MaterialType::Dielectric: return "dielectric";
    case MaterialType::Emissive: return "emissive";
  }
  return "?";
}

const char* lightKindName(Light::Kind k) {
  switch (k) {
    case Light::Kind::Point: return "point";
    case Light::Kind::Spot: return "spot";
    case Light::Kind::Directional: return "directional";
    case Light::Kind::Environment: return "environment";
    case Light::Kind::Area: return "area (emissive triangles)";
    case Light::Kind::IsoSurface: return "emissive iso-surface";
  }
  return "?";
}

// --ranks N: how a data-parallel render would split each volume (volume/partition.h): each
// rank's box of whole bricks, balanced by the bricks active for the volume's iso-surfaces, and
// what the rank would hold of it (with "replicate", its box and the copies of its neighbours'
// bricks around it).
void printPartition(const World& world, const SceneDesc& scene, int ranks) {
  const std::string& path = scene.path;
  const double replicate = scene.settings.replicate;
  std::printf("  data-parallel over %d ranks (render --data-parallel): each holds only its box of each volume "
              "(files and procedural fields are read only for it, OpenVDB and multi-frame DICOM files too; ASCII data whole, then cut); meshes, lights "
              "and the camera on every rank\n", ranks);
  if (replicate > 0)
    std::printf("  with \"replicate\": %g, each rank also holds copies of the bricks around its box, at most %g of each volume's bricks\n",
                replicate, replicate);
  for (size_t v = 0; v < world.volumes().size(); ++v) {
    const VolumeInfo& vi = world.volumes()[v];
    const Grid& g = *vi.grid;
    const BrickGrid& bricks = *vi.bricks;
    const std::vector<double> weights = activeBrickWeights(bricks, isoValuesOf(scene.volumes[v]));
    const CutRays rays = cameraCutRays(scene, scene.camera.frameScene ? nullptr : &world.camera(), v);
    std::vector<int> cuts;
    const std::vector<RankBox> boxes =
        partitionBricks(bricks, weights, ranks, path + ": volume " + std::to_string(v), &rays, &cuts);
    if (!cuts.empty()) {
      std::string axes;
      for (int a : cuts) axes += std::string(axes.empty() ? "" : ", ") + "xyz"[a];
      std::printf("    volume %zu: cut along %s (%s)\n", v, axes.c_str(),
                  rays.org.empty() ? "the longest axis: the camera frames the scene, or the file's placement is known only once it is read"
                                   : "where the fewest of the camera's rays and of rays leaving the surfaces pass");
    }
    const double whole = double(g.bytes() + bricks.bytes());
    double largest = 0;
    for (size_t r = 0; r < boxes.size(); ++r) {
      const RankBox& own = boxes[r];
      const RankBox box = heldBox(own, bricks, replicate);
      // What the rank holds: its samples (a sparse grid: its bricks' stored blocks) and brick ranges.
      double bytes = double(box.bricks) * 2 * sizeof(float);
      if (const SparseSamples* sparse = g.sparse()) {
        for (int z = box.brickLo.z; z < box.brickHi.z; ++z)
          for (int y = box.brickLo.y; y < box.brickHi.y; ++y)
            for (int x = box.brickLo.x; x < box.brickHi.x; ++x)
              bytes += sparse->slotOf(x, y, z) >= 0 ? double(SparseSamples::kBlockSize) * 4 + 4 : 8;
      } else {
        bytes += double(box.samples(g.dims())) * double(scalarTypeSize(g.type()));
      }
      largest = std::max(largest, bytes);
      Vec3d lo{INFINITY, INFINITY, INFINITY}, hi = -lo;
      for (int c = 0; c < 8; ++c) {
        const Vec3d cell{double(c & 1 ? own.cellHi.x : own.cellLo.x), double(c & 2 ? own.cellHi.y : own.cellLo.y),
                         double(c & 4 ? own.cellHi.z : own.cellLo.z)};
        const Vec3d w = vi.transform.point(g.origin() + cell * g.spacing());
        lo = min(lo, w);
        hi = max(hi, w);
      }
      std::printf("    volume %zu, rank %zu: cells [%d, %d) x [%d, %d) x [%d, %d), world (%g, %g, %g) to (%g, %g, %g); "
                  "%.2f MiB, %.0f of %zu bricks active",
                  v, r, own.cellLo.x, own.cellHi.x, own.cellLo.y, own.cellHi.y, own.cellLo.z, own.cellHi.z, lo.x, lo.y,
                  lo.z, hi.x, hi.y, hi.z, bytes / 1048576.0, own.weight, own.bricks);
      if (box.bricks > own.bricks)
        std::printf("; holds cells [%d, %d) x [%d, %d) x [%d, %d) (%zu bricks, %zu of them copies)", box.cellLo.x, box.cellHi.x,
                    box.cellLo.y, box.cellHi.y, box.cellLo.z, box.cellHi.z, box.bricks, box.bricks - own.bricks);
      std::printf("\n");
    }
    std::printf("    volume %zu: the largest rank holds %.2f MiB, %.0f%% of the whole volume's %.2f MiB\n", v,
                largest / 1048576.0, 100 * largest / std::max(whole, 1.0), whole / 1048576.0);
  }
}

int info(const std::string& path, const SceneOverrides& overrides, int ranks) {
  const SceneDesc scene = parseSceneFile(path, overrides);
  World world(scene, scene.settings.intersector);
  for (const std::string& w : world.warnings()) std::fprintf(stderr, "isotrace: warning: %s\n", w.c_str());
  const RenderSettings& s = scene.settings;
  std::printf("scene %s\n", path.c_str());
  std::printf("  film %dx%d, %d spp, integrator %s (max depth %d), intersector %s\n", s.width, s.height, s.spp,
              s.integrator.c_str(), s.maxDepth, intersectorName(s.intersector).c_str());
  const CameraDesc& c = world.camera();
  std::printf("  camera%s%s: position (%g, %g, %g), looking at (%g, %g, %g), fov %g degrees\n",
              scene.camera.gltfCamera.empty() ? "" : (" (glTF camera " + scene.camera.gltfCamera + ")").c_str(),
              scene.camera.frameScene ? " (none in the scene: framing its bounds)" : "", c.position.x, c.position.y, c.position.z, c.lookAt.x, c.lookAt.y, c.lookAt.z, c.fov);
  std::vector<std::string> skipped;
  if (world.meshes().empty()) skipped.push_back("no meshes: no triangle geometry is built");
  size_t images = 0;
  for (size_t m = 0; m < world.meshes().size(); ++m) {
    const MeshInfo& mi = world.meshes()[m];
    images += mi.images;
    std::printf("  mesh %zu: %s\n    %zu triangles in the world (%zu stored), %zu meshes, %zu placements "
                "(%zu as Embree instances); %zu materials, %zu textures, %zu cameras, %zu lights in the file\n",
                m, mi.name.c_str(), mi.triangles, mi.uniqueTriangles, mi.meshes, mi.instances, mi.embreeInstances,
                mi.materials, mi.textures, mi.cameras, mi.lights);
    if (mi.triangles)
      std::printf("    bounds (%g, %g, %g) to (%g, %g, %g)\n", mi.lower.x, mi.lower.y, mi.lower.z, mi.upper.x,
                  mi.upper.y, mi.upper.z);
  }
  if (world.volumes().empty()) skipped.push_back("no volumes: no grid, brick or iso-surface work is done");
  for (size_t v = 0; v < world.volumes().size(); ++v) {
    const VolumeInfo& vi = world.volumes()[v];
    const Grid& g = *vi.grid;
    bool drawn = false;
    for (const SurfaceInfo& si : world.surfaces()) drawn = drawn || si.volume == int(v);
    for (const SliceInfo& sl : world.slices()) drawn = drawn || sl.volume == int(v);
    std::printf("  volume %zu: %s (%s)\n    %dx%dx%d %s, %.2f MiB samples + %.2f MiB brick ranges; "
                "origin (%g, %g, %g), spacing (%g, %g, %g)%s\n",
                v, vi.name.c_str(), vi.format.c_str(), g.dims().x, g.dims().y, g.dims().z, scalarTypeName(g.type()),
                g.bytes() / 1048576.0, vi.bricks->bytes() / 1048576.0, g.origin().x, g.origin().y,
                g.origin().z, g.spacing().x, g.spacing().y, g.spacing().z,
                !drawn ? ", a data field (no iso-surface or slice: it colours others, is not drawn)"
                : vi.transform.isIdentity() ? "" : ", transformed (Embree instance)");
    for (const std::string& note : vi.notes) std::printf("    %s\n", note.c_str());
    if (const VolumeDesc::TimeSeries& t = scene.volumes[v].time; t.varying())
      std::printf("    changes over time: %d steps (%s; step 0 described here); a sequence (render --frames, or "
                  "one frame per step) steps through them\n",
                  t.steps, !t.files.empty() ? "a file each" : !t.arrays.empty() ? "an array each" : "the file's time axis");
    // Where the values lie, to choose iso values by: the range and a few quantiles.
    const std::vector<double> shares{0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99};
    const std::vector<double> q = g.quantiles(shares);
    std::printf("    values %g to %g; quantiles", double(vi.bricks->minValue()), double(vi.bricks->maxValue()));
    for (size_t i = 0; i < shares.size(); ++i) std::printf("%s %g%%: %.6g", i ? "," : "", shares[i] * 100, q[i]);
    std::printf("%s\n", g.type() == ScalarType::Float32 ? " (float32: within 1/65536 of the range)" : "");
    for (const SurfaceInfo& si : world.surfaces())
      if (si.volume == int(v))
        std::printf("    iso-surface %g: %zu of %zu bricks active (%.1f%%; %.1f MiB of tight boxes and cell classes), "
                    "material %s%s\n", si.iso, si.surface->activeBricks().size(), si.surface->totalBricks(),
                    100.0 * double(si.surface->activeBricks().size()) / double(std::max<size_t>(1, si.surface->totalBricks())),
                    si.surface->bytes() / 1048576.0, world.materials()[si.material].name.c_str(),
                    si.surface->activeBricks().empty() ? " (empty: not built)" : "");
    for (const SliceInfo& sl : world.slices())
      if (sl.volume == int(v))
        std::printf("    slice: %zu triangles, %s over [%g, %g]%s\n", sl.triangles, sl.map.name().c_str(), sl.lo, sl.hi,
                    sl.emit ? ", emitting (unlit)" : "");
    for (const SurfaceInfo& si : world.surfaces()) {
      if (si.volume != int(v)) continue;
      if (si.colorBy)
        std::printf("    iso-surface %g coloured by %s through %s over [%g, %g]\n", si.iso, si.colorBy->fieldName.c_str(),
                    si.colorBy->map.name().c_str(), si.colorBy->lo, si.colorBy->hi);
      const ClipRegion& clip = si.surface->clip();
      if (clip.empty()) {
        if (!scene.clip.empty() || !scene.volumes[v].clip.empty())
          std::printf("    iso-surface %g: the clip keeps its whole grid (not applied)\n", si.iso);
        continue;
      }
      std::printf("    iso-surface %g clipped by %zu planes, capped", si.iso, clip.planes().size());
      if (si.capColorBy)
        std::printf("; caps coloured by %s through %s over [%g, %g]", si.capColorBy->fieldName.c_str(),
                    si.capColorBy->map.name().c_str(), si.capColorBy->lo, si.capColorBy->hi);
      std::printf("\n");
    }
  }
  std::printf("  materials in use: %zu\n", world.materials().size());
  const size_t shown = std::min<size_t>(world.materials().size(), 12);
  for (size_t i = 0; i < shown; ++i) {
    const Material& m = world.materials()[i];
    std::printf("    %s: %s%s\n", m.name.c_str(), materialTypeName(m.type), m.emits() ? ", emissive" : "");
  }
  if (shown < world.materials().size()) std::printf("    ... and %zu more\n", world.materials().size() - shown);
  std::printf("  textures decoded: %zu", world.textures().size());
  if (images > world.textures().size()) std::printf(" (images in glTF files: %zu; unused ones are not decoded)", images);
  std::printf("\n");
  std::map<std::string, int> lightCounts;
  size_t areaTriangles = 0;
  for (const Light& l : world.lights()) {
    ++lightCounts[lightKindName(l.kind())];
    areaTriangles += l.triangleCount();
  }
  std::printf("  lights: %zu%s\n", world.lights().size(), world.lights().empty() ? " (direct lighting sees none)" : "");
  for (const auto& [kind, count] : lightCounts)
    std::printf("    %d %s%s\n", count, kind.c_str(),
                kind.rfind("area", 0) == 0 ? (", " + std::to_string(areaTriangles) + " triangles").c_str() : "");
  if (world.environmentLights().empty()) skipped.push_back("no environment light: escaped rays are black");
  if (ranks > 0) printPartition(world, scene, ranks);
  for (const std::string& line : skipped) std::printf("  skipped: %s\n", line.c_str());
  std::printf("  time: load %.2fs, build %.2fs\n", world.loadSeconds(), world.buildSeconds());
  return 0;
}

}  // namespace

Command addInfoCommand(CLI::App& app) {
  struct Flags {
    std::string scene;
    SceneOverrides overrides;
    int ranks = 0;
  };
  auto flags = std::make_shared<Flags>();
  CLI::App* cmd = app.add_subcommand("info", "what the scene holds and what will be built");
  cmd->add_option("scene", flags->scene, "scene file (JSON)")->required();
  addSceneOverrides(cmd, flags->overrides);
  cmd->add_option("--ranks", flags->ranks,
                  "also show how a data-parallel render over N ranks would split each volume (boxes of whole bricks, "
                  "balanced by active bricks) and what each rank would hold")
      ->check(CLI::Range(1, 65536));
  return {cmd, [flags] { return info(flags->scene, flags->overrides, flags->ranks); }};
}

}  // namespace iso
