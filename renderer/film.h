#pragma once
// The image being rendered (linear RGB, float), its extra layers (AOVs), and how it reaches
// disk.
#include <cstdint>
#include <deque>
#include <map>
#include <string>
#include <vector>

#include "volume/vec3.h"

#include "scene/colormap.h"

namespace iso {

class Film {
 public:
  // One named layer of 1 or 3 channels, written to EXR as "<name>.R/G/B" or "<name>.Z".
  struct Layer {
    std::string name;
    std::vector<std::string> channels;
    std::vector<float> data;  // channels.size() per pixel
  };

  Film(int width, int height) : m_width(width), m_height(height), m_pixels(size_t(width) * height) {}
  int width() const { return m_width; }
  int height() const { return m_height; }
  Vec3f& at(int x, int y) { return m_pixels[size_t(y) * m_width + x]; }
  const Vec3f& at(int x, int y) const { return m_pixels[size_t(y) * m_width + x]; }
  // The main layer, row by row.
  std::vector<Vec3f>& pixels() { return m_pixels; }
  const std::vector<Vec3f>& pixels() const { return m_pixels; }
  // The reference stays valid when more layers are added (a deque never moves its elements on
  // push_back; a vector did, and two AOVs wrote through a dangling reference).
  Layer& addLayer(const std::string& name, std::vector<std::string> channels) {
    m_layers.push_back({name, std::move(channels), {}});
    m_layers.back().data.assign(size_t(m_width) * m_height * m_layers.back().channels.size(), 0.f);
    return m_layers.back();
  }
  const std::deque<Layer>& layers() const { return m_layers; }
  std::deque<Layer>& layers() { return m_layers; }
  // Mean of the Rec. 709 luminance of the main layer.
  double meanLuminance() const;
  // Coverage: per pixel the share of camera samples that hit something (empty: not kept).
  // With it the main layer holds no background (premultiplied by the coverage).
  std::vector<float>& alpha() { return m_alpha; }
  const std::vector<float>& alpha() const { return m_alpha; }

 private:
  int m_width, m_height;
  std::vector<Vec3f> m_pixels;
  std::deque<Layer> m_layers;
  std::vector<float> m_alpha;
};

enum class ImageFormat { Exr, Png, Jpeg };

// How linear radiance becomes an 8-bit image (PNG, JPEG); EXR stays linear, untouched.
enum class Tonemap { Clamp, Aces, Filmic };
// A colour bar under a PNG or JPEG (--colorbar): the map, its range's end values, the field's name.
struct Legend {
  std::string title;
  ColorMap map;
  double lo = 0, hi = 1;
};

struct DisplaySettings {
  double exposure = 0;  // EV: radiance times 2^exposure before the curve
  Tonemap tonemap = Tonemap::Clamp;
  std::vector<Legend> legends;  // drawn in a strip below the image, one bar each
  std::string font;             // the legends' TrueType font (legendFont())
};
// The font legends are written in (DejaVu Sans, Debian's fonts-dejavu-core); empty if absent.
std::string legendFont();
// "clamp", "aces", "filmic"; false if unknown.
bool parseTonemap(const std::string& name, Tonemap& tonemap);
const char* tonemapName(Tonemap tonemap);
// Linear radiance (after exposure) to display-linear [0, 1] by the curve.
float applyTonemap(float v, Tonemap tonemap);

// The format an output name asks for; InputError for anything else.
ImageFormat imageFormatFor(const std::string& path);

// global - direct, pixel by pixel (the `compare` integrator's indirect image).
Film indirectOf(const Film& global, const Film& direct);

// The main layer as 8-bit sRGB, 3 bytes per pixel, row by row: what PNG and JPEG show.
std::vector<uint8_t> displayRgb(const Film& film, bool signedData, const DisplaySettings& display = {});

// What a video frame shows: displayRgb's image with the legends' strip below it (as PNG), 3 bytes
// per pixel, width film.width().
std::vector<uint8_t> displayFrame(const Film& film, bool signedData, const DisplaySettings& display);

// EXR: linear float as rendered, with every extra layer, and an "A" channel when the film has
// coverage (premultiplied, OpenEXR's convention). PNG and JPEG: 8-bit sRGB of the main layer
// after `display`; signed data (normals) is mapped from [-1, 1] to [0, 1] instead; PNG gets an
// alpha channel when the film has coverage (straight, PNG's convention; JPEG has none).
// Written to a temporary file beside `path` and renamed, so a failure never leaves a
// truncated image.
void writeImage(const std::string& path, const Film& film, bool signedData,
                const std::map<std::string, std::string>& metadata, const DisplaySettings& display = {});

}  // namespace iso
