#include "tests/test_util.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <sstream>

namespace iso::test {

namespace fs = std::filesystem;

std::string scratchDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::temp_directory_path() / "isotrace_tests" /
                       (std::string(info->test_suite_name()) + "." + info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

void writeText(const std::string& path, const std::string& text) { writeBytes(path, text); }

void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

static std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

CommandResult runIsotrace(const std::string& args) { return runCommand(std::string(ISOTRACE_BINARY) + " " + args); }

CommandResult runCommand(const std::string& command) {
  // ctest runs tests in parallel processes: capture files are named after the test.
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::temp_directory_path() / "isotrace_tests" / "commands";
  fs::create_directories(dir);
  const std::string stem = (dir / (std::string(info->test_suite_name()) + "." + info->name())).string();
  const std::string out = stem + ".out", err = stem + ".err";
  const std::string cmd = command + " >" + out + " 2>" + err;
  const int raw = std::system(cmd.c_str());
  CommandResult r;
  r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  r.out = slurp(out);
  r.err = slurp(err);
  return r;
}

std::string mixedScene() {
  return R"({"camera": {"position": [0, 1.5, 4], "look_at": [0, 0.5, 0]}, "film": {"width": 32, "height": 24},
    "meshes": [{"shape": "quad", "transform": {"scale": 3}, "material": "floor"}],
    "volumes": [{"procedural": {"field": "sphere", "resolution": [24, 24, 24]}, "transform": {"translate": [0, 1, 0]},
                 "isosurfaces": [{"value": 0.6, "inside": "below", "material": "ball"}]}],
    "materials": {"floor": {"type": "diffuse", "color": 0.7}, "ball": {"type": "metallic_roughness", "color": [0.8, 0.3, 0.2]}},
    "lights": [{"type": "point", "position": [2, 4, 2], "intensity": 30}, {"type": "environment", "radiance": 0.3}]})";
}

std::vector<float> readExr(const std::string& path, std::vector<std::string>* channels,
                           std::map<std::string, std::string>* metadata) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) return {};
  const OIIO::ImageSpec& spec = in->spec();
  std::vector<float> data(size_t(spec.width) * spec.height * spec.nchannels);
  in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, data.data());
  if (channels) *channels = spec.channelnames;
  if (metadata)
    for (const char* key : {"isotrace:spp", "isotrace:interrupted", "isotrace:integrator", "isotrace:spp_mean",
                            "isotrace:spp_max", "isotrace:clamp"})
      if (spec.find_attribute(key)) (*metadata)[key] = spec.get_string_attribute(key);
  return data;
}

}  // namespace iso::test
