// `isotrace watertight`: holes and double hits of every iso-surface under secondary rays.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <memory>
#include <regex>

#include "accuracy/watertight.h"
#include "renderer/commands.h"
#include "volume/input_error.h"

namespace iso {
namespace {

Vec3d parseOffset(const std::string& text) {
  Vec3d v{0, 0, 0};
  if (text.empty()) return v;
  std::smatch m;
  static const std::regex three(R"(\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*)");
  try {
    if (!std::regex_match(text, m, three)) throw std::invalid_argument("format");
    v = {std::stod(m[1]), std::stod(m[2]), std::stod(m[3])};
  } catch (const std::exception&) {
    throw InputError("--offset", "", "expected X,Y,Z, e.g. 1e5,1e5,1e5, got '" + text + "'");
  }
  if (!isFinite(v)) throw InputError("--offset", "", "offset must be finite");
  return v;
}

int watertight(const CheckFlags& flags) {
  SceneDesc scene = parseSceneFile(flags.scene);
  IntersectorSpec spec = scene.settings.intersector;
  if (!flags.intersector.empty()) {
    std::string error;
    if (!parseIntersector(flags.intersector, spec, error)) throw InputError("--intersector", "", error);
  }
  if (flags.rays < 1) throw InputError("--rays", "", "must be at least 1");
  if (flags.seed < 0) throw InputError("--seed", "", "must be at least 0");
  if (scene.volumes.empty()) throw InputError(flags.scene, "/volumes", "the scene has no volume to check");
  WatertightOptions options;
  options.rays = flags.rays;
  options.seed = uint64_t(flags.seed);
  options.offset = parseOffset(flags.offset);
  options.threads = flags.threads;
  const auto start = std::chrono::steady_clock::now();
  const std::vector<WatertightReport> reports = checkWatertight(scene, spec, options);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("watertight %s: intersector %s, %d rays per test and iso-surface, seed %lld, offset (%g, %g, %g)\n",
              flags.scene.c_str(), intersectorName(spec).c_str(), flags.rays, flags.seed, options.offset.x,
              options.offset.y, options.offset.z);
  std::printf("%-7s %-10s %9s %10s %10s %14s %10s %15s %18s\n", "volume", "iso", "rays", "crossings", "reference",
              "parity_errors", "self_hits", "inside_escapes", "shadow_mismatches");
  WatertightCounts total;
  auto row = [](const char* v, const std::string& iso, const WatertightCounts& c) {
    std::printf("%-7s %-10s %9llu %10llu %10llu %14llu %10llu %15llu %18llu\n", v, iso.c_str(), (unsigned long long)c.rays,
                (unsigned long long)c.crossings, (unsigned long long)c.referenceCrossings,
                (unsigned long long)c.parityErrors, (unsigned long long)c.selfHits,
                (unsigned long long)c.insideEscapes, (unsigned long long)c.shadowMismatches);
  };
  auto counts = [](const WatertightCounts& c) {
    char buf[400];
    std::snprintf(buf, sizeof buf,
                  "\"rays\": %llu, \"crossings\": %llu, \"reference_crossings\": %llu, \"parity_errors\": %llu, "
                  "\"self_hits\": %llu, \"inside_escapes\": %llu, \"shadow_mismatches\": %llu",
                  (unsigned long long)c.rays, (unsigned long long)c.crossings,
                  (unsigned long long)c.referenceCrossings, (unsigned long long)c.parityErrors,
                  (unsigned long long)c.selfHits, (unsigned long long)c.insideEscapes,
                  (unsigned long long)c.shadowMismatches);
    return std::string(buf);
  };
  std::string surfaces;
  for (const WatertightReport& r : reports) {
    char iso[32];
    std::snprintf(iso, sizeof iso, "%g", r.iso);
    row(std::to_string(r.volume).c_str(), iso, r.counts);
    total.add(r.counts);
    char head[200];
    std::snprintf(head, sizeof head, "    {\"volume\": %d, \"iso\": %s, \"intersector\": %s, ", r.volume, jsonNumber(r.iso).c_str(),
                  jsonString(r.intersector).c_str());
    surfaces += (surfaces.empty() ? "" : ",\n") + std::string(head) + counts(r.counts) + "}";
  }
  row("total", "", total);
  std::printf("%.2f s; %llu errors\n", seconds, (unsigned long long)total.errors());
  if (!flags.json.empty())
    writeJsonFile(flags.json, "{\n  \"total\": {" + counts(total) + "},\n  \"surfaces\": [\n" + surfaces + "\n  ]\n}\n");
  return 0;
}

}  // namespace

Command addWatertightCommand(CLI::App& app) {
  auto flags = std::make_shared<CheckFlags>();
  CheckFlags& f = *flags;
  CLI::App* cmd = app.add_subcommand("watertight", "count holes and double hits of every iso-surface under secondary rays");
  cmd->add_option("scene", f.scene, "scene file (JSON)")->required();
  cmd->add_option("--rays", f.rays, "rays per test and iso-surface (default 100000)")->check(CLI::Range(1, 1 << 30));
  cmd->add_option("--intersector", f.intersector, std::string("intersector: ") + intersectorList());
  cmd->add_option("--seed", f.seed, "random seed (default 1)")->check(CLI::Range(0LL, 1LL << 62));
  cmd->add_option("--offset", f.offset, "move every volume by X,Y,Z (e.g. 1e5,1e5,1e5)");
  cmd->add_option("--threads", f.threads, "worker threads (0: all cores, at most 1024)")->check(CLI::Range(0, 1024));
  cmd->add_option("--json", f.json, "write the counts as JSON");
  return {cmd, [flags] { return watertight(*flags); }};
}

}  // namespace iso
