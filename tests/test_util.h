#pragma once
// Helpers shared by the tests: data paths, a seeded RNG, running the isotrace binary, bad input.
#include <gtest/gtest.h>

#include <cstdio>
#include <map>
#include <random>
#include <string>
#include <vector>

namespace iso::test {

inline std::string dataPath(const std::string& rel) { return std::string(ISOTRACE_DATA_DIR) + "/" + rel; }

struct CommandResult {
  int status = -1;
  std::string err;  // stderr
  std::string out;  // stdout
};

// Runs `isotrace <args>` through the shell, capturing stdout and stderr.
CommandResult runIsotrace(const std::string& args);
// Runs a shell command line, capturing stdout and stderr.
CommandResult runCommand(const std::string& command);

// A small mixed scene: a floor quad, an iso-surface ball, a point light and a sky (32x24).
std::string mixedScene();
// An image's pixels as float (empty if it cannot be read), its channel names and isotrace's
// metadata (isotrace:spp, :interrupted, :integrator, :spp_mean, :spp_max, :clamp).
std::vector<float> readExr(const std::string& path, std::vector<std::string>* channels = nullptr,
                           std::map<std::string, std::string>* metadata = nullptr);

// A scratch directory unique to the current test, emptied first.
std::string scratchDir();
void writeText(const std::string& path, const std::string& text);
void writeBytes(const std::string& path, const std::string& bytes);

// Bad input: `load()` must throw an InputError (or another exception type E) whose message
// names `name` (a file, a place) and holds `fragment`, in one line.
template <typename E, typename F>
void expectRefusal(F&& load, const std::string& name, const std::string& fragment) {
  try {
    load();
    ADD_FAILURE() << "no error for " << name;
  } catch (const E& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(name), std::string::npos) << msg;
    EXPECT_NE(msg.find(fragment), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "one line: " << msg;
  }
}

}  // namespace iso::test
