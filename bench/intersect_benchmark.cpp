// Google Benchmark: time per ray of each intersector (and of neubauer and isolation with 1,
// 2, 3, 5 and 8 refinement steps) through the whole-grid traversal, for camera rays (from
// outside towards a random point inside) and incoherent secondary rays (from a random point
// inside in a random direction), on real volumes and procedural fields.
//   build/bench/intersect_benchmark [--benchmark_filter=...]
// Error against the reference for the same rays: `isotrace bench` / bench/intersector_accuracy.
#include <benchmark/benchmark.h>

#include <random>

#include "volume/bricks.h"
#include "volume/iso_surface.h"
#include "volume/loaders.h"
#include "volume/procedural.h"

using namespace iso;

namespace {

struct Volume {
  const char* name;
  Grid grid;
  double iso;
};

const std::vector<Volume>& volumes() {
  static const std::vector<Volume> v = [] {
    const std::string data = std::string(ISOTRACE_DATA_DIR) + "/volumes/";
    std::vector<Volume> list;
    list.push_back({"nucleon", loadVolumeFile(data + "nucleon/nucleon.nrrd"), 60});
    list.push_back({"neghip", loadVolumeFile(data + "neghip_64x64x64_uint8.raw"), 40.5});
    list.push_back({"hydrogen", loadVolumeFile(data + "hydrogen_atom_128x128x128_uint8.raw"), 20.5});
    list.push_back({"lidc2", loadVolumeFile(data + "lidc2_chest_ct_256x256x133_uint8.raw.gz"), 150.5});
    list.push_back({"gyroid", makeProceduralGrid(Field::Gyroid, {64, 64, 64}), 0});
    list.push_back({"marschner_lobb", makeProceduralGrid(Field::MarschnerLobb, {41, 41, 41}), 0.5});
    return list;
  }();
  return v;
}

struct RaySet {
  std::vector<Vec3d> org, dir;
};

RaySet makeRays(const Grid& g, bool camera, int n) {
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> u(0, 1);
  const Vec3i d = g.dims();
  const Vec3d size = Vec3d{double(d.x - 1), double(d.y - 1), double(d.z - 1)} * g.spacing();
  RaySet r;
  for (int i = 0; i < n; ++i) {
    const Vec3d p = g.origin() + Vec3d{u(rng), u(rng), u(rng)} * size;
    const double z = 1 - 2 * u(rng), s = std::sqrt(1 - z * z), phi = 2 * M_PI * u(rng);
    const Vec3d dir{s * std::cos(phi), s * std::sin(phi), z};
    r.org.push_back(camera ? p - dir * (2 * length(size)) : p);
    r.dir.push_back(dir);
  }
  return r;
}

void run(benchmark::State& state, int volume, bool camera, IntersectorSpec spec) {
  const Volume& v = volumes()[volume];
  const BrickGrid bricks(v.grid);
  const IsoSurface surface(v.grid, bricks, v.iso, spec);
  const RaySet rays = makeRays(v.grid, camera, 4096);
  TraversalStats stats;
  size_t i = 0, hits = 0;
  for (auto _ : state) {
    SurfaceHit hit;
    hits += surface.intersect(rays.org[i], rays.dir[i], 0, 1e30, hit, stats);
    benchmark::DoNotOptimize(hit);
    i = (i + 1) % rays.org.size();
  }
  state.counters["hit_rate"] = double(hits) / double(state.iterations());
}

const int registered = [] {
  const char* specs[] = {"linear", "neubauer:1", "neubauer:2", "neubauer:3", "neubauer:5", "neubauer:8", "schwarze",
                         "isolation:1", "isolation:2", "isolation:3", "isolation:5", "isolation:8", "reference"};
  for (int v = 0; v < 6; ++v)
    for (bool camera : {true, false})
      for (const char* name : specs) {
        IntersectorSpec spec;
        std::string error;
        parseIntersector(name, spec, error);
        const std::string label = std::string(volumes()[v].name) + "/" + (camera ? "camera" : "secondary") + "/" + name;
        benchmark::RegisterBenchmark(label.c_str(), run, v, camera, spec)->Unit(benchmark::kNanosecond);
      }
  return 0;
}();

}  // namespace

BENCHMARK_MAIN();
