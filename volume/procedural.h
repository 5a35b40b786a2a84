#pragma once
// Analytic test fields sampled on the grid points of [-1, 1]^3 (formulas: docs/scene-format.md).
#include <string>

#include "volume/bricks.h"
#include "volume/grid.h"

namespace iso {

enum class Field { Sphere, Torus, Gyroid, MarschnerLobb, GyroidBall };

bool parseField(const std::string& name, Field& field);
double evalField(Field field, const Vec3d& p);
// A float32 grid of `resolution` samples per axis; origin (-1,-1,-1), spacing 2/(n-1).
// A procedural grid spans [-1, 1] on each axis: its origin is (-1, -1, -1) and its spacing this.
Vec3d proceduralSpacing(Vec3i resolution);
Grid makeProceduralGrid(Field field, Vec3i resolution);
// The samples [first, first + extent) of that grid only (a data-parallel rank's window, Grid's
// window constructor): the same values, the whole grid's placement.
Grid makeProceduralWindow(Field field, Vec3i resolution, Vec3i first, Vec3i extent);
// The value range of every brick of that grid (BrickGrid), each sample evaluated once and none
// kept: what a data-parallel rank needs to split the grid before it makes its window.
BrickGrid proceduralBrickRanges(Field field, Vec3i resolution);

}  // namespace iso
