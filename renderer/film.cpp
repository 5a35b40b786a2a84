#include "renderer/film.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStandardAttributes.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <png.h>

#include <algorithm>
#include <cmath>
#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <stdexcept>
#include <unistd.h>

#include "scene/image_plugin.h"
#include "volume/input_error.h"

namespace iso {

namespace fs = std::filesystem;

ImageFormat imageFormatFor(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  if (ext == ".exr") return ImageFormat::Exr;
  if (ext == ".png") return ImageFormat::Png;
  if (ext == ".jpg" || ext == ".jpeg") return ImageFormat::Jpeg;
  throw InputError(path, "", "output must end in .exr, .png or .jpg");
}

namespace {

float linearToSrgb(float v) {
  v = v > 0 ? std::min(v, 1.f) : 0.f;  // NaN and negatives to 0
  return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1 / 2.4f) - 0.055f;
}

}  // namespace

bool parseTonemap(const std::string& name, Tonemap& tonemap) {
  if (name == "clamp") tonemap = Tonemap::Clamp;
  else if (name == "aces") tonemap = Tonemap::Aces;
  else if (name == "filmic") tonemap = Tonemap::Filmic;
  else return false;
  return true;
}

const char* tonemapName(Tonemap tonemap) {
  switch (tonemap) {
    case Tonemap::Clamp: return "clamp";
    case Tonemap::Aces: return "aces";
    case Tonemap::Filmic: return "filmic";
  }
  return "?";
}

float applyTonemap(float v, Tonemap tonemap) {
  if (!(v > 0)) return 0;  // NaN and negatives
  switch (tonemap) {
    case Tonemap::Clamp: return std::min(v, 1.f);
    case Tonemap::Aces:
      // Narkowicz 2015, "ACES Filmic Tone Mapping Curve": a fit of the ACES reference rendering
      // and output transforms, per channel (input pre-scaled by 0.6 as in that fit).
      v *= 0.6f;
      return std::clamp(v * (2.51f * v + 0.03f) / (v * (2.43f * v + 0.59f) + 0.14f), 0.f, 1.f);
    case Tonemap::Filmic: {
      // Hable 2010, "Filmic Tonemapping for Real-time Rendering" (Uncharted 2): a toe and a
      // long shoulder, white at 11.2, input doubled as in that talk.
      auto curve = [](float x) {
        const float A = 0.15f, B = 0.5f, C = 0.1f, D = 0.2f, E = 0.02f, F = 0.3f;
        return (x * (A * x + C * B) + D * E) / (x * (A * x + B) + D * F) - E / F;
      };
      return std::clamp(curve(2 * v) / curve(11.2f), 0.f, 1.f);
    }
  }
  return 0;
}

double Film::meanLuminance() const {
  double sum = 0;
  for (const Vec3f& p : m_pixels) sum += 0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z;
  return m_pixels.empty() ? 0 : sum / m_pixels.size();
}

namespace {

// One channel as shown: signed data mapped from [-1, 1], radiance tone mapped, then sRGB.
uint8_t displayByte(float v, bool signedData, float scale, Tonemap tonemap) {
  const float shown = signedData ? std::clamp(0.5f * v + 0.5f, 0.f, 1.f) : linearToSrgb(applyTonemap(v * scale, tonemap));
  return uint8_t(std::lround(shown * 255));
}

}  // namespace

Film indirectOf(const Film& global, const Film& direct) {
  Film indirect(global.width(), global.height());
  for (int y = 0; y < global.height(); ++y)
    for (int x = 0; x < global.width(); ++x) indirect.at(x, y) = global.at(x, y) - direct.at(x, y);
  return indirect;
}

std::vector<uint8_t> displayRgb(const Film& film, bool signedData, const DisplaySettings& display) {
  std::vector<uint8_t> bytes(size_t(film.width()) * film.height() * 3);
  const float scale = float(std::exp2(display.exposure));
  for (int y = 0; y < film.height(); ++y)
    for (int x = 0; x < film.width(); ++x)
      for (int c = 0; c < 3; ++c)
        bytes[(size_t(y) * film.width() + x) * 3 + c] = displayByte(film.at(x, y)[c], signedData, scale, display.tonemap);
  return bytes;
}

std::string legendFont() {
  for (const char* path : {"/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf", "/usr/share/fonts/TTF/DejaVuSans.ttf"})
    if (fs::exists(path)) return path;
  return "";
}

namespace {

constexpr int kLegendHeight = 40;  // pixels per colour bar: the bar, then its labels

// The legends' strip (width w, kLegendHeight per legend), 8-bit sRGB with `channels` channels
// (alpha opaque): a dark ground, each map as a bar, its end values under its ends and the
// field's name between them.
std::vector<uint8_t> legendStrip(const DisplaySettings& display, int w, int channels) {
  const int h = kLegendHeight * int(display.legends.size());
  std::vector<float> rgb(size_t(w) * h * 3, 0.08f);  // the ground
  const int margin = std::max(4, w / 40);
  const int size = std::clamp(w / 40, 9, 16);
  for (size_t k = 0; k < display.legends.size(); ++k) {
    const Legend& l = display.legends[k];
    const int top = int(k) * kLegendHeight + 4;
    for (int x = margin; x < w - margin; ++x) {
      const Vec3f c = l.map.srgb(float(x - margin) / float(std::max(1, w - 2 * margin - 1)));
      for (int y = top; y < top + 12; ++y) {
        float* p = &rgb[(size_t(y) * w + x) * 3];
        p[0] = c.x;
        p[1] = c.y;
        p[2] = c.z;
      }
    }
    const float white[3] = {0.92f, 0.92f, 0.92f};
    char lo[32], hi[32];
    std::snprintf(lo, sizeof lo, "%.4g", l.lo);
    std::snprintf(hi, sizeof hi, "%.4g", l.hi);
    const int baseline = top + 14 + size;
    ImagePlugin& text = imagePlugin();
    std::string error = text.drawText(rgb.data(), w, h, margin, baseline, lo, size, display.font, white, 0);
    if (error.empty()) error = text.drawText(rgb.data(), w, h, w - margin, baseline, hi, size, display.font, white, 1);
    if (error.empty()) error = text.drawText(rgb.data(), w, h, w / 2, baseline, l.title, size, display.font, white, 2);
    if (!error.empty()) throw InputError("--colorbar", "", "cannot draw the legend's text: " + error);
  }
  std::vector<uint8_t> bytes(size_t(w) * h * channels, 255);
  for (size_t p = 0; p < size_t(w) * h; ++p)
    for (int ch = 0; ch < 3; ++ch) bytes[p * channels + ch] = uint8_t(std::lround(std::clamp(rgb[p * 3 + ch], 0.f, 1.f) * 255));
  return bytes;
}

}  // namespace

std::vector<uint8_t> displayFrame(const Film& film, bool signedData, const DisplaySettings& display) {
  std::vector<uint8_t> bytes = displayRgb(film, signedData, display);
  if (!display.legends.empty()) {
    const std::vector<uint8_t> strip = legendStrip(display, film.width(), 3);
    bytes.insert(bytes.end(), strip.begin(), strip.end());
  }
  return bytes;
}

namespace {

// An image as writeExr and writePng take it: `channels` interleaved channels of 8-bit values or
// floats, row by row, and their names (EXR's).
struct ImageToWrite {
  int width = 0, height = 0, channels = 0;
  std::vector<std::string> names;
  const uint8_t* bytes = nullptr;  // or
  const float* floats = nullptr;
};

// The local time as EXR's capDate wants it: "YYYY:MM:DD HH:MM:SS".
std::string nowStamp() {
  const std::time_t now = std::time(nullptr);
  std::tm local{};
  localtime_r(&now, &local);
  char text[32];
  std::strftime(text, sizeof text, "%Y:%m:%d %H:%M:%S", &local);
  return text;
}

// Float channels, zip-compressed scan lines, the metadata as string attributes (what OpenImageIO
// wrote before, written with OpenEXR itself); "" or the error.
std::string writeExr(const std::string& path, const ImageToWrite& p, const std::map<std::string, std::string>& metadata) {
  try {
    Imf::Header header(p.width, p.height);
    header.compression() = Imf::ZIP_COMPRESSION;
    for (const std::string& name : p.names) header.channels().insert(name, Imf::Channel(Imf::FLOAT));
    Imf::addCapDate(header, nowStamp());
    for (const auto& [key, value] : metadata) header.insert(key, Imf::StringAttribute(value));
    Imf::FrameBuffer frame;
    const size_t pixelBytes = sizeof(float) * size_t(p.channels);
    for (int c = 0; c < p.channels; ++c)
      frame.insert(p.names[size_t(c)], Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(const_cast<float*>(p.floats + c)),
                                                  pixelBytes, pixelBytes * size_t(p.width)));
    Imf::OutputFile file(path.c_str(), header);
    file.setFrameBuffer(frame);
    file.writePixels(p.height);
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

// libpng's error handler: the message kept for writePng (libpng's own would print it), then back
// to its setjmp. Warnings are dropped: the message of a failure is the error's.
constexpr size_t kPngMessage = 200;  // the room writePng gives the message
[[noreturn]] void pngError(png_structp png, png_const_charp message) {
  std::snprintf(static_cast<char*>(png_get_error_ptr(png)), kPngMessage, "%s", message);
  png_longjmp(png, 1);
}
void pngWarning(png_structp, png_const_charp) {}

// 8-bit RGB or RGBA with the metadata as text chunks and the sRGB chunk; "" or the error.
std::string writePng(const std::string& path, const ImageToWrite& p, const std::map<std::string, std::string>& metadata) {
  // (Everything with a destructor is made before setjmp: libpng's errors jump back past the rest.)
  std::vector<png_text> texts;
  for (const auto& [key, value] : metadata) {
    png_text t{};
    t.compression = PNG_TEXT_COMPRESSION_NONE;
    t.key = const_cast<char*>(key.c_str());
    t.text = const_cast<char*>(value.c_str());
    t.text_length = value.size();
    texts.push_back(t);
  }
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (!file) return std::string("cannot open the file: ") + std::strerror(errno);
  char message[kPngMessage] = "";
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, message, pngError, pngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  const char* volatile error = nullptr;  // (set after a longjmp: volatile)
  if (!png || !info) {
    error = "out of memory";
  } else if (setjmp(png_jmpbuf(png))) {
    error = message;
  } else {
    png_init_io(png, file);
    png_set_IHDR(png, info, png_uint_32(p.width), png_uint_32(p.height), 8,
                 p.channels == 4 ? PNG_COLOR_TYPE_RGB_ALPHA : PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_set_sRGB(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
    if (!texts.empty()) png_set_text(png, info, texts.data(), int(texts.size()));
    png_write_info(png, info);
    const size_t rowBytes = size_t(p.width) * size_t(p.channels);
    for (int y = 0; y < p.height; ++y) png_write_row(png, const_cast<png_bytep>(p.bytes + size_t(y) * rowBytes));
    png_write_end(png, info);
  }
  png_destroy_write_struct(png ? &png : nullptr, info ? &info : nullptr);
  const bool closed = std::fclose(file) == 0;
  if (error) return error;
  if (!closed) return std::string("cannot write the file: ") + std::strerror(errno);
  return "";
}

}  // namespace

void writeImage(const std::string& path, const Film& film, bool signedData,
                const std::map<std::string, std::string>& metadata, const DisplaySettings& display) {
  const ImageFormat format = imageFormatFor(path);
  const fs::path target(path);
  if (target.has_parent_path() && !fs::is_directory(target.parent_path()))
    throw InputError(path, "", "output directory does not exist");
  // Same extension: the same writer for the temporary file.
  const fs::path temp = target.parent_path() /
                        ("." + target.stem().string() + ".partial-" + std::to_string(getpid()) +
                         target.extension().string());
  const int w = film.width(), h = film.height();
  const bool exr = format == ImageFormat::Exr;
  // PNG and JPEG with legends: the image, then their strip below it.
  const int legendRows = exr ? 0 : kLegendHeight * int(display.legends.size());
  const bool alpha = !film.alpha().empty() && format != ImageFormat::Jpeg;
  int channels = alpha ? 4 : 3;
  std::vector<std::string> names = {"R", "G", "B"};
  if (alpha) names.push_back("A");
  if (exr)
    for (const Film::Layer& layer : film.layers())
      for (const std::string& c : layer.channels) {
        names.push_back(layer.name + "." + c);
        ++channels;
      }
  std::vector<float> floats;
  std::vector<uint8_t> bytes;
  if (exr) {
    floats.resize(size_t(w) * h * channels);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t pixel = size_t(y) * w + x;
        float* out = &floats[pixel * channels];
        for (int c = 0; c < 3; ++c) *out++ = film.at(x, y)[c];
        if (alpha) *out++ = film.alpha()[pixel];
        for (const Film::Layer& layer : film.layers())
          for (size_t c = 0; c < layer.channels.size(); ++c) *out++ = layer.data[pixel * layer.channels.size() + c];
      }
  } else {
    bytes.resize(size_t(w) * (h + legendRows) * channels);
    if (legendRows > 0) {
      const std::vector<uint8_t> strip = legendStrip(display, w, channels);
      std::copy(strip.begin(), strip.end(), bytes.begin() + std::ptrdiff_t(size_t(w) * h * channels));
    }
    const float scale = float(std::exp2(display.exposure));
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t pixel = size_t(y) * w + x;
        // PNG's alpha is straight: the premultiplied film is divided by the coverage.
        const float a = alpha ? film.alpha()[pixel] : 1.f;
        for (int c = 0; c < 3; ++c) {
          const float v = film.at(x, y)[c] / (a > 0 ? a : 1.f);
          bytes[pixel * channels + c] = displayByte(v, signedData, scale, display.tonemap);
        }
        if (alpha) bytes[pixel * channels + 3] = uint8_t(std::lround(std::clamp(a, 0.f, 1.f) * 255));
      }
  }
  ImageToWrite image;
  image.width = w;
  image.height = h + legendRows;
  image.channels = channels;
  image.names = names;
  image.floats = exr ? floats.data() : nullptr;
  image.bytes = exr ? nullptr : bytes.data();
  const std::string why = format == ImageFormat::Exr   ? writeExr(temp.string(), image, metadata)
                          : format == ImageFormat::Png ? writePng(temp.string(), image, metadata)
                                                       : imagePlugin().writeJpeg(temp.string(), bytes.data(), w,
                                                                                 h + legendRows, metadata);
  std::error_code ec;
  if (!why.empty()) {
    fs::remove(temp, ec);
    throw InputError(path, "", "cannot write image: " + why);
  }
  fs::rename(temp, target, ec);
  if (ec) {
    fs::remove(temp, ec);
    throw InputError(path, "", "cannot write image: " + ec.message());
  }
}

}  // namespace iso
