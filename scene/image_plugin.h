#pragma once
// OpenImageIO behind a library loaded at first use. OpenImageIO brings ~260 shared libraries
// (FFmpeg, GDAL, OpenCV, Poppler, ...): linked into isotrace, the dynamic loader spent ~0.27 s and
// ~85 MB at every start resolving them, for --help as for a render. Now only what needs it loads
// it (libisotrace_oiio.so, scene/image_plugin_oiio.cpp): textures and environment maps, JPEG
// output, the legends' text, `view`'s frames, the Python module's image reading. EXR and PNG
// output are written without it (renderer/film.cpp).
#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace iso {

// An image being read: its header, then its pixels.
class ImageReader {
 public:
  virtual ~ImageReader() = default;
  int width = 0, height = 0, channels = 0;
  bool eightBit = false;  // stored as 8-bit unsigned integers
  // Every pixel as float (8-bit values to [0, 1]), channels interleaved, row by row, into `out`
  // (width * height * channels floats); an error message, or "" on success.
  virtual std::string readFloats(float* out) = 0;
};

class ImagePlugin {
 public:
  virtual ~ImagePlugin() = default;
  // The image in the file `name` (bytes == nullptr), or in `size` bytes in memory, of the format
  // `name`'s extension says (the bytes stay the caller's, alive until the reader is gone).
  // nullptr, with `error` set, if it cannot be opened.
  virtual std::unique_ptr<ImageReader> open(const std::string& name, const unsigned char* bytes,
                                            size_t size, std::string& error) = 0;
  // Writes 8-bit RGB (width x height, row by row) as the JPEG file `path`, with string
  // attributes; "" on success, else the error. (EXR and PNG are written without the plugin.)
  virtual std::string writeJpeg(const std::string& path, const uint8_t* rgb, int width, int height,
                                const std::map<std::string, std::string>& metadata) = 0;
  // 8-bit RGB as a JPEG file's bytes.
  virtual std::string encodeJpeg(const uint8_t* rgb, int width, int height, int quality,
                                 std::vector<unsigned char>& out) = 0;
  // Draws `text` into float RGB pixels (width x height) with its baseline at y, starting at x
  // (align 0), ending there (1) or centred on it (2), in the TrueType `font` at `size` pixels.
  virtual std::string drawText(float* rgb, int width, int height, int x, int y,
                               const std::string& text, int size, const std::string& font,
                               const float color[3], int align) = 0;
};

// The plugin cannot be loaded (an installation without it): not the input's fault.
class PluginMissing : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The plugin, loaded at the first call from beside the program (or the Python module) or from the
// build folder it was built in (only from $ISOTRACE_PLUGIN_DIR when that is set); PluginMissing
// naming the library if it cannot be loaded.
ImagePlugin& imagePlugin();

}  // namespace iso
