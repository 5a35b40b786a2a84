// Watertightness under secondary rays (accuracy/watertight.h, `isotrace watertight`): with the
// renderer's own spawned rays, fixed seeds, at the origin and 1e5 away.
#include <gtest/gtest.h>

#include "accuracy/watertight.h"
#include "volume/input_error.h"
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
// rays per test and iso-surface one ray at a time, and over 2 * 10^4 through the packet walk
// (each query an 8-lane packet, --ray-flow wavefront), near and far from the origin.
TEST_P(Watertight, IsolationHasNoErrorsNearAndFar) {
  const SceneDesc scene = parseSceneText(GetParam().scene, "watertight.json");
  for (const Vec3d offset : {Vec3d{0, 0, 0}, Vec3d{1e5, -1e5, 1e5}})
    for (const auto& [flow, rays] : {std::pair{RayFlow::Scalar, 100000}, std::pair{RayFlow::Wavefront, 20000}}) {
      WatertightOptions options;
      options.rays = rays;
      options.seed = 7;
      options.offset = offset;
      options.rayFlow = flow;
      for (const WatertightReport& r : checkWatertight(scene, IntersectorSpec{}, options)) {
        SCOPED_TRACE("iso " + std::to_string(r.iso) + " offset " + std::to_string(offset.x) + " " + rayFlowName(flow));
        EXPECT_EQ(r.counts.rays, uint64_t(rays));
        EXPECT_GT(r.counts.crossings, uint64_t(rays / 10));
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
        // A NIfTI file placed by its own oblique, mirrored affine (the check once ignored it and
        // judged the rays against the wrong place: a third of them "failed").
        WatertightCase{"example4d_oblique_nifti", volume(R"("file": ")" + test::dataPath("volumes/example4d.nii.gz") + R"(")", R"({"value": 300})")},
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

// A failing ray written by --dump and read back replays alone to the same failure, with the
// same hits, bit for bit (Schwarze in float fails often enough on the gyroid to test it).
TEST(WatertightDump, FailuresReplayAloneToTheSameOutcome) {
  const std::string dir = test::scratchDir();
  const SceneDesc scene = parseSceneText(volume(R"("procedural": {"field": "gyroid", "resolution": [32, 32, 32]})", R"({"value": 0})"),
                                         dir + "/g.json");
  IntersectorSpec schwarze;
  std::string error;
  ASSERT_TRUE(parseIntersector("schwarze", schwarze, error));
  WatertightOptions options;
  options.rays = 3000;
  options.offset = {1e5, 0, -1e5};
  options.keepFailures = true;
  const WatertightReport report = checkWatertight(scene, schwarze, options).at(0);
  ASSERT_EQ(report.failures.size(), report.counts.parityErrors + report.counts.insideEscapes + report.counts.shadowMismatches);
  ASSERT_GT(report.failures.size(), 50u);
  FailureFile file;
  file.scene = dir + "/g.json";
  file.intersector = intersectorName(schwarze);
  file.seed = options.seed;
  file.offset = options.offset;
  file.rays = report.failures;
  writeFailures(dir + "/f.txt", file);
  const FailureFile back = readFailures(dir + "/f.txt");
  ASSERT_EQ(back.rays.size(), file.rays.size());
  EXPECT_EQ(back.offset, file.offset);
  EXPECT_EQ(back.intersector, "schwarze");
  const std::vector<FailedRay> again = replayFailures(scene, schwarze, back.offset, back.rayFlow, back.rays);
  for (size_t i = 0; i < again.size(); ++i) {
    const FailedRay &a = file.rays[i], &b = back.rays[i], &c = again[i];
    EXPECT_EQ(a.org, b.org);
    EXPECT_EQ(a.dir, b.dir);
    EXPECT_EQ(a.hits, b.hits);
    EXPECT_EQ(a.reference, b.reference);
    EXPECT_EQ(c.what, a.what) << "ray " << a.index;
    EXPECT_EQ(c.hits, a.hits) << "ray " << a.index;
  }
  // With the reference intersector the same rays pass.
  IntersectorSpec reference{IntersectorKind::Reference, 8};
  for (const FailedRay& r : replayFailures(scene, reference, back.offset, back.rayFlow, back.rays))
    EXPECT_EQ(r.what, "") << testName(r.test) << " ray " << r.index;
}

// The failing rays of hunts (tests/data/exactness, its README says how each failed): 1e7 rays
// on rough float32 fields at 1e5, and 1e6 rays on the real volumes. Replayed alone, in both ray
// flows, every one passes now.
TEST(WatertightDump, TheHuntedFailuresPass) {
  const std::string dir = std::string(ISOTRACE_SOURCE_DIR) + "/tests/data/exactness";
  struct Hunt {
    std::string scene, failures;
    size_t count;
  };
  for (const Hunt& hunt : std::vector<Hunt>{{"rough_1", "rough_1", 1},
                                            {"rough_1", "rough_1_iso", 1},
                                            {"rough_2", "rough_2", 8},
                                            {"rough_2", "rough_2_5b406aa", 2},
                                            {"rough_2", "rough_2_box_faces", 11},
                                            {"rough_3", "rough_3", 2},
                                            {"real_volumes", "real_example4d", 1},
                                            {"real_volumes", "real_hydrogen_1e5", 1},
                                            {"real_volumes", "real_hydrogen_20", 1},
                                            {"real_volumes", "real_hydrogen_20_1e5", 1},
                                            {"real_volumes", "real_lidc2_restarts", 18},
                                            {"real_volumes", "real_lidc2_pairs", 31},
                                            {"real_volumes", "real_lidc2_faces", 4},
                                            {"real_volumes", "real_seams", 1},
                                            {"real_volumes", "real_seams_1e5", 1}}) {
    const SceneDesc scene = parseSceneFile(dir + "/" + hunt.scene + ".json");
    const FailureFile file = readFailures(dir + "/" + hunt.failures + ".failures.txt");
    ASSERT_EQ(file.rays.size(), hunt.count) << hunt.failures;
    IntersectorSpec spec;
    std::string error;
    ASSERT_TRUE(parseIntersector(file.intersector, spec, error)) << error;
    for (RayFlow flow : {RayFlow::Scalar, RayFlow::Wavefront})
      for (const FailedRay& r : replayFailures(scene, spec, file.offset, flow, file.rays))
        EXPECT_EQ(r.what, "") << hunt.failures << " (" << rayFlowName(flow) << "): " << testName(r.test) << " ray "
                              << r.index << " of iso-surface " << r.surface;
  }
}

// Malformed failure files: one line naming the file and the line, nothing replayed.
TEST(WatertightDump, MalformedFailureFilesAreRefused) {
  const std::string dir = test::scratchDir();
  const std::string header = "# isotrace watertight failures: intersector=isolation:8 seed=1 offset=0x0p+0,0x0p+0,0x0p+0 scene=s.json\n";
  const std::string ray = "parity volume=0 surface=0 index=5 org=0x1p+0,0x1p+0,0x1p+0 dir=0x1p+0,0x0p+0,0x0p+0 tfar=0x1p+2 ";
  for (const auto& [text, fragment] : std::vector<std::pair<std::string, std::string>>{
           {"", "empty"},
           {"hello\n", "line 1: not an isotrace failure file"},
           {header.substr(0, header.find(" scene=")) + "\n", "line 1: the header names no scene"},
           {header + ray + "\n", "line 2: no 'what=' field"},
           {header + "sideways volume=0 what=x\n", "line 2: unknown test 'sideways'"},
           {header + ray + "colour=1 what=x\n", "line 2: unknown field 'colour'"},
           {header + ray + "tfar=1 what=x\n", "line 2: 'tfar' given twice"},
           {header + "parity volume=0 surface=0 org=1,2 dir=1,0,0 tfar=1 what=x\n", "line 2: org: expected three"},
           {header + "parity volume=0 surface=0 org=1,2,nan dir=1,0,0 tfar=1 what=x\n", "line 2: org: 'nan' is not a finite number"},
           {header + "parity volume=99999999 surface=0 org=1,2,3 dir=1,0,0 tfar=1 what=x\n", "line 2: volume: 99999999 is more than"},
           {header + "parity surface=0 org=1,2,3 dir=1,0,0 tfar=1 what=x\n", "line 2: no 'volume' field"},
           {header + "parity volume=0 surface=0 org=1,2,3 dir=1,0,0 tfar=1 hits=1;x what=x\n", "line 2: hits: 'x' is not a finite number"}}) {
    test::writeText(dir + "/f.txt", text);
    test::expectRefusal<InputError>([&] { readFailures(dir + "/f.txt"); }, dir + "/f.txt", fragment);
  }
  // A ray naming an iso-surface the scene does not have.
  test::writeText(dir + "/f.txt", header + "inside volume=0 surface=3 org=1,2,3 dir=1,0,0 tfar=1 what=x\n");
  const SceneDesc scene = parseSceneText(volume(R"("procedural": {"field": "sphere", "resolution": [8, 8, 8]})", R"({"value": 0.5})"),
                                         dir + "/s.json");
  test::expectRefusal<InputError>([&] { replayFailures(scene, IntersectorSpec{}, {0, 0, 0}, RayFlow::Scalar, readFailures(dir + "/f.txt").rays); },
                                  dir + "/s.json", "names iso-surface 3 of volume 0, which this scene does not have");
}

}  // namespace
}  // namespace iso
