#pragma once
// Decoded images for materials and environment lights: linear RGBA float, bilinear lookup.
#include <string>
#include <vector>

#include "scene/gltf.h"

namespace iso {

// The sRGB transfer function undone: an encoded value in [0, 1] to linear light.
float srgbToLinear(float v);

struct Vec4f {
  float x = 0, y = 0, z = 0, w = 1;
  Vec3f rgb() const { return {x, y, z}; }
};

class Texture {
 public:
  Texture() = default;
  int width() const { return m_width; }
  int height() const { return m_height; }
  // (u, v) with v = 0 at the top row, as glTF defines texture coordinates.
  Vec4f lookup(float u, float v) const;
  const Vec4f& texel(int x, int y) const { return m_texels[size_t(y) * m_width + x]; }

  // `srgb`: 8-bit colour data is sRGB-encoded and is linearised (glTF base colour and
  // emissive textures); data textures (metallic-roughness, normal) are read as they are.
  static Texture decode(const std::vector<unsigned char>& encoded, const std::string& name, bool srgb,
                        TextureWrap wrapS = TextureWrap::Repeat, TextureWrap wrapT = TextureWrap::Repeat,
                        bool nearest = false);
  static Texture fromTexels(int width, int height, std::vector<Vec4f> texels);
  // A float image file (EXR, HDR, ...) for an environment light; InputError on failure.
  static Texture loadFile(const std::string& path);

 private:
  int m_width = 0, m_height = 0;
  std::vector<Vec4f> m_texels;
  TextureWrap m_wrapS = TextureWrap::Repeat, m_wrapT = TextureWrap::Repeat;
  bool m_nearest = false;
};

}  // namespace iso
