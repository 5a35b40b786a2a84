// `isotrace view`'s server (renderer/view.cpp) through its HTTP API: the page, the state, bad
// requests refused without a change, frames over server-sent events, Save that `isotrace
// render` reproduces, a dropped connection, stopping. The page itself is driven in Chromium by
// tests/view_browser.py.
#include <gtest/gtest.h>

#include <fstream>
#include <httplib.h>

#include <algorithm>
#include <chrono>
#include <future>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <thread>

#include "renderer/view.h"
#include "scene/colormap.h"
#include "tests/test_util.h"

namespace iso {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

// The server of a scene on a free port, serving from its own thread while the test runs.
struct Running {
  ViewServer server;
  int port;
  std::thread thread;
  Running(const std::string& scene, int width, int height, const SceneOverrides& overrides = {})
      : server(scene, [&] {
          ViewOptions o;
          o.port = 0;
          o.width = width;
          o.height = height;
          o.threads = 2;
          o.overrides = overrides;
          return o;
        }()),
        port(server.bind()), thread([this] { server.serve(); }) {}
  ~Running() {
    server.stop();
    thread.join();
  }
};

Json state(httplib::Client& c) {
  auto r = c.Get("/api/state");
  EXPECT_TRUE(r);
  return r ? Json::parse(r->body) : Json();
}

// Reads the event stream until a frame of `version` with at least `spp` samples comes; its data.
Json frameOf(int port, uint64_t version, int spp) {
  httplib::Client c("127.0.0.1", port);
  c.set_read_timeout(30, 0);
  std::string buffer;
  Json found;
  c.Get("/api/events", [&](const char* data, size_t n) {
    buffer.append(data, n);
    for (size_t end; (end = buffer.find("\n\n")) != std::string::npos; buffer.erase(0, end + 2)) {
      const std::string event = buffer.substr(0, end);
      const size_t at = event.find("data: ");
      if (event.rfind("event: frame", 0) != 0 || at == std::string::npos) continue;
      const Json f = Json::parse(event.substr(at + 6));
      if (f["version"] == version && f["spp"].get<int>() >= spp) {
        found = f;
        return false;  // enough: drop the connection
      }
    }
    return true;
  });
  return found;
}

TEST(View, ServesItsPageStateAndFramesOnly) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  Running view(dir + "/s.json", 48, 36);
  httplib::Client c("127.0.0.1", view.port);
  auto page = c.Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  for (const char* part : {"id=\"view\"", "id=\"spp\"", "id=\"integrator\"", "\"iso\"", "EventSource"})
    EXPECT_NE(page->body.find(part), std::string::npos) << part;
  EXPECT_EQ(page->body.find("http://"), std::string::npos) << "the page fetches nothing from elsewhere";
  // Never a file named by a request.
  for (const char* path : {"/s.json", "/../s.json", "/etc/passwd", "/api/../s.json", "/api/x", "/%2e%2e/s.json"}) {
    auto r = c.Get(path);
    ASSERT_TRUE(r) << path;
    EXPECT_EQ(r->status, 404) << path;
  }
  const Json s = state(c);
  ASSERT_EQ(s["surfaces"].size(), 1u);
  EXPECT_EQ(s["surfaces"][0]["value"], 0.6);
  EXPECT_LT(s["surfaces"][0]["min"].get<double>(), 0.6);
  EXPECT_GT(s["surfaces"][0]["max"].get<double>(), 0.6);
  EXPECT_EQ(s["width"], 48);
  const Json first = frameOf(view.port, s["version"], 1);
  ASSERT_FALSE(first.is_null());
  EXPECT_EQ(first["image"].get<std::string>().rfind("data:image/jpeg;base64,", 0), 0u);
  auto jpeg = c.Get("/api/frame.jpg");
  ASSERT_TRUE(jpeg);
  EXPECT_EQ(jpeg->get_header_value("Content-Type"), "image/jpeg");
  EXPECT_EQ(jpeg->body.substr(0, 2), std::string("\xff\xd8", 2));
}

// --iso and --set: the view starts from the scene as overridden (its state shows the values).
TEST(View, StartsFromTheOverriddenScene) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  SceneOverrides overrides;
  overrides.iso = {"0=0.45"};
  overrides.set = {"/integrator/type=normals"};
  Running view(dir + "/s.json", 32, 24, overrides);
  httplib::Client c("127.0.0.1", view.port);
  const Json s = state(c);
  ASSERT_EQ(s["surfaces"].size(), 1u);
  EXPECT_EQ(s["surfaces"][0]["value"], 0.45);
  EXPECT_EQ(s["integrator"], "normals");
}

// Colour by data and slices in the view: the state lists them; a change of map, range or slice
// position reaches the scene (a new version, Save writes it); bad ones are 400 and change nothing.
TEST(View, ColorByAndSlicesChangeLive) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", R"({"camera": {"position": [0, 0, 4]}, "film": {"width": 16, "height": 12},
    "volumes": [{"procedural": {"field": "sphere", "resolution": [16, 16, 16]},
                 "isosurfaces": [{"value": 0.7, "color_by": {"field": "gradient_magnitude", "map": "plasma", "range": [0, 2]}}],
                 "slices": [{"axis": "z", "position": 0.2}, {"point": [0, 0, 0], "normal": [0, 3, 4]}]}]})");
  Running view(dir + "/s.json", 16, 12);
  httplib::Client c("127.0.0.1", view.port);
  const Json s = state(c);
  ASSERT_EQ(s["surfaces"].size(), 1u);
  EXPECT_EQ(s["surfaces"][0]["color_by"]["map"], "plasma");
  EXPECT_EQ(s["surfaces"][0]["color_by"]["range"], Json::array({0, 2}));
  EXPECT_EQ(s["maps"].size(), ColorMap::names().size());
  ASSERT_EQ(s["slices"].size(), 2u);
  EXPECT_DOUBLE_EQ(s["slices"][0]["position"].get<double>(), 0.2);
  EXPECT_DOUBLE_EQ(s["slices"][0]["min"].get<double>(), -1);  // the procedural grid spans [-1, 1]
  EXPECT_DOUBLE_EQ(s["slices"][0]["max"].get<double>(), 1);
  EXPECT_NEAR(s["slices"][1]["max"].get<double>(), 1.4, 1e-12);  // (3 + 4) / 5 at the corner (1, 1, 1)
  auto post = [&](const std::string& body) { return c.Post("/api/state", body, "application/json"); };
  auto ok = post(R"({"surface": 0, "color_by": {"map": "cividis", "range": [0.5, 1.5]}})");
  ASSERT_TRUE(ok);
  ASSERT_EQ(ok->status, 200) << ok->body;
  ok = post(R"({"slice": 1, "position": -0.5})");
  ASSERT_TRUE(ok);
  ASSERT_EQ(ok->status, 200) << ok->body;
  const Json now = Json::parse(ok->body);
  EXPECT_EQ(now["version"], s["version"].get<uint64_t>() + 2);
  EXPECT_EQ(now["surfaces"][0]["color_by"]["map"], "cividis");
  EXPECT_EQ(now["surfaces"][0]["color_by"]["range"], Json::array({0.5, 1.5}));
  EXPECT_NEAR(now["slices"][1]["position"].get<double>(), -0.5, 1e-12);
  for (const char* bad : {R"({"surface": 0, "color_by": {"map": "jet"}})", R"({"surface": 0, "color_by": {"range": [2, 1]}})",
                          R"({"surface": 0, "color_by": {"field": "x"}})", R"({"slice": 2, "position": 0})",
                          R"({"slice": 0, "position": 3})", R"({"slice": 0})", R"({"position": 0})"}) {
    auto r = post(bad);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 400) << bad << ": " << r->body;
  }
  EXPECT_EQ(state(c)["version"], now["version"]) << "a refused change changes nothing";
  const Json frame = frameOf(view.port, now["version"], 1);
  EXPECT_FALSE(frame.is_null()) << "the changed scene renders";
}

// Clip planes across the axes: the state offers one per axis over the volumes' extent; turning
// one on puts a plane into every volume's "clip" (after the file's own entries; meshes stay
// whole), flipping turns its normal round, off takes it out; bad ones are 400 and change nothing.
TEST(View, AxisClipPlanesChangeTheScene) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", R"({"camera": {"position": [0, 0, 4]}, "film": {"width": 16, "height": 12},
    "volumes": [{"procedural": {"field": "sphere", "resolution": [16, 16, 16]}, "isosurfaces": [{"value": 0.7}],
                 "clip": [{"box": {"min": [-2, -2, -2], "max": [2, 2, 2]}}]}]})");
  Running view(dir + "/s.json", 16, 12);
  httplib::Client c("127.0.0.1", view.port);
  const Json s = state(c);
  ASSERT_EQ(s["clip"].size(), 3u);
  EXPECT_EQ(s["clip"][1]["axis"], "y");
  EXPECT_EQ(s["clip"][1]["on"], false);
  EXPECT_DOUBLE_EQ(s["clip"][1]["min"].get<double>(), -1);  // the procedural grid spans [-1, 1]
  EXPECT_DOUBLE_EQ(s["clip"][1]["max"].get<double>(), 1);
  auto post = [&](const std::string& body) { return c.Post("/api/state", body, "application/json"); };
  auto r = post(R"({"clip": {"axis": "y", "on": true, "position": 0.25}})");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200) << r->body;
  r = post(R"({"clip": {"axis": "y", "flip": true}})");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200) << r->body;
  const Json now = Json::parse(r->body);
  EXPECT_EQ(now["clip"][1]["on"], true);
  EXPECT_EQ(now["clip"][1]["flip"], true);
  EXPECT_DOUBLE_EQ(now["clip"][1]["position"].get<double>(), 0.25);
  // Save writes the file's box and the view's plane.
  const Json frame = frameOf(view.port, now["version"], 1);
  ASSERT_FALSE(frame.is_null()) << "the clipped scene renders";
  auto saved = c.Post("/api/save", "", "application/json");
  ASSERT_TRUE(saved);
  ASSERT_EQ(saved->status, 200) << saved->body;
  std::ifstream file(Json::parse(saved->body)["files"][0].get<std::string>());
  const Json written = Json::parse(file);
  const Json& clip = written["volumes"][0]["clip"];
  ASSERT_EQ(clip.size(), 2u);
  EXPECT_TRUE(clip[0].contains("box"));
  EXPECT_EQ(clip[1]["plane"]["normal"], Json::array({0, -1, 0}));
  EXPECT_EQ(clip[1]["plane"]["point"], Json::array({0, 0.25, 0}));
  EXPECT_FALSE(written.contains("clip"));
  r = post(R"({"clip": {"axis": "y", "on": false}})");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200) << r->body;
  const Json off = Json::parse(r->body);
  for (const char* bad : {R"({"clip": {"axis": "w", "on": true}})", R"({"clip": {"on": true}})",
                          R"({"clip": {"axis": "x", "position": 5}})", R"({"clip": {"axis": "x", "on": 1}})",
                          R"({"clip": {"axis": "x", "offset": 0}})", R"({"clip": [1]})"}) {
    auto b = post(bad);
    ASSERT_TRUE(b);
    EXPECT_EQ(b->status, 400) << bad << ": " << b->body;
  }
  EXPECT_EQ(state(c)["version"], off["version"]) << "a refused change changes nothing";
}

// Volumes that change over time: a time slider's steps in the state, {"time": K} shows step K
// (its own picture), and a bad step is refused.
TEST(View, TheTimeStepChangesLive) {
  const std::string dir = test::scratchDir();
  for (int k = 0; k < 2; ++k) {
    std::vector<float> v(16 * 16 * 16);
    for (int z = 0; z < 16; ++z)
      for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x)
          v[size_t((z * 16 + y) * 16 + x)] = float((k == 0 ? 3 : 6) - std::sqrt((x - 7.5) * (x - 7.5) + (y - 7.5) * (y - 7.5) + (z - 7.5) * (z - 7.5)));
    test::writeBytes(dir + "/b" + std::to_string(k) + ".raw", std::string(reinterpret_cast<const char*>(v.data()), v.size() * 4));
  }
  test::writeText(dir + "/s.json", R"({"camera": {"position": [7.5, 7.5, 40], "look_at": [7.5, 7.5, 7.5]}, "film": {"width": 16, "height": 12},
    "integrator": {"type": "eyelight", "spp": 1},
    "volumes": [{"file": ["b0.raw", "b1.raw"], "dims": [16, 16, 16], "type": "float32", "isosurfaces": [{"value": 0}]}]})");
  Running view(dir + "/s.json", 16, 12);
  httplib::Client c("127.0.0.1", view.port);
  const Json s = state(c);
  ASSERT_TRUE(s.contains("time")) << s.dump();
  EXPECT_EQ(s["time"]["steps"], 2);
  EXPECT_EQ(s["time"]["step"], 0);
  const Json first = frameOf(view.port, s["version"], 1);
  ASSERT_FALSE(first.is_null());
  auto r = c.Post("/api/state", R"({"time": 1})", "application/json");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200) << r->body;
  const Json now = Json::parse(r->body);
  EXPECT_EQ(now["time"]["step"], 1);
  const Json second = frameOf(view.port, now["version"], 1);
  ASSERT_FALSE(second.is_null());
  EXPECT_NE(first["image"], second["image"]) << "a bigger ball at step 1";
  for (const char* bad : {R"({"time": 2})", R"({"time": -1})", R"({"time": "1"})", R"({"time": 0.5})"}) {
    auto b = c.Post("/api/state", bad, "application/json");
    ASSERT_TRUE(b);
    EXPECT_EQ(b->status, 400) << bad << ": " << b->body;
  }
  EXPECT_EQ(state(c)["time"]["step"], 1) << "a refused change changes nothing";
}

TEST(View, BadRequestsAre400AndChangeNothing) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  Running view(dir + "/s.json", 32, 24);
  httplib::Client c("127.0.0.1", view.port);
  const Json before = state(c);
  const std::string deep = std::string(100, '[') + std::string(100, ']');
  for (const auto& [body, message] : std::vector<std::pair<std::string, std::string>>{
           {"{", "expected a JSON object"},
           {"[1]", "expected a JSON object"},
           {deep, "nested"},
           {R"({"bogus": 1})", "/bogus: unknown key"},
           {R"({"surface": 1, "value": 0.5})", "no iso-surface 1 (the scene has 1)"},
           {R"({"surface": -1, "value": 0.5})", "no iso-surface -1"},
           {R"({"surface": 0.5, "value": 0.5})", "/surface: expected the index"},
           {R"({"value": 0.5})", "/surface: expected the index"},
           {R"({"surface": 0, "value": 1e9})", "/value: iso value out of the volume's range"},
           {R"({"surface": 0, "value": "x"})", "/value: expected a number"},
           {R"({"surface": 0, "color": "red"})", "/color: expected a colour"},
           {R"({"surface": 0})", "a surface goes with a value, a color or a color_by"},
           {R"({"integrator": "fancy"})", "/integrator: expected one of"},
           {R"({"camera": {"position": [0, 1, 0], "look_at": [0, 1, 0]}})", "camera looks at its own position"},
           {R"({"camera": {"fov": 500}})", "/camera/fov"},
           {R"({"camera": {"position": [0, "a", 0]}})", "/camera/position"},
           {R"({"camera": {"zoom": 2}})", "/camera/zoom: unknown key"},
           {R"({"time": 0})", "/time: no volume of the scene changes over time"}}) {
    auto r = c.Post("/api/state", body, "application/json");
    ASSERT_TRUE(r) << body;
    EXPECT_EQ(r->status, 400) << body << ": " << r->body;
    const Json error = Json::parse(r->body, nullptr, false);
    ASSERT_TRUE(error.is_object()) << r->body;
    EXPECT_NE(error.value("error", "").find(message), std::string::npos) << body << ": " << r->body;
  }
  EXPECT_EQ(state(c), before) << "nothing changed";
  // A request larger than any change is refused before it is read.
  auto big = c.Post("/api/state", std::string(1 << 20, ' '), "application/json");
  ASSERT_TRUE(big);
  EXPECT_EQ(big->status, 413);
}

TEST(View, ChangesReachTheFramesAndSaveRendersTheSamePicture) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  Running view(dir + "/s.json", 40, 30);
  httplib::Client c("127.0.0.1", view.port);
  const Json before = state(c);
  const Json firstFrame = frameOf(view.port, before["version"], 1);
  ASSERT_FALSE(firstFrame.is_null());
  auto changed = c.Post("/api/state", R"({"surface": 0, "value": 0.3, "color": "#20c040", "integrator": "path"})",
                        "application/json");
  ASSERT_TRUE(changed);
  ASSERT_EQ(changed->status, 200) << changed->body;
  const Json after = Json::parse(changed->body);
  EXPECT_EQ(after["version"], before["version"].get<uint64_t>() + 1);
  EXPECT_EQ(after["surfaces"][0]["value"], 0.3);
  EXPECT_EQ(after["surfaces"][0]["color"], "#20c040");
  EXPECT_EQ(after["integrator"], "path");
  // A camera change leaves what it does not name.
  auto moved = c.Post("/api/state", R"({"camera": {"position": [0, 2, 5]}})", "application/json");
  ASSERT_TRUE(moved);
  ASSERT_EQ(moved->status, 200) << moved->body;
  const Json now = Json::parse(moved->body);
  EXPECT_EQ(now["camera"]["position"], Json::array({0, 2, 5}));
  EXPECT_EQ(now["camera"]["look_at"], before["camera"]["look_at"]);
  // The scene's spp (4) is reached, then Save.
  const Json done = frameOf(view.port, now["version"], 4);
  ASSERT_FALSE(done.is_null());
  EXPECT_NE(done["image"], firstFrame["image"]);
  auto saved = c.Post("/api/save", "", "application/json");
  ASSERT_TRUE(saved);
  ASSERT_EQ(saved->status, 200) << saved->body;
  const Json files = Json::parse(saved->body)["files"];
  ASSERT_EQ(files.size(), 3u);
  EXPECT_EQ(files[0], dir + "/s.view-1.json");
  EXPECT_EQ(files[1], dir + "/s.view-1.exr");
  for (const auto& f : files) EXPECT_TRUE(fs::exists(f.get<std::string>())) << f;
  const auto r = test::runIsotrace("render " + dir + "/s.view-1.json -o " + dir + "/batch.exr --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  const std::vector<float> batch = test::readExr(dir + "/batch.exr");
  ASSERT_FALSE(batch.empty());
  EXPECT_EQ(batch, test::readExr(dir + "/s.view-1.exr")) << "Save reproduces the picture";
  // A second save never overwrites the first.
  auto again = c.Post("/api/save", "", "application/json");
  ASSERT_TRUE(again);
  EXPECT_EQ(Json::parse(again->body)["files"][0], dir + "/s.view-2.json");
}

// The denoise toggle: the fast mode while samples come in, the scene's mode at the last pass;
// Save keeps it, and the saved scene renders the same denoised picture.
TEST(View, DenoiseToggleDenoisesWhileSamplesComeInAndSaveKeepsIt) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  SceneOverrides overrides;
  overrides.set = {"/integrator/type=path", "/integrator/spp=4"};
  Running view(dir + "/s.json", 40, 30, overrides);
  httplib::Client c("127.0.0.1", view.port);
  EXPECT_EQ(state(c)["denoise"], false);
  auto changed = c.Post("/api/state", R"({"denoise": true})", "application/json");
  ASSERT_TRUE(changed);
  ASSERT_EQ(changed->status, 200) << changed->body;
  const Json after = Json::parse(changed->body);
  EXPECT_EQ(after["denoise"], true);
  const Json first = frameOf(view.port, after["version"], 1);
  ASSERT_FALSE(first.is_null());
  EXPECT_EQ(first["denoise"], first["spp"].get<int>() < 4 ? "fast" : "quality");
  const Json last = frameOf(view.port, after["version"], 4);
  ASSERT_FALSE(last.is_null());
  EXPECT_EQ(last["denoise"], "quality");
  auto saved = c.Post("/api/save", "", "application/json");
  ASSERT_TRUE(saved);
  ASSERT_EQ(saved->status, 200) << saved->body;
  const std::string base = dir + "/s.view-1";
  std::ifstream in(base + ".json");
  const Json doc = Json::parse(in);
  EXPECT_EQ(doc["film"]["denoise"], "quality");
  const auto r = test::runIsotrace("render " + base + ".json -o " + dir + "/batch.exr --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  const std::vector<float> batch = test::readExr(dir + "/batch.exr");
  ASSERT_FALSE(batch.empty());
  // (The batch EXR also holds the raw layer; the view's EXR only the denoised image.)
  const std::vector<float> shown = test::readExr(base + ".exr");
  ASSERT_EQ(batch.size(), shown.size() * 2);
  for (size_t p = 0; p < shown.size() / 3; ++p)
    for (int k = 0; k < 3; ++k) ASSERT_EQ(batch[6 * p + size_t(k)], shown[3 * p + size_t(k)]) << p;
  auto off = c.Post("/api/state", R"({"denoise": "yes"})", "application/json");
  ASSERT_TRUE(off);
  EXPECT_EQ(off->status, 400);
}

TEST(View, SurvivesDroppedConnectionsAndStopsPromptly) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  auto view = std::make_unique<Running>(dir + "/s.json", 32, 24);
  // Event streams dropped at once, and one dropped mid-stream.
  for (int i = 0; i < 5; ++i) {
    httplib::Client c("127.0.0.1", view->port);
    c.set_read_timeout(0, 200000);
    c.Get("/api/events", [](const char*, size_t) { return false; });
  }
  httplib::Client c("127.0.0.1", view->port);
  auto r = c.Get("/api/state");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200);
  // An open event stream does not hold the server up: it stops long before the listener would
  // give up waiting (120 s; the bound below is a safety net, not a measure of speed). The
  // server is stopped once the listener has had its first bytes: the stream is open.
  std::promise<void> streaming;
  std::thread listener([port = view->port, &streaming] {
    httplib::Client l("127.0.0.1", port);
    l.set_read_timeout(120, 0);
    bool first = true;
    l.Get("/api/events", [&](const char*, size_t) {
      if (first) streaming.set_value();
      first = false;
      return true;
    });
    if (first) streaming.set_value();  // no bytes at all: the wait below ends, the test fails
  });
  streaming.get_future().wait();
  const auto t0 = std::chrono::steady_clock::now();
  view.reset();
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 60.0);
  listener.join();
}

// Bad flags and scenes: one line, status 2, nothing listening.
TEST(View, BadFlagsAndScenesAreBadInput) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  test::writeText(dir + "/bad.json", "{\"camera\": {\"fov\": 500}}");
  for (const auto& [args, message] : std::vector<std::pair<std::string, std::string>>{
           {dir + "/missing.json", dir + "/missing.json"},
           {dir + "/bad.json", "/camera/fov"},
           {dir + "/s.json --port 70000", "--port"},
           {dir + "/s.json --resolution 0x5", "--resolution: expected WIDTHxHEIGHT"},
           {dir + "/s.json --resolution 4000x4000", "at most 2^22 pixels"},
           {dir + "/s.json --host 999.1.1.1 --port 0", "cannot listen on 999.1.1.1"},
           {dir + "/s.json --threads -1", "--threads"},
           {dir + "/s.json --iso 3=1", "--iso 3=1: no iso-surface '3' (the scene has 1"},
           {dir + "/s.json --set /camera/fov=x", "/camera/fov: expected a number"}}) {
    const auto r = test::runIsotrace("view " + args);
    EXPECT_EQ(r.status, 2) << args << ": " << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << ": " << r.err;
    EXPECT_EQ(r.out, "") << args;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << args << ": " << r.err;
  }
}

}  // namespace
}  // namespace iso
