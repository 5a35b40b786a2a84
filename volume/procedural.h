#pragma once
// Analytic test fields sampled on the grid points of [-1, 1]^3 (formulas: docs/scene-format.md).
#include <string>

#include "volume/grid.h"

namespace iso {

enum class Field { Sphere, Torus, Gyroid, MarschnerLobb, GyroidBall };

bool parseField(const std::string& name, Field& field);
double evalField(Field field, const Vec3d& p);
// A float32 grid of `resolution` samples per axis; origin (-1,-1,-1), spacing 2/(n-1).
Grid makeProceduralGrid(Field field, Vec3i resolution);

}  // namespace iso
