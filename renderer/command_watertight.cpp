// `isotrace watertight`: holes and double hits of every iso-surface under secondary rays.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <memory>
#include <regex>

#include "accuracy/watertight.h"
#include "renderer/commands.h"
#include "renderer/distributed.h"
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

std::string listOf(const std::vector<double>& ts) {
  if (ts.empty()) return "none";
  std::string s;
  char buf[32];
  for (double t : ts) {
    std::snprintf(buf, sizeof buf, "%.17g", t);
    s += (s.empty() ? "" : ", ") + std::string(buf);
  }
  return s;
}

// `--replay FILE`: each failing ray of a dump, run alone again; what it found then and now.
int replay(const CheckFlags& flags) {
  for (const auto& [given, name] : {std::pair{!flags.intersector.empty(), "--intersector"}, {!flags.offset.empty(), "--offset"},
                                    {!flags.dump.empty(), "--dump"}, {flags.dumpLost, "--dump-lost"},
                                    {!flags.json.empty(), "--json"},
                                    {!flags.rayFlow.empty(), "--ray-flow"}, {flags.ranks != 1, "--ranks"},
                                    {flags.dataParallel, "--data-parallel"}})
    if (given) throw InputError(name, "", "not with --replay: the failure file gives the intersector, ray flow, offset and ranks");
  const FailureFile file = readFailures(flags.replay);
  const SceneDesc scene = parseSceneFile(flags.scene, flags.overrides);
  IntersectorSpec spec;
  std::string error;
  if (!parseIntersector(file.intersector, spec, error)) throw InputError(flags.replay, "line 1", "intersector: " + error);
  const std::vector<FailedRay> now = replayFailures(scene, spec, file.offset, file.rayFlow, file.rays, file.ranks);
  std::printf("replay %s on %s: intersector %s, offset (%a, %a, %a), %zu rays\n", flags.replay.c_str(), flags.scene.c_str(),
              file.intersector.c_str(), file.offset.x, file.offset.y, file.offset.z, file.rays.size());
  size_t failing = 0;
  for (size_t i = 0; i < now.size(); ++i) {
    const FailedRay& was = file.rays[i];
    const FailedRay& is = now[i];
    failing += is.what.empty() || is.countDifference() ? 0 : 1;
    std::printf("ray %zu: %s test, volume %d, iso-surface %d (iso %.17g), ray %llu of seed %llu\n", i + 1, testName(is.test),
                is.volume, is.surface, scene.volumes[size_t(is.volume)].isosurfaces[size_t(is.surface)].value,
                (unsigned long long)is.index, (unsigned long long)file.seed);
    std::printf("  origin (%.9g, %.9g, %.9g), direction (%.9g, %.9g, %.9g), tfar %.9g\n", is.org.x, is.org.y, is.org.z,
                is.dir.x, is.dir.y, is.dir.z, is.tfar);
    std::printf("  class at the start %s, at the end %s%s\n", is.startInside ? "inside" : "outside",
                is.endInside ? "inside" : "outside",
                is.test == FailedRay::Test::Shadow ? (is.occluded ? "; occlusion query: occluded" : "; occlusion query: clear") : "");
    std::printf("  hits (t along the ray): %s\n", listOf(is.hits).c_str());
    if (is.test == FailedRay::Test::Parity) std::printf("  reference crossings:   %s\n", listOf(is.reference).c_str());
    std::printf("  then: %s; now: %s\n", was.what.empty() ? "passed" : was.what.c_str(), is.what.empty() ? "passes" : is.what.c_str());
  }
  std::printf("%zu of %zu rays fail now\n", failing, now.size());
  return failing == 0 ? 0 : 1;
}

int check(const CheckFlags& flags, const MpiJob& job);

int watertight(const CheckFlags& flags) {
  if (!flags.replay.empty()) return replay(flags);
  MpiJob job;  // under mpirun with --data-parallel: one rank of the check
  if (flags.dataParallel) {
    if (!job.distributed())
      throw InputError("--data-parallel", "", "runs under mpirun with 2 or more ranks (in one process the same split: --ranks N)");
    if (flags.ranks != 1) throw InputError("--data-parallel", "", "not with --ranks (the ranks are mpirun's)");
  }
  if (!job.distributed() || !flags.dataParallel) return check(flags, job);
  // Every rank loads for itself and checks the same rays; a failure on any rank is one line from
  // rank 0 (naming the rank), and every rank ends with status 2.
  try {
    return check(flags, job);
  } catch (const InputError& e) {
    if (job.rank() == 0) std::fprintf(stderr, "isotrace: %s\n", e.what());
    return 2;
  }
}

int check(const CheckFlags& flags, const MpiJob& job) {
  const bool ranks = job.distributed() && flags.dataParallel;
  SceneDesc scene;
  IntersectorSpec spec;
  WatertightOptions options;
  std::string failure;
  try {
    scene = parseSceneFile(flags.scene, flags.overrides);
    spec = scene.settings.intersector;
    if (!flags.intersector.empty()) {
      std::string error;
      if (!parseIntersector(flags.intersector, spec, error)) throw InputError("--intersector", "", error);
    }
    if (flags.rays < 1) throw InputError("--rays", "", "must be at least 1");
    if (flags.seed < 0) throw InputError("--seed", "", "must be at least 0");
    if (scene.volumes.empty()) throw InputError(flags.scene, "/volumes", "the scene has no volume to check");
    options.rays = flags.rays;
    options.seed = uint64_t(flags.seed);
    options.offset = parseOffset(flags.offset);
    options.threads = flags.threads;
    options.rayFlow = scene.settings.rayFlow;
    if (!flags.rayFlow.empty() && !parseRayFlow(flags.rayFlow, options.rayFlow))
      throw InputError("--ray-flow", "", "unknown ray flow '" + flags.rayFlow + "' (known: wavefront, scalar)");
    options.ranks = flags.ranks;
    options.keepFailures = !flags.dump.empty();
    if (flags.dumpLost && flags.dump.empty()) throw InputError("--dump-lost", "", "needs --dump FILE (the file it adds rays to)");
    options.keepCountDifferences = flags.dumpLost;
    if (!flags.dump.empty() && job.rank() == 0) checkWritable(flags.dump);
  } catch (const InputError& e) {
    if (!ranks) throw;
    failure = e.what();
  }
  // Under mpirun the ranks agree on the first failure before any of them checks a ray.
  if (ranks && !(failure = job.firstError(failure)).empty()) throw InputError(failure);
  const RankExchange exchange = ranks ? job.rankExchange() : RankExchange{};
  if (ranks) options.exchange = &exchange;
  const auto start = std::chrono::steady_clock::now();
  const std::vector<WatertightReport> reports = checkWatertight(scene, spec, options);
  if (job.rank() != 0 && ranks) return 0;  // every rank has the same counts: rank 0 reports them
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("watertight %s: intersector %s, %s flow, %d rays per test and iso-surface, seed %lld, offset (%g, %g, %g)%s\n",
              flags.scene.c_str(), intersectorName(spec).c_str(), rayFlowName(options.rayFlow), flags.rays, flags.seed, options.offset.x,
              options.offset.y, options.offset.z,
              options.ranks > 1 ? (", each volume split over " + std::to_string(options.ranks) + " ranks").c_str()
              : ranks           ? (", each volume split over " + std::to_string(job.size()) + " MPI ranks").c_str()
                                : "");
  std::printf("%-7s %-10s %9s %10s %10s %6s %6s %14s %10s %15s %18s\n", "volume", "iso", "rays", "crossings", "reference", "lost",
              "extra", "parity_errors", "self_hits", "inside_escapes", "shadow_mismatches");
  WatertightCounts total;
  auto row = [](const char* v, const std::string& iso, const WatertightCounts& c) {
    std::printf("%-7s %-10s %9llu %10llu %10llu %6llu %6llu %14llu %10llu %15llu %18llu\n", v, iso.c_str(), (unsigned long long)c.rays,
                (unsigned long long)c.crossings, (unsigned long long)c.referenceCrossings,
                (unsigned long long)c.lostCrossings, (unsigned long long)c.extraCrossings,
                (unsigned long long)c.parityErrors, (unsigned long long)c.selfHits,
                (unsigned long long)c.insideEscapes, (unsigned long long)c.shadowMismatches);
  };
  auto counts = [](const WatertightCounts& c) {
    char buf[400];
    std::snprintf(buf, sizeof buf,
                  "\"rays\": %llu, \"crossings\": %llu, \"reference_crossings\": %llu, \"lost_crossings\": %llu, "
                  "\"extra_crossings\": %llu, \"parity_errors\": %llu, "
                  "\"self_hits\": %llu, \"inside_escapes\": %llu, \"shadow_mismatches\": %llu",
                  (unsigned long long)c.rays, (unsigned long long)c.crossings,
                  (unsigned long long)c.referenceCrossings, (unsigned long long)c.lostCrossings,
                  (unsigned long long)c.extraCrossings, (unsigned long long)c.parityErrors,
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
  if (!flags.dump.empty()) {
    FailureFile file;
    file.scene = flags.scene;
    file.intersector = intersectorName(spec);
    file.rayFlow = options.rayFlow;
    file.seed = uint64_t(flags.seed);
    file.offset = options.offset;
    file.ranks = ranks ? job.size() : options.ranks;  // a replay splits the volume the same way, in one process
    for (const WatertightReport& r : reports) file.rays.insert(file.rays.end(), r.failures.begin(), r.failures.end());
    writeFailures(flags.dump, file);
    const size_t differing = size_t(std::count_if(file.rays.begin(), file.rays.end(), [](const FailedRay& r) { return r.countDifference(); }));
    std::printf("%zu failing rays%s written to %s (replay: isotrace watertight %s --replay %s)\n",
                file.rays.size() - differing,
                flags.dumpLost ? (" and " + std::to_string(differing) + " whose crossings differ from the reference's").c_str() : "",
                flags.dump.c_str(), flags.scene.c_str(), flags.dump.c_str());
  }
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
  cmd->add_option("--ray-flow", f.rayFlow, "wavefront (default: each query an 8-lane packet, the packet walk) or scalar");
  cmd->add_option("--offset", f.offset, "move every volume by X,Y,Z (e.g. 1e5,1e5,1e5)");
  cmd->add_option("--ranks", f.ranks,
                  "split each volume as a data-parallel render over N ranks would (render --data-parallel), each part "
                  "a World of its own in this process, and check the closest of their hits: the seams between ranks "
                  "(default 1, at most 64)")
      ->check(CLI::Range(1, 64));
  cmd->add_flag("--data-parallel", f.dataParallel,
               "under mpirun: each rank holds only its part of each volume (as render --data-parallel) and the "
               "ranks' answers are combined for every query (one ray at a time)");
  cmd->add_option("--threads", f.threads, "worker threads (0: all cores, at most 1024)")->check(CLI::Range(0, 1024));
  cmd->add_option("--json", f.json, "write the counts as JSON");
  cmd->add_option("--dump", f.dump, "write every failing ray (exact, in hexadecimal) to FILE, to replay alone");
  cmd->add_flag("--dump-lost", f.dumpLost,
               "with --dump: also the parity rays whose crossings differ from the double reference's count on "
               "their line (not errors: pairs of crossings one has and the other not), to compare the hit lists");
  addSceneOverrides(cmd, f.overrides);
  cmd->add_option("--replay", f.replay, "run the rays of a --dump FILE again, alone, and say what each finds now");
  return {cmd, [flags] { return watertight(*flags); }};
}

}  // namespace iso
