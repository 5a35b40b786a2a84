// libFuzzer target: the glTF reader (tinygltf behind isotrace's own checks). The first byte
// picks .gltf or .glb. Bad input must be an InputError.
#include <cstdint>
#include <string>

#include "fuzz/fuzz_util.h"
#include "scene/gltf.h"
#include "volume/input_error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const std::string path = iso::fuzz::scratchFile(data[0] & 1 ? "m.glb" : "m.gltf", data + 1, size - 1);
  try {
    iso::loadGltf(path);
  } catch (const iso::InputError&) {
  }
  return 0;
}
