#include "renderer/film.h"

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <stdexcept>
#include <unistd.h>

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
  OIIO::ImageBuf strip(OIIO::ImageSpec(w, h, 3, OIIO::TypeDesc::FLOAT));
  const float ground[3] = {0.08f, 0.08f, 0.08f};
  OIIO::ImageBufAlgo::fill(strip, ground);
  const int margin = std::max(4, w / 40);
  const int size = std::clamp(w / 40, 9, 16);
  for (size_t k = 0; k < display.legends.size(); ++k) {
    const Legend& l = display.legends[k];
    const int top = int(k) * kLegendHeight + 4;
    for (int x = margin; x < w - margin; ++x) {
      const Vec3f c = l.map.srgb(float(x - margin) / float(std::max(1, w - 2 * margin - 1)));
      const float rgb[3] = {c.x, c.y, c.z};
      for (int y = top; y < top + 12; ++y) strip.setpixel(x, y, rgb, 3);
    }
    const float white[3] = {0.92f, 0.92f, 0.92f};
    char lo[32], hi[32];
    std::snprintf(lo, sizeof lo, "%.4g", l.lo);
    std::snprintf(hi, sizeof hi, "%.4g", l.hi);
    const int baseline = top + 14 + size;
    bool ok = OIIO::ImageBufAlgo::render_text(strip, margin, baseline, lo, size, display.font, white);
    ok = ok && OIIO::ImageBufAlgo::render_text(strip, w - margin, baseline, hi, size, display.font, white,
                                               OIIO::ImageBufAlgo::TextAlignX::Right);
    ok = ok && OIIO::ImageBufAlgo::render_text(strip, w / 2, baseline, l.title, size, display.font, white,
                                               OIIO::ImageBufAlgo::TextAlignX::Center);
    if (!ok) throw InputError("--colorbar", "", "cannot draw the legend's text: " + strip.geterror());
  }
  std::vector<uint8_t> bytes(size_t(w) * h * channels, 255);
  std::vector<float> rgb(size_t(w) * h * 3);
  strip.get_pixels(strip.roi(), OIIO::TypeDesc::FLOAT, rgb.data());
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

void writeImage(const std::string& path, const Film& film, bool signedData,
                const std::map<std::string, std::string>& metadata, const DisplaySettings& display) {
  const ImageFormat format = imageFormatFor(path);
  const fs::path target(path);
  if (target.has_parent_path() && !fs::is_directory(target.parent_path()))
    throw InputError(path, "", "output directory does not exist");
  // Same extension, so OpenImageIO picks the same writer for the temporary file.
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
  OIIO::ImageSpec spec(w, h + legendRows, channels, exr ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8);
  spec.channelnames = names;
  for (const auto& [key, value] : metadata) spec.attribute(key, value);
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
    if (alpha) spec.alpha_channel = 3;
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
  auto out = OIIO::ImageOutput::create(temp.string());
  bool ok = out && out->open(temp.string(), spec);
  if (ok) {
    ok = exr ? out->write_image(OIIO::TypeDesc::FLOAT, floats.data())
                                    : out->write_image(OIIO::TypeDesc::UINT8, bytes.data());
    ok = out->close() && ok;
  }
  std::error_code ec;
  if (!ok) {
    const std::string why = out ? out->geterror() : OIIO::geterror();
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
