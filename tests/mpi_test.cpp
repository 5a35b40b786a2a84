// `mpirun -np N isotrace render ...` (renderer/distributed.h): the image and the ray counts of
// any number of ranks are those of one process, bit for bit; a rank that fails ends the run.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>

#include "renderer/distributed.h"
#include "tests/test_util.h"

namespace iso {
namespace {

namespace fs = std::filesystem;
using test::readExr;
using test::runCommand;
using test::runIsotrace;

// mpirun with N ranks of isotrace (as root too, more ranks than cores allowed), bounded in time
// so that a hang fails the test instead of the suite.
// Under ./test.sh --sanitize the ranks keep AddressSanitizer's checks but not its leak check:
// Open MPI leaves its runtime's allocations behind at MPI_Finalize, in components it has
// already unloaded (stack frames without a name, which no suppression can match).
std::string mpirun(int ranks) {
  const char* asan = std::getenv("ASAN_OPTIONS");
  const std::string env = asan ? "env ASAN_OPTIONS=\"" + std::string(asan) + ":detect_leaks=0\" " : "";
  // --foreground: a signal to timeout goes to mpirun alone. Without it timeout sends it to
  // mpirun and then to its whole process group again, and a second SIGINT makes mpirun kill
  // the ranks at once (no image: an intermittent failure of the interrupt test below).
  return env + "timeout --foreground -k 10 120 " + std::string(ISOTRACE_MPIEXEC) + " --allow-run-as-root --oversubscribe --mca btl_vader_single_copy_mechanism none -np " +
         std::to_string(ranks) + " ";
}

nlohmann::json readJson(const std::string& path) {
  std::ifstream in(path);
  return nlohmann::json::parse(in, nullptr, false);
}

// A scene with 9 tiles of different cost (an iso-surface ball, a floor, sky) and paths that
// bounce, with every layer a pixel accumulates.
std::string pathScene() {
  std::string scene = test::mixedScene();
  scene.replace(scene.find("\"width\": 32, \"height\": 24"), 25, "\"width\": 40, \"height\": 36");
  return scene;
}

void expectSameRays(const nlohmann::json& a, const nlohmann::json& b) {
  EXPECT_EQ(a["rays"], b["rays"]);
  EXPECT_EQ(a["counters"], b["counters"]);
}

TEST(Mpi, RanksRenderTheSingleProcessImageBitForBit) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", pathScene());
  for (const std::string& flags : {std::string("--integrator path --spp 20 --aov albedo,normal,depth,variance,samples"),
                                   std::string("--integrator path --spp 48 --adaptive 0.2 --aov samples")}) {
    const auto one = runIsotrace("render " + dir + "/s.json " + flags + " --threads 1 --quiet -o " + dir +
                                 "/one.exr --stats " + dir + "/one.json");
    ASSERT_EQ(one.status, 0) << one.err;
    const std::vector<float> reference = readExr(dir + "/one.exr");
    ASSERT_FALSE(reference.empty());
    for (const auto& [ranks, threads] : std::vector<std::pair<int, int>>{{2, 1}, {3, 2}}) {
      const std::string name = dir + "/n" + std::to_string(ranks);
      const auto r = runCommand(mpirun(ranks) + ISOTRACE_BINARY + " render " + dir + "/s.json " + flags +
                                " --threads " + std::to_string(threads) + " --quiet -o " + name + ".exr --stats " +
                                name + ".json");
      ASSERT_EQ(r.status, 0) << flags << "\n" << r.err;
      EXPECT_EQ(r.out, name + ".exr\n") << "only rank 0 writes the image";
      EXPECT_EQ(readExr(name + ".exr"), reference) << flags << ", " << ranks << " ranks";
      const nlohmann::json stats = readJson(name + ".json"), single = readJson(dir + "/one.json");
      expectSameRays(stats, single);
      EXPECT_EQ(stats["ranks"], ranks);
      EXPECT_EQ(stats["spp"], single["spp"]);
      EXPECT_EQ(stats["spp_mean"], single["spp_mean"]);
      // Every tile ends on one rank (9 tiles).
      int tiles = 0;
      for (const auto& n : stats["tiles_per_rank"]) tiles += n.get<int>();
      EXPECT_EQ(tiles, 9) << stats.dump();
    }
  }
}

// A rank that runs out of tiles takes idle ones from the others (their sums and next pass with
// them). ISOTRACE_TEST_DEAL=first deals every tile to rank 0, so the other ranks render only
// what they take: the image is still the single process's, bit for bit, with adaptive sampling
// and every layer, and every tile ends on one rank.
TEST(Mpi, RanksThatRunOutTakeTilesFromOthers) {
  const std::string dir = test::scratchDir();
  std::string scene = pathScene();
  scene.replace(scene.find("\"width\": 40, \"height\": 36"), 25, "\"width\": 96, \"height\": 64");  // 6x4 tiles
  test::writeText(dir + "/s.json", scene);
  const std::string flags = " --integrator path --spp 40 --adaptive 0.2 --aov albedo,normal,depth,variance,samples --quiet";
  ASSERT_EQ(runIsotrace("render " + dir + "/s.json" + flags + " --threads 1 -o " + dir + "/one.exr --stats " + dir +
                        "/one.json")
                .status,
            0);
  const std::vector<float> reference = readExr(dir + "/one.exr");
  ASSERT_FALSE(reference.empty());
  for (int ranks : {2, 3}) {
    SCOPED_TRACE(ranks);
    const std::string out = dir + "/taken" + std::to_string(ranks);
    const auto r = runCommand(mpirun(ranks) + "-x ISOTRACE_TEST_DEAL=first " + ISOTRACE_BINARY + " render " + dir +
                              "/s.json" + flags + " --threads 1 -o " + out + ".exr --stats " + out + ".json");
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_EQ(readExr(out + ".exr"), reference);
    const nlohmann::json stats = readJson(out + ".json");
    expectSameRays(stats, readJson(dir + "/one.json"));
    int tiles = 0;
    for (int q = 0; q < ranks; ++q) tiles += stats["tiles_per_rank"][size_t(q)].get<int>();
    EXPECT_EQ(tiles, 24) << stats.dump();
    EXPECT_GT(stats["tiles_moved_per_rank"][0].get<int>(), 0) << "rank 0 handed tiles over: " << stats.dump();
    EXPECT_GT(stats["tiles_per_rank"][1].get<int>(), 0) << "rank 1 took tiles: " << stats.dump();
  }
}

TEST(Mpi, CompareAndSequencesMatchOneProcess) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", pathScene());
  // compare: the direct, global and indirect images.
  ASSERT_EQ(runIsotrace("render " + dir + "/s.json --integrator compare --spp 6 --quiet -o " + dir + "/one.exr").status, 0);
  const auto c = runCommand(mpirun(2) + ISOTRACE_BINARY + " render " + dir +
                            "/s.json --integrator compare --spp 6 --threads 1 --quiet -o " + dir + "/two.exr");
  ASSERT_EQ(c.status, 0) << c.err;
  for (const char* part : {"direct", "global", "indirect"})
    EXPECT_EQ(readExr(dir + "/two." + part + ".exr"), readExr(dir + "/one." + part + ".exr")) << part;

  // A sequence: whole frames go to ranks (frame f to rank f mod N), each the single render's.
  const std::string seq = " --frames 3 --orbit 60 --spp 3 --quiet --stats ";
  ASSERT_EQ(runIsotrace("render " + dir + "/s.json -o " + dir + "/f1.exr" + seq + dir + "/f1.json").status, 0);
  const auto f = runCommand(mpirun(2) + ISOTRACE_BINARY + " render " + dir + "/s.json --threads 1 -o " + dir + "/f2.exr" +
                            seq + dir + "/f2.json");
  ASSERT_EQ(f.status, 0) << f.err;
  for (const char* frame : {"0000", "0001", "0002"}) {
    const std::vector<float> a = readExr(dir + "/f1." + frame + ".exr");
    ASSERT_FALSE(a.empty()) << frame;
    EXPECT_EQ(readExr(dir + "/f2." + frame + ".exr"), a) << frame;
  }
  const nlohmann::json one = readJson(dir + "/f1.json"), two = readJson(dir + "/f2.json");
  expectSameRays(one, two);
  EXPECT_EQ(two["frames"], 3);
  EXPECT_EQ(two["spp"], 3);
}

// --denoise under MPI: the denoiser runs once, on rank 0, on the gathered sums: the same bits as
// one process, by tiles (image-parallel, compare too) and with the volumes split (data-parallel).
TEST(Mpi, DenoisedOnceOnTheGatheredImage) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", pathScene());
  for (const std::string& flags : {std::string("--integrator path --spp 8 --denoise"),
                                   std::string("--integrator path --spp 8 --denoise fast --data-parallel"),
                                   std::string("--integrator compare --spp 6 --denoise")}) {
    SCOPED_TRACE(flags);
    const auto one = runIsotrace("render " + dir + "/s.json " + flags + " --threads 2 --quiet -o " + dir + "/one.exr");
    ASSERT_EQ(one.status, 0) << one.err;
    const auto two = runCommand(mpirun(2) + ISOTRACE_BINARY + " render " + dir + "/s.json " + flags +
                                " --threads 1 --quiet -o " + dir + "/two.exr");
    ASSERT_EQ(two.status, 0) << two.err;
    const bool compare = flags.find("compare") != std::string::npos;
    for (const std::string& part : compare ? std::vector<std::string>{".direct", ".global", ".indirect"}
                                          : std::vector<std::string>{""}) {
      const std::vector<float> a = readExr(dir + "/one" + part + ".exr");
      ASSERT_FALSE(a.empty()) << part;
      EXPECT_EQ(readExr(dir + "/two" + part + ".exr"), a) << part;
    }
  }
}

// Bad input seen by one rank only (MPMD: rank 1 gets another scene, or other settings): one line
// from rank 0 naming that rank and the file, status 2, no image, no hang. A rank that crashes ends the run
// too (mpirun kills the others), with no image left behind.
TEST(Mpi, ARankThatFailsEndsTheRun) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/good.json", pathScene());
  test::writeText(dir + "/bad.json", "{\"camera\": {\"fov\": 500}}");
  const std::string image = dir + "/out.png";
  const std::string common = " render --quiet -o " + image;
  const auto t0 = std::chrono::steady_clock::now();
  const auto r = runCommand(mpirun(1) + ISOTRACE_BINARY + common + " --spp 4 " + dir + "/good.json : -np 1 " +
                            ISOTRACE_BINARY + common + " --spp 4 " + dir + "/bad.json");
  EXPECT_EQ(r.status, 2) << r.err;
  const std::string expected = "isotrace: rank 1 of 2: " + dir + "/bad.json: /camera/fov";
  EXPECT_NE(r.err.find(expected), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("isotrace:", r.err.find(expected) + 1), std::string::npos) << "one line from isotrace: " << r.err;
  EXPECT_FALSE(fs::exists(image));

  // Ranks given different render settings (here the samples, in both modes): their tiles would
  // be gathered into a wrong image. One line from rank 0, status 2, no image.
  for (const std::string mode : {"", " --data-parallel"}) {
    const auto d = runCommand(mpirun(1) + ISOTRACE_BINARY + common + mode + " --spp 4 " + dir + "/good.json : -np 1 " +
                              ISOTRACE_BINARY + common + mode + " --spp 5 " + dir + "/good.json");
    EXPECT_EQ(d.status, 2) << mode << d.err;
    EXPECT_NE(d.err.find("isotrace: the ranks were given different render settings"), std::string::npos) << d.err;
    EXPECT_EQ(d.err.find("isotrace:", d.err.find("isotrace:") + 1), std::string::npos) << "one line: " << d.err;
    EXPECT_FALSE(fs::exists(image));
  }

  // Rank 1 crashes while it loads: its volume is a named pipe, so the test knows it is loading
  // (past MPI's start on every rank) once the pipe opens for writing.
  const std::string pipe = dir + "/v.raw";
  ASSERT_EQ(mkfifo(pipe.c_str(), 0600), 0);
  test::writeText(dir + "/crash.json", R"({"volumes": [{"file": "v.raw", "dims": [16, 16, 16], "type": "uint8",
    "isosurfaces": [{"value": 100}]}]})");
  test::Process crash(mpirun(1) + ISOTRACE_BINARY + common + " --spp 100000 " + dir + "/good.json : -np 1 " +
                      ISOTRACE_BINARY + common + " " + dir + "/crash.json");
  const int fd = crash.openPipeForWriting(pipe);
  ASSERT_GE(fd, 0) << crash.err();
  const std::vector<pid_t> loading = test::processesWithArgument(ISOTRACE_BINARY, dir + "/crash.json");
  ASSERT_EQ(loading.size(), 1u);
  kill(loading[0], SIGSEGV);
  close(fd);
  EXPECT_NE(crash.wait(), 0) << crash.err();
  EXPECT_NE(crash.err().find("rank 1"), std::string::npos) << crash.err();
  EXPECT_FALSE(fs::exists(image));
  for (const auto& entry : fs::directory_iterator(dir))
    EXPECT_EQ(entry.path().filename().string().find(".partial"), std::string::npos) << entry.path();
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 100) << "no hang";
}

// Data-parallel (--data-parallel): each rank holds only its box of each volume and the ranks
// answer each other's rays; the image is the single process's, bit for bit, for any number of
// ranks and threads. Scenes where paths cross the rank seams many times: a CT with a glass skin
// around bone (two iso values, path tracing), a field whose seams run through the surface,
// glTF meshes with two volumes, and a sparse OpenVDB grid beside an oblique NIfTI volume.
// Scenes for data-parallel rendering, by name: a CT with a glass skin, a procedural field, glTF
// meshes with two volumes (moved and scaled), and formats split by their own readers (a sparse
// OpenVDB grid, an oblique NIfTI placed by an instance).
std::map<std::string, std::string> dataParallelScenes() {
  const std::string data = test::dataPath("");
  const std::string materials = R"("materials": {"glass": {"type": "dielectric", "ior": 1.3, "color": [0.95, 0.85, 0.8]},
      "bone": {"type": "diffuse", "color": [0.9, 0.85, 0.7]}, "red": {"type": "metallic_roughness", "color": [0.8, 0.3, 0.2], "roughness": 0.3},
      "floor": {"type": "diffuse", "color": 0.6}},
    "lights": [{"type": "directional", "direction": [0.4, -1, 0.5], "irradiance": 2.5}, {"type": "environment", "radiance": [0.35, 0.4, 0.5]}])";
  return {
      {"ct", R"({"film": {"width": 40, "height": 30}, "integrator": {"type": "path", "spp": 6, "max_depth": 6},
        "volumes": [{"file": ")" + data + R"(volumes/lidc2_chest_ct_256x256x133_uint8.raw.gz", "spacing": [1.40625, 1.40625, 2.5],
          "isosurfaces": [{"value": 50, "material": "glass"}, {"value": 150, "material": "bone"}]}], )" + materials + "}"},
      {"field", R"({"film": {"width": 40, "height": 30}, "integrator": {"type": "path", "spp": 6, "max_depth": 5},
        "volumes": [{"procedural": {"field": "gyroid_ball", "resolution": [72, 72, 72]},
          "isosurfaces": [{"value": 0.0, "material": "glass"}]}], )" + materials + "}"},
      {"mixed", R"({"film": {"width": 40, "height": 30}, "integrator": {"type": "path", "spp": 4, "max_depth": 4},
        "meshes": [{"file": ")" + data + R"(meshes/2CylinderEngine.glb", "transform": {"translate": [0, 181, 0]}},
                   {"shape": "quad", "transform": {"scale": 1500, "translate": [250, 0, 0]}, "material": "floor"}],
        "volumes": [{"file": ")" + data + R"(volumes/neghip_64x64x64_uint8.raw", "spacing": [5, 5, 5], "transform": {"translate": [450, 0, -160]},
                     "isosurfaces": [{"value": 40, "material": "glass"}, {"value": 100, "material": "red"}]},
                    {"file": ")" + data + R"(volumes/headsq/quarter.nhdr", "transform": {"translate": [-300, 0, -100]},
                     "isosurfaces": [{"value": 1150, "material": "red"}]}], )" + materials + "}"},
      // Formats split by their own readers: a sparse OpenVDB grid, an oblique NIfTI (placed by an instance).
      {"formats", R"({"film": {"width": 40, "height": 30}, "integrator": {"type": "path", "spp": 4, "max_depth": 4},
        "volumes": [{"file": ")" + data + R"(volumes/smoke.vdb", "transform": {"scale": 20, "translate": [300, 0, 0]},
                     "isosurfaces": [{"value": 0.2, "material": "glass"}]},
                    {"file": ")" + data + R"(volumes/example4d.nii.gz", "isosurfaces": [{"value": 300, "material": "red"}]}], )" +
                      materials + "}"}};
}

TEST(Mpi, DataParallelRendersTheSingleProcessImageBitForBit) {
  const std::string dir = test::scratchDir();
  const std::map<std::string, std::string> scenes = dataParallelScenes();
  for (const auto& [name, text] : scenes) {
    SCOPED_TRACE(name);
    test::writeText(dir + "/" + name + ".json", text);
    const std::string base = dir + "/" + name;
    const auto one = runIsotrace("render " + base + ".json --data-parallel --threads 2 --quiet --aov albedo,normal,depth -o " +
                                 base + "_one.exr --stats " + base + "_one.json");
    ASSERT_EQ(one.status, 0) << one.err;
    const std::vector<float> reference = readExr(base + "_one.exr");
    ASSERT_FALSE(reference.empty());
    for (const auto& [ranks, threads] : std::vector<std::pair<int, int>>{{2, 1}, {3, 2}}) {
      const std::string out = base + "_" + std::to_string(ranks);
      const auto r = runCommand(mpirun(ranks) + ISOTRACE_BINARY + " render " + base + ".json --data-parallel --threads " +
                                std::to_string(threads) + " --quiet --aov albedo,normal,depth -o " + out + ".exr --stats " +
                                out + ".json");
      ASSERT_EQ(r.status, 0) << r.err;
      EXPECT_EQ(r.out, out + ".exr\n") << "only rank 0 writes the image";
      EXPECT_EQ(readExr(out + ".exr"), reference) << ranks << " ranks";
      const nlohmann::json stats = readJson(out + ".json"), single = readJson(base + "_one.json");
      EXPECT_EQ(stats["rays"], single["rays"]);
      EXPECT_EQ(stats["distribution"], "data");
      // Every ray of a path was asked of the ranks by the rank that owns its pixel.
      double asked = 0;
      for (const auto& n : stats["rays_asked_per_rank"]) {
        EXPECT_GT(n.get<double>(), 0) << stats.dump();
        asked += n.get<double>();
      }
      EXPECT_EQ(asked, single["rays"]["total"].get<double>());
      // Every copy a rank sent, another received.
      double sent = 0, received = 0;
      for (int q = 0; q < ranks; ++q) {
        sent += stats["rays_sent_per_rank"][size_t(q)].get<double>();
        received += stats["rays_received_per_rank"][size_t(q)].get<double>();
      }
      EXPECT_EQ(sent, received);
      EXPECT_EQ(stats["bytes_sent_per_rank"].size(), size_t(ranks));
    }
  }
  // The other integrators' stages go the same way: compare's three images, ao.
  for (const std::string integrator : {"compare", "ao"}) {
    const std::string base = dir + "/field_" + integrator;
    const std::string args = " render " + dir + "/field.json --data-parallel --integrator " + integrator + " --spp 3 --quiet -o ";
    ASSERT_EQ(runIsotrace(args.substr(1) + base + "_one.exr").status, 0);
    const auto r = runCommand(mpirun(2) + ISOTRACE_BINARY + args + base + "_two.exr --threads 1");
    ASSERT_EQ(r.status, 0) << r.err;
    for (const std::string& part : integrator == "compare" ? std::vector<std::string>{".direct", ".global", ".indirect"}
                                                          : std::vector<std::string>{""})
    {
      const std::vector<float> one = readExr(base + "_one" + part + ".exr");
      ASSERT_FALSE(one.empty()) << base + "_one" + part + ".exr";
      EXPECT_EQ(readExr(base + "_two" + part + ".exr"), one) << integrator << part;
    }
  }
}

// Ranks that hold copies of their neighbours' bricks ("replicate") ask each other about fewer
// rays and render the same image: volumes whose grid axes are the world's (tested in world space)
// and an oblique one (in its grid's index space), on 2 and 3 ranks; holding everything, no rank
// asks another anything. (ISOTRACE_TEST_REDEAL=rotate makes the tiles' ranks, and so the rays
// sent, the same from run to run.)
TEST(Mpi, RanksHoldingCopiesOfBricksAskLessForTheSameImage) {
  const std::string dir = test::scratchDir();
  const std::map<std::string, std::string> scenes = dataParallelScenes();
  for (const std::string name : {"ct", "mixed", "formats"}) {
    SCOPED_TRACE(name);
    const std::string base = dir + "/" + name;
    test::writeText(base + ".json", scenes.at(name));
    const auto one = runIsotrace("render " + base + ".json --threads 2 --quiet -o " + base + "_one.exr");
    ASSERT_EQ(one.status, 0) << one.err;
    const std::vector<float> reference = readExr(base + "_one.exr");
    ASSERT_FALSE(reference.empty());
    for (const int ranks : {2, 3}) {
      std::map<std::string, double> sent;
      for (const std::string replicate : {"0", "0.3", "1"}) {
        const std::string out = base + "_" + std::to_string(ranks) + "_" + replicate;
        const auto r = runCommand(mpirun(ranks) + "-x ISOTRACE_TEST_REDEAL=rotate " + ISOTRACE_BINARY + " render " + base +
                                  ".json --data-parallel --replicate " + replicate + " --threads 1 --quiet -o " + out +
                                  ".exr --stats " + out + ".json");
        ASSERT_EQ(r.status, 0) << r.err;
        EXPECT_EQ(readExr(out + ".exr"), reference) << ranks << " ranks, replicate " << replicate;
        const nlohmann::json stats = readJson(out + ".json");
        ASSERT_EQ(stats["rays_sent_per_rank"].size(), size_t(ranks)) << stats.dump();
        for (const auto& n : stats["rays_sent_per_rank"]) sent[replicate] += n.get<double>();
      }
      EXPECT_GT(sent["0"], 0);
      EXPECT_LT(sent["0.3"], sent["0"]) << ranks << " ranks";
      EXPECT_EQ(sent["1"], 0) << ranks << " ranks";
    }
  }
}

// neghip with a glass skin (iso 40) around an opaque core (iso 100), lit from above (and by
// `moreLights`, a JSON list's further entries), on the given film and integrator.
std::string glassNeghip(const std::string& film, const std::string& integrator, const std::string& moreLights = "") {
  return R"({"film": )" + film + R"(, "integrator": )" + integrator + R"(,
    "volumes": [{"file": ")" + test::dataPath("volumes/neghip_64x64x64_uint8.raw") + R"(",
      "isosurfaces": [{"value": 40, "material": "glass"}, {"value": 100}]}],
    "materials": {"glass": {"type": "dielectric", "ior": 1.3}},
    "lights": [{"type": "directional", "direction": [0.4, -1, 0.5], "irradiance": 2.5})" + moreLights + "]}";
}

// neghip with a glass skin on a `width` x `height` film at `spp`, rendered data-parallel on 2
// and 3 ranks with a test hook (`hook`, an environment setting): the image is the single
// process's, bit for bit, with the same rays; `check(ranks, stats)` looks at each run's stats.
void expectTheSingleProcessImageWith(const std::string& hook, int width, int height, int spp,
                                     const std::function<void(int, const nlohmann::json&)>& check) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", glassNeghip(R"({"width": )" + std::to_string(width) + R"(, "height": )" + std::to_string(height) + "}",
                                               R"({"type": "path", "spp": )" + std::to_string(spp) + R"(, "max_depth": 5})",
                                               R"(, {"type": "environment", "radiance": 0.3})"));
  const std::string common = " render " + dir + "/s.json --data-parallel --quiet --aov albedo,normal,depth";
  const auto one = runIsotrace(common.substr(1) + " --threads 2 -o " + dir + "/one.exr --stats " + dir + "/one.json");
  ASSERT_EQ(one.status, 0) << one.err;
  const std::vector<float> reference = readExr(dir + "/one.exr");
  ASSERT_FALSE(reference.empty());
  for (int ranks : {2, 3}) {
    SCOPED_TRACE(ranks);
    const std::string out = dir + "/ranks" + std::to_string(ranks);
    const auto r = runCommand(mpirun(ranks) + "-x " + hook + " " + ISOTRACE_BINARY + common + " --threads 1 -o " + out +
                              ".exr --stats " + out + ".json");
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_EQ(readExr(out + ".exr"), reference);
    const nlohmann::json stats = readJson(out + ".json");
    EXPECT_EQ(stats["rays"], readJson(dir + "/one.json")["rays"]);
    check(ranks, stats);
  }
}

// Tiles dealt again between passes (ISOTRACE_TEST_REDEAL=rotate: every tile to the next rank
// after every pass, its sums with it): the image stays the single process's, bit for bit, on 2
// and 3 ranks, and every tile is in the gathered frame once.
TEST(Mpi, DataParallelTilesDealtAgainKeepTheImage) {
  expectTheSingleProcessImageWith("ISOTRACE_TEST_REDEAL=rotate", 56, 40, 6, [](int ranks, const nlohmann::json& stats) {
    // 56x40 pixels: 4x3 tiles of 16, each moved after each of the first 3 passes (1, 1, 2, 2 samples).
    int tiles = 0, moved = 0;
    for (int q = 0; q < ranks; ++q) {
      tiles += stats["tiles_per_rank"][size_t(q)].get<int>();
      moved += int(stats["tiles_moved_per_rank"][size_t(q)].get<double>());
    }
    EXPECT_EQ(tiles, 12) << stats.dump();
    EXPECT_EQ(moved, 3 * 12) << stats.dump();
  });
}

// Camera rays asked of another rank are traced there in the packets they were traced in by the
// rank that asked (the rays of one packet asked of it, flagged in the message): with camera rays
// alone (normals), every cell any rank solves is solved in a packet's lanes, as in one process,
// and the image is the same bits. (Traced one at a time, a rank's answers solve cells outside
// the packets' counters.) ISOTRACE_TEST_REDEAL=rotate moves tiles to ranks whose boxes their rays
// reach second: rays are asked of the others every pass.
TEST(Mpi, CameraRaysAskedOfAnotherRankAreTracedThereInTheirPackets) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", glassNeghip(R"({"width": 64, "height": 48})", R"({"type": "normals", "spp": 3})"));
  const std::string common = " render " + dir + "/s.json --data-parallel --quiet";
  ASSERT_EQ(runIsotrace(common.substr(1) + " --threads 1 -o " + dir + "/one.exr --stats " + dir + "/one.json").status, 0);
  const nlohmann::json single = readJson(dir + "/one.json");
  ASSERT_GT(single["counters"]["Iso/CellsSolved"].get<double>(), 0);
  ASSERT_EQ(single["counters"]["Packet/SolveLanes"], single["counters"]["Iso/CellsSolved"]);
  const std::vector<float> reference = readExr(dir + "/one.exr");
  for (int ranks : {2, 3}) {
    SCOPED_TRACE(ranks);
    const std::string out = dir + "/ranks" + std::to_string(ranks);
    const auto r = runCommand(mpirun(ranks) + "-x ISOTRACE_TEST_REDEAL=rotate " + ISOTRACE_BINARY + common +
                              " --threads 1 -o " + out + ".exr --stats " + out + ".json");
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_EQ(readExr(out + ".exr"), reference);
    const nlohmann::json stats = readJson(out + ".json");
    double sent = 0;
    for (const auto& n : stats["rays_sent_per_rank"]) sent += n.get<double>();
    EXPECT_GT(sent, 0) << stats.dump();
    EXPECT_EQ(stats["counters"]["Packet/SolveLanes"], stats["counters"]["Iso/CellsSolved"]) << stats.dump();
  }
}

// A data-parallel rank with no round left to start takes tiles from another during the pass (the
// giver's unstarted tiles from the end of its list, at most half, with their sums).
// ISOTRACE_TEST_DEAL=first deals every tile to rank 0, which answers every other rank's first
// request before it starts a round, so the others take tiles in the first pass whatever the
// machine's speed: the image stays the single process's, bit for bit, on 2 and 3 ranks, and
// every tile is in the gathered frame once.
TEST(Mpi, DataParallelRanksThatRunOutTakeTilesDuringAPass) {
  expectTheSingleProcessImageWith("ISOTRACE_TEST_DEAL=first", 64, 48, 5, [](int ranks, const nlohmann::json& stats) {
    int tiles = 0;
    for (int q = 0; q < ranks; ++q) tiles += stats["tiles_per_rank"][size_t(q)].get<int>();
    EXPECT_EQ(tiles, 12) << stats.dump();  // 64x48: 4x3 tiles of 16
    // Rank 0 gave half its 12 tiles to the first asker (and half the rest to the next).
    EXPECT_GE(stats["tiles_moved_per_rank"][0].get<int>(), ranks == 2 ? 6 : 9) << stats.dump();
  });
}

// Which tiles move between passes (dealTilesByCost): from the busier rank to the idler, the
// receiver's own tiles (whose centre ray enters its box first) first, then tiles that see no
// volume, each only while it fits in the gap to the mean; never a tile whose rays enter another
// rank's box first, and nothing when the ranks are within 3% of the mean.
TEST(Mpi, TilesDealtByCostGoToTheRankTheirRaysReachFirst) {
  // Rank 0 busy 3 s, rank 1 1 s: 1 s to move. Tile 0 enters rank 0's box first (stays, however
  // costly), tile 1 rank 1's (moves first), tile 2 no box (moves next while it fits), tile 3
  // no box but costlier than what is left of the gap.
  const std::vector<int> owner = {0, 0, 0, 0, 1, 1};
  const std::vector<int> first = {0, 1, -1, -1, 1, -1};
  const std::vector<double> cost = {1.5, 0.6, 0.3, 0.5, 0.4, 0.6};
  EXPECT_EQ(dealTilesByCost(owner, first, cost, {3.0, 1.0}), (std::vector<int>{0, 1, 1, 0, 1, 1}));
  // Within 3% of the mean: nothing moves.
  EXPECT_EQ(dealTilesByCost(owner, first, cost, {1.02, 0.98}), owner);
  // The other way round: rank 1 gives its no-box tile; tile 4 (rank 1's own box) stays.
  EXPECT_EQ(dealTilesByCost(owner, first, cost, {1.0, 3.0}), (std::vector<int>{0, 0, 0, 0, 1, 0}));
  // Three ranks: the busiest gives to both idler ones, each its own tiles first.
  const std::vector<int> owner3 = {0, 0, 0, 0, 1, 2};
  const std::vector<int> first3 = {1, 2, -1, 0, 1, 2};
  const std::vector<double> cost3 = {0.9, 0.9, 0.2, 2.0, 1.0, 1.0};
  EXPECT_EQ(dealTilesByCost(owner3, first3, cost3, {4.0, 1.0, 1.0}), (std::vector<int>{1, 2, 0, 0, 1, 2}));
  // One rank, or no time measured: nothing moves.
  EXPECT_EQ(dealTilesByCost({0, 0}, {-1, -1}, {1.0, 1.0}, {2.0}), (std::vector<int>{0, 0}));
  EXPECT_EQ(dealTilesByCost(owner, first, cost, {0.0, 0.0}), owner);
}

// What a data-parallel render cannot do yet is refused in one line, alone and under mpirun.
TEST(Mpi, DataParallelRefusesWhatItCannotDoYet) {
  const std::string dir = test::scratchDir();
  const std::string volume = test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw");
  test::writeText(dir + "/colour.json", R"({"volumes": [{"file": ")" + volume +
                                            R"(", "isosurfaces": [{"value": 20, "color_by": {"field": "gradient_magnitude", "range": [0, 10]}}]}]})");
  test::writeText(dir + "/thin.json", R"({"materials": {"sheet": {"type": "dielectric", "thin": true}},
    "volumes": [{"file": ")" + volume + R"(", "isosurfaces": [{"value": 20, "material": "sheet"}]}]})");
  test::writeText(dir + "/plain.json", R"({"volumes": [{"file": ")" + volume + R"(", "isosurfaces": [{"value": 20}]}]})");
  const std::string image = dir + "/out.png";
  struct Case {
    std::string args, expected;
  };
  for (const Case& c : {Case{dir + "/colour.json", dir + "/colour.json: /volumes/0/isosurfaces/0: colouring by data is not supported"},
                        Case{dir + "/thin.json", dir + "/thin.json: /materials/sheet: a thin dielectric"},
                        Case{dir + "/plain.json --adaptive 0.1", "adaptive sampling is not supported"}}) {
    for (int ranks : {1, 2}) {
      const std::string command = (ranks > 1 ? mpirun(ranks) : std::string()) + ISOTRACE_BINARY + " render " + c.args +
                                  " --data-parallel --quiet -o " + image;
      const auto r = runCommand(command);
      EXPECT_EQ(r.status, 2) << command << "\n" << r.err;
      EXPECT_NE(r.err.find(c.expected), std::string::npos) << command << "\n" << r.err;
      EXPECT_EQ(r.err.find("isotrace:", r.err.find("isotrace:") + 1), std::string::npos) << "one line: " << r.err;
      EXPECT_FALSE(fs::exists(image));
    }
  }
  // Bad input on one rank only (MPMD): one line from rank 0 naming that rank, no image, no hang.
  test::writeText(dir + "/bad.json", "{\"camera\": {\"fov\": 500}}");
  const std::string common = " render --data-parallel --quiet -o " + image + " ";
  const auto r = runCommand(mpirun(1) + ISOTRACE_BINARY + common + dir + "/plain.json : -np 1 " + ISOTRACE_BINARY + common +
                            dir + "/bad.json");
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("isotrace: rank 1 of 2: " + dir + "/bad.json: /camera/fov"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(image));
}

// A data-parallel sequence: every frame over all ranks (each holding its part of the volume),
// rank 0 writing each; an orbit keeps each rank's part, an iso sweep makes new parts per value
// (balanced by that value's bricks). Each frame is the single process's, for path and compare;
// the stats sum the frames' per-rank figures.
TEST(Mpi, DataParallelSequencesMatchOneProcess) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", glassNeghip(R"({"width": 40, "height": 30})", R"({"type": "path", "spp": 3, "max_depth": 4})"));
  struct Case {
    std::string flags;
    std::vector<std::string> parts;
  };
  for (const Case& c : {Case{"--frames 3 --orbit 60", {""}},
                        Case{"--frames 3 --iso-sweep 1:30:120 --integrator compare", {".direct", ".global", ".indirect"}}}) {
    SCOPED_TRACE(c.flags);
    const std::string common = " render " + dir + "/s.json --data-parallel --quiet " + c.flags;
    const auto one = runIsotrace(common.substr(1) + " --threads 2 -o " + dir + "/one.exr --stats " + dir + "/one.json");
    ASSERT_EQ(one.status, 0) << one.err;
    const auto two = runCommand(mpirun(2) + ISOTRACE_BINARY + common + " --threads 1 -o " + dir + "/two.exr --stats " + dir +
                                "/two.json");
    ASSERT_EQ(two.status, 0) << two.err;
    for (const char* frame : {"0000", "0001", "0002"})
      for (const std::string& part : c.parts) {
        const std::vector<float> a = readExr(dir + "/one." + frame + part + ".exr");
        ASSERT_FALSE(a.empty()) << frame << part;
        EXPECT_EQ(readExr(dir + "/two." + frame + part + ".exr"), a) << frame << part;
      }
    const nlohmann::json stats = readJson(dir + "/two.json"), single = readJson(dir + "/one.json");
    EXPECT_EQ(stats["rays"], single["rays"]);  // (the cells walked differ: a ray is walked in each part it reaches)
    EXPECT_EQ(stats["frames"], 3);
    // Tiles per rank summed over the frames: every frame's tiles (40x30 pixels: 3x2 tiles of 16).
    EXPECT_EQ(stats["tiles_per_rank"][0].get<int>() + stats["tiles_per_rank"][1].get<int>(), 3 * 6) << stats.dump();
    double asked = 0;
    for (const auto& n : stats["rays_asked_per_rank"]) asked += n.get<double>();
    EXPECT_EQ(asked, single["rays"]["total"].get<double>());
  }
}

// A time series over ranks: frames dealt to ranks (each rank reads its own frames' steps), every
// frame over all ranks with --data-parallel (each rank its part of each step), and a video
// (each of its frames by tiles): the frames of one process, bit for bit.
TEST(Mpi, TimeSeriesMatchOneProcess) {
  const std::string dir = test::scratchDir();
  std::string files;
  for (int k = 0; k < 3; ++k) {
    std::vector<float> v(20 * 20 * 20);
    for (int z = 0; z < 20; ++z)
      for (int y = 0; y < 20; ++y)
        for (int x = 0; x < 20; ++x)
          v[size_t((z * 20 + y) * 20 + x)] = float(4 + 2 * k - std::sqrt((x - 9.5) * (x - 9.5) + (y - 9.5) * (y - 9.5) + (z - 9.5) * (z - 9.5)));
    test::writeBytes(dir + "/b" + std::to_string(k) + ".raw", std::string(reinterpret_cast<const char*>(v.data()), v.size() * 4));
    files += std::string(k ? ", " : "") + "\"b" + std::to_string(k) + ".raw\"";
  }
  test::writeText(dir + "/s.json", R"({"film": {"width": 32, "height": 24}, "integrator": {"type": "path", "spp": 2, "max_depth": 3},
    "volumes": [{"file": [)" + files + R"(], "dims": [20, 20, 20], "type": "float32", "isosurfaces": [{"value": 0}]}],
    "lights": [{"type": "directional", "direction": [0.4, -1, 0.5], "irradiance": 2.5}]})");
  const auto one = runIsotrace("render " + dir + "/s.json --quiet --threads 2 -o " + dir + "/one.exr");
  ASSERT_EQ(one.status, 0) << one.err;
  for (const std::string& flags : {std::string(""), std::string("--data-parallel")}) {
    SCOPED_TRACE(flags);
    const auto two = runCommand(mpirun(2) + ISOTRACE_BINARY + " render " + dir + "/s.json --quiet --threads 1 " + flags +
                                " -o " + dir + "/two.exr");
    ASSERT_EQ(two.status, 0) << two.err;
    for (const char* frame : {"0000", "0001", "0002"}) {
      const std::vector<float> a = readExr(dir + "/one." + frame + ".exr");
      ASSERT_FALSE(a.empty());
      EXPECT_EQ(readExr(dir + "/two." + frame + ".exr"), a) << frame;
    }
  }
  const auto video = runCommand(mpirun(2) + ISOTRACE_BINARY + " render " + dir + "/s.json --quiet -o " + dir + "/v.mp4 --keep-frames");
  ASSERT_EQ(video.status, 0) << video.err;
  ASSERT_EQ(runIsotrace("render " + dir + "/s.json --quiet -o " + dir + "/one.png").status, 0);
  for (const char* frame : {"0000", "0001", "0002"}) {
    const std::vector<float> png = readExr(dir + "/one." + std::string(frame) + ".png");
    ASSERT_EQ(png.size(), size_t(32 * 24 * 3)) << frame;
    EXPECT_EQ(readExr(dir + "/v." + std::string(frame) + ".png"), png) << frame;
  }
  EXPECT_TRUE(fs::exists(dir + "/v.mp4"));
}

// `isotrace watertight --data-parallel` under mpirun: each rank holds only its part of the volume
// and every query is the closest of the ranks' answers, exchanged between the processes. The
// counts are those of the same split in one process (`--ranks N`, tests/data_parallel_test.cpp),
// with 0 errors of every kind, at the origin and at 1e5, on 2 and 3 ranks. Bad input on one rank
// is one line from rank 0 naming it; --data-parallel without mpirun is refused.
TEST(Mpi, WatertightAcrossRanksUnderMpirun) {
  const std::string dir = test::scratchDir();
  const std::string volume = test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw");
  test::writeText(dir + "/h.json", R"({"volumes": [{"file": ")" + volume + R"(", "isosurfaces": [{"value": 20}, {"value": 10}]}]})");
  for (const std::string offset : {"0,0,0", "1e5,1e5,1e5"})
    for (int ranks : {2, 3}) {
      SCOPED_TRACE(offset + ", " + std::to_string(ranks) + " ranks");
      const std::string args = " watertight " + dir + "/h.json --rays 1500 --offset " + offset + " --json ";
      const auto one = runIsotrace(args.substr(1) + dir + "/one.json --ranks " + std::to_string(ranks));
      ASSERT_EQ(one.status, 0) << one.err;
      const auto many = runCommand(mpirun(ranks) + ISOTRACE_BINARY + args + dir + "/many.json --data-parallel");
      ASSERT_EQ(many.status, 0) << many.err;
      EXPECT_NE(many.out.find("split over " + std::to_string(ranks) + " MPI ranks"), std::string::npos) << many.out;
      EXPECT_EQ(many.out.find("watertight", many.out.find("watertight") + 1), std::string::npos) << "rank 0 reports: " << many.out;
      const nlohmann::json a = readJson(dir + "/one.json"), b = readJson(dir + "/many.json");
      EXPECT_EQ(a, b);
      EXPECT_EQ(b["total"]["parity_errors"], 0);
      EXPECT_EQ(b["total"]["self_hits"], 0);
      EXPECT_EQ(b["total"]["inside_escapes"], 0);
      EXPECT_EQ(b["total"]["shadow_mismatches"], 0);
      EXPECT_GT(b["total"]["crossings"].get<double>(), 1000);
    }
  const auto alone = runIsotrace("watertight " + dir + "/h.json --rays 10 --data-parallel");
  EXPECT_EQ(alone.status, 2);
  EXPECT_NE(alone.err.find("--data-parallel: runs under mpirun"), std::string::npos) << alone.err;
  // Rank 1's scene names a volume file that is not there: one line from rank 0, no hang.
  test::writeText(dir + "/missing.json", R"({"volumes": [{"file": ")" + dir + R"(/gone_8x8x8_uint8.raw", "isosurfaces": [{"value": 2}]}]})");
  const std::string common = " watertight --rays 10 --data-parallel ";
  const auto r = runCommand(mpirun(1) + ISOTRACE_BINARY + common + dir + "/h.json : -np 1 " + ISOTRACE_BINARY + common + dir +
                            "/missing.json");
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("isotrace: rank 1 of 2: " + dir + "/gone_8x8x8_uint8.raw"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("isotrace:", r.err.find("isotrace:") + 1), std::string::npos) << "one line: " << r.err;
}

// The hostile cases of a data-parallel run: a rank killed mid-frame ends the whole run (mpirun
// names it; nobody waits for its answers forever; the same for an image-parallel run, where the
// others would wait for its tiles), and a truncated OpenVDB file on one rank only is one line
// from rank 0 naming that rank, no image.
TEST(Mpi, DataParallelRankLostOrBadFileEndsTheRun) {
  const std::string dir = test::scratchDir();
  const std::string vdb = test::dataPath("volumes/smoke.vdb");
  auto scene = [&](const std::string& file) {
    return R"({"film": {"width": 40, "height": 30}, "integrator": {"type": "path", "spp": 4},
      "volumes": [{"file": ")" + file + R"(", "isosurfaces": [{"value": 0.2}]}]})";
  };
  test::writeText(dir + "/good.json", scene(vdb));
  const std::string image = dir + "/out.exr";
  const auto t0 = std::chrono::steady_clock::now();
  for (const std::string mode : {" --data-parallel", ""}) {  // (image-parallel: a rank rendering or taking tiles)
    SCOPED_TRACE(mode);
    test::Process run(mpirun(2) + ISOTRACE_BINARY + " render " + dir + "/good.json" + mode +
                      " --spp 1000000 --threads 1 -o " + image + " >/dev/null");
    ASSERT_TRUE(run.waitForErr("isotrace: rendering")) << run.err();  // every rank is past loading
    const std::vector<pid_t> ranks = test::processesWithArgument(ISOTRACE_BINARY, dir + "/good.json");
    ASSERT_EQ(ranks.size(), 2u) << run.err();
    kill(std::max(ranks[0], ranks[1]), SIGKILL);  // (the later one started: not necessarily rank 1)
    EXPECT_NE(run.wait(), 0) << run.err();
    EXPECT_NE(run.err().find("rank"), std::string::npos) << run.err();
    EXPECT_FALSE(fs::exists(image));
  }
  // The same file cut short, on rank 1 only (MPMD).
  std::string bytes;
  {
    std::ifstream in(vdb, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_GT(bytes.size(), 1000u);
  {
    std::ofstream out(dir + "/cut.vdb", std::ios::binary);
    out.write(bytes.data(), std::streamsize(bytes.size() / 2));
  }
  test::writeText(dir + "/cut.json", scene(dir + "/cut.vdb"));
  const std::string common = " render --data-parallel --quiet --threads 1 -o " + image + " ";
  const auto r = runCommand(mpirun(1) + ISOTRACE_BINARY + common + dir + "/good.json : -np 1 " + ISOTRACE_BINARY + common +
                            dir + "/cut.json");
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("isotrace: rank 1 of 2: " + dir + "/cut.vdb"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("isotrace:", r.err.find("isotrace:") + 1), std::string::npos) << "one line: " << r.err;
  EXPECT_FALSE(fs::exists(image));
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 100) << "no hang";
}

// `isotrace view` is one server in one process: under mpirun with more ranks it says so in one
// line (rank 0's) and ends with status 2, instead of every rank starting a server on the port.
TEST(Mpi, ViewRunsInOneProcess) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", pathScene());
  const auto r = runCommand(mpirun(2) + ISOTRACE_BINARY + " view " + dir + "/s.json --port 0");
  EXPECT_NE(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("isotrace: view: runs in one process: start it without mpirun (it was started as 2 ranks)"),
            std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("isotrace:", r.err.find("isotrace:") + 1), std::string::npos) << "one line: " << r.err;
}

// SIGINT on mpirun (it forwards SIGTERM to the ranks, and kills them a second later): rank 0
// writes the image of the samples gathered so far, every pixel sampled (pieces go out pass
// by pass; data-parallel ranks stop together after a pass over all pixels), marked interrupted.
TEST(Mpi, InterruptWritesThePartialImage) {
  for (const std::string mode : {"", " --data-parallel"}) {
    SCOPED_TRACE(mode);
    const std::string dir = test::scratchDir();
    test::writeText(dir + "/s.json", pathScene());
    const std::string image = dir + "/t.exr";
    fs::remove(image);  // (the scratch folder is the test's: the other mode's image may be there)
    // The signal goes once rank 0 says the render has begun (every rank has loaded by then).
    test::Process run(mpirun(2) + ISOTRACE_BINARY + " render " + dir + "/s.json --integrator path" + mode +
                      " --spp 1000000 --threads 1 -o " + image + " >/dev/null");
    ASSERT_TRUE(run.waitForErr("isotrace: rendering")) << run.err();
    run.signal(SIGINT);
    EXPECT_NE(run.wait(), 0) << "mpirun ends with an error status after a signal";
    std::map<std::string, std::string> metadata;
    const std::vector<float> pixels = readExr(image, nullptr, &metadata);
    ASSERT_FALSE(pixels.empty()) << run.err();
    EXPECT_EQ(metadata["isotrace:interrupted"], "1");
    EXPECT_GE(std::stoi(metadata["isotrace:spp"]), 1) << "every pixel has samples";
    for (const auto& entry : fs::directory_iterator(dir))
      EXPECT_EQ(entry.path().filename().string().find(".partial"), std::string::npos) << entry.path();
  }
}

}  // namespace
}  // namespace iso
