// `isotrace bench`: time per ray against error versus the double-precision `reference`.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <memory>

#include "accuracy/accuracy.h"
#include "scene/world.h"
#include "renderer/commands.h"
#include "volume/input_error.h"

namespace iso {
namespace {

int bench(const CheckFlags& flags) {
  const SceneDesc scene = parseSceneFile(flags.scene, flags.overrides);
  std::vector<IntersectorSpec> specs;
  const std::string list = flags.intersector.empty()
                               ? "linear,neubauer:1,neubauer:2,neubauer:3,neubauer:5,neubauer:8,schwarze,"
                                 "isolation:1,isolation:2,isolation:3,isolation:5,isolation:8,reference"
                               : flags.intersector;
  for (size_t start = 0; start <= list.size();) {
    const size_t comma = std::min(list.find(',', start), list.size());
    IntersectorSpec spec;
    std::string error;
    if (!parseIntersector(list.substr(start, comma - start), spec, error)) throw InputError("--intersector", "", error);
    specs.push_back(spec);
    start = comma + 1;
  }
  if (flags.rays < 1) throw InputError("--rays", "", "must be at least 1");
  RayFlow flow = scene.settings.rayFlow;
  if (!flags.rayFlow.empty() && !parseRayFlow(flags.rayFlow, flow))
    throw InputError("--ray-flow", "", "unknown ray flow '" + flags.rayFlow + "' (known: wavefront, scalar)");
  if (scene.volumes.empty()) throw InputError(flags.scene, "/volumes", "the scene has no volume to measure");
  std::printf("bench %s: %d rays of each kind per iso-surface and intersector, single thread, seed %lld, %s flow;\n"
              "error against `reference` in cell units (misses/false hits judged by each hit's own bound)\n",
              flags.scene.c_str(), flags.rays, flags.seed, rayFlowName(flow));
  std::printf("%-7s %-9s %-10s %-12s %8s %8s %8s %10s %10s %10s %8s\n", "volume", "iso", "rays", "intersector",
              "refHits", "misses", "false", "median|dt|", "p99|dt|", "max|dt|", "ns/ray");
  std::string rows;
  for (size_t v = 0; v < scene.volumes.size(); ++v) {
    const Grid grid = loadVolume(scene.volumes[v]).grid;
    for (const IsoSurfaceDesc& iso : scene.volumes[v].isosurfaces)
      for (RayKind kind : {RayKind::Camera, RayKind::Secondary})
        for (const IntersectorSpec& spec : specs) {
          const AccuracyReport r = measureAccuracy(grid, iso.value, spec, kind, flags.rays, uint64_t(flags.seed),
                                                     flow == RayFlow::Wavefront);
          const char* kindName = kind == RayKind::Camera ? "camera" : "secondary";
          std::printf("%-7zu %-9g %-10s %-12s %8llu %8llu %8llu %10.2e %10.2e %10.2e %8.0f\n", v, iso.value, kindName,
                      intersectorName(spec).c_str(), (unsigned long long)r.referenceHits,
                      (unsigned long long)r.misses, (unsigned long long)r.falseHits, r.medianDt, r.p99Dt, r.maxDt,
                      r.nsPerRay);
          std::fflush(stdout);
          char buf[600];
          std::snprintf(buf, sizeof buf,
                        "    {\"volume\": %zu, \"iso\": %s, \"rays\": %s, \"intersector\": %s, \"count\": %llu, "
                        "\"reference_hits\": %llu, \"tangent\": %llu, \"misses\": %llu, \"false_hits\": %llu, "
                        "\"miss_rate\": %.6g, \"false_hit_rate\": %.6g, \"median_dt\": %.6g, \"p99_dt\": %.6g, "
                        "\"max_dt\": %.6g, \"ns_per_ray\": %.2f}",
                        v, jsonNumber(iso.value).c_str(), jsonString(kindName).c_str(), jsonString(intersectorName(spec)).c_str(),
                        (unsigned long long)r.rays, (unsigned long long)r.referenceHits,
                        (unsigned long long)r.tangentOnly, (unsigned long long)r.misses,
                        (unsigned long long)r.falseHits, r.referenceHits ? double(r.misses) / r.referenceHits : 0.0,
                        r.rays ? double(r.falseHits) / r.rays : 0.0, r.medianDt, r.p99Dt, r.maxDt, r.nsPerRay);
          rows += (rows.empty() ? "" : ",\n") + std::string(buf);
        }
  }
  if (!flags.json.empty()) writeJsonFile(flags.json, "{\n  \"scene\": " + jsonString(flags.scene) + ",\n  \"ray_flow\": " +
                                          jsonString(rayFlowName(flow)) + ",\n  \"results\": [\n" + rows + "\n  ]\n}\n");
  return 0;
}

}  // namespace

Command addBenchCommand(CLI::App& app) {
  auto flags = std::make_shared<CheckFlags>();
  CheckFlags& f = *flags;
  f.rays = 20000;
  CLI::App* cmd = app.add_subcommand("bench", "time per ray against error versus `reference`, per intersector");
  cmd->add_option("scene", f.scene, "scene file (JSON)")->required();
  cmd->add_option("--intersector", f.intersector, "comma-separated intersectors (default: all, with 1-8 iterations)");
  cmd->add_option("--rays", f.rays, "rays of each kind per iso-surface and intersector (default 20000)")
      ->check(CLI::Range(1, 1 << 26));
  cmd->add_option("--seed", f.seed, "random seed (default 1)")->check(CLI::Range(0LL, 1LL << 62));
  cmd->add_option("--ray-flow", f.rayFlow, "wavefront (default: the rays walked 8 at a time, the packet walk) or scalar");
  cmd->add_option("--json", f.json, "write the results as JSON");
  addSceneOverrides(cmd, f.overrides);
  return {cmd, [flags] { return bench(*flags); }};
}

}  // namespace iso
