#include <gtest/gtest.h>

#include <random>

#include "volume/cell_cubic.h"

namespace iso {
namespace {

// The cubic's coefficients reproduce direct trilinear evaluation along the segment.
template <typename Real>
void checkCubic(Real tolerance) {
  std::mt19937 rng(1234);
  std::uniform_real_distribution<double> value(-100, 100), unit(0, 1);
  double worst = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    CellSegment<Real> seg;
    for (Real& g : seg.g) g = Real(value(rng));
    seg.a = Vec3<Real>(Vec3d{unit(rng), unit(rng), unit(rng)});
    seg.b = Vec3<Real>(Vec3d{unit(rng), unit(rng), unit(rng)});
    const Cubic<Real> cubic = cellCubic(seg);
    for (int k = 0; k < 5; ++k) {
      const Real s = Real(unit(rng));
      const Real direct = trilinear(seg.g, seg.a + (seg.b - seg.a) * s);
      worst = std::max(worst, double(std::fabs(cubic(s) - direct)));
    }
  }
  EXPECT_LT(worst, tolerance) << "largest |cubic - trilinear| over 1e5 points";
}

TEST(Cubic, MatchesTrilinearInDouble) { checkCubic<double>(1e-11); }
TEST(Cubic, MatchesTrilinearInFloat) { checkCubic<float>(2e-4f); }

TEST(Cubic, LerpIsExactAtFacesAndKeepsSignClass) {
  EXPECT_EQ(lerp(3.7f, -1.25f, 0.f), 3.7f);
  EXPECT_EQ(lerp(3.7f, -1.25f, 1.f), -1.25f);
  // Corners all on one side never interpolate to the other: the skip test is exact.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> v(-1e-3f, 0.f), t(0, 1);
  for (int i = 0; i < 100000; ++i) {
    float g[8];
    for (float& x : g) x = v(rng);
    EXPECT_LE(trilinear(g, Vec3f{t(rng), t(rng), t(rng)}), 0.f);
  }
}

TEST(Cubic, GradientMatchesFiniteDifferences) {
  std::mt19937 rng(99);
  std::uniform_real_distribution<double> value(-10, 10), unit(0.1, 0.9);
  for (int trial = 0; trial < 1000; ++trial) {
    double g[8];
    for (double& x : g) x = value(rng);
    const Vec3d p{unit(rng), unit(rng), unit(rng)};
    const Vec3d grad = trilinearGradient(g, p);
    for (int a = 0; a < 3; ++a) {
      Vec3d lo = p, hi = p;
      lo[a] -= 1e-6;
      hi[a] += 1e-6;
      EXPECT_NEAR(grad[a], (trilinear(g, hi) - trilinear(g, lo)) / 2e-6, 1e-6);
    }
  }
}

}  // namespace
}  // namespace iso
