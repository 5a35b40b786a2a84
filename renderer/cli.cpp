// The command line: the shared flag helpers, parsing, and the dispatch to the commands
// (command_<name>.cpp). Exit status: 0 success, 2 bad input, 1 internal error.
#include "renderer/cli.h"

#include <CLI/CLI.hpp>
#include <OpenImageIO/oiioversion.h>
#include <embree3/rtcore_config.h>
#include <oneapi/tbb/version.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <regex>

#include "renderer/commands.h"
#include "scene/image_plugin.h"
#include "volume/input_error.h"
#include "volume/iso_mesh.h"

namespace iso {

void addSceneOverrides(CLI::App* cmd, SceneOverrides& overrides) {
  cmd->add_option("--set", overrides.set,
                  "POINTER=VALUE: change the scene's JSON at a JSON pointer, e.g. /camera/fov=30 or "
                  "/volumes/0/isosurfaces/1/value=300 (repeatable; a bare word is a string)")
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  cmd->add_option("--iso", overrides.iso, "S=V: set iso-surface S (counted over all volumes from 0) to V (repeatable)")
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
}

void parseResolution(const std::string& text, int& width, int& height) {
  std::smatch m;
  static const std::regex wxh(R"((\d{1,5})x(\d{1,5}))");
  if (!std::regex_match(text, m, wxh) || std::stoi(m[1]) < 1 || std::stoi(m[2]) < 1)
    throw InputError("--resolution", "", "expected WIDTHxHEIGHT, e.g. 640x480, got '" + text + "'");
  width = std::stoi(m[1]);
  height = std::stoi(m[2]);
  if (width > kMaxFilmSide || height > kMaxFilmSide)
    throw InputError("--resolution", "", "each side must be at most " + std::to_string(kMaxFilmSide) + " pixels");
}

std::string temporaryBeside(const std::string& path) {
  const std::filesystem::path p(path);
  return (p.parent_path() / ("." + p.filename().string() + ".partial-" + std::to_string(getpid()))).string();
}

void checkWritable(const std::string& path) {
  namespace fs = std::filesystem;
  const fs::path p(path);
  std::error_code ec;
  if (fs::is_directory(p, ec)) throw InputError(path, "", "is a directory; name the output file");
  if (p.has_parent_path() && !fs::is_directory(p.parent_path(), ec))
    throw InputError(path, "", "output directory does not exist");
  const std::string probe = temporaryBeside(path);
  FILE* f = std::fopen(probe.c_str(), "w");
  if (!f) throw InputError(path, "", std::string("cannot write in its directory: ") + std::strerror(errno));
  std::fclose(f);
  std::remove(probe.c_str());
}

std::string jsonNumber(double v) {
  char buf[32];
  for (int digits = 15; digits <= 17; ++digits) {
    std::snprintf(buf, sizeof buf, "%.*g", digits, v);
    if (std::strtod(buf, nullptr) == v) break;
  }
  return buf;
}

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      out += buf;
      continue;
    }
    out += c;
  }
  return out + "\"";
}

void writeJsonFile(const std::string& path, const std::string& text) {
  const std::filesystem::path p(path);
  if (p.has_parent_path() && !std::filesystem::is_directory(p.parent_path()))
    throw InputError(path, "", "output directory does not exist");
  const std::string temp = temporaryBeside(path);
  FILE* f = std::fopen(temp.c_str(), "w");
  const bool ok = f && std::fputs(text.c_str(), f) >= 0;
  if (f && std::fclose(f) != 0) throw InputError(path, "", "cannot write");
  if (!ok || std::rename(temp.c_str(), path.c_str()) != 0) {
    std::remove(temp.c_str());
    throw InputError(path, "", "cannot write");
  }
}

namespace {

std::string versionText() {
  return std::string("isotrace ") + ISOTRACE_VERSION + "\nEmbree " + RTC_VERSION_STRING + ", OpenVDB " +
         openVdbVersion() + ", OpenImageIO " + OIIO_VERSION_STRING + ", oneTBB " + TBB_VERSION_STRING;
}

}  // namespace

int runCommandLine(int argc, char** argv) {
  CLI::App app{"isotrace: a path tracer for glTF meshes and exact iso-surfaces of volume data"};
  app.require_subcommand(1);
  app.set_version_flag("--version", versionText(), "print the version of isotrace and of its libraries");
  // A first word that is no command and no option: say so, with the commands.
  const char* names[] = {"render", "view", "info", "watertight", "bench", "mesh"};
  if (argc >= 2 && argv[1][0] != '-' &&
      std::none_of(std::begin(names), std::end(names), [&](const char* c) { return std::strcmp(argv[1], c) == 0; })) {
    std::fprintf(stderr, "isotrace: unknown command '%s' (commands: render, view, info, watertight, bench, mesh; see isotrace --help)\n", argv[1]);
    return 2;
  }
  const Command commands[] = {addRenderCommand(app),     addViewCommand(app),  addInfoCommand(app),
                              addWatertightCommand(app), addBenchCommand(app), addMeshCommand(app)};
  for (const Command& c : commands) c.app->allow_extras();
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "isotrace: %s (see isotrace --help)\n", e.what());
    return 2;
  }
  // Arguments no option takes, in the order given (CLI11's own message lists them backwards).
  for (CLI::App* sub : app.get_subcommands()) {
    const std::vector<std::string> extra = sub->remaining();
    if (extra.empty()) continue;
    std::string list;
    for (const std::string& e : extra) list += (list.empty() ? "" : " ") + e;
    std::fprintf(stderr, "isotrace %s: unexpected argument%s '%s' (see isotrace %s --help)\n", sub->get_name().c_str(),
                 extra.size() > 1 ? "s" : "", list.c_str(), sub->get_name().c_str());
    return 2;
  }
  try {
    for (const Command& c : commands)
      if (*c.app) return c.run();
  } catch (const InputError& e) {
    std::fprintf(stderr, "isotrace: %s\n", e.what());
    return 2;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "isotrace: out of memory\n");
    return 1;
  } catch (const PluginMissing& e) {
    std::fprintf(stderr, "isotrace: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "isotrace: internal error: %s\n", e.what());
    return 1;
  }
  return 1;
}

}  // namespace iso
