// libFuzzer target: images as textures (decoded from memory through OpenImageIO, as glTF
// textures are). The first byte picks the format's extension. Bad input must be an InputError.
#include <cstdint>
#include <string>
#include <vector>

#include "scene/texture.h"
#include "volume/input_error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  static const char* names[] = {"t.png", "t.jpg", "t.hdr", "t.exr"};
  const std::vector<unsigned char> encoded(data + 1, data + size);
  try {
    iso::Texture::decode(encoded, names[data[0] % 4], data[0] & 4);
  } catch (const iso::InputError&) {
  }
  return 0;
}
