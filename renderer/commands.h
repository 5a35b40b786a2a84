#pragma once
// The commands of `isotrace`, one file each (command_<name>.cpp: its flags and its work), and
// the helpers they share (cli.cpp, which also parses the command line and dispatches).
#include <functional>
#include <string>

#include "scene/scene.h"


namespace CLI {
class App;
}

namespace iso {

struct GltfMeshOut;
struct RenderResult;
struct RankFigures;

// A command added to the command line: its subcommand, and what runs it once parsed.
struct Command {
  CLI::App* app = nullptr;
  std::function<int()> run;
};
Command addRenderCommand(CLI::App& app);
Command addViewCommand(CLI::App& app);
Command addInfoCommand(CLI::App& app);
Command addWatertightCommand(CLI::App& app);
Command addBenchCommand(CLI::App& app);
Command addMeshCommand(CLI::App& app);

// Images above this many pixels need --allow-large; no side may exceed kMaxFilmSide.
constexpr long long kMaxFilmPixels = 1LL << 25;
constexpr int kMaxFilmSide = 16384;

// --set POINTER=VALUE and --iso S=V (repeatable): the scene file changed on the command line
// (SceneOverrides), for every command that reads a scene.
void addSceneOverrides(CLI::App* cmd, SceneOverrides& overrides);

// --resolution WIDTHxHEIGHT, each side 1 to kMaxFilmSide.
void parseResolution(const std::string& text, int& width, int& height);
// A temporary name beside `path`, unique to this process: ".NAME.partial-PID".
std::string temporaryBeside(const std::string& path);
// An output must be writable before any work is done: its directory exists and takes a file,
// and the name is no directory.
void checkWritable(const std::string& path);
// Writes `text` to `path` whole or not at all (through a temporary beside it).
void writeJsonFile(const std::string& path, const std::string& text);
// The shortest decimal that reads back as the same double (0.28, not 0.28000000000000003).
std::string jsonNumber(double v);
std::string jsonString(const std::string& s);

// Iso-surface `surfaceIndex` of volume `volumeIndex` as triangles in world space (OpenVDB's
// volumeToMesh), normals out of the solid, with the surface's material colour: `isotrace mesh`
// and the Python module's isotrace.mesh(). The scene's and the volume's "clip" cut it as the
// render does, and the cut is capped, so that a surface closed before is closed after;
// "color_by" ("cap_color_by" on the caps) becomes vertex colours (the material's colour then
// white). An index out of range is an InputError naming `volumeFlag` / `surfaceFlag`; so is an
// iso value that gives no surface.
// Sets a scene's time series to step `step` of the longest (the others stretched over it, as a
// sequence's frames are) for `isotrace mesh --time`; an InputError naming `flag` out of range.
void selectMeshTimeStep(SceneDesc& scene, int step, const std::string& flag);
GltfMeshOut surfaceMesh(const SceneDesc& scene, int volumeIndex, int surfaceIndex, const std::string& volumeFlag,
                        const std::string& surfaceFlag);

// What `render --stats FILE` writes (JSON text): the scene's settings, samples, seconds, rays and
// traversal counters of a render; `perRank` (MPI) may be null. The Python module's frame.stats.
std::string statsJson(const SceneDesc& scene, double loadSeconds, double buildSeconds, const RenderResult& r, int frames,
                      int threads, double totalSeconds, int ranks, const RankFigures* perRank);

// The flags of the exactness commands (`watertight`, `bench`).
struct CheckFlags {
  std::string scene, intersector, json, offset, dump, replay, rayFlow;
  int rays = 100000, threads = 0, ranks = 1;
  bool dataParallel = false, dumpLost = false;
  long long seed = 1;
  SceneOverrides overrides;
};

}  // namespace iso
