// Volumes that change over time (scene/time_series.h): a list or pattern of files, or a file's
// time axis, stepped through by a sequence of frames. Every frame must be the picture a single
// render of that step's scene gives, bit for bit (whether its step was read ahead or not), and
// a bad series must be refused in one line before any frame is written.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "scene/time_series.h"
#include "test_util.h"
#include "volume/input_error.h"

namespace iso {
namespace {
namespace fs = std::filesystem;
using test::readExr;
using test::runIsotrace;

// A float32 ball of radius `radius` (in samples) in an n^3 raw file: radius minus the distance to
// the centre, so that iso value 0 is the sphere.
void writeBall(const std::string& path, int n, double radius) {
  std::vector<float> v(size_t(n) * n * n);
  const double c = 0.5 * (n - 1);
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x)
        v[(size_t(z) * n + y) * n + x] = float(radius - std::sqrt((x - c) * (x - c) + (y - c) * (y - c) + (z - c) * (z - c)));
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(v.data()), std::streamsize(v.size() * 4));
}

// A scene with one volume whose "file" is `file` (JSON: a string or a list) and `extra` keys; the
// raw layout of writeBall's files unless `raw` is false.
std::string ballScene(const std::string& file, const std::string& extra = "", bool raw = true) {
  return R"({"camera": {"position": [30, 25, 60], "look_at": [10, 10, 10]}, "film": {"width": 32, "height": 24},
    "integrator": {"type": "direct", "spp": 2},
    "volumes": [{"file": )" + file + (raw ? R"(, "dims": [20, 20, 20], "type": "float32")" : "") + extra + R"(,
                 "isosurfaces": [{"value": 0, "color": [0.8, 0.4, 0.3]}]}],
    "lights": [{"type": "directional", "direction": [-1, -2, -1], "irradiance": 3}, {"type": "environment", "radiance": 0.3}]})";
}

std::string q(const std::string& s) { return "\"" + s + "\""; }

TEST(TimeSeries, EachFrameIsTheSingleRenderOfItsStep) {
  const std::string dir = test::scratchDir();
  const double radii[3] = {4, 6, 8};
  for (int k = 0; k < 3; ++k) writeBall(dir + "/ball" + std::to_string(k) + ".raw", 20, radii[k]);
  test::writeText(dir + "/series.json", ballScene("[" + q(dir + "/ball0.raw") + ", " + q(dir + "/ball1.raw") + ", " +
                                                  q(dir + "/ball2.raw") + "]"));
  // No --frames: one frame per step.
  const auto r = runIsotrace("render " + dir + "/series.json -o " + dir + "/s.exr --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, dir + "/s.0000.exr\n" + dir + "/s.0001.exr\n" + dir + "/s.0002.exr\n");
  std::vector<std::vector<float>> singles;
  for (int k = 0; k < 3; ++k) {
    test::writeText(dir + "/one.json", ballScene(q(dir + "/ball" + std::to_string(k) + ".raw")));
    ASSERT_EQ(runIsotrace("render " + dir + "/one.json -o " + dir + "/one.exr --quiet").status, 0);
    singles.push_back(readExr(dir + "/one.exr"));
    ASSERT_FALSE(singles.back().empty());
    EXPECT_EQ(readExr(dir + "/s.000" + std::to_string(k) + ".exr"), singles.back()) << "step " << k;
  }
  EXPECT_NE(singles[0], singles[2]);
  // More frames than steps hold each step: 6 frames over 3 steps show 0 0 1 1 2 2; an orbit on
  // top turns the camera too (frame 0 unturned).
  const auto held = runIsotrace("render " + dir + "/series.json -o " + dir + "/h.exr --frames 6 --quiet");
  ASSERT_EQ(held.status, 0) << held.err;
  for (int f = 0; f < 6; ++f) EXPECT_EQ(readExr(dir + "/h.000" + std::to_string(f) + ".exr"), singles[size_t(f / 2)]) << f;
  const auto turned = runIsotrace("render " + dir + "/series.json -o " + dir + "/t.exr --frames 3 --orbit 90 --quiet");
  ASSERT_EQ(turned.status, 0) << turned.err;
  EXPECT_EQ(readExr(dir + "/t.0000.exr"), singles[0]);
  EXPECT_NE(readExr(dir + "/t.0001.exr"), singles[1]);
  // --frames 1: the first step alone.
  const auto still = runIsotrace("render " + dir + "/series.json -o " + dir + "/still.exr --frames 1 --quiet");
  ASSERT_EQ(still.status, 0) << still.err;
  EXPECT_EQ(readExr(dir + "/still.exr"), singles[0]);
}

// `isotrace mesh --time K`: the surface of step K; a step out of range is bad input.
TEST(TimeSeries, MeshOfATimeStep) {
  const std::string dir = test::scratchDir();
  writeBall(dir + "/a.raw", 20, 4);
  writeBall(dir + "/b.raw", 20, 8);
  test::writeText(dir + "/s.json", ballScene("[" + q(dir + "/a.raw") + ", " + q(dir + "/b.raw") + "]"));
  for (int t = 0; t < 2; ++t) {
    const auto r = runIsotrace("mesh " + dir + "/s.json --time " + std::to_string(t) + " -o " + dir + "/m" + std::to_string(t) + ".glb");
    ASSERT_EQ(r.status, 0) << r.err;
  }
  EXPECT_LT(fs::file_size(dir + "/m0.glb") * 2, fs::file_size(dir + "/m1.glb")) << "the bigger ball of step 1";
  const auto bad = runIsotrace("mesh " + dir + "/s.json --time 2 -o " + dir + "/m2.glb");
  EXPECT_EQ(bad.status, 2);
  EXPECT_NE(bad.err.find("--time: expected a time step from 0 to 1"), std::string::npos) << bad.err;
  EXPECT_FALSE(fs::exists(dir + "/m2.glb"));
}

TEST(TimeSeries, APatternMatchesInNaturalOrder) {
  const std::string dir = test::scratchDir();
  writeBall(dir + "/t_2.raw", 20, 5);
  writeBall(dir + "/t_10.raw", 20, 8);
  writeBall(dir + "/t_1.raw", 20, 3);
  writeBall(dir + "/other.raw", 20, 9);
  const std::vector<std::string> files = expandFilePattern(dir + "/t_*.raw", "scene.json", "/volumes/0/file");
  EXPECT_EQ(files, (std::vector<std::string>{dir + "/t_1.raw", dir + "/t_2.raw", dir + "/t_10.raw"}));
  test::writeText(dir + "/p.json", ballScene(q("t_*.raw")));  // relative to the scene file
  const auto r = runIsotrace("render " + dir + "/p.json -o " + dir + "/p.exr --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  test::writeText(dir + "/one.json", ballScene(q(dir + "/t_10.raw")));
  ASSERT_EQ(runIsotrace("render " + dir + "/one.json -o " + dir + "/one.exr --quiet").status, 0);
  EXPECT_EQ(readExr(dir + "/p.0002.exr"), readExr(dir + "/one.exr"));
  EXPECT_EQ(timeStepOfFrame(0, 4, 2), 0);
  EXPECT_EQ(timeStepOfFrame(1, 4, 2), 0);
  EXPECT_EQ(timeStepOfFrame(2, 4, 2), 1);
  EXPECT_EQ(timeStepOfFrame(3, 4, 2), 1);
  EXPECT_EQ(timeStepOfFrame(1, 2, 5), 2);  // fewer frames than steps skip some
}

// A 4D NIfTI (nibabel's example4d: 2 time points): "time": "all" steps through them, and frame t
// is the single render with "time": t; the two differ.
TEST(TimeSeries, AFilesTimeAxisStepsThroughItsTimePoints) {
  const std::string dir = test::scratchDir();
  auto scene = [&](const std::string& time) {
    return R"({"camera": {"position": [-230, -330, 190], "look_at": [-9, 50, 25], "up": [0, 0, 1], "fov": 24},
      "film": {"width": 40, "height": 30}, "integrator": {"type": "direct", "spp": 1},
      "volumes": [{"file": ")" + test::dataPath("volumes/example4d.nii.gz") + R"(", "time": )" + time + R"(,
                   "isosurfaces": [{"value": 300}]}],
      "lights": [{"type": "directional", "direction": [0.4, 0.6, -1], "irradiance": 2.6}]})";
  };
  test::writeText(dir + "/all.json", scene(q("all")));
  const auto r = runIsotrace("render " + dir + "/all.json -o " + dir + "/a.exr --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, dir + "/a.0000.exr\n" + dir + "/a.0001.exr\n");
  for (int t = 0; t < 2; ++t) {
    test::writeText(dir + "/one.json", scene(std::to_string(t)));
    ASSERT_EQ(runIsotrace("render " + dir + "/one.json -o " + dir + "/one" + std::to_string(t) + ".exr --quiet").status, 0);
    EXPECT_EQ(readExr(dir + "/a.000" + std::to_string(t) + ".exr"), readExr(dir + "/one" + std::to_string(t) + ".exr"));
  }
  EXPECT_NE(readExr(dir + "/one0.exr"), readExr(dir + "/one1.exr"));
}

// Bad series: one line naming the scene file and the place (and the step's file and index where
// there is one), status 2, no frame written.
TEST(TimeSeries, BadSeriesAreRefusedBeforeAnyFrame) {
  const std::string dir = test::scratchDir();
  writeBall(dir + "/a.raw", 20, 5);
  writeBall(dir + "/b.raw", 20, 6);
  writeBall(dir + "/small.raw", 18, 5);
  // A 4D NIfTI header with one time point: nibabel's 3D anatomical.nii with dim[0] = 4, dim[4] = 1.
  {
    std::ifstream in("/usr/lib/python3/dist-packages/nibabel/tests/data/anatomical.nii", std::ios::binary);
    ASSERT_TRUE(in.good());
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const int16_t four = 4, one = 1;
    std::memcpy(&bytes[40], &four, 2);  // dim[0]
    std::memcpy(&bytes[48], &one, 2);   // dim[4]
    test::writeBytes(dir + "/one_step.nii", bytes);
  }
  const std::string json = dir + "/bad.json";
  struct Case {
    std::string scene, place, message;
  };
  for (const Case& c : std::vector<Case>{
           {ballScene("[" + q(dir + "/a.raw") + ", " + q(dir + "/gone.raw") + ", " + q(dir + "/b.raw") + "]"),
            "/volumes/0/file", "time step 1 of 3: '" + dir + "/gone.raw' does not exist"},
           {ballScene(q(dir + "/nothing_*.raw")), "/volumes/0/file", "matches no file"},
           {ballScene("[]"), "/volumes/0/file", "expected a list of 1 to 100000 file names"},
           {ballScene("[" + q(dir + "/a.raw") + ", 3]"), "/volumes/0/file/1", "expected a file name"},
           {ballScene("[" + q(dir + "/a.raw") + "]", ", \"time\": \"all\""), "/volumes/0/time", "a list or pattern of files is a series already"},
           {ballScene(q(dir + "/a.raw"), ", \"time\": \"all\""), "/volumes/0/time", "has no time axis: nothing to step through"},
           {ballScene(q(dir + "/a.raw"), ", \"time\": 1"), "a.raw", "has no time axis"},
           {ballScene(q(dir + "/a.raw"), ", \"time\": \"some\""), "/volumes/0/time", "expected \"all\""},
           {ballScene(q(dir + "/one_step.nii"), ", \"time\": \"all\"", false),
            "/volumes/0/time", "has one time step: nothing to step through"},
           {ballScene(q(test::dataPath("volumes/example4d.nii.gz")), ", \"time\": 2", false),
            "dim[4]", "time point 2 is past the file's 2"}}) {
    test::writeText(json, c.scene);
    const auto r = runIsotrace("render " + json + " -o " + dir + "/out.png");
    EXPECT_EQ(r.status, 2) << c.message << ": " << r.err;
    EXPECT_NE(r.err.find(c.place), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_FALSE(fs::exists(dir + "/out.0000.png") || fs::exists(dir + "/out.png")) << c.message;
  }
  // NIfTI steps, their headers read together (one child process): a step of another shape, and a
  // step that is no NIfTI at all, named.
  const std::string anatomical = "/usr/lib/python3/dist-packages/nibabel/tests/data/anatomical.nii";
  for (int k = 0; k < 3; ++k) fs::copy_file(anatomical, dir + "/n" + std::to_string(k) + ".nii");
  fs::copy_file(test::dataPath("volumes/example4d.nii.gz"), dir + "/n3.nii.gz");
  test::writeBytes(dir + "/junk.nii", std::string(400, 'x'));
  test::writeText(json, ballScene("[" + q(dir + "/n0.nii") + ", " + q(dir + "/n1.nii") + ", " + q(dir + "/n3.nii.gz") + "]", "", false));
  auto nifti = runIsotrace("render " + json + " -o " + dir + "/out.png");
  EXPECT_EQ(nifti.status, 2) << nifti.err;
  EXPECT_NE(nifti.err.find("time step 2 ('" + dir + "/n3.nii.gz') is 128x96x24 int16, step 0"), std::string::npos) << nifti.err;
  test::writeText(json, ballScene("[" + q(dir + "/n0.nii") + ", " + q(dir + "/junk.nii") + ", " + q(dir + "/n2.nii") + "]", "", false));
  nifti = runIsotrace("render " + json + " -o " + dir + "/out.png");
  EXPECT_EQ(nifti.status, 2) << nifti.err;
  EXPECT_NE(nifti.err.find("/volumes/0/file: time step 1 of 3: " + dir + "/junk.nii: header"), std::string::npos) << nifti.err;
  EXPECT_EQ(std::count(nifti.err.begin(), nifti.err.end(), '\n'), 1) << nifti.err;
  EXPECT_FALSE(fs::exists(dir + "/out.0000.png"));
  // Steps of different shapes: named with their index, before any frame (the raw layout is the
  // scene's, so a file of another size is refused as its own; a NRRD header tells its shape).
  for (const auto& [name, dims] : std::vector<std::pair<std::string, std::string>>{{"n0.nrrd", "20 20 20"}, {"n1.nrrd", "18 18 18"}}) {
    const std::string raw = name == "n0.nrrd" ? "a.raw" : "small.raw";
    test::writeText(dir + "/" + name, "NRRD0004\ntype: float\ndimension: 3\nsizes: " + dims +
                                          "\nencoding: raw\nendian: little\ndata file: " + raw + "\n");
  }
  test::writeText(json, ballScene("[" + q(dir + "/n0.nrrd") + ", " + q(dir + "/n1.nrrd") + "]", "", false));
  const auto r = runIsotrace("render " + json + " -o " + dir + "/out.png");
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("/volumes/0/file: time step 1 ('" + dir + "/n1.nrrd') is 18x18x18 float32, step 0"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir + "/out.0000.png"));
}

}  // namespace
}  // namespace iso

namespace iso {
namespace {

std::string readFileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// Mean absolute difference of two RGB8 images of `pixels` pixels (a at its own row stride).
double meanDifference(const std::string& a, const std::string& b) {
  double sum = 0;
  const size_t n = std::min(a.size(), b.size());
  for (size_t i = 0; i < n; ++i) sum += std::abs(int(uint8_t(a[i])) - int(uint8_t(b[i])));
  return n ? sum / double(n) : 1e9;
}

// A video holds every frame of the sequence, in order, as the PNG frames show them (within the
// codec's loss); --keep-frames writes those PNGs too, the same bits as a render to PNG.
TEST(Video, HoldsTheSequencesFramesInOrder) {
  const std::string dir = test::scratchDir();
  for (int k = 0; k < 3; ++k) writeBall(dir + "/ball" + std::to_string(k) + ".raw", 20, 3 + 3 * k);
  test::writeText(dir + "/series.json", ballScene("[" + q(dir + "/ball0.raw") + ", " + q(dir + "/ball1.raw") + ", " +
                                                  q(dir + "/ball2.raw") + "]"));
  const auto png = runIsotrace("render " + dir + "/series.json -o " + dir + "/p.png --quiet");
  ASSERT_EQ(png.status, 0) << png.err;
  const auto video = runIsotrace("render " + dir + "/series.json -o " + dir + "/v.mp4 --keep-frames --fps 10 --quiet");
  ASSERT_EQ(video.status, 0) << video.err;
  EXPECT_EQ(video.out, dir + "/v.0000.png\n" + dir + "/v.0001.png\n" + dir + "/v.0002.png\n" + dir + "/v.mp4\n");
  for (int f = 0; f < 3; ++f)
    EXPECT_EQ(readFileBytes(dir + "/v.000" + std::to_string(f) + ".png").size() > 0 &&
                  test::readExr(dir + "/v.000" + std::to_string(f) + ".png") == test::readExr(dir + "/p.000" + std::to_string(f) + ".png"),
              true) << f;
  const auto probe = test::runCommand("ffprobe -v error -count_frames -show_entries stream=codec_name,width,height,nb_read_frames,r_frame_rate -of compact " + dir + "/v.mp4");
  EXPECT_EQ(probe.out, "stream|codec_name=h264|width=32|height=24|r_frame_rate=10/1|nb_read_frames=3\n") << probe.err;
  // Decoded, frame f is nearest the PNG of frame f.
  ASSERT_EQ(test::runCommand("ffmpeg -v error -i " + dir + "/v.mp4 -f rawvideo -pix_fmt rgb24 " + dir + "/v.rgb").status, 0);
  const std::string decoded = readFileBytes(dir + "/v.rgb");
  const size_t frameBytes = 32 * 24 * 3;
  ASSERT_EQ(decoded.size(), 3 * frameBytes);
  for (int f = 0; f < 3; ++f) {
    const std::vector<float> p = test::readExr(dir + "/p.000" + std::to_string(f) + ".png");
    std::string bytes;
    for (float v : p) bytes.push_back(char(std::lround(v * 255)));
    const double same = meanDifference(decoded.substr(size_t(f) * frameBytes, frameBytes), bytes);
    EXPECT_LT(same, 6) << "frame " << f;
    for (int g = 0; g < 3; ++g) {
      if (g == f) continue;
      std::string other;
      for (float v : test::readExr(dir + "/p.000" + std::to_string(g) + ".png")) other.push_back(char(std::lround(v * 255)));
      EXPECT_LT(same, meanDifference(decoded.substr(size_t(f) * frameBytes, frameBytes), other)) << f << " vs " << g;
    }
  }
  // WebM: VP9, every frame.
  const auto webm = runIsotrace("render " + dir + "/series.json -o " + dir + "/v.webm --quiet");
  ASSERT_EQ(webm.status, 0) << webm.err;
  EXPECT_EQ(test::runCommand("ffprobe -v error -count_frames -show_entries stream=codec_name,nb_read_frames -of compact " + dir + "/v.webm").out,
            "stream|codec_name=vp9|nb_read_frames=3\n");
}

// Ctrl-C during a video's first frame: that frame is finished from the samples done and the video
// ends with it (status 130), no temporary file left. The frame is long by its work (a million
// samples per pixel); the signal goes once isotrace says the frame has begun.
TEST(Video, AnInterruptedSequenceEndsItsVideoWithTheFrameInProgress) {
  const std::string dir = test::scratchDir();
  for (int k = 0; k < 2; ++k) writeBall(dir + "/b" + std::to_string(k) + ".raw", 20, 5 + k);
  test::writeText(dir + "/s.json", ballScene("[" + q(dir + "/b0.raw") + ", " + q(dir + "/b1.raw") + "]"));
  test::Process render(std::string(ISOTRACE_BINARY) + " render " + dir + "/s.json --integrator path --spp 1000000 -o " +
                       dir + "/v.mp4 >" + dir + "/out.txt");
  ASSERT_TRUE(render.waitForErr("(frame 1 of 2)")) << render.err();
  render.signal(SIGINT);
  EXPECT_EQ(render.wait(), 130) << render.err();
  EXPECT_EQ(test::runCommand("ffprobe -v error -count_frames -show_entries stream=nb_read_frames -of csv=p=0 " + dir + "/v.mp4").out, "1\n");
  for (const auto& entry : fs::directory_iterator(dir))
    EXPECT_EQ(entry.path().filename().string().find(".partial"), std::string::npos) << entry.path();
}

// Bad video requests: one line, status 2, and no video (nor a temporary file) left behind.
TEST(Video, BadRequestsLeaveNoFile) {
  const std::string dir = test::scratchDir() + "/out";
  fs::create_directories(dir);
  writeBall(dir + "/../a.raw", 20, 5);
  writeBall(dir + "/../b.raw", 20, 7);
  const std::string scene = dir + "/../s.json";
  test::writeText(scene, ballScene("[" + q(dir + "/../a.raw") + ", " + q(dir + "/../b.raw") + "]"));
  for (const auto& [args, message] : std::vector<std::pair<std::string, std::string>>{
           {"-o " + dir + "/v.mp4 --fps 0", "--fps: expected frames per second in [1, 240]"},
           {"-o " + dir + "/v.png --fps 30", "--fps: sets a video's frame rate"},
           {"-o " + dir + "/v.png --keep-frames", "--keep-frames: keeps a video's frames as images"},
           {"-o " + dir + "/v.mp4 --alpha", "--alpha: a video has no alpha channel"},
           {"-o " + dir + "/v.mp4 --aov albedo", "--aov: extra layers need an EXR output"},
           {"-o " + dir + "/missing/v.mp4", "output directory does not exist"}}) {
    const auto r = runIsotrace("render " + scene + " " + args);
    EXPECT_EQ(r.status, 2) << args << ": " << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << ": " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
  // No ffmpeg, or one that fails: said in one line, nothing left in the folder.
  for (const auto& [ffmpeg, message] : std::vector<std::pair<std::string, std::string>>{
           {"/nonexistent/ffmpeg", "ISOTRACE_FFMPEG: '/nonexistent/ffmpeg' is not an executable program"},
           {"/bin/false", dir + "/v.mp4: ffmpeg"}}) {
    const auto r = test::runCommand("ISOTRACE_FFMPEG=" + ffmpeg + " " ISOTRACE_BINARY " render " + scene + " -o " + dir + "/v.mp4 --quiet");
    EXPECT_EQ(r.status, 2) << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
  EXPECT_TRUE(fs::is_empty(dir)) << "a file was left in " << dir;
}

}  // namespace
}  // namespace iso
