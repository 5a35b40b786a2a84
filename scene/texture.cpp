#include "scene/texture.h"

#include <zlib.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>

#include "scene/image_plugin.h"
#include "volume/input_error.h"
#include "volume/input_file.h"

namespace iso {

float srgbToLinear(float v) {
  return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f);
}

namespace {

int wrapIndex(int i, int n, TextureWrap wrap) {
  switch (wrap) {
    case TextureWrap::Clamp: return std::clamp(i, 0, n - 1);
    case TextureWrap::Mirror: {
      const int period = 2 * n;
      int k = ((i % period) + period) % period;
      return k < n ? k : period - 1 - k;
    }
    case TextureWrap::Repeat: break;
  }
  return ((i % n) + n) % n;
}

constexpr size_t kMaxTexels = size_t(1) << 25;

// Reads `name` (a file, or `size` bytes in memory whose format the name's extension says) as
// float RGBA, linearising sRGB 8-bit colour if asked.
// Errors name `shown`; one opening the image begins with `failure`.
void readImage(const std::string& name, const unsigned char* bytes, size_t size, const std::string& shown,
               const char* failure, bool srgb, std::vector<Vec4f>& texels, int& width, int& height) {
  std::string error;
  std::unique_ptr<ImageReader> in = imagePlugin().open(name, bytes, size, error);
  if (!in) throw InputError(shown, "", failure + error);
  width = in->width;
  height = in->height;
  const int channels = in->channels;
  // The memory budget of one image: 2^25 texels (e.g. 8192x4096) of float RGBA, 512 MiB, plus
  // the decoded channels while converting. Checked from the header, before decoding.
  if (width <= 0 || height <= 0 || channels <= 0 || channels > 16)
    throw InputError(shown, "", "image has an unusable size (" + std::to_string(width) + "x" + std::to_string(height) +
                                    ", " + std::to_string(channels) + " channels)");
  if (size_t(width) * size_t(height) > kMaxTexels)
    throw InputError(shown, "", "image of " + std::to_string(width) + "x" + std::to_string(height) +
                                    " is more than 2^25 texels (e.g. 8192x4096), the limit of one texture");
  std::vector<float> data(size_t(width) * height * channels);
  error = in->readFloats(data.data());
  if (!error.empty()) throw InputError(shown, "", "cannot decode image: " + error);
  const bool linearise = srgb && in->eightBit;
  texels.resize(size_t(width) * height);
  for (size_t i = 0; i < texels.size(); ++i) {
    const float* p = &data[i * channels];
    float c[4] = {p[0], channels > 1 ? p[1] : p[0], channels > 2 ? p[2] : p[0], 1};
    if (channels == 4) c[3] = p[3];
    if (channels == 2) c[3] = p[1];
    if (linearise)
      for (int k = 0; k < 3; ++k) c[k] = srgbToLinear(c[k]);
    for (int k = 0; k < 4; ++k)
      if (!std::isfinite(c[k])) throw InputError(shown, "pixel " + std::to_string(i), "value is not finite");
    texels[i] = {c[0], c[1], c[2], c[3]};
  }
}

}  // namespace

Vec4f Texture::lookup(float u, float v) const {
  if (m_texels.empty()) return {};
  const float fx = u * m_width - 0.5f, fy = v * m_height - 0.5f;
  if (m_nearest || !std::isfinite(fx) || !std::isfinite(fy)) {
    const float cx = std::isfinite(fx) ? std::floor(fx + 0.5f) : 0, cy = std::isfinite(fy) ? std::floor(fy + 0.5f) : 0;
    return texel(wrapIndex(int(std::fmod(cx, 1 << 24)), m_width, m_wrapS),
                 wrapIndex(int(std::fmod(cy, 1 << 24)), m_height, m_wrapT));
  }
  const float x0f = std::floor(fx), y0f = std::floor(fy);
  const float ax = fx - x0f, ay = fy - y0f;
  // fmod keeps the integer conversion defined for huge coordinates.
  const int x0 = int(std::fmod(x0f, float(1 << 24))), y0 = int(std::fmod(y0f, float(1 << 24)));
  const int xa = wrapIndex(x0, m_width, m_wrapS), xb = wrapIndex(x0 + 1, m_width, m_wrapS);
  const int ya = wrapIndex(y0, m_height, m_wrapT), yb = wrapIndex(y0 + 1, m_height, m_wrapT);
  auto mix = [](const Vec4f& a, const Vec4f& b, float t) {
    return Vec4f{a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t, a.z + (b.z - a.z) * t, a.w + (b.w - a.w) * t};
  };
  return mix(mix(texel(xa, ya), texel(xb, ya), ax), mix(texel(xa, yb), texel(xb, yb), ax), ay);
}

namespace {

// PNG chunks are checked before OpenImageIO sees them, and a copy without ICC profile goes on:
// every chunk lies inside the data; the compressed text chunks, which libpng inflates whole
// while reading the header, inflate to at most 16 MiB (the fuzzer found a 1.6 KB PNG that took
// 2.3 GB); the iCCP chunk is dropped (colour is sRGB or linear by glTF's rules anyway, and
// OpenImageIO 2.4's ICC parser reads past the end of a malformed profile: the fuzzer's crash).
std::vector<unsigned char> checkedPng(const std::vector<unsigned char>& png, const std::string& name) {
  std::vector<unsigned char> out(png.begin(), png.begin() + long(std::min<size_t>(8, png.size())));
  constexpr size_t kMaxInflated = size_t(16) << 20;
  size_t at = 8;
  while (at + 8 <= png.size()) {
    const size_t length = size_t(png[at]) << 24 | size_t(png[at + 1]) << 16 | size_t(png[at + 2]) << 8 | png[at + 3];
    const std::string type(png.begin() + long(at + 4), png.begin() + long(at + 8));
    if (length > png.size() - at - 8)
      throw InputError(name, "byte " + std::to_string(at), "PNG chunk '" + type + "' runs past the end of the image");
    if (type == "iCCP") {
      at += 12 + length;
      continue;
    }
    if (type == "zTXt" || type == "iTXt") {
      // Keyword, NUL, [iTXt: compression flag], compression method, then the zlib stream.
      const unsigned char* data = png.data() + at + 8;
      const unsigned char* nul = static_cast<const unsigned char*>(std::memchr(data, 0, length));
      size_t start = nul ? size_t(nul - data) + 2 : length;
      bool compressed = true;
      if (type == "iTXt") {
        compressed = nul && size_t(nul - data) + 1 < length && data[nul - data + 1] == 1;
        start += 1;
        // Language tag and translated keyword follow, each ended by a NUL.
        for (int k = 0; k < 2 && start < length; ++k) {
          const void* end = std::memchr(data + start, 0, length - start);
          start = end ? size_t(static_cast<const unsigned char*>(end) - data) + 1 : length;
        }
      }
      if (compressed && start < length) {
        z_stream zs{};
        if (inflateInit(&zs) != Z_OK) throw InputError(name, "", "zlib init failed");
        zs.next_in = const_cast<Bytef*>(data + start);
        zs.avail_in = uInt(length - start);
        unsigned char buffer[1 << 16];
        size_t produced = 0;
        int rc = Z_OK;
        while (rc == Z_OK && produced <= kMaxInflated) {
          zs.next_out = buffer;
          zs.avail_out = sizeof buffer;
          rc = inflate(&zs, Z_NO_FLUSH);
          produced += sizeof buffer - zs.avail_out;
          if (rc == Z_OK && zs.avail_out == sizeof buffer) break;  // no progress: input ended
        }
        inflateEnd(&zs);
        if (produced > kMaxInflated)
          throw InputError(name, "byte " + std::to_string(at), "PNG chunk '" + type + "' inflates to more than 16 MiB");
      }
    }
    const size_t end = std::min(png.size(), at + 12 + length);  // length, type, data, CRC
    out.insert(out.end(), png.begin() + long(at), png.begin() + long(end));
    at = end;
  }
  out.insert(out.end(), png.begin() + long(std::min(at, png.size())), png.end());
  return out;
}

}  // namespace

Texture Texture::decode(const std::vector<unsigned char>& encoded, const std::string& name, bool srgb,
                        TextureWrap wrapS, TextureWrap wrapT, bool nearest) {
  // The plugin's reader is picked by extension; the bytes say which one it is.
  std::string ext = ".png";
  if (encoded.size() >= 3 && encoded[0] == 0xFF && encoded[1] == 0xD8) ext = ".jpg";
  else if (!(encoded.size() >= 8 && encoded[0] == 0x89 && encoded[1] == 'P'))
    throw InputError(name, "", "image is neither PNG nor JPEG");
  const std::vector<unsigned char> bytes = ext == ".png" ? checkedPng(encoded, name) : encoded;
  Texture t;
  readImage("texture" + ext, bytes.data(), bytes.size(), name, "cannot decode image: ", srgb, t.m_texels, t.m_width, t.m_height);
  t.m_wrapS = wrapS;
  t.m_wrapT = wrapT;
  t.m_nearest = nearest;
  return t;
}

Texture Texture::fromTexels(int width, int height, std::vector<Vec4f> texels) {
  Texture t;
  t.m_width = width;
  t.m_height = height;
  t.m_texels = std::move(texels);
  t.m_wrapT = TextureWrap::Clamp;
  return t;
}

Texture Texture::loadFile(const std::string& path) {
  // A PNG is read from memory after the checks textures get (the magic decides, not the name).
  std::vector<unsigned char> png;
  checkInputFile(path, "image", false);
  {
    std::ifstream file(path, std::ios::binary);
    char magic[8] = {0};
    if (file.read(magic, 8) && std::memcmp(magic, "\x89PNG\r\n\x1a\n", 8) == 0) {
      file.seekg(0);
      png = checkedPng(std::vector<unsigned char>((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>()), path);
    }
  }
  Texture t;
  if (png.empty()) readImage(path, nullptr, 0, path, "cannot read image: ", true, t.m_texels, t.m_width, t.m_height);
  else readImage("environment.png", png.data(), png.size(), path, "cannot read image: ", true, t.m_texels, t.m_width, t.m_height);
  t.m_wrapS = TextureWrap::Repeat;
  t.m_wrapT = TextureWrap::Clamp;
  return t;
}

}  // namespace iso
