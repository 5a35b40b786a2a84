// libisotrace_oiio.so: scene/image_plugin.h's ImagePlugin on OpenImageIO, loaded at first use
// (scene/image_plugin.cpp). Nothing else in isotrace links OpenImageIO.
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include "scene/image_plugin.h"

namespace iso {
namespace {

class OiioReader : public ImageReader {
 public:
  OiioReader(std::unique_ptr<OIIO::Filesystem::IOMemReader> memory,
             std::unique_ptr<OIIO::ImageInput> in)
      : m_memory(std::move(memory)), m_in(std::move(in)) {
    const OIIO::ImageSpec& spec = m_in->spec();
    width = spec.width;
    height = spec.height;
    channels = spec.nchannels;
    eightBit = spec.format.basetype == OIIO::TypeDesc::UINT8;
  }
  std::string readFloats(float* out) override {
    if (!m_in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, out)) {
      const std::string why = m_in->geterror();
      return why.empty() ? "cannot decode the pixels" : why;
    }
    return "";
  }

 private:
  std::unique_ptr<OIIO::Filesystem::IOMemReader> m_memory;  // (declared first: outlives m_in)
  std::unique_ptr<OIIO::ImageInput> m_in;
};

class OiioPlugin : public ImagePlugin {
 public:
  std::unique_ptr<ImageReader> open(const std::string& name, const unsigned char* bytes,
                                    size_t size, std::string& error) override {
    std::unique_ptr<OIIO::Filesystem::IOMemReader> memory;
    if (bytes)
      memory =
          std::make_unique<OIIO::Filesystem::IOMemReader>(const_cast<unsigned char*>(bytes), size);
    auto in = OIIO::ImageInput::open(name, nullptr, memory.get());
    if (!in) {
      error = OIIO::geterror();
      if (error.empty()) error = "unknown image format";
      return nullptr;
    }
    return std::make_unique<OiioReader>(std::move(memory), std::move(in));
  }

  std::string writeJpeg(const std::string& path, const uint8_t* rgb, int width, int height,
                        const std::map<std::string, std::string>& metadata) override {
    OIIO::ImageSpec spec(width, height, 3, OIIO::TypeDesc::UINT8);
    for (const auto& [key, value] : metadata) spec.attribute(key, value);
    auto out = OIIO::ImageOutput::create(path);
    bool ok = out && out->open(path, spec);
    if (ok) {
      ok = out->write_image(OIIO::TypeDesc::UINT8, rgb);
      ok = out->close() && ok;
    }
    if (ok) return "";
    const std::string why = out ? out->geterror() : OIIO::geterror();
    return why.empty() ? "cannot write the image" : why;
  }

  std::string encodeJpeg(const uint8_t* rgb, int width, int height, int quality,
                         std::vector<unsigned char>& bytes) override {
    OIIO::Filesystem::IOVecOutput memory(bytes);
    OIIO::ImageSpec spec(width, height, 3, OIIO::TypeDesc::UINT8);
    spec.attribute("Compression", "jpeg:" + std::to_string(quality));
    void* proxy = &memory;
    spec.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &proxy);
    auto out = OIIO::ImageOutput::create("frame.jpg");
    if (!out || !out->open("frame.jpg", spec) || !out->write_image(OIIO::TypeDesc::UINT8, rgb) ||
        !out->close())
      return out ? out->geterror() : OIIO::geterror();
    return "";
  }

  std::string drawText(float* rgb, int width, int height, int x, int y, const std::string& text,
                       int size, const std::string& font, const float color[3],
                       int align) override {
    OIIO::ImageBuf image(OIIO::ImageSpec(width, height, 3, OIIO::TypeDesc::FLOAT),
                         rgb);  // wraps the caller's pixels
    const auto alignX = align == 1   ? OIIO::ImageBufAlgo::TextAlignX::Right
                        : align == 2 ? OIIO::ImageBufAlgo::TextAlignX::Center
                                     : OIIO::ImageBufAlgo::TextAlignX::Left;
    if (OIIO::ImageBufAlgo::render_text(image, x, y, text, size, font, OIIO::cspan<float>(color, 3),
                                        alignX))
      return "";
    const std::string why = image.geterror();
    return why.empty() ? "cannot draw text" : why;
  }
};

}  // namespace
}  // namespace iso

// The one symbol the loader looks up.
extern "C" __attribute__((visibility("default"))) iso::ImagePlugin* isotraceImagePlugin() {
  static iso::OiioPlugin plugin;
  return &plugin;
}
