#include "volume/procedural.h"

#include <tbb/parallel_for.h>

#include <memory>

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

Vec3d proceduralSpacing(Vec3i n) { return {2.0 / (n.x - 1), 2.0 / (n.y - 1), 2.0 / (n.z - 1)}; }

namespace {

// Samples [first, first + extent) into `out` (x fastest), layers in parallel.
void sampleBox(Field field, Vec3i n, Vec3i first, Vec3i extent, float* out) {
  const Vec3d s = proceduralSpacing(n);
  tbb::parallel_for(0, extent.z, [&](int k) {
    const int z = first.z + k;
    float* v = out + size_t(k) * size_t(extent.y) * size_t(extent.x);
    for (int y = first.y; y < first.y + extent.y; ++y)
      for (int x = first.x; x < first.x + extent.x; ++x)
        *v++ = float(evalField(field, {-1 + x * s.x, -1 + y * s.y, -1 + z * s.z}));
  });
}
}  // namespace

Grid makeProceduralGrid(Field field, Vec3i n) {
  std::vector<float> v(size_t(n.x) * n.y * n.z);
  sampleBox(field, n, {0, 0, 0}, n, v.data());
  return Grid(n, std::move(v), {-1, -1, -1}, proceduralSpacing(n));
}

Grid makeProceduralWindow(Field field, Vec3i n, Vec3i first, Vec3i extent) {
  std::shared_ptr<float[]> v(new float[size_t(extent.x) * extent.y * extent.z]);
  sampleBox(field, n, first, extent, v.get());
  return Grid(n, ScalarType::Float32, std::shared_ptr<const void>(v, v.get()), first, extent, {-1, -1, -1}, proceduralSpacing(n));
}

BrickGrid proceduralBrickRanges(Field field, Vec3i n) {
  std::vector<float> layers;
  return BrickGrid::fromLayers(n, [&](int z0, int z1) -> const float* {
    layers.resize(size_t(z1 - z0 + 1) * size_t(n.x) * size_t(n.y));
    sampleBox(field, n, {0, 0, z0}, {n.x, n.y, z1 - z0 + 1}, layers.data());
    return layers.data();
  });
}

}  // namespace iso
