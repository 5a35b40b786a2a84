#pragma once
// Colour maps for colouring surfaces by data (scene key "color_by", docs/scene-format.md):
// the named maps of matplotlib and ParaView, or a user's list of stops. Colours are defined in
// sRGB, as those tools publish them, and rendered in linear light.
#include <string>
#include <vector>

#include "volume/vec3.h"

namespace iso {

class ColorMap {
 public:
  struct Stop {
    float position;  // in [0, 1] over the mapped range; strictly rising along a map
    Vec3f color;     // sRGB, each channel in [0, 1]
  };
  // A built-in map by name (false if there is none of that name).
  static bool named(const std::string& name, ColorMap& map);
  static const char* list();  // the built-in names, comma-separated
  static std::vector<std::string> names();
  // A user's map: stops rising strictly from position 0 to 1 (the caller checks).
  static ColorMap fromStops(std::vector<Stop> stops);

  // The colour at x in [0, 1] (outside: the end colours; NaN: the first), in sRGB and linear.
  Vec3f srgb(float x) const;
  Vec3f linear(float x) const;
  // The linear colour of `value` mapped over [lo, hi] (lo < hi).
  Vec3f linear(double value, double lo, double hi) const { return linear(float((value - lo) / (hi - lo))); }
  const std::string& name() const { return m_name; }
  bool empty() const { return m_stops.empty(); }

 private:
  std::vector<Stop> m_stops;
  std::string m_name;
};

}  // namespace iso
