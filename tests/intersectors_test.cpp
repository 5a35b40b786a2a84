#include <gtest/gtest.h>

#include <random>

#include "accuracy/accuracy.h"
#include "tests/test_util.h"
#include "volume/loaders.h"
#include "volume/procedural.h"

namespace iso {
namespace {

// A segment from corner values (iso already subtracted) and its local end points, with
// the end values computed the way the traversal computes them.
template <typename Real>
CellSegment<Real> makeSegment(const Real g[8], Vec3<Real> a, Vec3<Real> b) {
  CellSegment<Real> seg;
  for (int c = 0; c < 8; ++c) seg.g[c] = g[c];
  seg.a = a;
  seg.b = b;
  seg.f0 = trilinear(seg.g, seg.a);
  seg.f1 = trilinear(seg.g, seg.b);
  return seg;
}

// A cell whose value is low at two opposite corners and high elsewhere: along the main
// diagonal f(s) = 50 - 100((1-s)^3 + s^3) (iso 50 subtracted), negative at both ends and
// positive in the middle. The ray enters and leaves outside but crosses twice, at
// s = (3 - sqrt(3)) / 6 and its mirror image.
CellSegment<float> doubleCrossingCell() {
  float g[8];
  for (int c = 0; c < 8; ++c) g[c] = (c == 0 || c == 7) ? 0.f - 50.f : 100.f - 50.f;
  return makeSegment<float>(g, {0, 0, 0}, {1, 1, 1});
}

TEST(Intersectors, LinearAndNeubauerMissADoubleCrossingIsolationFindsIt) {
  const CellSegment<float> seg = doubleCrossingCell();
  ASSERT_LT(seg.f0, 0);
  ASSERT_LT(seg.f1, 0);
  Root<float> root;
  EXPECT_FALSE(LinearIntersector{}.first(seg, root));
  EXPECT_FALSE(NeubauerIntersector{3}.first(seg, root));
  EXPECT_FALSE(NeubauerIntersector{8}.first(seg, root));
  EXPECT_FALSE(LinearIntersector{}.any(seg));
  const double expected = (3 - std::sqrt(3.0)) / 6;
  ASSERT_TRUE(IsolationIntersector{8}.first(seg, root));
  EXPECT_NEAR(root.s, expected, 1e-6);
  EXPECT_LE(std::fabs(root.s - expected), root.sError);
  EXPECT_TRUE(IsolationIntersector{}.any(seg));

  double gD[8];
  for (int c = 0; c < 8; ++c) gD[c] = seg.g[c];
  const CellSegment<double> segD = makeSegment<double>(gD, {0, 0, 0}, {1, 1, 1});
  Root<double> ref;
  ASSERT_TRUE(ReferenceIntersector{}.first(segD, ref));
  EXPECT_FALSE(ref.tangent);
  EXPECT_NEAR(ref.s, expected, 1e-14);
}

TEST(Intersectors, ReferenceReportsTangentRoots) {
  // Lower the same cell until its maximum along the diagonal (f = 25 at s = 0.5 with iso 50)
  // just touches zero: iso 75 puts the maximum exactly on the surface.
  double g[8];
  for (int c = 0; c < 8; ++c) g[c] = ((c == 0 || c == 7) ? 0.0 : 100.0) - 75.0;
  const CellSegment<double> seg = makeSegment<double>(g, {0, 0, 0}, {1, 1, 1});
  Root<double> root;
  ASSERT_TRUE(ReferenceIntersector{}.first(seg, root));
  EXPECT_TRUE(root.tangent);
  EXPECT_NEAR(root.s, 0.5, 1e-12);
  EXPECT_FALSE(ReferenceIntersector{}.any(seg)) << "a touch does not occlude";
}

TEST(Intersectors, SchwarzeSolvesAWellConditionedCubic) {
  // (s - 0.2)(s - 0.5)(s - 0.9): the analytic solver is exact when c3 is well away from 0.
  const float c[4] = {-0.09f, 0.73f, -1.6f, 1.f};
  float r[3];
  ASSERT_EQ(SchwarzeIntersector::solveCubic(c, r), 3);
  std::sort(r, r + 3);
  EXPECT_NEAR(r[0], 0.2f, 1e-5f);
  EXPECT_NEAR(r[1], 0.5f, 1e-5f);
  EXPECT_NEAR(r[2], 0.9f, 1e-5f);
}

TEST(Intersectors, SchwarzeFailsOnAxisParallelRays) {
  // Along an axis the trilinear field is linear: c3 = c2 = 0 and the published solver
  // divides by zero. It finds nothing where every other intersector finds the crossing.
  float g[8];
  for (int c = 0; c < 8; ++c) g[c] = (c & 1) ? 10.f : -10.f;
  const CellSegment<float> seg = makeSegment<float>(g, {0, 0.3f, 0.6f}, {1, 0.3f, 0.6f});
  Root<float> root;
  EXPECT_FALSE(SchwarzeIntersector{}.first(seg, root));
  ASSERT_TRUE(IsolationIntersector{}.first(seg, root));
  EXPECT_NEAR(root.s, 0.5f, 1e-6f);
  ASSERT_TRUE(LinearIntersector{}.first(seg, root));
  EXPECT_NEAR(root.s, 0.5f, 1e-6f);
}

TEST(Intersectors, IsolationAgreesWithReferenceOnRandomCells) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> value(-1, 1), unit(0, 1);
  int compared = 0;
  for (int trial = 0; trial < 200000; ++trial) {
    CellSegment<float> seg;
    CellSegment<double> segD;
    for (int c = 0; c < 8; ++c) segD.g[c] = seg.g[c] = value(rng);
    seg.a = {unit(rng), unit(rng), unit(rng)};
    seg.b = {unit(rng), unit(rng), unit(rng)};
    segD.a = Vec3d(seg.a);
    segD.b = Vec3d(seg.b);
    seg.f0 = trilinear(seg.g, seg.a);
    seg.f1 = trilinear(seg.g, seg.b);
    segD.f0 = trilinear(segD.g, segD.a);
    segD.f1 = trilinear(segD.g, segD.b);
    Root<double> ref;
    Root<float> got;
    const bool refHit = ReferenceIntersector{}.first(segD, ref) && !ref.tangent;
    const bool hit = IsolationIntersector{}.first(seg, got);
    if (!refHit) {
      // Only a crossing within rounding of tangency may be seen by float alone.
      if (hit) {
        EXPECT_GT(got.sError, 1e-4) << "false hit with a tight bound, trial " << trial;
      }
      continue;
    }
    ASSERT_TRUE(hit) << "isolation missed a crossing at s = " << ref.s << ", trial " << trial;
    EXPECT_LE(std::fabs(got.s - ref.s), got.sError + 1e-6) << "trial " << trial;
    ++compared;
  }
  EXPECT_GT(compared, 50000);
}

// Near-tangent passes: segments whose cubic (of the float segment, in double) has an extremum
// 1e-9 to 1e-5 of the corners' magnitude (log-uniform) from zero, on either side. Float alone
// decides many of them by rounding (the value at the extremum is within its evaluation error of zero); the
// isolation intersector then decides in double (detail::unprovenExtremum, firstInDouble) and
// agrees with the reference on the same segment on every one.
TEST(Intersectors, IsolationDecidesNearTangentPassesAsTheReference) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> value(-1, 1), unit(0, 1), exponent(-9, -5);
  int tested = 0, floatAloneWrong = 0;
  for (int trial = 0; trial < 100000 && tested < 20000; ++trial) {
    CellSegment<float> seg;
    for (int c = 0; c < 8; ++c) seg.g[c] = float(value(rng));
    seg.a = {float(unit(rng)), float(unit(rng)), float(unit(rng))};
    seg.b = {float(unit(rng)), float(unit(rng)), float(unit(rng))};
    // Shift the corners so that the double cubic's first interior extremum sits just off zero.
    CellSegment<double> wide;
    auto widen = [&] {
      for (int c = 0; c < 8; ++c) wide.g[c] = seg.g[c];
      wide.a = Vec3d(seg.a);
      wide.b = Vec3d(seg.b);
    };
    widen();
    const Cubic<double> cubic = cellCubic(wide);
    double e[2];
    if (detail::quadraticRootsInUnit(cubic.c[1], 2 * cubic.c[2], 3 * cubic.c[3], e) == 0) continue;
    double scale = 0;
    for (double g : wide.g) scale += std::fabs(g);
    const double shift = cubic(e[0]) + (rng() % 2 ? 1 : -1) * std::pow(10.0, exponent(rng)) * scale;
    for (int c = 0; c < 8; ++c) seg.g[c] = float(seg.g[c] - shift);
    seg.f0 = trilinear(seg.g, seg.a);
    seg.f1 = trilinear(seg.g, seg.b);
    if (seg.f0 == 0 || seg.f1 == 0) continue;
    widen();
    wide.f0 = seg.f0;
    wide.f1 = seg.f1;
    Root<double> ref;
    const bool refHit = ReferenceIntersector{}.first(wide, ref);
    ASSERT_FALSE(refHit && ref.tangent) << "trial " << trial;  // 1e-9 off zero is no touch in double
    Root<float> got;
    const bool hit = IsolationIntersector{}.first(seg, got);
    ++tested;
    // What float alone would say: the first piece between the float extrema whose ends differ.
    const Cubic<float> fc = cellCubic(seg);
    float s[4], f[4];
    const int n = detail::isolate(seg, fc, s, f);
    bool floatHit = false;
    for (int i = 0; i + 1 < n && !floatHit; ++i) floatHit = isInside(f[i]) != isInside(f[i + 1]);
    floatAloneWrong += floatHit != refHit;
    ASSERT_EQ(hit, refHit) << "trial " << trial;
    ASSERT_EQ(IsolationIntersector{}.any(seg), refHit) << "trial " << trial;
    if (hit) {
      EXPECT_LE(std::fabs(got.s - ref.s), got.sError + 1e-6) << "trial " << trial;
    }
  }
  EXPECT_GT(tested, 10000);
  EXPECT_GT(floatAloneWrong, tested / 100);  // the cases are hard: float alone decides many wrongly
}

// Whole rays through real volumes and procedural fields, against the reference.
struct VolumeCase {
  const char* name;
  double iso;
};

void PrintTo(const VolumeCase& c, std::ostream* os) { *os << c.name << " iso " << c.iso; }

class RealVolumeAccuracy : public ::testing::TestWithParam<VolumeCase> {};

Grid loadCase(const std::string& name) {
  if (name == "gyroid") return makeProceduralGrid(Field::Gyroid, {48, 48, 48});
  if (name == "marschner_lobb") return makeProceduralGrid(Field::MarschnerLobb, {41, 41, 41});
  return loadVolumeFile(test::dataPath("volumes/" + name));
}

TEST_P(RealVolumeAccuracy, IsolationNeverMissesAndStaysWithinItsBound) {
  const Grid grid = loadCase(GetParam().name);
  for (RayKind kind : {RayKind::Camera, RayKind::Secondary}) {
    const AccuracyReport r = measureAccuracy(grid, GetParam().iso, {IntersectorKind::Isolation, 8},
                                             kind, 20000, 17);
    EXPECT_GT(r.referenceHits, 2000u);
    EXPECT_EQ(r.misses, 0u);
    EXPECT_EQ(r.falseHits, 0u);
    EXPECT_LT(r.p99Dt, 1e-4) << "|dt| in cells, 99th percentile";
    EXPECT_LT(r.maxDt, 1e-2);
  }
}

TEST_P(RealVolumeAccuracy, LinearIsLessAccurateThanIsolation) {
  const Grid grid = loadCase(GetParam().name);
  const AccuracyReport lin = measureAccuracy(grid, GetParam().iso, {IntersectorKind::Linear, 0},
                                             RayKind::Camera, 20000, 17);
  const AccuracyReport isol = measureAccuracy(grid, GetParam().iso,
                                              {IntersectorKind::Isolation, 8}, RayKind::Camera, 20000, 17);
  EXPECT_GT(lin.p99Dt, 100 * isol.p99Dt);
}

INSTANTIATE_TEST_SUITE_P(
    Volumes, RealVolumeAccuracy,
    ::testing::Values(VolumeCase{"nucleon/nucleon.nrrd", 60}, VolumeCase{"neghip_64x64x64_uint8.raw", 40.5},
                      VolumeCase{"bucky_32x32x32_uint8.raw", 128}, VolumeCase{"HeadMRVolume.mhd", 70},
                      VolumeCase{"gyroid", 0}, VolumeCase{"marschner_lobb", 0.5}),
    [](const auto& info) {
      std::string n = info.param.name;
      return n.substr(0, n.find_first_of("_./"));
    });

}  // namespace
}  // namespace iso
