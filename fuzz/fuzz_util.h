#pragma once
// Shared by the libFuzzer targets (scripts/fuzz.sh): the readers take file names, so each
// input is written to a file in a scratch folder of this process first.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>

namespace iso::fuzz {

inline std::string scratchFile(const std::string& name, const uint8_t* data, size_t size) {
  static const std::string dir = [] {
    const std::string d = std::filesystem::temp_directory_path().string() + "/isotrace-fuzz-" + std::to_string(getpid());
    std::filesystem::create_directories(d);
    return d;
  }();
  const std::string path = dir + "/" + name;
  FILE* f = std::fopen(path.c_str(), "wb");
  if (f) {
    if (size) std::fwrite(data, 1, size, f);
    std::fclose(f);
  }
  return path;
}

}  // namespace iso::fuzz
