#include <gtest/gtest.h>
#include <zlib.h>

#include <OpenImageIO/imageio.h>
#include <algorithm>
#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "scene/colormap.h"
#include "scene/gltf.h"
#include "renderer/film.h"
#include "scene/world.h"
#include "tests/test_util.h"

namespace iso {
namespace {

namespace fs = std::filesystem;
using test::mixedScene;
using test::readExr;
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
  test::writeText(path, scene(R"({"procedural": {"field": "sphere"}, "isosurfaces": {"value": 0.5}})"));
  expectBadInput(dir, path, "/volumes/0/isosurfaces: expected an array of iso-surfaces, found an object");
  test::writeText(path, "{\"film\": {\"width\": 16,}\n}");
  expectBadInput(dir, path, "s.json: line 1, column 23: JSON syntax error");
  expectBadInput(dir, dir + "/absent.json", "absent.json: scene file not found");
}

// OpenImageIO (and the ~260 libraries it brings) lives in a plugin loaded at first use: a render
// of an untextured scene to EXR or PNG never maps it (the dynamic loader's own list of the files
// it opens says so); a textured glTF and JPEG output load it, and the texture shows.
TEST(Cli, OpenImageIoLoadsOnlyForWhatNeedsIt) {
  const std::string dir = test::scratchDir();
  // `render dir/SCENE.json -o dir/IMAGE` with the environment `env`: its result and whether it
  // mapped OpenImageIO.
  auto render = [&](const std::string& env, const std::string& scene, const std::string& image, bool& loaded) {
    const auto r = test::runCommand("LD_DEBUG=files " + env + " " + std::string(ISOTRACE_BINARY) + " render " + dir + "/" +
                                    scene + " --spp 2 --quiet -o " + dir + "/" + image);
    loaded = r.err.find("file=libOpenImageIO.so") != std::string::npos;
    return r;
  };
  bool loaded = false;
  test::writeText(dir + "/plain.json", mixedScene());
  for (const char* image : {"plain.exr", "plain.png"}) {
    const auto r = render("", "plain.json", image, loaded);
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_FALSE(loaded) << image;
    EXPECT_TRUE(fs::file_size(dir + "/" + image) > 0);
  }
  // The box's base colour texture is the glTF logo, blue and green on grey; white without it.
  const std::string textured = R"({"camera": {"position": [1.5, 1.2, 2.2], "look_at": [0, 0, 0], "fov": 40},
    "film": {"width": 48, "height": 36}, "integrator": {"type": "eyelight"},
    "meshes": [{"file": ")" + test::dataPath("meshes/BoxTextured/BoxTextured.gltf") + R"("}]})";
  test::writeText(dir + "/textured.json", textured);
  for (const char* image : {"textured.exr", "textured.jpg"}) {
    const auto r = render("", "textured.json", image, loaded);
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_TRUE(loaded) << image;
  }
  // Without the plugin: what needs it ends with one line naming the library and no image; the rest
  // renders as before.
  const auto missing = render("ISOTRACE_PLUGIN_DIR=" + dir, "textured.json", "none.png", loaded);
  EXPECT_EQ(missing.status, 1) << missing.err;
  const std::string line = "isotrace: cannot load libisotrace_oiio.so";
  ASSERT_NE(missing.err.find(line), std::string::npos) << missing.err;
  size_t ours = 0;  // lines of isotrace's own (the loader's begin with its process id)
  for (size_t at = 0; at < missing.err.size(); at = missing.err.find('\n', at) + 1) {
    ours += missing.err.compare(at, 9, "isotrace:") == 0;
    if (missing.err.find('\n', at) == std::string::npos) break;
  }
  EXPECT_EQ(ours, 1u) << missing.err;
  EXPECT_FALSE(fs::exists(dir + "/none.png"));
  EXPECT_EQ(render("ISOTRACE_PLUGIN_DIR=" + dir, "plain.json", "plain2.png", loaded).status, 0);
  std::vector<std::string> channels;
  const std::vector<float> pixels = readExr(dir + "/textured.exr", &channels);
  ASSERT_EQ(pixels.size(), size_t(48 * 36) * channels.size());
  double red = 0, blue = 0;
  for (size_t p = 0; p < size_t(48 * 36); ++p) {
    red += pixels[p * channels.size()];
    blue += pixels[p * channels.size() + 2];
  }
  EXPECT_GT(red, 0) << "the box is seen";
  EXPECT_GT(blue, 1.3 * red) << "the texture's blue and green, not the white of an untextured box";
}

TEST(Cli, BadFlagsExitWithStatus2) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json";
  test::writeText(path, scene(R"({"procedural": {"field": "sphere", "resolution": [8,8,8]}, "isosurfaces": [{"value": 0.5}]})"));
  expectBadInput(dir, path + " --intersector cubic", "unknown intersector 'cubic'");
  expectBadInput(dir, path + " --integrator magic", "unknown integrator 'magic'");
  expectBadInput(dir, path + " --ray-flow packets", "--ray-flow: unknown ray flow 'packets' (known: wavefront, scalar)");
  expectBadInput(dir, path + " --resolution 10by10", "expected WIDTHxHEIGHT");
  expectBadInput(dir, path + " --tonemap reinhard", "--tonemap: unknown curve 'reinhard' (known: clamp, aces, filmic)");
  expectBadInput(dir, path + " --exposure nan", "--exposure: expected EV in [-30, 30]");
  expectBadInput(dir, path + " --exposure 40", "--exposure: expected EV in [-30, 30]");
  const auto r = runIsotrace("render " + path + " -o " + dir + "/out.tiff");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("out.tiff: output must end in .exr, .png or .jpg"), std::string::npos) << r.err;
  const auto jpegAlpha = runIsotrace("render " + path + " --alpha -o " + dir + "/out.jpg");
  EXPECT_EQ(jpegAlpha.status, 2);
  EXPECT_NE(jpegAlpha.err.find("--alpha: JPEG has no alpha channel"), std::string::npos) << jpegAlpha.err;
  EXPECT_FALSE(fs::exists(dir + "/out.jpg"));
  // A device configuration Embree refuses is bad input too, named with its variable.
  const auto embree = test::runCommand("env ISOTRACE_EMBREE_CONFIG=threads=abc " + std::string(ISOTRACE_BINARY) + " render " +
                                 path + " -o " + dir + "/e.png");
  EXPECT_EQ(embree.status, 2) << embree.err;
  EXPECT_NE(embree.err.find("ISOTRACE_EMBREE_CONFIG: Embree refused the device configuration 'threads=abc'"),
            std::string::npos) << embree.err;
  EXPECT_EQ(std::count(embree.err.begin(), embree.err.end(), '\n'), 1) << embree.err;
  EXPECT_FALSE(fs::exists(dir + "/e.png"));
}

// --set and --iso change the scene as if its file said so: the same image as the edited file,
// recorded in the stats and the image's metadata; every command that reads a scene takes them;
// a bad pointer or value is one line, exit 2, no image.
TEST(Cli, SetAndIsoOverrideTheSceneFile) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json", edited = dir + "/edited.json";
  const std::string sphere = R"({"procedural": {"field": "sphere", "resolution": [12,12,12]}, "isosurfaces": [{"value": 0.5}, {"value": 0.8}]})";
  test::writeText(path, scene(sphere));
  test::writeText(edited, R"({"camera": {"position": [0, 0, 4], "fov": 30}, "film": {"width": 16, "height": 12},
    "integrator": {"type": "normals"},
    "volumes": [{"procedural": {"field": "sphere", "resolution": [12,12,12]}, "isosurfaces": [{"value": 0.5}, {"value": 0.3}]}]})");
  const auto a = runIsotrace("render " + path + " -o " + dir + "/a.exr --quiet --set /camera/fov=30 --set /integrator/type=normals"
                             " --iso 1=0.3 --stats " + dir + "/a.json");
  ASSERT_EQ(a.status, 0) << a.err;
  const auto b = runIsotrace("render " + edited + " -o " + dir + "/b.exr --quiet");
  ASSERT_EQ(b.status, 0) << b.err;
  std::map<std::string, std::string> metadata;
  const std::vector<float> pa = readExr(dir + "/a.exr", nullptr, &metadata), pb = readExr(dir + "/b.exr");
  ASSERT_FALSE(pa.empty());
  EXPECT_EQ(pa, pb);
  std::ifstream stats(dir + "/a.json");
  const nlohmann::json s = nlohmann::json::parse(stats);
  EXPECT_EQ(s["overrides"], nlohmann::json::parse(R"(["/volumes/0/isosurfaces/1/value=0.3", "/camera/fov=30", "/integrator/type=\"normals\""])"));
  EXPECT_EQ(metadata["isotrace:overrides"],
            "/volumes/0/isosurfaces/1/value=0.3\n/camera/fov=30\n/integrator/type=\"normals\"");
  // The other commands that read a scene.
  const auto info = runIsotrace("info " + path + " --iso 0=0.25");
  EXPECT_EQ(info.status, 0) << info.err;
  EXPECT_NE(info.out.find("iso-surface 0.25:"), std::string::npos) << info.out;
  for (const std::string& command : {"watertight " + path + " --rays 100", "bench " + path + " --rays 100",
                                     "mesh " + path + " -o " + dir + "/m.glb"}) {
    const auto bad = runIsotrace(command + " --iso 7=1");
    EXPECT_EQ(bad.status, 2) << command;
    EXPECT_NE(bad.err.find("--iso 7=1: no iso-surface '7' (the scene has 2"), std::string::npos) << command << ": " << bad.err;
  }
  // Malformed overrides.
  expectBadInput(dir, path + " --set /camera/fov", "--set /camera/fov: expected POINTER=VALUE");
  expectBadInput(dir, path + " --set camera/fov=3", "'camera/fov' is not a JSON pointer");
  expectBadInput(dir, path + " --set /camera/fov=3O", "--set /camera/fov=3O: '3O' is not a JSON value");
  expectBadInput(dir, path + " --set /camera/fov=", "no value after '='");
  expectBadInput(dir, path + " --set /lights/0/type=sun", "s.json: /lights: expected an array");
  expectBadInput(dir, path + " --set /nothing/here=1", "s.json: /nothing: unknown key 'nothing'");
  expectBadInput(dir, path + " --set /volumes/3/isosurfaces=[]", "/volumes is an array of 1: no entry '3'");
  expectBadInput(dir, path + " --set /volumes/01/x=1", "/volumes is an array of 1: no entry '01'");
  expectBadInput(dir, path + " --set /film/width/x=1", "--set /film/width/x=1: /film/width is a number: nothing goes under it");
  expectBadInput(dir, path + " --set /camera/position/x=1", "/camera/position is an array of 3: no entry 'x'");
  expectBadInput(dir, path + " --set /camera/fov=abc", "s.json: /camera/fov: expected a number");
  expectBadInput(dir, path + " --set /camera/fvo=30", "s.json: /camera/fvo: unknown key 'fvo' (did you mean 'fov'?)");
  expectBadInput(dir, path + " --set /film/width=0", "s.json: /film/width: value 0 is out of range");
  expectBadInput(dir, path + " --set '/camera/~2=1'", "is not a JSON pointer");
  expectBadInput(dir, path + " --iso 2=0.5", "--iso 2=0.5: no iso-surface '2' (the scene has 2");
  expectBadInput(dir, path + " --iso 0=inf", "--iso 0=inf: 'inf' is not a finite number");
  expectBadInput(dir, path + " --iso x", "--iso x: expected SURFACE=VALUE");
  expectBadInput(dir, path + " --iso -1=0.5", "no iso-surface '-1'");
  expectBadInput(dir, path + " --set /camera/fov=" + std::string(5000, '[') + std::string(5000, ']'),
                 "JSON nested more than 128 levels deep");
}

// Colour by data: a plane iso-surface (z = 7 of a volume whose value is z) coloured by a second
// volume on another grid and placement whose value rises linearly with world x. The albedo AOV
// at the centre pixel, where the ray meets the plane at the camera's x, is the map's colour of
// the value there (within 1/255 in sRGB); where the second volume has no value, the NaN colour.
TEST(Cli, ColorByDataSamplesTheOtherVolumeAtTheHit) {
  const std::string dir = test::scratchDir();
  auto writeFloats = [](const std::string& path, const std::vector<float>& v) {
    std::ofstream out(path, std::ios::binary);
    out.write(reinterpret_cast<const char*>(v.data()), std::streamsize(v.size() * sizeof(float)));
  };
  std::vector<float> slab, temp;
  for (int k = 0; k < 8; ++k)
    for (int j = 0; j < 8; ++j)
      for (int i = 0; i < 8; ++i) slab.push_back(float(2 * k));  // world z, spacing 2
  for (int k = 0; k < 3; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 3; ++i) temp.push_back(float(8 * i + 6));  // 10 + 2 x, x = 4 i - 2
  writeFloats(dir + "/slab.raw", slab);
  writeFloats(dir + "/temp.raw", temp);
  ColorMap viridis;
  ASSERT_TRUE(ColorMap::named("viridis", viridis));
  auto toSrgb = [](float v) { return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1 / 2.4f) - 0.055f; };
  for (const double x : {0.4, 2.5, 5.1, 10.0}) {
    char camera[160];
    std::snprintf(camera, sizeof camera, R"("camera": {"position": [%g, 8, 40], "look_at": [%g, 8, 7], "fov": 0.25})", x, x);
    test::writeText(dir + "/s.json", std::string("{") + camera + R"(, "film": {"width": 33, "height": 33},
      "integrator": {"type": "eyelight", "spp": 1},
      "volumes": [
        {"file": "slab.raw", "dims": [8, 8, 8], "type": "float32", "spacing": [2, 2, 2],
         "isosurfaces": [{"value": 7, "color_by": {"field": "temp", "map": "viridis", "range": [10, 22], "nan_color": [1, 0, 1]}}]},
        {"name": "temp", "file": "temp.raw", "dims": [3, 4, 3], "type": "float32", "spacing": [4, 5, 7],
         "origin": [-3, -1, -2], "transform": {"translate": [1, 2, 3]}}]})");
    const auto r = runIsotrace("render " + dir + "/s.json -o " + dir + "/c.exr --aov albedo --quiet");
    ASSERT_EQ(r.status, 0) << r.err;
    std::vector<std::string> channels;
    const std::vector<float> pixels = readExr(dir + "/c.exr", &channels);
    const size_t n = channels.size(), centre = (16 * 33 + 16) * n;
    const size_t red = size_t(std::find(channels.begin(), channels.end(), "albedo.R") - channels.begin());
    ASSERT_LT(red + 2, n);
    const Vec3f albedo{pixels[centre + red], pixels[centre + red + 1], pixels[centre + red + 2]};
    // The second volume covers world x in [-2, 6]: beyond, the NaN colour (magenta).
    const Vec3f expected = x <= 6 ? viridis.srgb(float((10 + 2 * x - 10) / 12)) : Vec3f{1, 0, 1};
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(toSrgb(albedo[c]), expected[c], 1.0 / 255) << "x " << x << ", channel " << c;
  }
}

// Slices: the plane through a ramp volume (value 10 + 2 x, on a placed grid) shows the map's
// colour of the value where each ray meets it (the albedo AOV at the centre pixel); an emitting
// slice shows that colour as light; the polygon ends at the grid (a ray past it misses); bad
// slices are refused by place.
TEST(Cli, SlicesShowTheVolumesValuesOnThePlane) {
  const std::string dir = test::scratchDir();
  std::vector<float> ramp;
  for (int k = 0; k < 3; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 5; ++i) ramp.push_back(float(8 * i + 6));  // 10 + 2 x, x = 4 i - 2
  {
    std::ofstream out(dir + "/ramp.raw", std::ios::binary);
    out.write(reinterpret_cast<const char*>(ramp.data()), std::streamsize(ramp.size() * sizeof(float)));
  }
  ColorMap magma;
  ASSERT_TRUE(ColorMap::named("magma", magma));
  auto toSrgb = [](float v) { return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1 / 2.4f) - 0.055f; };
  auto sceneAt = [&](double x, const std::string& slice) {
    char camera[160];
    std::snprintf(camera, sizeof camera, R"("camera": {"position": [%g, 8, 40], "look_at": [%g, 8, 7], "fov": 0.25})", x, x);
    return std::string("{") + camera + R"(, "film": {"width": 33, "height": 33}, "integrator": {"type": "eyelight", "spp": 1},
      "volumes": [{"file": "ramp.raw", "dims": [5, 4, 3], "type": "float32", "spacing": [4, 5, 7], "origin": [-3, -1, -2],
                   "transform": {"translate": [1, 2, 3]}, "slices": [)" + slice + "]}]}";
  };
  auto centre = [&](const std::string& layer, std::vector<std::string>& channels, const std::vector<float>& pixels) {
    const size_t n = channels.size(), at = (16 * 33 + 16) * n;
    const size_t c = size_t(std::find(channels.begin(), channels.end(), layer) - channels.begin());
    return c + 2 < n ? Vec3f{pixels[at + c], pixels[at + c + 1], pixels[at + c + 2]} : Vec3f{-1, -1, -1};
  };
  for (const double x : {-1.0, 3.3, 13.0, 20.0}) {
    // Lit (the albedo AOV), and unlit (the colour itself is the light the camera sees).
    for (const bool emit : {false, true}) {
      test::writeText(dir + "/s.json", sceneAt(x, std::string(R"({"axis": "z", "position": 7, "map": "magma", "range": [10, 38], "emit": )") +
                                                      (emit ? "true" : "false") + "}"));
      const auto r = runIsotrace("render " + dir + "/s.json -o " + dir + "/c.exr --aov albedo --quiet");
      ASSERT_EQ(r.status, 0) << r.err;
      std::vector<std::string> channels;
      const std::vector<float> pixels = readExr(dir + "/c.exr", &channels);
      const Vec3f colour = centre(emit ? "R" : "albedo.R", channels, pixels);
      if (x > 14) {  // the grid covers world x in [-2, 14]: nothing there
        EXPECT_EQ(colour, Vec3f(0, 0, 0)) << "x " << x << (emit ? " emitting" : "");
        continue;
      }
      const Vec3f expected = magma.srgb(float((10 + 2 * x - 10) / 28));
      for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(toSrgb(colour[c]), expected[c], 1.0 / 255) << "x " << x << ", channel " << c << (emit ? " emitting" : "");
    }
  }
  for (const auto& [slice, fragment] : std::vector<std::pair<std::string, std::string>>{
           {R"({"axis": "w", "position": 7})", "/volumes/0/slices/0/axis: unknown value 'w'"},
           {R"({"axis": "z"})", "/volumes/0/slices/0/position: required key is missing"},
           {R"({"point": [0, 0, 7], "normal": [0, 0, 0]})", "/volumes/0/slices/0/normal: the normal has zero length"},
           {R"({"axis": "z", "position": 7, "normal": [0, 0, 1]})", "/volumes/0/slices/0: a slice needs either"},
           {R"({"axis": "z", "position": 99})", "/volumes/0/slices/0: the plane does not cut the volume's grid"},
           {R"({"axis": "z", "position": 7, "map": "jet"})", "/volumes/0/slices/0/map: unknown colour map 'jet'"},
           {R"({"axis": "z", "position": 7, "range": [3, 3]})", "/volumes/0/slices/0/range: an empty range"},
           {R"({"axis": "z", "position": 7, "emit": 1})", "/volumes/0/slices/0/emit: expected true or false"}}) {
    test::writeText(dir + "/s.json", sceneAt(0, slice));
    expectBadInput(dir, dir + "/s.json", fragment);
  }
}

// Reads an 8-bit image into bytes; its channel count in `channels`.
std::vector<uint8_t> readBytes(const std::string& path, int& channels, int& width) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) return {};
  const OIIO::ImageSpec& spec = in->spec();
  channels = spec.nchannels;
  width = spec.width;
  std::vector<uint8_t> bytes(size_t(spec.width) * spec.height * spec.nchannels);
  in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::UINT8, bytes.data());
  return bytes;
}

// --colorbar: a strip below a PNG/JPEG with one bar per colour map; the image above it is the
// image without the flag; the bar runs through the map from end to end. A scene with nothing
// coloured by data refuses the flag.
TEST(Cli, ColorbarDrawsEachMapBelowTheImage) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json";
  test::writeText(path, R"({"camera": {"position": [0, 0, 4]}, "film": {"width": 160, "height": 90},
    "integrator": {"type": "eyelight", "spp": 1},
    "volumes": [{"procedural": {"field": "sphere", "resolution": [16, 16, 16]},
                 "isosurfaces": [{"value": 0.7, "color_by": {"field": "gradient_magnitude", "map": "plasma", "range": [0, 2]}}],
                 "slices": [{"axis": "z", "position": 0.2, "map": "viridis", "range": [0, 1]}]}]})");
  ASSERT_EQ(runIsotrace("render " + path + " -o " + dir + "/plain.png --quiet").status, 0);
  const auto r = runIsotrace("render " + path + " -o " + dir + "/bar.png --quiet --colorbar");
  ASSERT_EQ(r.status, 0) << r.err;
  int channels = 0, width = 0, plainChannels = 0, plainWidth = 0;
  const std::vector<uint8_t> plain = readBytes(dir + "/plain.png", plainChannels, plainWidth);
  const std::vector<uint8_t> bar = readBytes(dir + "/bar.png", channels, width);
  ASSERT_EQ(width, 160);
  ASSERT_EQ(channels, plainChannels);
  ASSERT_EQ(bar.size(), size_t(160) * (90 + 2 * 40) * size_t(channels));  // two maps: two bars of 40 rows
  EXPECT_TRUE(std::equal(plain.begin(), plain.end(), bar.begin())) << "the image above the strip is unchanged";
  ColorMap plasma, viridis;
  ASSERT_TRUE(ColorMap::named("plasma", plasma) && ColorMap::named("viridis", viridis));
  const int margin = 4;  // max(4, 160 / 40)
  for (const auto& [row, map] : std::vector<std::pair<int, const ColorMap*>>{{90 + 8, &plasma}, {90 + 40 + 8, &viridis}})
    for (const auto& [x, t] : std::vector<std::pair<int, float>>{{margin, 0.f}, {160 - margin - 1, 1.f}, {80, float(80 - margin) / (160 - 2 * margin - 1)}}) {
      const Vec3f expected = map->srgb(t);
      for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(bar[(size_t(row) * 160 + size_t(x)) * size_t(channels) + size_t(c)], expected[c] * 255, 1.0)
            << "row " << row << " x " << x << " channel " << c;
    }
  ASSERT_EQ(runIsotrace("render " + path + " -o " + dir + "/bar.jpg --quiet --colorbar").status, 0);
  const auto exr = runIsotrace("render " + path + " -o " + dir + "/bar.exr --quiet --colorbar");
  EXPECT_EQ(exr.status, 0);
  EXPECT_NE(exr.err.find("warning: --colorbar draws under PNG and JPEG images"), std::string::npos) << exr.err;
  test::writeText(path, scene(R"({"procedural": {"field": "sphere", "resolution": [8,8,8]}, "isosurfaces": [{"value": 0.5}]})"));
  expectBadInput(dir, path + " --colorbar", "--colorbar: the scene colours nothing by data");
}


// Display options: --alpha gives coverage (0 where the camera sees only the sky, 1 on the
// ball) and keeps the sky out of the colour; --exposure scales before the curve; the curves
// keep 0 black, rise monotonically and never pass 1; JPEG is written.
TEST(Cli, ExposureTonemapAndAlpha) {
  for (Tonemap t : {Tonemap::Clamp, Tonemap::Aces, Tonemap::Filmic}) {
    EXPECT_EQ(applyTonemap(0, t), 0.f);
    EXPECT_EQ(applyTonemap(-1, t), 0.f);
    EXPECT_EQ(applyTonemap(NAN, t), 0.f);
    float last = 0;
    for (float v = 0.01f; v < 1000; v *= 1.1f) {
      const float m = applyTonemap(v, t);
      EXPECT_GE(m, last) << tonemapName(t) << " at " << v;
      EXPECT_LE(m, 1.f);
      last = m;
    }
    EXPECT_GT(last, 0.95f) << tonemapName(t) << " must reach white";
  }
  // Unlike clamp, the curves still tell 2 from 4.
  EXPECT_EQ(applyTonemap(2, Tonemap::Clamp), applyTonemap(4, Tonemap::Clamp));
  EXPECT_LT(applyTonemap(2, Tonemap::Aces), applyTonemap(4, Tonemap::Aces));
  EXPECT_LT(applyTonemap(2, Tonemap::Filmic), applyTonemap(4, Tonemap::Filmic));

  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json";
  test::writeText(path, R"({"camera": {"position": [0, 0, 4]}, "film": {"width": 32, "height": 24},
    "integrator": {"type": "direct", "spp": 4},
    "volumes": [{"procedural": {"field": "sphere", "resolution": [16,16,16]}, "isosurfaces": [{"value": 0.5, "inside": "below"}]}],
    "lights": [{"type": "environment", "radiance": 0.05}]})");
  const auto plain = runIsotrace("render " + path + " -o " + dir + "/plain.png --quiet");
  const auto alpha = runIsotrace("render " + path + " -o " + dir + "/alpha.png --alpha --quiet");
  const auto bright = runIsotrace("render " + path + " -o " + dir + "/bright.png --exposure 2 --quiet");
  const auto jpeg = runIsotrace("render " + path + " -o " + dir + "/a.jpg --tonemap filmic --quiet");
  for (const auto* r : {&plain, &alpha, &bright, &jpeg}) ASSERT_EQ(r->status, 0) << r->err;
  int cp = 0, ca = 0, cb = 0, cj = 0, w = 0;
  const auto p = readBytes(dir + "/plain.png", cp, w), a = readBytes(dir + "/alpha.png", ca, w),
             b = readBytes(dir + "/bright.png", cb, w), j = readBytes(dir + "/a.jpg", cj, w);
  ASSERT_EQ(cp, 3);
  ASSERT_EQ(ca, 4);
  ASSERT_EQ(cj, 3);
  ASSERT_EQ(p.size(), size_t(32 * 24 * 3));
  ASSERT_EQ(a.size(), size_t(32 * 24 * 4));
  // Corner: sky only. Centre: the ball.
  const size_t corner = 0, centre = size_t(12 * 32 + 16);
  EXPECT_GT(p[corner * 3], 0);         // the sky is seen without --alpha
  EXPECT_EQ(a[corner * 4 + 3], 0);     // transparent with it
  EXPECT_EQ(a[corner * 4], 0);
  EXPECT_EQ(a[centre * 4 + 3], 255);   // the ball is opaque, its colour unchanged
  EXPECT_NEAR(a[centre * 4], p[centre * 3], 1);
  EXPECT_GT(b[centre * 3], p[centre * 3]);  // two stops brighter
}

// Hostile flags and scenes (issue 14): out-of-range flags are errors, never ignored; limits on
// the film and procedural grids hold before any allocation; JSON that would make a parser or
// a tree walk recurse without end is refused; misspelled keys are named with a suggestion;
// cameras and directories that would crash Embree or the writer are bad input.
TEST(Cli, HostileFlagsAndScenesAreBadInput) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json";
  test::writeText(path, scene(R"({"procedural": {"field": "sphere", "resolution": [8,8,8]}, "isosurfaces": [{"value": 0.5}]})"));
  expectBadInput(dir, path + " --threads 65537", "--threads: Value 65537 not in range 0 to 1024");
  expectBadInput(dir, path + " --threads -5", "--threads: Value -5 not in range");
  expectBadInput(dir, path + " --spp 0", "--spp: Value 0 not in range");
  expectBadInput(dir, path + " --max-depth 0", "--max-depth: Value 0 not in range");
  expectBadInput(dir, path + " --seed -7", "--seed: Value -7 not in range");
  expectBadInput(dir, path + " --resolution 99999x99999", "--resolution: each side must be at most 16384 pixels");
  expectBadInput(dir, path + " --resolution 16384x16384", "--resolution: 16384x16384 is more than 33554432 pixels");
  expectBadInput(dir, path + " --nthreads 2", "isotrace render: unexpected arguments '--nthreads 2'");
  auto write = [&](const std::string& name, const std::string& text) {
    test::writeText(dir + "/" + name, text);
    return dir + "/" + name;
  };
  expectBadInput(dir, write("film.json", R"({"film": {"width": 32768, "height": 32768}})"),
                 "/film/width: value 32768 is out of range [1, 16384]");
  expectBadInput(dir, write("proc.json", R"({"volumes": [{"procedural": {"field": "sphere", "resolution": [4096, 4096, 4096]},
                                             "isosurfaces": [{"value": 0.5}]}]})"),
                 "/volumes/0/procedural/resolution: more than 2^30 samples");
  expectBadInput(dir, write("big.json", R"({"camera": {"fov": 1e400}})"), "JSON: number overflow parsing '1e400'");
  expectBadInput(dir, write("nan.json", R"({"camera": {"fov": NaN}})"),
                 "line 1, column 20: JSON syntax error: syntax error while parsing value - invalid literal; last read: '\"fov\": N'");
  expectBadInput(dir, write("flie.json", R"({"volumes": [{"flie": "x.raw", "isosurfaces": [{"value": 1}]}]})"),
                 "/volumes/0/flie: unknown key 'flie' (did you mean 'file'?)");
  expectBadInput(dir, write("deep.json", "{\"camera\": " + std::string(100000, '[') + std::string(100000, ']') + "}"),
                 "deep.json: byte 139: JSON nested more than 128 levels deep");
  expectBadInput(dir, write("far.json", R"({"camera": {"position": [1e20, 0, 0]}, "meshes": [{"shape": "quad"}]})"),
                 "far.json: /camera: camera coordinate 100000000000000000000.000000 is beyond +-1e15");
  fs::create_directories(dir + "/adir");
  expectBadInput(dir, dir + "/adir", "adir: is a directory, not a scene file");
  // glTF: a node chain 100,000 deep, and extras nested 100,000 deep (both overflowed the stack).
  std::string chain = R"({"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [)";
  for (int i = 0; i < 100000; ++i) chain += i + 1 < 100000 ? "{\"children\": [" + std::to_string(i + 1) + "]}," : "{}";
  write("chain.gltf", chain + "]}");
  expectBadInput(dir, write("chain.json", R"({"meshes": [{"file": "chain.gltf"}]})"),
                 "chain.gltf: /nodes/1001: the node hierarchy is more than 1000 levels deep");
  write("extras.gltf", R"({"asset": {"version": "2.0"}, "extras": )" + std::string(100000, '[') + std::string(100000, ']') + "}");
  expectBadInput(dir, write("extras.json", R"({"meshes": [{"file": "extras.gltf"}]})"), "extras.gltf: byte 168: JSON nested more than 128 levels deep");
  // Outputs: a directory, a directory nothing can be written in (checked before rendering).
  const auto toDir = runIsotrace("render " + path + " -o " + dir + "/adir");
  EXPECT_EQ(toDir.status, 2);
  EXPECT_NE(toDir.err.find("adir: is a directory; name the output file"), std::string::npos) << toDir.err;
  const auto unwritable = runIsotrace("render " + path + " -o /proc/isotrace-test.png");
  EXPECT_EQ(unwritable.status, 2);
  EXPECT_NE(unwritable.err.find("/proc/isotrace-test.png: cannot write in its directory"), std::string::npos) << unwritable.err;
  // The command line itself.
  const auto version = runIsotrace("--version");
  EXPECT_EQ(version.status, 0);
  EXPECT_NE(version.out.find("isotrace 0."), std::string::npos) << version.out;
  EXPECT_NE(version.out.find("Embree 3."), std::string::npos) << version.out;
  EXPECT_NE(version.out.find("OpenVDB"), std::string::npos) << version.out;
  const auto unknown = runIsotrace("foo");
  EXPECT_EQ(unknown.status, 2);
  EXPECT_NE(unknown.err.find("unknown command 'foo' (commands: render, view, info, watertight, bench, mesh"), std::string::npos)
      << unknown.err;
}

// `watertight` and `bench` write the JSON the docs describe; the totals are the sums of the
// surfaces; bad flags are bad input.
TEST(Cli, WatertightAndBenchJson) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/w.json";
  test::writeText(path, scene(R"({"procedural": {"field": "torus", "resolution": [24, 24, 24]}, "isosurfaces": [{"value": 0.2}, {"value": 0.3}]})"));
  auto r = runIsotrace("watertight " + path + " --rays 2000 --intersector linear --json " + dir + "/w_out.json");
  ASSERT_EQ(r.status, 0) << r.err;
  std::ifstream in(dir + "/w_out.json");
  const nlohmann::json w = nlohmann::json::parse(in);
  ASSERT_EQ(w.at("surfaces").size(), 2u);
  const char* keys[] = {"rays", "crossings", "reference_crossings", "lost_crossings", "extra_crossings", "parity_errors",
                        "self_hits", "inside_escapes",
                        "shadow_mismatches"};
  for (const char* key : keys) {
    uint64_t sum = 0;
    for (const auto& surface : w.at("surfaces")) sum += surface.at(key).get<uint64_t>();
    EXPECT_EQ(w.at("total").at(key).get<uint64_t>(), sum) << key;
  }
  EXPECT_EQ(w.at("surfaces")[0].at("intersector"), "linear");
  EXPECT_EQ(w.at("surfaces")[1].at("iso").get<double>(), 0.3);
  std::ifstream raw(dir + "/w_out.json");
  const std::string text((std::istreambuf_iterator<char>(raw)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"iso\": 0.3,"), std::string::npos);  // the shortest form, not 0.29999999999999999
  EXPECT_EQ(w.at("total").at("rays"), 4000);
  EXPECT_GT(w.at("total").at("crossings").get<uint64_t>(), 1000u);
  // Lost and extra are counted ray by ray: their difference is the totals' difference; linear
  // interpolation loses pairs inside the gyroid's cells. --dump-lost keeps the rays whose
  // crossings differ; they are not failures, in the run or replayed.
  const std::string gyroid = dir + "/g.json";
  test::writeText(gyroid, scene(R"({"procedural": {"field": "gyroid", "resolution": [32, 32, 32]}, "isosurfaces": [{"value": 0}]})"));
  r = runIsotrace("watertight " + gyroid + " --rays 3000 --intersector linear --json " + dir + "/g_out.json --dump " + dir +
                  "/lost.txt --dump-lost");
  ASSERT_EQ(r.status, 0) << r.err;
  std::ifstream gin(dir + "/g_out.json");
  const nlohmann::json g = nlohmann::json::parse(gin);
  const auto n = [&](const char* key) { return g.at("total").at(key).get<int64_t>(); };
  EXPECT_EQ(n("reference_crossings") - n("crossings"), n("lost_crossings") - n("extra_crossings"));
  EXPECT_GT(n("lost_crossings"), 10);
  EXPECT_EQ(n("parity_errors"), 0);
  std::ifstream lost(dir + "/lost.txt");
  const std::string dumped((std::istreambuf_iterator<char>(lost)), std::istreambuf_iterator<char>());
  const int64_t differing = int64_t(std::count(dumped.begin(), dumped.end(), '\n')) - 1;  // after the header
  EXPECT_GE(differing * 2, n("lost_crossings") / 8);  // a ray loses a pair or a few
  EXPECT_LE(differing * 2, n("lost_crossings") + n("extra_crossings"));
  EXPECT_NE(r.out.find("0 failing rays and " + std::to_string(differing) + " whose crossings differ"), std::string::npos) << r.out;
  r = runIsotrace("watertight " + gyroid + " --replay " + dir + "/lost.txt");
  EXPECT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("0 of " + std::to_string(differing) + " rays fail now"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("now: crossings differ from the reference's"), std::string::npos) << r.out;

  r = runIsotrace("bench " + path + " --rays 500 --intersector isolation:2,reference --json " + dir + "/b_out.json");
  ASSERT_EQ(r.status, 0) << r.err;
  std::ifstream bin(dir + "/b_out.json");
  const nlohmann::json b = nlohmann::json::parse(bin);
  ASSERT_EQ(b.at("results").size(), 8u);  // 2 surfaces x 2 ray kinds x 2 intersectors
  for (const auto& row : b.at("results")) {
    EXPECT_EQ(row.at("count"), 500);
    EXPECT_GT(row.at("ns_per_ray").get<double>(), 0);
    if (row.at("intersector") == "reference") {
      EXPECT_EQ(row.at("max_dt").get<double>(), 0);
    }
  }

  for (const std::string& bad : {"watertight " + path + " --rays 0", "watertight " + path + " --intersector cubic",
                                 "watertight " + path + " --ray-flow packets", "watertight " + path + " --dump-lost",
                                 "watertight " + path + " --replay " + dir + "/lost.txt --dump-lost",
                                 "bench " + path + " --intersector isolation,nope", "watertight " + dir + "/none.json"}) {
    r = runIsotrace(bad);
    EXPECT_EQ(r.status, 2) << bad;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << bad << ": " << r.err;
  }
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
  // The value range of the sphere's distances (0 at the centre sample is not on the grid of
  // 16 points: the smallest is at the 8 samples next to it), and its quantiles.
  EXPECT_NE(info.out.find("values 0.11547 to 1.73205; quantiles 1%:"), std::string::npos) << info.out;
}

// An iso value outside the volume's values renders nothing: both commands say so on stderr
// (a warning, not an error), naming the scene and the surface. A scene without a camera
// frames what it holds.
TEST(Cli, IsoOutsideTheValuesWarnsAndNoCameraFramesTheScene) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/s.json";
  test::writeText(path, R"({"film": {"width": 40, "height": 30}, "volumes": [{"procedural": {"field": "sphere",
    "resolution": [16,16,16]}, "transform": {"translate": [100, 20, -30]}, "isosurfaces": [{"value": 0.5}, {"value": 7}]}]})");
  const std::string warning = path + ": /volumes/0/isosurfaces/1: iso value 7 lies outside the volume's values 0.11547 to 1.73205";
  const auto info = runIsotrace("info " + path);
  ASSERT_EQ(info.status, 0) << info.err;
  EXPECT_NE(info.err.find(warning), std::string::npos) << info.err;
  EXPECT_NE(info.out.find("(none in the scene: framing its bounds)"), std::string::npos) << info.out;
  const auto r = runIsotrace("render " + path + " -o " + dir + "/n.exr --integrator normals --spp 1 --aov depth --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find(warning), std::string::npos) << r.err;

  // The framing camera sees the ball (radius 0.5 at (100, 20, -30)) whole: hits in the image's
  // centre, none on its border.
  World world(parseSceneFile(path), IntersectorSpec{});
  Camera camera(world.camera(), 40, 30);
  TraversalStats stats;
  int centreHits = 0, borderHits = 0;
  for (int y = 0; y < 30; ++y)
    for (int x = 0; x < 40; ++x) {
      Hit hit;
      const bool hits = world.intersect(camera.generateRay(x + 0.5f, y + 0.5f), hit, stats);
      const bool border = x == 0 || y == 0 || x == 39 || y == 29;
      borderHits += hits && border;
      centreHits += hits && std::abs(x - 20) < 3 && std::abs(y - 15) < 3;
    }
  EXPECT_EQ(centreHits, 25);
  EXPECT_EQ(borderHits, 0);
}

// Frame sequences: every frame is the picture a single render of that frame's scene gives, bit
// for bit (an iso sweep builds each value's surface anew; an orbit only moves the camera).
TEST(Cli, FrameSequencesAreTheSingleRendersOfTheirFrames) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", mixedScene());
  const auto sweep = runIsotrace("render " + dir + "/s.json -o " + dir + "/sweep.exr --frames 3 --iso-sweep 0:0.4:0.8 --spp 2 --quiet --stats " + dir + "/sweep.json");
  ASSERT_EQ(sweep.status, 0) << sweep.err;
  EXPECT_EQ(sweep.out, dir + "/sweep.0000.exr\n" + dir + "/sweep.0001.exr\n" + dir + "/sweep.0002.exr\n");
  std::string scene = mixedScene();
  scene.replace(scene.find("\"value\": 0.6"), 12, "\"value\": 0.6000");  // frame 1 of 0.4 .. 0.8
  test::writeText(dir + "/middle.json", scene);
  ASSERT_EQ(runIsotrace("render " + dir + "/middle.json -o " + dir + "/middle.exr --spp 2 --quiet").status, 0);
  EXPECT_EQ(readExr(dir + "/sweep.0001.exr"), readExr(dir + "/middle.exr"));
  EXPECT_NE(readExr(dir + "/sweep.0000.exr"), readExr(dir + "/sweep.0002.exr"));
  std::ifstream stats(dir + "/sweep.json");
  const std::string text((std::istreambuf_iterator<char>(stats)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"frames\": 3"), std::string::npos) << text;

  const auto orbit = runIsotrace("render " + dir + "/s.json -o " + dir + "/orbit.exr --frames 4 --orbit 360 --spp 2 --quiet");
  ASSERT_EQ(orbit.status, 0) << orbit.err;
  ASSERT_EQ(runIsotrace("render " + dir + "/s.json -o " + dir + "/still.exr --spp 2 --quiet").status, 0);
  EXPECT_EQ(readExr(dir + "/orbit.0000.exr"), readExr(dir + "/still.exr"));
  EXPECT_NE(readExr(dir + "/orbit.0001.exr"), readExr(dir + "/still.exr"));
  // A half turn of this scene (symmetric about the vertical plane through the camera) mirrors
  // the picture: the ball stays in the middle, so the centre pixel is the same colour.
  const std::vector<float> half = readExr(dir + "/orbit.0002.exr"), still = readExr(dir + "/still.exr");
  const size_t centre = (size_t(12) * 32 + 16) * 3;
  EXPECT_NEAR(half[centre], still[centre], 0.25f * still[centre] + 0.02f);

  for (const auto& [args, message] : std::vector<std::pair<std::string, std::string>>{
           {"--frames 3", "--frames: a sequence needs --iso-sweep, --orbit or a volume that changes over time"},
           {"--orbit 90", "--iso-sweep and --orbit make a sequence: give --frames N"},
           {"--frames 2 --iso-sweep 1:0:1", "--iso-sweep: no iso-surface 1 (the scene has 1, counted from 0 over all volumes)"},
           {"--frames 2 --iso-sweep 0:0", "--iso-sweep: expected SURFACE:FROM:TO"},
           {"--frames 2 --iso-sweep 0:a:1", "'a' and '1' must be numbers"},
           {"--frames 2 --iso-sweep 0:0:inf", "the iso values must be finite"},
           {"--frames 2 --orbit 1e9", "--orbit: expected degrees in [-36000, 36000]"}}) {
    const auto r = runIsotrace("render " + dir + "/s.json -o " + dir + "/bad.png " + args);
    EXPECT_EQ(r.status, 2) << args;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << ": " << r.err;
    EXPECT_FALSE(fs::exists(dir + "/bad.0000.png")) << args;
  }
}

TEST(Cli, CompareWritesDirectGlobalAndIndirect) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/m.json", mixedScene());
  const auto r = runIsotrace("render " + dir + "/m.json --integrator compare --spp 8 -o " + dir + "/c.exr");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, dir + "/c.direct.exr\n" + dir + "/c.global.exr\n" + dir + "/c.indirect.exr\n");
  EXPECT_NE(r.err.find("of the light is indirect"), std::string::npos) << r.err;
  const auto direct = readExr(dir + "/c.direct.exr"), global = readExr(dir + "/c.global.exr"),
             indirect = readExr(dir + "/c.indirect.exr");
  ASSERT_EQ(direct.size(), 32u * 24u * 3u);
  ASSERT_EQ(global.size(), direct.size());
  ASSERT_EQ(indirect.size(), direct.size());
  double sumIndirect = 0;
  for (size_t i = 0; i < direct.size(); ++i) {
    EXPECT_NEAR(global[i], direct[i] + indirect[i], 1e-6 * (1 + global[i]));
    EXPECT_GE(indirect[i], -1e-6f);  // indirect paths only add light
    sumIndirect += indirect[i];
  }
  EXPECT_GT(sumIndirect, 0);  // the floor lights the ball and the ball the floor
}

// --clamp clips each sample's indirect part only: the direct image is bit for bit the same,
// the indirect image never exceeds the clamp, and without the clamp it does somewhere.
TEST(Cli, ClampLimitsTheIndirectPartOnly) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/m.json", mixedScene());
  const std::string base = "render " + dir + "/m.json --integrator compare --spp 8 --quiet ";
  ASSERT_EQ(runIsotrace(base + "-o " + dir + "/free.exr").status, 0);
  const auto r = runIsotrace(base + "--clamp 0.05 -o " + dir + "/clamped.exr");
  ASSERT_EQ(r.status, 0) << r.err;
  std::map<std::string, std::string> meta;
  const auto direct = readExr(dir + "/clamped.direct.exr"), freeDirect = readExr(dir + "/free.direct.exr");
  const auto indirect = readExr(dir + "/clamped.indirect.exr", nullptr, &meta), freeIndirect = readExr(dir + "/free.indirect.exr");
  ASSERT_EQ(direct.size(), freeDirect.size());
  EXPECT_EQ(direct, freeDirect);
  EXPECT_EQ(meta["isotrace:clamp"], "0.05");
  float peak = 0, freePeak = 0;
  for (size_t i = 0; i < indirect.size(); ++i) {
    peak = std::max(peak, indirect[i]);
    freePeak = std::max(freePeak, freeIndirect[i]);
  }
  EXPECT_LE(peak, 0.05f * (1 + 1e-5f));
  EXPECT_GT(freePeak, 0.05f);
  EXPECT_EQ(runIsotrace(base + "--clamp -1 -o " + dir + "/x.exr").status, 2);
}

// --adaptive: black sky pixels stop at the minimum of 16 samples, noisy pixels take more, none
// more than --spp; what each took is in the "samples" layer, the metadata and the stats; the
// image does not depend on the thread count.
TEST(Cli, AdaptiveSamplingStopsConvergedPixels) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", R"({"camera": {"position": [0, 1.5, 4], "look_at": [0, 0.5, 0]}, "film": {"width": 32, "height": 24},
    "meshes": [{"shape": "quad", "transform": {"scale": 1.5}, "material": "floor"}],
    "materials": {"floor": {"type": "diffuse", "color": 0.7}},
    "lights": [{"type": "spot", "position": [0, 2, 0], "direction": [0, -1, 0], "intensity": 5, "outer_angle": 50}]})");
  const std::string base = "render " + dir + "/s.json --integrator path --spp 256 --adaptive 0.05 --aov samples --quiet ";
  const auto one = runIsotrace(base + "--threads 1 -o " + dir + "/a1.exr");
  const auto two = runIsotrace(base + "--threads 2 -o " + dir + "/a2.exr --stats " + dir + "/st.json");
  ASSERT_EQ(one.status, 0) << one.err;
  ASSERT_EQ(two.status, 0) << two.err;
  std::vector<std::string> channels;
  std::map<std::string, std::string> meta;
  const auto a1 = readExr(dir + "/a1.exr", &channels, &meta), a2 = readExr(dir + "/a2.exr");
  EXPECT_EQ(a1, a2);
  ASSERT_EQ(channels, (std::vector<std::string>{"R", "G", "B", "samples.N"}));
  int least = 1 << 30, most = 0, sixteen = 0;
  double total = 0;
  for (size_t i = 3; i < a1.size(); i += 4) {
    const int n = int(a1[i]);
    least = std::min(least, n);
    most = std::max(most, n);
    sixteen += n == 16;
    total += n;
  }
  EXPECT_EQ(least, 16);
  EXPECT_GT(sixteen, 32 * 24 / 4);  // the sky, and the floor beyond the cone, is black
  EXPECT_GT(most, 16);
  EXPECT_LE(most, 256);
  EXPECT_EQ(meta["isotrace:spp"], "16");
  EXPECT_EQ(meta["isotrace:spp_max"], std::to_string(most));
  std::ifstream in(dir + "/st.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_NEAR(j["spp_mean"].get<double>(), total / (32 * 24), 1e-3);
  EXPECT_EQ(j["noise_threshold"].get<double>(), 0.05);
  EXPECT_EQ(j["interrupted"], false);
  EXPECT_EQ(runIsotrace(base + "--adaptive 2 -o " + dir + "/x.exr").status, 2);
}

TEST(Cli, StatsJsonAndAovLayers) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/m.json", mixedScene());
  const auto r = runIsotrace("render " + dir + "/m.json --integrator path --spp 2 --threads 2 --aov albedo,normal,depth -o " +
                             dir + "/a.exr --stats " + dir + "/s.json");
  ASSERT_EQ(r.status, 0) << r.err;
  std::ifstream in(dir + "/s.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  for (const char* key : {"width", "height", "spp", "threads", "integrator", "intersector", "rays_per_second"})
    EXPECT_TRUE(j.contains(key)) << key;
  for (const char* key : {"load", "build", "render", "total"}) EXPECT_TRUE(j["seconds"].contains(key)) << key;
  for (const char* key : {"camera", "shadow", "indirect"}) EXPECT_TRUE(j["rays"].contains(key)) << key;
  EXPECT_EQ(j["rays"]["camera"], 32 * 24 * 2);
  EXPECT_GT(j["rays"]["shadow"].get<long long>(), 0);
  EXPECT_GT(j["rays"]["indirect"].get<long long>(), 0);
  EXPECT_EQ(j["width"], 32);
  EXPECT_EQ(j["spp"], 2);
  EXPECT_EQ(j["threads"], 2);
  EXPECT_EQ(j["integrator"], "path");
  EXPECT_EQ(j["intersector"], "isolation:8");
  EXPECT_GT(j["counters"]["Iso/CellsVisited"].get<long long>(), 0);

  std::vector<std::string> channels;
  const auto data = readExr(dir + "/a.exr", &channels);
  // OpenEXR stores channels sorted by name; look them up.
  ASSERT_EQ(channels.size(), 10u);
  auto channel = [&](const std::string& name) {
    const auto it = std::find(channels.begin(), channels.end(), name);
    EXPECT_NE(it, channels.end()) << name;
    return size_t(it - channels.begin());
  };
  const size_t albedoR = channel("albedo.R"), albedoG = channel("albedo.G"), depth = channel("depth.Z");
  channel("normal.X");
  channel("normal.Y");
  channel("normal.Z");
  channel("R");
  // The centre pixel sees the ball (albedo of its material), the corners the sky (infinite depth).
  const size_t centre = (size_t(12) * 32 + 16) * 10;
  EXPECT_NEAR(data[centre + albedoR], 0.8, 1e-5);
  EXPECT_NEAR(data[centre + albedoG], 0.3, 1e-5);
  EXPECT_GT(data[centre + depth], 2.5);
  EXPECT_LT(data[centre + depth], 4.5);
  EXPECT_TRUE(std::isinf(data[depth]));

  // Layers need EXR.
  const auto png = runIsotrace("render " + dir + "/m.json --aov depth -o " + dir + "/a.png");
  EXPECT_EQ(png.status, 2);
  EXPECT_NE(png.err.find("--aov: extra layers need an EXR output"), std::string::npos) << png.err;
  const auto bad = runIsotrace("render " + dir + "/m.json --aov depth,shadows -o " + dir + "/b.exr");
  EXPECT_EQ(bad.status, 2);
  EXPECT_NE(bad.err.find("unknown layer 'shadows'"), std::string::npos) << bad.err;
}

// The progress bar shows on a terminal (faked with util-linux `script`), not in a pipe or
// a file, and never with --quiet.
TEST(Cli, ProgressBarOnlyOnATerminal) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/m.json", mixedScene());
  const std::string render = std::string(ISOTRACE_BINARY) + " render " + dir + "/m.json --integrator path --spp 256 --resolution 128x96 -o " + dir + "/p.png";
  auto onTerminal = [&](const std::string& extra) {
    const std::string cmd = "script -qec '" + render + extra + "' /dev/null > " + dir + "/tty.txt 2>&1";
    EXPECT_EQ(std::system(cmd.c_str()), 0);
    std::ifstream in(dir + "/tty.txt");
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
  };
  const std::string shown = onTerminal("");
  EXPECT_NE(shown.find("100.0%"), std::string::npos) << shown;
  EXPECT_NE(shown.find("ETA"), std::string::npos) << shown;
  EXPECT_EQ(onTerminal(" --quiet").find("ETA"), std::string::npos);
  const auto piped = runIsotrace("render " + dir + "/m.json --integrator path --spp 256 --resolution 128x96 -o " + dir + "/p.png");
  EXPECT_EQ(piped.status, 0);
  EXPECT_EQ(piped.err.find("ETA"), std::string::npos) << piped.err;
  EXPECT_NE(piped.err.find("rays:"), std::string::npos) << piped.err;  // the summary still is
}

// Ctrl-C stops at the next tile boundary, writes what is finished, and exits with 130. The
// render is long by its work (a million samples per pixel); the signal goes once isotrace says
// it has begun rendering.
TEST(Cli, SigintWritesTheFinishedSamplesAndExits130) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/m.json", mixedScene());
  test::Process render(std::string(ISOTRACE_BINARY) + " render " + dir + "/m.json --integrator path --spp 1000000 " +
                       "--resolution 64x48 -o " + dir + "/i.exr >" + dir + "/out.txt");
  ASSERT_TRUE(render.waitForErr("isotrace: rendering 64x48")) << render.err();
  render.signal(SIGINT);
  EXPECT_EQ(render.wait(), 130) << render.err();
  std::map<std::string, std::string> metadata;
  const auto data = readExr(dir + "/i.exr", nullptr, &metadata);
  ASSERT_EQ(data.size(), 64u * 48u * 3u);
  EXPECT_EQ(metadata["isotrace:interrupted"], "1");
  const int spp = std::stoi(metadata["isotrace:spp"]);
  EXPECT_GE(spp, 1);
  EXPECT_LT(spp, 1000000);
  for (float v : data) ASSERT_TRUE(std::isfinite(v));
  for (const auto& entry : fs::directory_iterator(dir))
    EXPECT_EQ(entry.path().filename().string().find(".partial"), std::string::npos) << entry.path();
}


// `isotrace mesh` writes a glTF the loader reads back, in world space (origin, spacing and the
// transform applied), with the surface's material; bad flags and empty surfaces are bad input
// and leave no file.
// An image used as environment (or texture) beyond the texel budget is refused by name from its
// header, before decoding (a 1 MB PNG of 16384^2 used to take 8.5 GB).
TEST(Cli, OversizedImagesAreRefusedFromTheirHeader) {
  const std::string dir = test::scratchDir();
  {
    auto out = OIIO::ImageOutput::create(dir + "/big.png");
    ASSERT_TRUE(out);
    OIIO::ImageSpec spec(8193, 4097, 1, OIIO::TypeDesc::UINT8);
    ASSERT_TRUE(out->open(dir + "/big.png", spec));
    std::vector<uint8_t> row(8193, 7);
    for (int y = 0; y < 4097; ++y) out->write_scanline(y, 0, OIIO::TypeDesc::UINT8, row.data());
    out->close();
  }
  test::writeText(dir + "/s.json", R"({"meshes": [{"shape": "quad"}], "lights": [{"type": "environment", "file": "big.png"}]})");
  const auto r = runIsotrace("info " + dir + "/s.json");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("big.png: image of 8193x4097 is more than 2^25 texels"), std::string::npos) << r.err;
}

// PNG chunks that libpng would allocate or inflate whole are checked first: a chunk longer
// than the file (found by the fuzzer: this 1.6 KB file took 2.3 GB inside OpenImageIO), and an
// ICC profile that inflates beyond 16 MiB.
TEST(Cli, HostilePngChunksAreRefused) {
  const std::string dir = test::scratchDir();
  const std::string source = ISOTRACE_SOURCE_DIR;
  test::writeText(dir + "/a.json", R"({"meshes": [{"shape": "quad"}], "lights": [{"type": "environment", "file": ")" +
                                       source + R"(/tests/data/hostile/itxt_past_end.png"}]})");
  const auto a = runIsotrace("info " + dir + "/a.json");
  EXPECT_EQ(a.status, 2);
  EXPECT_NE(a.err.find("itxt_past_end.png: byte 1103: PNG chunk 'iTXt' runs past the end of the image"), std::string::npos)
      << a.err;
  // A PNG whose zTXt chunk holds 32 MiB of zeros, deflated.
  const std::string zeros(32 << 20, '\0');
  std::string z(compressBound(uLong(zeros.size())), '\0');
  uLongf zn = uLongf(z.size());
  compress2(reinterpret_cast<Bytef*>(z.data()), &zn, reinterpret_cast<const Bytef*>(zeros.data()), uLong(zeros.size()), 9);
  z.resize(zn);
  auto chunk = [](const std::string& type, const std::string& data) {
    const uint32_t n = uint32_t(data.size());
    std::string c{char(n >> 24), char(n >> 16), char(n >> 8), char(n)};
    return c + type + data + std::string(4, '\0');  // the CRC is not looked at before the check
  };
  const std::string ihdr{0, 0, 0, 1, 0, 0, 0, 1, 8, 0, 0, 0, 0};
  test::writeBytes(dir + "/bomb.png", std::string("\x89PNG\r\n\x1a\n", 8) + chunk("IHDR", ihdr) +
                                          chunk("zTXt", std::string("txt\0\0", 5) + z) + chunk("IEND", ""));
  test::writeText(dir + "/b.json", R"({"meshes": [{"shape": "quad"}], "lights": [{"type": "environment", "file": "bomb.png"}]})");
  const auto b = runIsotrace("info " + dir + "/b.json");
  EXPECT_EQ(b.status, 2);
  EXPECT_NE(b.err.find("bomb.png: byte 33: PNG chunk 'zTXt' inflates to more than 16 MiB"), std::string::npos) << b.err;
  // The fuzzer's crash inside OpenImageIO's ICC profile parser: the profile is dropped before
  // OpenImageIO reads the image, which then loads (or is refused in one line), never crashes.
  test::writeText(dir + "/c.json", R"({"meshes": [{"shape": "quad"}], "lights": [{"type": "environment", "file": ")" +
                                       source + R"(/tests/data/hostile/icc_profile_crash.png"}]})");
  const auto c = runIsotrace("info " + dir + "/c.json");
  EXPECT_TRUE(c.status == 0 || c.status == 2) << c.status << " " << c.err;
  EXPECT_LE(std::count(c.err.begin(), c.err.end(), '\n'), 1) << c.err;
}

// Two renders writing the same --stats file at once both succeed (the temporary names are
// unique per process; a fixed ".partial" name raced in 4 of 100 pairs).
TEST(Cli, ConcurrentStatsWritesDoNotRace) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", scene(R"({"procedural": {"field": "sphere", "resolution": [8,8,8]}, "isosurfaces": [{"value": 0.5}]})"));
  const std::string one = std::string(ISOTRACE_BINARY) + " render " + dir + "/s.json --spp 1 --quiet --stats " + dir + "/st.json -o " + dir;
  for (int pair = 0; pair < 6; ++pair) {
    const std::string cmd = "(" + one + "/a.png >/dev/null 2>&1; echo $? > " + dir + "/ra) & (" + one + "/b.png >/dev/null 2>&1; echo $? > " +
                            dir + "/rb) & wait";
    ASSERT_EQ(std::system(cmd.c_str()), 0);
    for (const char* r : {"/ra", "/rb"}) {
      std::ifstream in(dir + r);
      int status = -1;
      in >> status;
      EXPECT_EQ(status, 0) << "pair " << pair;
    }
  }
  std::ifstream in(dir + "/st.json");
  EXPECT_NO_THROW(nlohmann::json::parse(in));
}

// A stop signal while the scene loads writes nothing and says so (it used to kill silently).
// The volume is a named pipe: isotrace blocks loading it until the test, having sent the
// signal, writes the samples.
TEST(Cli, InterruptWhileLoadingWritesNothing) {
  const std::string dir = test::scratchDir();
  const std::string pipe = dir + "/v.raw";
  ASSERT_EQ(mkfifo(pipe.c_str(), 0600), 0);
  test::writeText(dir + "/s.json", R"({"volumes": [{"file": "v.raw", "dims": [16, 16, 16], "type": "uint8",
    "isosurfaces": [{"value": 100}]}]})");
  test::Process render(std::string(ISOTRACE_BINARY) + " render " + dir + "/s.json -o " + dir + "/t.png >/dev/null");
  const int fd = render.openPipeForWriting(pipe);  // once isotrace has opened the pipe: it is loading
  ASSERT_GE(fd, 0) << render.err();
  render.signal(SIGINT);
  std::string samples(16 * 16 * 16, '\0');
  for (size_t i = 0; i < samples.size(); ++i) samples[i] = char(i % 200);
  EXPECT_EQ(write(fd, samples.data(), samples.size()), ssize_t(samples.size()));
  close(fd);
  EXPECT_EQ(render.wait(), 130) << render.err();
  EXPECT_NE(render.err().find("interrupted while loading: no image written"), std::string::npos) << render.err();
  EXPECT_FALSE(fs::exists(dir + "/t.png"));
}

// A job started with `&` by a script begins with SIGINT ignored (so that Ctrl-C at the terminal
// reaches the foreground job only); isotrace keeps that ignore, and SIGTERM still stops it.
TEST(Cli, AnInheritedSigintIgnoreIsKept) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/m.json", mixedScene());
  test::Process render("bash -c 'trap \"\" INT; exec " + std::string(ISOTRACE_BINARY) + " render " + dir +
                       "/m.json --integrator path --spp 1000000 --resolution 64x48 -o " + dir + "/t.png >/dev/null'");
  ASSERT_TRUE(render.waitForErr("isotrace: rendering 64x48")) << render.err();
  // Both pending at once are taken in number order, SIGINT first: the message names the one
  // that stopped the render.
  render.signal(SIGINT);
  render.signal(SIGTERM);
  EXPECT_EQ(render.wait(), 130) << render.err();
  EXPECT_NE(render.err().find("interrupted by SIGTERM: wrote the image"), std::string::npos) << render.err();
  EXPECT_TRUE(fs::exists(dir + "/t.png"));
}

// SIGTERM stops a render like SIGINT: the image of the samples so far is written whole, the
// exit status is 130, no temporary file is left.
TEST(Cli, SigtermWritesTheFinishedSamples) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/m.json", mixedScene());
  test::Process render(std::string(ISOTRACE_BINARY) + " render " + dir + "/m.json --integrator path --spp 100000 " +
                       "--resolution 64x48 -o " + dir + "/t.png >/dev/null");
  ASSERT_TRUE(render.waitForErr("isotrace: rendering 64x48")) << render.err();
  render.signal(SIGTERM);
  EXPECT_EQ(render.wait(), 130) << render.err();
  EXPECT_NE(render.err().find("interrupted by SIGTERM: wrote the image"), std::string::npos) << render.err();
  EXPECT_TRUE(fs::exists(dir + "/t.png"));
  for (const auto& entry : fs::directory_iterator(dir))
    EXPECT_EQ(entry.path().filename().string().find(".partial"), std::string::npos) << entry.path();
}

// Every path a scene names, when it is a device (here a link to /dev/zero, which a reader would
// read forever): refused by name before a byte is read, by `info` as by `render`.
TEST(Cli, DevicesAreRefusedByNameByEveryReader) {
  const std::string dir = test::scratchDir();
  auto zero = [&](const std::string& name) { fs::create_symlink("/dev/zero", dir + "/" + name); };
  const std::string quad = R"({"shape": "quad"})";
  const std::string iso = R"(, "isosurfaces": [{"value": 1}])";
  std::vector<std::pair<std::string, std::string>> cases;  // scene text, the path refused
  zero("scene.json");
  for (const char* mesh : {"m.glb", "m.gltf", "m.obj"}) {
    zero(mesh);
    cases.push_back({R"({"meshes": [{"file": ")" + std::string(mesh) + R"("}]})", mesh});
  }
  zero("b.bin");
  test::writeText(dir + "/buffer.gltf", R"({"asset": {"version": "2.0"}, "buffers": [{"uri": "b.bin", "byteLength": 12}]})");
  cases.push_back({R"({"meshes": [{"file": "buffer.gltf"}]})", "b.bin"});
  zero("z.mtl");
  test::writeText(dir + "/with_mtl.obj", "mtllib z.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  cases.push_back({R"({"meshes": [{"file": "with_mtl.obj"}]})", "z.mtl"});
  cases.push_back({R"({"volumes": [{"file": "v.raw", "dims": [4, 4, 4], "type": "uint8")" + iso + "}]}", "v.raw"});
  zero("v.raw");
  for (const char* volume : {"v.raw.gz", "v.nrrd", "v.mhd", "v.vtk", "v.nii", "v.nii.gz", "v.dcm", "v.vdb"}) {
    zero(volume);
    cases.push_back({R"({"volumes": [{"file": ")" + std::string(volume) + R"(")" + iso + "}]}", volume});
  }
  zero("sky.png");
  cases.push_back({R"({"meshes": [)" + quad + R"(], "lights": [{"type": "environment", "file": "sky.png"}]})", "sky.png"});
  int k = 0;
  for (const auto& [text, refused] : cases) {
    const std::string scene = dir + "/s" + std::to_string(k++) + ".json";
    test::writeText(scene, text);
    for (const char* command : {"info ", "render --quiet -o "}) {
      const std::string args = std::string(command) + (command[0] == 'r' ? dir + "/out.png " : "") + scene;
      const auto r = runIsotrace(args);
      EXPECT_EQ(r.status, 2) << args << "\n" << r.err;
      EXPECT_NE(r.err.find(dir + "/" + refused), std::string::npos) << text << "\n" << r.err;
      EXPECT_NE(r.err.find("is a character device"), std::string::npos) << text << "\n" << r.err;
      EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
      EXPECT_FALSE(fs::exists(dir + "/out.png"));
    }
  }
  // A DICOM folder lists regular files only: a device in it is passed over, never read.
  fs::create_directories(dir + "/series");
  fs::create_symlink("/dev/zero", dir + "/series/x.dcm");
  test::writeText(dir + "/series.json", R"({"volumes": [{"file": "series")" + iso + "}]}");
  const auto folder = runIsotrace("info " + dir + "/series.json");
  EXPECT_EQ(folder.status, 2);
  EXPECT_NE(folder.err.find(dir + "/series: holds no DICOM files"), std::string::npos) << folder.err;
  const auto r = runIsotrace("info " + dir + "/scene.json");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find(dir + "/scene.json: is a character device, not a scene file"), std::string::npos) << r.err;
}

// A named pipe fed without end: readers that stream read no further than the format's size
// (a raw volume's dims) or their stated cap (a scene's JSON), then refuse it in one line;
// readers that need a regular file refuse the pipe by name without opening it.
TEST(Cli, NamedPipesAreReadNoFurtherThanTheFormatAllows) {
  const std::string dir = test::scratchDir();
  std::signal(SIGPIPE, SIG_IGN);  // the writer learns of the reader's end by EPIPE
  // Writes zeros into the pipe until the reader closes it; the bytes it wrote.
  auto endlessWriter = [](const std::string& pipe, uint64_t& written) {
    return std::thread([pipe, &written] {
      const int fd = open(pipe.c_str(), O_WRONLY);
      if (fd < 0) return;
      const std::string chunk(1 << 16, '\0');
      for (ssize_t n; (n = write(fd, chunk.data(), chunk.size())) > 0;) written += uint64_t(n);
      close(fd);
    });
  };
  // After isotrace has ended: a writer still waiting for a reader is let go.
  auto release = [](const std::string& pipe) {
    const int fd = open(pipe.c_str(), O_RDONLY | O_NONBLOCK);
    if (fd >= 0) close(fd);
  };
  {
    const std::string pipe = dir + "/v.raw";
    ASSERT_EQ(mkfifo(pipe.c_str(), 0600), 0);
    test::writeText(dir + "/raw.json", R"({"volumes": [{"file": "v.raw", "dims": [16, 16, 16], "type": "uint8",
      "isosurfaces": [{"value": 1}]}]})");
    uint64_t written = 0;
    std::thread writer = endlessWriter(pipe, written);
    const auto r = runIsotrace("info " + dir + "/raw.json");
    release(pipe);
    writer.join();
    EXPECT_EQ(r.status, 2) << r.err;
    EXPECT_NE(r.err.find(pipe + ": "), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("4096 bytes"), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    // dims 16^3: 4096 bytes, with room for gzip framing (65536 + 16), then what the pipe holds.
    EXPECT_LE(written, uint64_t(4096 + 16 + 65537 + (1 << 16) + (1 << 16)));
  }
  {
    const std::string pipe = dir + "/scene.json";
    ASSERT_EQ(mkfifo(pipe.c_str(), 0600), 0);
    uint64_t written = 0;
    std::thread writer = endlessWriter(pipe, written);
    const auto r = runIsotrace("info " + pipe);
    release(pipe);
    writer.join();
    EXPECT_EQ(r.status, 2) << r.err;
    EXPECT_NE(r.err.find(pipe + ": a scene file read from a named pipe may hold at most 67108864 bytes"), std::string::npos)
        << r.err;
    EXPECT_LE(written, (uint64_t(64) << 20) + 3 * (1 << 16));
  }
  for (const char* name : {"p.nii", "p.vdb", "p.dcm"}) {
    const std::string pipe = dir + "/" + name;
    ASSERT_EQ(mkfifo(pipe.c_str(), 0600), 0);
    test::writeText(dir + "/p.json", R"({"volumes": [{"file": ")" + std::string(name) + R"(", "isosurfaces": [{"value": 1}]}]})");
    const auto r = runIsotrace("info " + dir + "/p.json");
    EXPECT_EQ(r.status, 2) << name << ": " << r.err;
    EXPECT_NE(r.err.find(pipe + ": is a named pipe"), std::string::npos) << r.err;
  }
}

TEST(Cli, MeshExportsTheSurfaceInWorldSpace) {
  const std::string dir = test::scratchDir();
  const std::string path = dir + "/m.json";
  test::writeText(path, R"({"volumes": [{"procedural": {"field": "sphere", "resolution": [24, 24, 24]},
      "transform": {"scale": 2, "translate": [10, 0, 0]},
      "isosurfaces": [{"value": 0.5, "material": "gold", "inside": "below"}, {"value": 7}]}],
    "materials": {"gold": {"type": "metallic_roughness", "color": [1, 0.8, 0.3], "metallic": 1, "roughness": 0.2}}})");
  const std::string glb = dir + "/sphere.glb";
  auto r = runIsotrace("mesh " + path + " -o " + glb);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, glb + "\n");
  const GltfModel model = loadGltf(glb);
  ASSERT_EQ(model.meshes.size(), 1u);
  const TriangleMesh& mesh = model.meshes[0][0];
  EXPECT_GT(mesh.triangleCount(), 500u);
  for (const Vec3f& p : mesh.positions)  // the sphere of radius 0.5, scaled by 2, centred at x = 10
    EXPECT_NEAR(length(Vec3d(p) - Vec3d{10, 0, 0}), 1.0, 2 * 2.0 / 23) << p.x << " " << p.y << " " << p.z;
  for (size_t i = 0; i < mesh.positions.size(); ++i)  // "inside": "below": normals point outwards
    EXPECT_GT(dot(Vec3d(mesh.normals[i]), Vec3d(mesh.positions[i]) - Vec3d{10, 0, 0}), 0);
  ASSERT_EQ(model.materials.size(), 1u);
  EXPECT_FLOAT_EQ(model.materials[0].baseColor.y, 0.8f);
  EXPECT_FLOAT_EQ(model.materials[0].metallic, 1.f);
  EXPECT_FLOAT_EQ(model.materials[0].roughness, 0.2f);

  auto bad = [&](const std::string& args, const std::string& fragment) {
    const auto e = runIsotrace("mesh " + path + " " + args);
    EXPECT_EQ(e.status, 2) << args << "\n" << e.err;
    EXPECT_NE(e.err.find(fragment), std::string::npos) << e.err;
    EXPECT_EQ(std::count(e.err.begin(), e.err.end(), '\n'), 1) << e.err;
  };
  bad("-o " + dir + "/a.glb --volume 1", "--volume: no volume 1 (the scene has 1, counted from 0)");
  bad("-o " + dir + "/a.glb --surface 2", "--surface: no iso-surface 2 in /volumes/0 (it has 2");
  bad("-o " + dir + "/a.glb --surface 1", "/volumes/0/isosurfaces/1/value: iso value 7 gives no surface");
  bad("-o " + dir + "/a.obj", "the mesh output must be .glb or .gltf");
  bad("-o " + dir + "/missing/a.glb", "output directory does not exist");
  for (const auto& entry : fs::directory_iterator(dir))
    EXPECT_TRUE(entry.path().filename() == "m.json" || entry.path().filename() == "sphere.glb") << entry.path();
}


// bench/packet_coherence (issue 11's packet question): its figures obey what a lockstep walk
// can do, and its arguments are checked like isotrace's.
TEST(BenchTools, PacketCoherenceFiguresAreBoundedAndConsistent) {
  const std::string dir = test::scratchDir();
  const std::string scene = dir + "/s.json";
  test::writeText(scene, mixedScene());  // 32x24 film: 4x2 and 4x4 tiles cover every pixel
  const auto r = test::runCommand(std::string(ISOTRACE_PACKET_COHERENCE) + " " + scene + " 32");
  ASSERT_EQ(r.status, 0) << r.err;
  std::map<std::string, std::pair<long, long>> totals;  // kind -> queries, cells (8-wide)
  std::istringstream lines(r.out);
  std::string line;
  int rows = 0;
  while (std::getline(lines, line)) {
    if (line.find("-wide:") == std::string::npos) continue;
    const std::string kind = line.substr(0, 15);
    int lanes = 0;
    long queries = 0, cells = 0, groups = 0;
    double active = 0, perStep = 0, percent = 0;
    ASSERT_EQ(std::sscanf(line.c_str() + 15, " %d-wide: %ld queries %ld cells | %ld packet-bricks, %lf lanes active, "
                          "%lf cells per lockstep step (%lf%%", &lanes, &queries, &cells, &groups, &active, &perStep,
                          &percent), 7) << line;
    ++rows;
    EXPECT_GT(queries, 0) << line;  // the ball is in view, lit from above, and bounced off
    EXPECT_GE(cells, queries) << line;  // a query walks at least its first cell
    EXPECT_GE(active, 1.0) << line;
    EXPECT_LE(active, double(lanes)) << line;
    EXPECT_GE(perStep, 1.0 - 1e-9) << line;  // a lockstep step does at least one lane's cell
    EXPECT_LE(perStep, double(lanes) + 1e-9) << line;
    EXPECT_NEAR(percent, 100 * perStep / lanes, 0.05 + 0.5 / lanes) << line;  // both printed rounded
    auto [it, first] = totals.insert({kind, {queries, cells}});
    if (!first) {  // the same rays, tiled two ways
      EXPECT_EQ(it->second.first, queries) << line;
      EXPECT_EQ(it->second.second, cells) << line;
    }
  }
  EXPECT_EQ(rows, 6) << r.out;

  auto bad = [&](const std::string& args, const std::string& fragment) {
    const auto e = test::runCommand(std::string(ISOTRACE_PACKET_COHERENCE) + " " + args);
    EXPECT_EQ(e.status, 2) << args << "\n" << e.err;
    EXPECT_NE(e.err.find(fragment), std::string::npos) << e.err;
    EXPECT_EQ(std::count(e.err.begin(), e.err.end(), '\n'), 1) << e.err;
  };
  bad(scene + " 7", "WIDTH: expected a whole number from 16 to 1920, got '7'");
  bad(scene + " 32x", "got '32x'");
  bad(scene + " 99999999999999999999", "from 16 to 1920");
  bad(dir + "/missing.json", dir + "/missing.json");
  bad("", "usage: packet_coherence SCENE.json [WIDTH]");
  test::writeText(dir + "/no_iso.json", R"({"camera": {"position": [0, 1, 4]}, "meshes": [{"shape": "quad"}]})");
  bad(dir + "/no_iso.json", "no_iso.json: the scene has no iso-surface");
  test::writeText(dir + "/broken.json", "{\"camera\": ");
  bad(dir + "/broken.json", "broken.json");
}

}  // namespace
}  // namespace iso
