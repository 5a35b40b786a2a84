#include "renderer/film.h"

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
  throw InputError(path, "", "output must end in .exr or .png");
}

namespace {

float linearToSrgb(float v) {
  v = v > 0 ? std::min(v, 1.f) : 0.f;  // NaN and negatives to 0
  return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1 / 2.4f) - 0.055f;
}

}  // namespace

double Film::meanLuminance() const {
  double sum = 0;
  for (const Vec3f& p : m_pixels) sum += 0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z;
  return m_pixels.empty() ? 0 : sum / m_pixels.size();
}

void writeImage(const std::string& path, const Film& film, bool signedData,
                const std::map<std::string, std::string>& metadata) {
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
  int channels = 3;
  std::vector<std::string> names = {"R", "G", "B"};
  if (exr)
    for (const Film::Layer& layer : film.layers())
      for (const std::string& c : layer.channels) {
        names.push_back(layer.name + "." + c);
        ++channels;
      }
  OIIO::ImageSpec spec(w, h, channels, exr ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8);
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
        for (const Film::Layer& layer : film.layers())
          for (size_t c = 0; c < layer.channels.size(); ++c) *out++ = layer.data[pixel * layer.channels.size() + c];
      }
  } else {
    bytes.resize(size_t(w) * h * 3);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        for (int c = 0; c < 3; ++c) {
          const float v = film.at(x, y)[c];
          const float display = signedData ? std::clamp(0.5f * v + 0.5f, 0.f, 1.f) : linearToSrgb(v);
          bytes[(size_t(y) * w + x) * 3 + c] = uint8_t(std::lround(display * 255));
        }
  }
  auto out = OIIO::ImageOutput::create(temp.string());
  bool ok = out && out->open(temp.string(), spec);
  if (ok) {
    ok = format == ImageFormat::Exr ? out->write_image(OIIO::TypeDesc::FLOAT, floats.data())
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
