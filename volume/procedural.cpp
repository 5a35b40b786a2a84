#include "volume/procedural.h"

#include <cmath>

namespace iso {

bool parseField(const std::string& name, Field& field) {
  if (name == "sphere") field = Field::Sphere;
  else if (name == "torus") field = Field::Torus;
  else if (name == "gyroid") field = Field::Gyroid;
  else if (name == "marschner_lobb") field = Field::MarschnerLobb;
  else if (name == "gyroid_ball") field = Field::GyroidBall;
  else return false;
  return true;
}

double evalField(Field field, const Vec3d& p) {
  switch (field) {
    case Field::Sphere: return length(p);
    case Field::Torus: {
      const double r = std::sqrt(p.x * p.x + p.z * p.z) - 0.6;
      return std::sqrt(r * r + p.y * p.y);
    }
    case Field::Gyroid: {
      const double k = 3 * M_PI;
      return std::sin(k * p.x) * std::cos(k * p.y) + std::sin(k * p.y) * std::cos(k * p.z) +
             std::sin(k * p.z) * std::cos(k * p.x);
    }
    case Field::GyroidBall: {
      // The gyroid cut to a ball of radius 0.9: the solids below 0 of both, intersected (max).
      // The distance term is scaled by k so that both have about the same slope at 0.
      const double k = 3 * M_PI;
      return std::max(evalField(Field::Gyroid, p), k * (length(p) - 0.9));
    }
    case Field::MarschnerLobb: {
      // Marschner & Lobb 1994, "An evaluation of reconstruction filters for volume rendering".
      const double fM = 6, alpha = 0.25;
      const double r = std::sqrt(p.x * p.x + p.y * p.y);
      const double rho = std::cos(2 * M_PI * fM * std::cos(M_PI * r / 2));
      return (1 - std::sin(M_PI * p.z / 2) + alpha * (1 + rho)) / (2 * (1 + alpha));
    }
  }
  return 0;
}

Grid makeProceduralGrid(Field field, Vec3i n) {
  std::vector<float> v(size_t(n.x) * n.y * n.z);
  const Vec3d spacing{2.0 / (n.x - 1), 2.0 / (n.y - 1), 2.0 / (n.z - 1)};
  size_t i = 0;
  for (int z = 0; z < n.z; ++z)
    for (int y = 0; y < n.y; ++y)
      for (int x = 0; x < n.x; ++x)
        v[i++] = float(evalField(field, {-1 + x * spacing.x, -1 + y * spacing.y, -1 + z * spacing.z}));
  return Grid(n, std::move(v), {-1, -1, -1}, spacing);
}

}  // namespace iso
