#pragma once
// Helpers shared by the tests: data paths, a seeded RNG, running the isotrace binary.
#include <cstdio>
#include <random>
#include <string>

namespace iso::test {

inline std::string dataPath(const std::string& rel) { return std::string(ISOTRACE_DATA_DIR) + "/" + rel; }

struct CommandResult {
  int status = -1;
  std::string err;  // stderr
  std::string out;  // stdout
};

// Runs `isotrace <args>` through the shell, capturing stdout and stderr.
CommandResult runIsotrace(const std::string& args);

// A scratch directory unique to the current test, emptied first.
std::string scratchDir();
void writeText(const std::string& path, const std::string& text);
void writeBytes(const std::string& path, const std::string& bytes);

}  // namespace iso::test
