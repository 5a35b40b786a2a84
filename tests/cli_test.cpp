#include <gtest/gtest.h>

#include <filesystem>

#include "tests/test_util.h"

namespace iso {
namespace {

namespace fs = std::filesystem;
using test::runIsotrace;

// Bad input: exit status 2, exactly one line on stderr that contains `fragment` (which
// names the file and the place), and no image left behind.
void expectBadInput(const std::string& dir, const std::string& args, const std::string& fragment) {
  const std::string image = dir + "/out.png";
  fs::remove(image);
  const auto r = runIsotrace("render " + args + " -o " + image + " --quiet");
  EXPECT_EQ(r.status, 2) << args << "\n" << r.err;
  EXPECT_NE(r.err.find(fragment), std::string::npos) << "stderr: " << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "stderr: " << r.err;
  EXPECT_FALSE(fs::exists(image));
  for (const auto& entry : fs::directory_iterator(dir))
    EXPECT_EQ(entry.path().filename().string().find(".partial"), std::string::npos) << entry.path();
}

std::string scene(const std::string& volume) {
  return R"({"camera": {"position": [0, 0, 4]}, "film": {"width": 16, "height": 12},
             "volumes": [)" + volume + "]}";
}

TEST(Cli, BadVolumesExitWithStatus2AndNameTheFile) {
  const std::string dir = test::scratchDir();
  auto write = [&](const std::string& name, const std::string& volume) {
    test::writeText(dir + "/" + name, scene(volume));
    return dir + "/" + name;
  };
  expectBadInput(dir, write("missing.json", R"({"file": "nope.raw", "dims": [2,2,2], "type": "uint8", "isosurfaces": [{"value": 1}]})"),
                 dir + "/nope.raw: file not found");
  test::writeBytes(dir + "/v.raw", std::string(7, '\1'));
  expectBadInput(dir, write("size.json", R"({"file": "v.raw", "dims": [2,2,2], "type": "uint8", "isosurfaces": [{"value": 1}]})"),
                 dir + "/v.raw: data has 7 bytes but 2x2x2 uint8 needs 8");
  expectBadInput(dir, write("type.json", R"({"file": "v.raw", "dims": [2,2,2], "type": "int64", "isosurfaces": [{"value": 1}]})"),
                 "type.json: /volumes/0/type: unknown type 'int64'");
  expectBadInput(dir, write("dims.json", R"({"file": "v.raw", "dims": [0,2,2], "type": "uint8", "isosurfaces": [{"value": 1}]})"),
                 "dims.json: /volumes/0/dims/0: value 0 is out of range");
  expectBadInput(dir, write("spacing.json", R"({"file": "v.raw", "dims": [2,2,2], "type": "uint8", "spacing": [1, 0, 1], "isosurfaces": [{"value": 1}]})"),
                 "spacing.json: /volumes/0/spacing: spacing must be positive");
  test::writeText(dir + "/bad.nrrd", "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: bz2\n\n");
  expectBadInput(dir, write("enc.json", R"({"file": "bad.nrrd", "isosurfaces": [{"value": 1}]})"),
                 "bad.nrrd: line 5: unsupported encoding 'bz2'");
  test::writeBytes(dir + "/cut_2x2x2_uint8.raw.gz", std::string("\x1f\x8b\x08\x00\x00\x00", 6));
  expectBadInput(dir, write("gz.json", R"({"file": "cut_2x2x2_uint8.raw.gz", "isosurfaces": [{"value": 1}]})"),
                 "cut_2x2x2_uint8.raw.gz: byte");
}

TEST(Cli, SceneErrorsNameTheirJsonPath) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json";
  test::writeText(path, scene(R"({"procedural": {"field": "sphere"}, "isosurfaces": [{"value": 0.5, "colour": [1,0,0]}]})"));
  expectBadInput(dir, path, "s.json: /volumes/0/isosurfaces/0/colour: unknown key 'colour'");
  test::writeText(path, scene(R"({"procedural": {"field": "cube"}, "isosurfaces": [{"value": 0.5}]})"));
  expectBadInput(dir, path, "/volumes/0/procedural/field: unknown field 'cube'");
  test::writeText(path, scene(R"({"procedural": {"field": "sphere"}, "isosurfaces": [{"value": "high"}]})"));
  expectBadInput(dir, path, "/volumes/0/isosurfaces/0/value: expected a number, found a string");
  test::writeText(path, scene(R"({"procedural": {"field": "sphere"}})"));
  expectBadInput(dir, path, "/volumes/0/isosurfaces: required key is missing");
  test::writeText(path, "{\"film\": {\"width\": 16,}\n}");
  expectBadInput(dir, path, "s.json: line 1, column 23: JSON syntax error");
  expectBadInput(dir, dir + "/absent.json", "absent.json: scene file not found");
}

TEST(Cli, BadFlagsExitWithStatus2) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json";
  test::writeText(path, scene(R"({"procedural": {"field": "sphere", "resolution": [8,8,8]}, "isosurfaces": [{"value": 0.5}]})"));
  expectBadInput(dir, path + " --intersector cubic", "unknown intersector 'cubic'");
  expectBadInput(dir, path + " --integrator magic", "unknown integrator 'magic'");
  expectBadInput(dir, path + " --resolution 10by10", "expected WIDTHxHEIGHT");
  const auto r = runIsotrace("render " + path + " -o " + dir + "/out.tiff");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("out.tiff: output must end in .exr or .png"), std::string::npos) << r.err;
}

TEST(Cli, RendersAnExrWithNormalsAndPrintsItsPath) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json";
  test::writeText(path, scene(R"({"procedural": {"field": "sphere", "resolution": [16,16,16]}, "isosurfaces": [{"value": 0.5}]})"));
  const auto r = runIsotrace("render " + path + " -o " + dir + "/n.exr --integrator normals --spp 1 --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, dir + "/n.exr\n");
  EXPECT_TRUE(fs::exists(dir + "/n.exr"));
  EXPECT_GT(fs::file_size(dir + "/n.exr"), 100u);
  const auto info = runIsotrace("info " + path);
  ASSERT_EQ(info.status, 0) << info.err;
  EXPECT_NE(info.out.find("16x16x16 float32"), std::string::npos) << info.out;
  EXPECT_NE(info.out.find("bricks active"), std::string::npos) << info.out;
}

}  // namespace
}  // namespace iso
