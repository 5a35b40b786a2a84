// libFuzzer target: the mesh readers (tinygltf and tinyobjloader behind isotrace's own
// checks). The first byte picks .gltf, .glb or .obj. Bad input must be an InputError.
#include <cstdint>
#include <string>

#include "fuzz/fuzz_util.h"
#include "scene/gltf.h"
#include "volume/input_error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  static const char* names[] = {"m.gltf", "m.glb", "m.obj"};
  const std::string name = names[data[0] % 3];
  const std::string path = iso::fuzz::scratchFile(name, data + 1, size - 1);
  try {
    if (name == "m.obj")
      iso::loadObj(path);
    else
      iso::loadGltf(path);
  } catch (const iso::InputError&) {
  }
  return 0;
}
