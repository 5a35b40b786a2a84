// libFuzzer target: the scene parser on arbitrary text. Bad input must be an InputError, never
// a crash, a hang or another exception.
#include <cstdint>
#include <string>

#include "scene/scene.h"
#include "volume/input_error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    iso::parseSceneText(std::string(reinterpret_cast<const char*>(data), size), "/fuzz/scene.json");
  } catch (const iso::InputError&) {
  }
  return 0;
}
