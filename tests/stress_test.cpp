// The numerical stress suite (accuracy/stress.h), one named test per case: `isolation` has no
// misses, wrong roots, NaNs or parity errors; where the other intersectors fail by design
// (docs/BENCHMARKS.md explains why), the tests assert that the failure shows.
#include <gtest/gtest.h>

#include <map>

#include "accuracy/stress.h"

namespace iso {
namespace {

const StressCase& stressCase(const std::string& name) {
  static const std::vector<StressCase> cases = stressCases();
  for (const StressCase& c : cases)
    if (c.name == name) return c;
  throw std::runtime_error("no stress case " + name);
}

StressResult run(const std::string& name, const char* intersector) {
  IntersectorSpec spec;
  std::string error;
  if (!parseIntersector(intersector, spec, error)) throw std::runtime_error(error);
  return runStress(stressCase(name), spec);
}

void expectIsolationClean(const std::string& name) {
  for (const char* spec : {"isolation", "reference"}) {
    const StressResult r = run(name, spec);
    EXPECT_EQ(r.misses, 0u) << spec;
    EXPECT_EQ(r.wrongRoots, 0u) << spec;
    EXPECT_EQ(r.nans, 0u) << spec;
    EXPECT_EQ(r.parityErrors, 0u) << spec;
  }
  // No intersector produces NaNs on well-formed data, and none crashes (we got here).
  for (const char* spec : {"linear", "neubauer", "schwarze", "isolation:1"}) EXPECT_GE(run(name, spec).rays, 1u);
}

TEST(Stress, Tangent) { expectIsolationClean("tangent"); }

TEST(Stress, TwoCrossingsInACell) {
  expectIsolationClean("two_crossings_in_a_cell");
  // Entry and exit are outside: linear interpolation and plain regula falsi see nothing.
  for (const char* spec : {"linear", "neubauer", "neubauer:8"}) {
    const StressResult r = run("two_crossings_in_a_cell", spec);
    EXPECT_EQ(r.misses, r.referenceHits) << spec;
  }
  EXPECT_EQ(run("two_crossings_in_a_cell", "isolation:1").misses, 0u);
}

TEST(Stress, FacesEdgesVertices) {
  expectIsolationClean("faces_edges_vertices");
  EXPECT_GT(run("faces_edges_vertices", "linear").misses, 0u);
  EXPECT_GT(run("faces_edges_vertices", "schwarze").misses, 0u);
}

TEST(Stress, AxisParallel) {
  expectIsolationClean("axis_parallel");
  // The cubic's leading coefficient is zero: Schwarze's normalised solver divides by it.
  const StressResult s = run("axis_parallel", "schwarze");
  EXPECT_EQ(s.misses, s.referenceHits);
}

TEST(Stress, CornerClips) {
  expectIsolationClean("corner_clips");
  EXPECT_GT(run("corner_clips", "linear").misses, 0u);
}

TEST(Stress, FarFromOrigin) { expectIsolationClean("far_from_origin"); }
TEST(Stress, TinySpacing) { expectIsolationClean("tiny_spacing"); }
TEST(Stress, HugeSpacing) { expectIsolationClean("huge_spacing"); }
TEST(Stress, Values1e30) { expectIsolationClean("values_1e30"); }
TEST(Stress, Values1eMinus30) { expectIsolationClean("values_1e-30"); }

TEST(Stress, IsoEqualsData) { expectIsolationClean("iso_equals_data"); }

TEST(Stress, PlateauAtIso) {
  expectIsolationClean("plateau_at_iso");
  const StressResult s = run("plateau_at_iso", "schwarze");
  EXPECT_GT(s.misses, s.referenceHits / 2);
}

TEST(Stress, NanInfData) {
  expectIsolationClean("nan_inf_data");
  EXPECT_GT(run("nan_inf_data", "linear").nans, 0u);  // Inf - Inf in its interpolation
}

TEST(Stress, BadRays) {
  for (const char* spec : {"linear", "neubauer", "schwarze", "isolation", "reference"}) {
    const StressResult r = run("bad_rays", spec);
    EXPECT_EQ(r.nans, 0u) << spec;
    EXPECT_EQ(r.wrongRoots, 0u) << spec;
  }
}

}  // namespace
}  // namespace iso
