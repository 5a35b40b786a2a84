// Watertightness under secondary rays (accuracy/watertight.h, `isotrace watertight`): with the
// renderer's own spawned rays, fixed seeds, at the origin and 1e5 away.
#include <gtest/gtest.h>

#include "accuracy/watertight.h"
#include "tests/test_util.h"

namespace iso {
namespace {

struct WatertightCase {
  const char* name;
  std::string scene;  // JSON
};

void PrintTo(const WatertightCase& c, std::ostream* os) { *os << c.name; }

class Watertight : public ::testing::TestWithParam<WatertightCase> {};

std::string volume(const std::string& source, const std::string& isos) {
  return R"({"volumes": [{)" + source + R"(, "isosurfaces": [)" + isos + "]}]}";
}

// Isolation: zero parity errors, self hits, inside escapes and shadow mismatches over 10^5
// rays per test and iso-surface, near and far from the origin.
TEST_P(Watertight, IsolationHasNoErrorsNearAndFar) {
  const SceneDesc scene = parseSceneText(GetParam().scene, "watertight.json");
  for (const Vec3d offset : {Vec3d{0, 0, 0}, Vec3d{1e5, -1e5, 1e5}}) {
    WatertightOptions options;
    options.rays = 100000;
    options.seed = 7;
    options.offset = offset;
    for (const WatertightReport& r : checkWatertight(scene, IntersectorSpec{}, options)) {
      SCOPED_TRACE("iso " + std::to_string(r.iso) + " offset " + std::to_string(offset.x));
      EXPECT_EQ(r.counts.rays, 100000u);
      EXPECT_GT(r.counts.crossings, 10000u);
      EXPECT_EQ(r.counts.parityErrors, 0u);
      EXPECT_EQ(r.counts.selfHits, 0u);
      EXPECT_EQ(r.counts.insideEscapes, 0u);
      EXPECT_EQ(r.counts.shadowMismatches, 0u);
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    Fields, Watertight,
    ::testing::Values(
        WatertightCase{"sphere", volume(R"("procedural": {"field": "sphere", "resolution": [40, 40, 40]})", R"({"value": 0.7})")},
        WatertightCase{"torus_transformed",
                       volume(R"("procedural": {"field": "torus", "resolution": [64, 64, 64]}, "transform": {"scale": 2.2, "rotate": {"axis": [1, 0, 0], "degrees": 65}, "translate": [-0.4, 1.2, 0.5]})",
                              R"({"value": 0.28})")},
        WatertightCase{"nucleon", volume(R"("file": ")" + test::dataPath("volumes/nucleon/nucleon.nrrd") + R"(")", R"({"value": 60}, {"value": 90})")},
        WatertightCase{"neghip", volume(R"("file": ")" + test::dataPath("volumes/neghip_64x64x64_uint8.raw") + R"(")", R"({"value": 40.5}, {"value": 100})")},
        // Surfaces that fill the box to its faces, with close pairs of crossings: the last
        // ones isolation got wrong before spawned rays carried their class.
        WatertightCase{"gyroid", volume(R"("procedural": {"field": "gyroid", "resolution": [64, 64, 64]})", R"({"value": 0})")},
        WatertightCase{"marschner_lobb", volume(R"("procedural": {"field": "marschner_lobb", "resolution": [41, 41, 41]})", R"({"value": 0.5})")},
        // Thin noisy skin of a CT scan at an integer iso value on integer data.
        WatertightCase{"lidc2_skin", volume(R"("file": ")" + test::dataPath("volumes/lidc2_chest_ct_256x256x133_uint8.raw.gz") + R"(")", R"({"value": 18})")},
        // A sparse OpenVDB grid: crossings across its stored blocks and against its constant
        // bricks (the background), two iso values.
        WatertightCase{"smoke_sparse_vdb", volume(R"("file": ")" + test::dataPath("volumes/smoke.vdb") + R"(")", R"({"value": 0.05}, {"value": 0.3})")}),
    [](const ::testing::TestParamInfo<WatertightCase>& info) { return std::string(info.param.name); });

// What the check sees of the other intersectors. The float analytic solver (Schwarze) divides
// by noise on the smooth gyroid and leaks. Linear interpolation tests only a cell's entry and
// exit, so a pair of crossings inside one cell vanishes: it does not leak (its classes still
// telescope), but it finds fewer crossings than the reference; isolation finds them all.
TEST(WatertightDetects, SchwarzeLeaksAndLinearLosesPairs) {
  const SceneDesc scene = parseSceneText(volume(R"("procedural": {"field": "gyroid", "resolution": [48, 48, 48]})", R"({"value": 0})"), "g.json");
  WatertightOptions options;
  options.rays = 20000;
  auto check = [&](const char* name) {
    IntersectorSpec spec;
    std::string error;
    EXPECT_TRUE(parseIntersector(name, spec, error));
    return checkWatertight(scene, spec, options).at(0).counts;
  };
  const WatertightCounts schwarze = check("schwarze"), linear = check("linear"), isolation = check("isolation"),
                         reference = check("reference");
  EXPECT_GT(schwarze.parityErrors, 1000u);
  EXPECT_GT(schwarze.insideEscapes, 1000u);
  EXPECT_EQ(reference.parityErrors, 0u);
  EXPECT_EQ(reference.crossings, reference.referenceCrossings);
  EXPECT_EQ(linear.parityErrors, 0u);
  EXPECT_GT(linear.referenceCrossings, linear.crossings + 100);  // pairs inside one cell
  EXPECT_EQ(isolation.crossings, isolation.referenceCrossings);
}

TEST(WatertightDetects, CountsDoNotDependOnThreads) {
  const SceneDesc scene = parseSceneText(volume(R"("procedural": {"field": "gyroid", "resolution": [24, 24, 24]})", R"({"value": 0})"), "g.json");
  WatertightOptions options;
  options.rays = 5000;
  IntersectorSpec linear{IntersectorKind::Linear, 8};
  options.threads = 1;
  const WatertightCounts one = checkWatertight(scene, linear, options).at(0).counts;
  options.threads = 2;
  const WatertightCounts two = checkWatertight(scene, linear, options).at(0).counts;
  EXPECT_EQ(one.crossings, two.crossings);
  EXPECT_EQ(one.parityErrors, two.parityErrors);
  EXPECT_EQ(one.shadowMismatches, two.shadowMismatches);
}

}  // namespace
}  // namespace iso
