#pragma once
// The image being rendered (linear RGB, float) and how it reaches disk.
#include <map>
#include <string>
#include <vector>

#include "volume/vec3.h"

namespace iso {

class Film {
 public:
  Film(int width, int height) : m_width(width), m_height(height), m_pixels(size_t(width) * height) {}
  int width() const { return m_width; }
  int height() const { return m_height; }
  Vec3f& at(int x, int y) { return m_pixels[size_t(y) * m_width + x]; }
  const Vec3f& at(int x, int y) const { return m_pixels[size_t(y) * m_width + x]; }

 private:
  int m_width, m_height;
  std::vector<Vec3f> m_pixels;
};

enum class ImageFormat { Exr, Png };

// The format an output name asks for; InputError for anything else.
ImageFormat imageFormatFor(const std::string& path);

// EXR: linear float as rendered. PNG: 8-bit sRGB, clamped; signed data (normals) is mapped
// from [-1, 1] to [0, 1] instead. Written to a temporary file beside `path` and renamed, so
// a failure never leaves a truncated image behind.
void writeImage(const std::string& path, const Film& film, bool signedData,
                const std::map<std::string, std::string>& metadata);

}  // namespace iso
