#include "renderer/view.h"

#include <httplib.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "renderer/render.h"
#include "renderer/view_page.h"
#include "scene/image_plugin.h"
#include "scene/time_series.h"
#include "scene/world.h"
#include "volume/input_error.h"

namespace iso {

namespace {

using Json = nlohmann::json;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

const char* const kIntegrators[] = {"normals", "eyelight", "ao", "direct", "path", "compare"};

double srgbToLinear(double v) { return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4); }
double linearToSrgb(double v) {
  v = std::clamp(v, 0.0, 1.0);
  return v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1 / 2.4) - 0.055;
}

std::string hexColour(const Vec3d& linear) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "#%02x%02x%02x", int(std::lround(linearToSrgb(linear.x) * 255)),
                int(std::lround(linearToSrgb(linear.y) * 255)), int(std::lround(linearToSrgb(linear.z) * 255)));
  return buf;
}

// "#rrggbb" (the colour input's sRGB) to linear RGB; false if it is no such colour.
bool parseHexColour(const std::string& text, Vec3d& linear) {
  if (text.size() != 7 || text[0] != '#') return false;
  for (size_t i = 1; i < 7; ++i)
    if (!std::isxdigit(static_cast<unsigned char>(text[i]))) return false;
  for (int c = 0; c < 3; ++c) linear[c] = srgbToLinear(std::stoi(text.substr(1 + 2 * c, 2), nullptr, 16) / 255.0);
  return true;
}

std::string base64(const std::string& bytes) {
  static const char* digits = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  for (size_t i = 0; i < bytes.size(); i += 3) {
    const uint32_t a = uint8_t(bytes[i]), b = i + 1 < bytes.size() ? uint8_t(bytes[i + 1]) : 0,
                   c = i + 2 < bytes.size() ? uint8_t(bytes[i + 2]) : 0;
    const uint32_t n = (a << 16) | (b << 8) | c;
    out += digits[(n >> 18) & 63];
    out += digits[(n >> 12) & 63];
    out += i + 1 < bytes.size() ? digits[(n >> 6) & 63] : '=';
    out += i + 2 < bytes.size() ? digits[n & 63] : '=';
  }
  return out;
}

// 8-bit RGB as a JPEG file's bytes (empty if it cannot be encoded).
std::string jpeg(const std::vector<uint8_t>& rgb, int w, int h) {
  std::vector<unsigned char> bytes;
  if (!imagePlugin().encodeJpeg(rgb.data(), w, h, 90, bytes).empty()) return {};
  return std::string(bytes.begin(), bytes.end());
}

Json vec(const Vec3d& v) { return Json::array({v.x, v.y, v.z}); }

}  // namespace

// The scene being explored: its JSON (the source of truth: every change patches it and is
// validated by the scene parser before it is taken), the render thread, the latest frame.
class ViewSession {
 public:
  ViewSession(const std::string& path, const ViewOptions& options);
  ~ViewSession() { quit(); }

  std::string stateJson();
  // A change, as JSON; an InputError (a 400) changes nothing.
  void apply(const std::string& body);
  // Waits up to `timeout` for a frame newer than `seen`; the event text, or "" (none / quit).
  // A stream that has seen a frame gets every later frame of the version shown, in order (the
  // steps of its refinement; one that falls more than kRecentFrames behind skips the oldest);
  // frames of a version that a change superseded are skipped. A new stream (`seen` 0) starts
  // at the latest.
  std::string waitFrame(uint64_t& seen, std::chrono::milliseconds timeout);
  std::string latestJpeg();
  Json save();
  void quit();
  bool quitting() const { return m_quit; }

 private:
  struct Surface {
    int volume, index;  // in the scene: volumes[volume].isosurfaces[index]
    std::string label;
    double min, max;
  };
  // A slice plane: volumes[volume].slices[index], movable along its normal within its grid's
  // box (min, max: the box's extent along the normal, as dot(point, normal)).
  struct Slice {
    int volume, index;
    std::string label;
    double min, max;
  };
  // A clip plane across one axis (the view's own, added to every volume's "clip" entries: meshes
  // such as a floor stay whole): it keeps
  // the points whose coordinate is at most `position` (`flip`: at least), within the volumes'
  // boxes' extent [min, max] along the axis.
  struct AxisClip {
    bool on = false, flip = false;
    double position = 0, min = 0, max = 0;
  };
  struct Frame {
    uint64_t serial = 0, version = 0;
    int spp = 0;
    bool preview = false;  // a quick look at a fraction of the resolution: shown, never saved
    DenoiseMode denoised = DenoiseMode::Off;  // the mode its image went through
    std::string event;     // the server-sent event of this frame
    std::string jpeg;
    int shownWidth = 0;    // of the JPEG (compare: three images side by side)
    std::shared_ptr<Film> film, direct;
    bool signedData = false;
    Json doc;              // the scene this frame shows
    CameraDesc camera;
  };

  void run();
  // Samples [s0, s1) of every pixel into `sums`; false if a newer version than `version`
  // (or quitting) cancelled it.
  bool renderPassOver(tbb::task_arena& arena, const Camera& camera, const Integrator& integrator,
                      const RenderOptions& options, int w, int h, int s0, int s1, std::vector<PixelSums>& sums,
                      uint64_t& rays, uint64_t version);
  // `denoise`: the mode the frame's image goes through (Off: as rendered).
  Frame makeFrame(const std::vector<PixelSums>& sums, int w, int h, const RenderOptions& options,
                  const Integrator& integrator, DenoiseMode denoise);
  // Makes `frame` the one shown (and, unless a preview, the one Save writes), if `version` is
  // still the current one.
  void publish(Frame frame, uint64_t version, int spp, int target, Clock::time_point changedAt, double mrays);
  // The patched scene document, checked by the parser (InputError otherwise).
  SceneDesc parse(const Json& doc) const;
  Vec3d colourOf(const Surface& s) const;
  CameraDesc cameraOf(const SceneDesc& desc, const World& world) const;
  // The camera of the scene as it stands (one found in a glTF or framing the scene: as the
  // latest frame resolved it). Under m_mutex.
  CameraDesc cameraShown() const {
    const bool explicitCamera = m_desc.camera.gltfCamera.empty() && !m_desc.camera.frameScene;
    return explicitCamera || !m_saveable.film ? m_desc.camera : m_saveable.camera;
  }

  std::string m_path;
  ViewOptions m_options;
  int m_width = 0, m_height = 0;
  std::vector<Surface> m_surfaces;
  std::vector<Slice> m_slices;
  AxisClip m_axisClips[3];
  // Volumes that change over time: the time step shown (of the longest series' m_timeSteps; the
  // others stretched over it as a sequence's frames are), set on every parse of the scene.
  int m_timeSteps = 1, m_timeStep = 0;
  bool m_axisClipsShown = false;  // the scene has volumes: the view offers them
  std::vector<Json> m_fileClips;  // each volume's own "clip" entries in the file (arrays; they stay)

  std::mutex m_mutex;
  std::condition_variable m_changed, m_framed;
  Json m_doc;
  SceneDesc m_desc;
  std::atomic<uint64_t> m_version{1};
  bool m_rebuild = false;  // the constructor's World is the first one
  Clock::time_point m_changedAt = Clock::now();
  std::string m_error;
  Frame m_frame;     // the latest frame shown
  static constexpr size_t kRecentFrames = 32;
  std::deque<std::pair<uint64_t, std::string>> m_recent;  // (serial, event) of m_frame's version, oldest first
  Frame m_saveable;  // the latest full-resolution frame
  std::atomic<bool> m_quit{false};
  std::unique_ptr<World> m_firstWorld;  // built by the constructor, taken by the render thread
  std::thread m_thread;
};

ViewSession::ViewSession(const std::string& path, const ViewOptions& options) : m_path(path), m_options(options) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, "", "cannot read the scene file");
  std::stringstream file;
  file << in.rdbuf();
  // With the command line's overrides: the view edits (and saves) the scene as overridden.
  const std::string text = overriddenSceneText(file.str(), path, options.overrides);
  checkJsonNesting(text, path);
  m_doc = Json::parse(text, nullptr, false);
  m_desc = parseSceneText(text, path);  // the parser's own message for any problem
  if (m_doc.is_discarded() || !m_doc.is_object()) throw InputError(path, "", "expected a JSON object");
  m_timeSteps = sceneTimeSteps(m_desc);
  m_firstWorld = std::make_unique<World>(m_desc, m_desc.settings.intersector);
  for (const std::string& w : m_firstWorld->warnings()) std::fprintf(stderr, "isotrace: warning: %s\n", w.c_str());
  for (size_t v = 0; v < m_desc.volumes.size(); ++v) {
    const VolumeInfo& info = m_firstWorld->volumes()[v];
    const std::string name = m_desc.volumes[v].field ? "procedural" : fs::path(m_desc.volumes[v].file).filename().string();
    for (size_t k = 0; k < m_desc.volumes[v].isosurfaces.size(); ++k)
      m_surfaces.push_back({int(v), int(k), name + (m_desc.volumes[v].isosurfaces.size() > 1 ? " #" + std::to_string(k) : ""),
                            double(info.bricks->minValue()), double(info.bricks->maxValue())});
    for (size_t k = 0; k < m_desc.volumes[v].slices.size(); ++k) {
      const SliceDesc& slice = m_desc.volumes[v].slices[k];
      double lo = INFINITY, hi = -INFINITY;
      for (const Vec3d& corner : gridBoxCorners(info)) {
        lo = std::min(lo, dot(corner, slice.normal));
        hi = std::max(hi, dot(corner, slice.normal));
      }
      m_slices.push_back({int(v), int(k), name + " slice " + std::to_string(k), lo, hi});
    }
  }
  for (size_t v = 0; v < m_desc.volumes.size(); ++v) {
    const Json& volume = m_doc["volumes"][v];
    m_fileClips.push_back(volume.contains("clip") ? volume["clip"] : Json::array());
  }
  for (int a = 0; a < 3; ++a) {
    AxisClip& c = m_axisClips[a];
    c.min = INFINITY, c.max = -INFINITY;
    for (const VolumeInfo& info : m_firstWorld->volumes())
      for (const Vec3d& corner : gridBoxCorners(info)) c.min = std::min(c.min, corner[a]), c.max = std::max(c.max, corner[a]);
    c.position = 0.5 * (c.min + c.max);
    m_axisClipsShown = c.min < c.max;
  }
  const double aspect = double(m_desc.settings.width) / m_desc.settings.height;
  m_width = options.width > 0 ? options.width : 480;
  m_height = options.height > 0 ? options.height : std::max(1, int(std::lround(480 / aspect)));
  m_thread = std::thread([this] { run(); });
}

void ViewSession::quit() {
  {
    std::lock_guard<std::mutex> lock(m_mutex);
    m_quit = true;
  }
  m_changed.notify_all();
  m_framed.notify_all();
  if (m_thread.joinable()) m_thread.join();
}

SceneDesc ViewSession::parse(const Json& doc) const {
  SceneDesc desc = parseSceneText(doc.dump(), m_path);
  for (VolumeDesc& v : desc.volumes) selectTimeStep(v, timeStepOfFrame(m_timeStep, m_timeSteps, v.time.steps));
  return desc;
}

Vec3d ViewSession::colourOf(const Surface& s) const {
  const IsoSurfaceDesc& iso = m_desc.volumes[size_t(s.volume)].isosurfaces[size_t(s.index)];
  if (!iso.material.empty()) return m_desc.materials.at(iso.material).color;
  return iso.color.value_or(Vec3d{0.8, 0.8, 0.8});
}

CameraDesc ViewSession::cameraOf(const SceneDesc& desc, const World& world) const {
  return desc.camera.gltfCamera.empty() && !desc.camera.frameScene ? desc.camera : world.camera();
}

std::string ViewSession::stateJson() {
  std::lock_guard<std::mutex> lock(m_mutex);
  Json s;
  s["version"] = m_version.load();
  s["scene"] = m_path;
  s["width"] = m_width;
  s["height"] = m_height;
  s["spp_target"] = m_desc.settings.spp;
  s["integrator"] = m_desc.settings.integrator;
  s["denoise"] = m_desc.settings.denoise != DenoiseMode::Off;
  s["integrators"] = Json::array();
  for (const char* name : kIntegrators) s["integrators"].push_back(name);
  const CameraDesc c = cameraShown();
  s["camera"] = {{"position", vec(c.position)}, {"look_at", vec(c.lookAt)}, {"up", vec(c.up)}, {"fov", c.fov}};
  s["surfaces"] = Json::array();
  for (size_t i = 0; i < m_surfaces.size(); ++i) {
    const Surface& f = m_surfaces[i];
    const IsoSurfaceDesc& iso = m_desc.volumes[size_t(f.volume)].isosurfaces[size_t(f.index)];
    s["surfaces"].push_back({{"index", i}, {"label", f.label}, {"min", f.min}, {"max", f.max},
                             {"value", iso.value}, {"color", hexColour(colourOf(f))}});
    if (iso.colorBy)
      s["surfaces"].back()["color_by"] = {{"field", iso.colorBy->fieldName}, {"map", iso.colorBy->map.name()},
                                          {"range", {iso.colorBy->lo, iso.colorBy->hi}}};
  }
  s["maps"] = Json::array();
  for (const std::string& name : ColorMap::names()) s["maps"].push_back(name);
  s["slices"] = Json::array();
  for (size_t i = 0; i < m_slices.size(); ++i) {
    const Slice& f = m_slices[i];
    const SliceDesc& d = m_desc.volumes[size_t(f.volume)].slices[size_t(f.index)];
    s["slices"].push_back({{"index", i}, {"label", f.label}, {"min", f.min}, {"max", f.max},
                           {"position", dot(d.point, d.normal)}, {"map", d.map.name()}});
  }
  s["clip"] = Json::array();
  if (m_axisClipsShown)
    for (int a = 0; a < 3; ++a) {
      const AxisClip& c = m_axisClips[a];
      s["clip"].push_back({{"axis", std::string(1, "xyz"[a])}, {"on", c.on}, {"flip", c.flip}, {"position", c.position},
                           {"min", c.min}, {"max", c.max}});
    }
  if (m_timeSteps > 1) s["time"] = {{"step", m_timeStep}, {"steps", m_timeSteps}};
  s["error"] = m_error;
  return s.dump();
}

void ViewSession::apply(const std::string& body) {
  const std::string where = "request";
  checkJsonNesting(body, where, 16);
  const Json change = Json::parse(body, nullptr, false);
  if (change.is_discarded() || !change.is_object()) throw InputError(where, "", "expected a JSON object");
  std::unique_lock<std::mutex> lock(m_mutex);
  Json doc = m_doc;
  bool rebuild = false;
  for (const auto& [key, value] : change.items()) {
    if (key != "surface" && key != "value" && key != "color" && key != "color_by" && key != "slice" &&
        key != "position" && key != "integrator" && key != "camera" && key != "clip" && key != "denoise" && key != "time")
      throw InputError(where, "/" + key,
                       "unknown key (known: surface, value, color, color_by, slice, position, clip, integrator, camera, "
                       "denoise, time)");
  }
  const int timeStepBefore = m_timeStep;
  if (change.contains("time")) {
    // {"time": K}: show time step K of the scene's volumes that change over time.
    const Json& t = change["time"];
    if (m_timeSteps < 2) throw InputError(where, "/time", "no volume of the scene changes over time");
    if (!t.is_number_integer() || t.get<long long>() < 0 || t.get<long long>() >= m_timeSteps)
      throw InputError(where, "/time", "expected a time step from 0 to " + std::to_string(m_timeSteps - 1));
    m_timeStep = int(t.get<long long>());
    rebuild = true;
  }
  AxisClip axisClips[3] = {m_axisClips[0], m_axisClips[1], m_axisClips[2]};
  if (change.contains("clip")) {
    // {"axis": "x"|"y"|"z", "on": bool, "position": number, "flip": bool}: one of the view's
    // axis planes, the keys left out as they are.
    const Json& c = change["clip"];
    if (!c.is_object()) throw InputError(where, "/clip", "expected an object");
    for (const auto& [key, value] : c.items())
      if (key != "axis" && key != "on" && key != "position" && key != "flip")
        throw InputError(where, "/clip/" + key, "unknown key (known: axis, on, position, flip)");
    if (!m_axisClipsShown) throw InputError(where, "/clip", "the scene has no volume to clip");
    const std::string axis = c.contains("axis") && c["axis"].is_string() ? c["axis"].get<std::string>() : "";
    if (axis != "x" && axis != "y" && axis != "z") throw InputError(where, "/clip/axis", "expected \"x\", \"y\" or \"z\"");
    AxisClip& a = axisClips[axis[0] - 'x'];
    for (const auto& [key, flag] : {std::pair<const char*, bool*>{"on", &a.on}, {"flip", &a.flip}})
      if (c.contains(key)) {
        if (!c[key].is_boolean()) throw InputError(where, std::string("/clip/") + key, "expected true or false");
        *flag = c[key].get<bool>();
      }
    if (c.contains("position")) {
      if (!c["position"].is_number()) throw InputError(where, "/clip/position", "expected a number");
      const double p = c["position"].get<double>();
      if (!(p >= a.min && p <= a.max))
        throw InputError(where, "/clip/position", "outside the volumes' extent [" + std::to_string(a.min) + ", " +
                                                      std::to_string(a.max) + "]");
      a.position = p;
    }
    // Each volume's "clip": the file's own entries, then the view's planes that are on.
    for (size_t v = 0; v < m_fileClips.size(); ++v) {
      Json clip = m_fileClips[v];
      for (int k = 0; k < 3; ++k) {
        if (!axisClips[k].on) continue;
        Vec3d point{0, 0, 0}, normal{0, 0, 0};
        point[k] = axisClips[k].position;
        normal[k] = axisClips[k].flip ? -1 : 1;
        clip.push_back({{"plane", {{"point", vec(point)}, {"normal", vec(normal)}}}});
      }
      Json& volume = doc["volumes"][v];
      if (clip.empty()) volume.erase("clip");
      else volume["clip"] = clip;
    }
    rebuild = true;
  }
  if (change.contains("slice") != change.contains("position"))
    throw InputError(where, change.contains("slice") ? "/position" : "/slice", "a slice goes with a position");
  if (change.contains("slice")) {
    if (!change["slice"].is_number_integer()) throw InputError(where, "/slice", "expected the index of a slice");
    const long long index = change["slice"].get<long long>();
    if (index < 0 || index >= (long long)m_slices.size())
      throw InputError(where, "/slice", "no slice " + std::to_string(index) + " (the scene has " + std::to_string(m_slices.size()) + ")");
    const Slice& f = m_slices[size_t(index)];
    if (!change["position"].is_number()) throw InputError(where, "/position", "expected a number");
    const double p = change["position"].get<double>();
    if (!(p >= f.min && p <= f.max))
      throw InputError(where, "/position", "outside the volume's grid [" + std::to_string(f.min) + ", " + std::to_string(f.max) + "]");
    Json& slice = doc["volumes"][size_t(f.volume)]["slices"][size_t(f.index)];
    if (slice.contains("axis")) {
      slice["position"] = p;
    } else {  // move the point along the normal
      const SliceDesc& d = m_desc.volumes[size_t(f.volume)].slices[size_t(f.index)];
      slice["point"] = vec(d.point + d.normal * (p - dot(d.point, d.normal)));
    }
    rebuild = true;
  }
  // A change of an iso-surface (value, color, color_by) names it.
  const bool ofSurface = change.contains("value") || change.contains("color") || change.contains("color_by");
  if (change.contains("surface") && !ofSurface)
    throw InputError(where, "/surface", "a surface goes with a value, a color or a color_by");
  const Surface* surface = nullptr;
  if (ofSurface) {
    if (!change.contains("surface") || !change["surface"].is_number_integer())
      throw InputError(where, "/surface", "expected the index of an iso-surface");
    const long long index = change["surface"].get<long long>();
    if (index < 0 || index >= (long long)m_surfaces.size())
      throw InputError(where, "/surface", "no iso-surface " + std::to_string(index) + " (the scene has " +
                                              std::to_string(m_surfaces.size()) + ")");
    surface = &m_surfaces[size_t(index)];
  }
  if (change.contains("color_by")) {
    Json& iso = doc["volumes"][size_t(surface->volume)]["isosurfaces"][size_t(surface->index)];
    if (!iso.contains("color_by")) throw InputError(where, "/color_by", "the surface is not coloured by data (its scene has no \"color_by\")");
    const Json& c = change["color_by"];
    if (!c.is_object()) throw InputError(where, "/color_by", "expected an object");
    for (const auto& [key, value] : c.items()) {
      if (key != "map" && key != "range") throw InputError(where, "/color_by/" + key, "unknown key (known: map, range)");
      iso["color_by"][key] = value;  // the parser checks them below
    }
    rebuild = true;
  }
  if (change.contains("value") || change.contains("color")) {
    const Surface& s = *surface;
    Json& iso = doc["volumes"][size_t(s.volume)]["isosurfaces"][size_t(s.index)];
    if (change.contains("value")) {
      if (!change["value"].is_number()) throw InputError(where, "/value", "expected a number");
      const double v = change["value"].get<double>();
      if (!(v >= s.min && v <= s.max))
        throw InputError(where, "/value", "iso value out of the volume's range [" + std::to_string(s.min) + ", " +
                                              std::to_string(s.max) + "]");
      iso["value"] = v;
    }
    if (change.contains("color")) {
      Vec3d rgb;
      if (!change["color"].is_string() || !parseHexColour(change["color"].get<std::string>(), rgb))
        throw InputError(where, "/color", "expected a colour as \"#rrggbb\"");
      if (iso.contains("material") && iso["material"].is_string())
        doc["materials"][iso["material"].get<std::string>()]["color"] = vec(rgb);
      else
        iso["color"] = vec(rgb);
    }
    rebuild = true;
  }
  if (change.contains("integrator")) {
    const Json& name = change["integrator"];
    if (!name.is_string() ||
        std::none_of(std::begin(kIntegrators), std::end(kIntegrators), [&](const char* k) { return name == k; }))
      throw InputError(where, "/integrator", "expected one of normals, eyelight, ao, direct, path, compare");
    if (!doc.contains("integrator") || !doc["integrator"].is_object()) doc["integrator"] = Json::object();
    doc["integrator"]["type"] = name;
  }
  if (change.contains("denoise")) {
    // On: the fast mode while samples come in, the scene's mode (quality unless it says fast) at
    // the last pass; the saved scene keeps it.
    const Json& on = change["denoise"];
    if (!on.is_boolean()) throw InputError(where, "/denoise", "expected true or false");
    if (!doc.contains("film") || !doc["film"].is_object()) doc["film"] = Json::object();
    const bool fast = m_desc.settings.denoise == DenoiseMode::Fast;
    doc["film"]["denoise"] = on.get<bool>() ? (fast ? "fast" : "quality") : "off";
  }
  if (change.contains("camera")) {
    const Json& c = change["camera"];
    if (!c.is_object()) throw InputError(where, "/camera", "expected an object");
    for (const auto& [key, value] : c.items())
      if (key != "position" && key != "look_at" && key != "up" && key != "fov")
        throw InputError(where, "/camera/" + key, "unknown key (known: position, look_at, up, fov)");
    Json camera = c;
    // What the change leaves out stays as it is (the camera shown, also one found in a glTF).
    const CameraDesc now = cameraShown();
    if (!camera.contains("position")) camera["position"] = vec(now.position);
    if (!camera.contains("look_at")) camera["look_at"] = vec(now.lookAt);
    if (!camera.contains("up")) camera["up"] = vec(now.up);
    if (!camera.contains("fov")) camera["fov"] = now.fov;
    doc["camera"] = camera;
  }
  SceneDesc desc;
  try {
    desc = parse(doc);
  } catch (const InputError& e) {
    m_timeStep = timeStepBefore;
    // The parser names the scene file; the request is what was wrong.
    std::string msg = e.what();
    const std::string prefix = m_path + ": ";
    if (msg.rfind(prefix, 0) == 0) msg = msg.substr(prefix.size());
    throw InputError(where, "", msg);
  }
  m_doc = std::move(doc);
  m_desc = std::move(desc);
  for (int a = 0; a < 3; ++a) m_axisClips[a] = axisClips[a];
  m_rebuild = m_rebuild || rebuild;
  m_changedAt = Clock::now();
  ++m_version;
  lock.unlock();
  m_changed.notify_all();
}

std::string ViewSession::waitFrame(uint64_t& seen, std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(m_mutex);
  m_framed.wait_for(lock, timeout, [&] { return m_quit || m_frame.serial > seen; });
  if (m_quit || m_frame.serial <= seen) return "";
  if (seen != 0)
    for (const auto& [serial, event] : m_recent)
      if (serial > seen) {
        seen = serial;
        return event;
      }
  seen = m_frame.serial;
  return m_frame.event;
}

std::string ViewSession::latestJpeg() {
  std::lock_guard<std::mutex> lock(m_mutex);
  return m_frame.jpeg;
}

void ViewSession::run() {
  std::unique_ptr<World> world = std::move(m_firstWorld);
  std::unique_ptr<Integrator> integrator;
  std::unique_ptr<Camera> camera;
  CameraDesc cameraDesc;
  SceneDesc desc;
  Json doc;
  uint64_t built = 0;
  RenderOptions options;
  std::vector<PixelSums> sums;
  int pass = 0, s0 = 0;
  uint64_t rays = 0;
  double renderSeconds = 0;
  Clock::time_point changedAt;
  bool preview = false;
  tbb::task_arena arena(m_options.threads > 0 ? m_options.threads : tbb::task_arena::automatic);
  for (;;) {
    bool changed = false, rebuild = false;
    {
      std::unique_lock<std::mutex> lock(m_mutex);
      m_changed.wait(lock, [&] { return m_quit || m_version != built || (integrator && s0 < options.spp); });
      if (m_quit) return;
      if (m_version != built) {
        changed = true;
        built = m_version;
        desc = m_desc;
        doc = m_doc;
        rebuild = m_rebuild;
        m_rebuild = false;
        changedAt = m_changedAt;
      }
    }
    if (changed) {
      // Everything about the frame starts over; iso values and colours need a new World.
      if (rebuild || !world) {
        try {
          // The volumes stay loaded: a change alters only their surfaces, or which time step
          // of a series is shown (only that volume is read, each other one kept: World's sources).
          world = std::make_unique<World>(desc, desc.settings.intersector, world.get());
        } catch (const std::exception& e) {
          std::lock_guard<std::mutex> lock(m_mutex);
          m_error = e.what();
          integrator.reset();
          continue;
        }
      }
      {
        std::lock_guard<std::mutex> lock(m_mutex);
        m_error.clear();
      }
      integrator = makeIntegrator(desc.settings.integrator, *world, desc.settings);
      cameraDesc = cameraOf(desc, *world);
      camera = std::make_unique<Camera>(cameraDesc, m_width, m_height);
      // The view refines every pixel pass by pass up to spp on its own threads (--threads):
      // no adaptive stop, and the scene's thread count is the batch render's.
      options = renderOptions(desc.settings);
      options.threads = m_options.threads;
      options.noiseThreshold = 0;
      sums.assign(size_t(m_width) * m_height, PixelSums());
      pass = 0;
      s0 = 0;
      rays = 0;
      renderSeconds = 0;
      preview = true;
    }
    // Right after a change, a preview: one sample per pixel on about 20,000 pixels (480x360:
    // a third of the width and height, a ninth of the work), shown stretched; then the full
    // passes.
    if (preview) {
      preview = false;
      const int scale = std::max(2, int(std::ceil(std::sqrt(double(m_width) * m_height / 20000))));
      if (m_width >= 32 * scale && m_height >= 24 * scale) {
        const int pw = m_width / scale, ph = m_height / scale;
        const Camera small(cameraDesc, pw, ph);
        std::vector<PixelSums> previewSums(size_t(pw) * ph);
        uint64_t previewRays = 0;
        if (!renderPassOver(arena, small, *integrator, options, pw, ph, 0, 1, previewSums, previewRays, built)) continue;
        const bool denoise = desc.settings.denoise != DenoiseMode::Off && integratorDenoises(desc.settings.integrator);
        const DenoiseMode mode = denoise ? DenoiseMode::Fast : DenoiseMode::Off;
        Frame frame = makeFrame(previewSums, pw, ph, options, *integrator, mode);
        frame.preview = true;
        publish(std::move(frame), built, 0, options.spp, changedAt, 0);
        continue;
      }
    }
    // One pass over all tiles; a newer version cancels it at the next tile.
    const int s1 = TileRenderer::nextPassStart(s0, pass, options.spp);
    const auto passStart = Clock::now();
    if (!renderPassOver(arena, *camera, *integrator, options, m_width, m_height, s0, s1, sums, rays, built)) continue;
    renderSeconds += std::chrono::duration<double>(Clock::now() - passStart).count();
    ++pass;
    s0 = s1;
    const bool denoise = desc.settings.denoise != DenoiseMode::Off && integratorDenoises(desc.settings.integrator);
    const DenoiseMode mode = !denoise ? DenoiseMode::Off : s1 >= options.spp ? desc.settings.denoise : DenoiseMode::Fast;
    Frame frame = makeFrame(sums, m_width, m_height, options, *integrator, mode);
    frame.doc = doc;
    frame.camera = cameraDesc;
    publish(std::move(frame), built, s1, options.spp, changedAt, renderSeconds > 0 ? double(rays) / renderSeconds * 1e-6 : 0);
  }
}

bool ViewSession::renderPassOver(tbb::task_arena& arena, const Camera& camera, const Integrator& integrator,
                                 const RenderOptions& options, int w, int h, int s0, int s1,
                                 std::vector<PixelSums>& sums, uint64_t& rays, uint64_t version) {
  const TileRenderer tiles(camera, integrator, options, w, h);
  tbb::enumerable_thread_specific<RayCounters> counters;
  std::atomic<bool> cancelled{false};
  arena.execute([&] {
    tbb::parallel_for(0, tiles.tiles(), [&](int t) {
      if (cancelled || m_quit || m_version != version) {
        cancelled = true;
        return;
      }
      const TileRenderer::Rect r = tiles.rect(t);
      tiles.renderPass(t, s0, s1, &sums[size_t(r.y0) * w + r.x0], size_t(w), counters.local());
    });
  });
  for (const RayCounters& c : counters) rays += c.camera + c.shadow + c.indirect;
  return !cancelled;
}

ViewSession::Frame ViewSession::makeFrame(const std::vector<PixelSums>& sums, int w, int h, const RenderOptions& options,
                                          const Integrator& integrator, DenoiseMode denoise) {
  Frame frame;
  frame.film = std::make_shared<Film>(w, h);
  if (integrator.splitsDirect()) frame.direct = std::make_shared<Film>(w, h);
  RenderResult result;
  DenoiseInput input;
  const bool denoising = denoise != DenoiseMode::Off;
  RenderOptions resolve = options;
  resolve.denoiseInput = denoising ? &input : nullptr;
  resolveFrame(sums, resolve, *frame.film, frame.direct.get(), result);
  Film indirect(0, 0);
  if (denoising) {
    denoiseFrame(input, denoise, m_options.threads, false, *frame.film, frame.direct.get(), &indirect, result);
    frame.denoised = denoise;
  }
  frame.signedData = integrator.signedOutput();
  std::vector<uint8_t> rgb = displayRgb(*frame.film, frame.signedData);
  int shownWidth = w;
  if (frame.direct) {
    // compare: direct, global and indirect side by side.
    const std::vector<uint8_t> parts[3] = {
        displayRgb(*frame.direct, false), rgb,
        displayRgb(frame.denoised != DenoiseMode::Off ? indirect : indirectOf(*frame.film, *frame.direct), false)};
    shownWidth = 3 * w;
    rgb.assign(size_t(shownWidth) * h * 3, 0);
    for (int y = 0; y < h; ++y)
      for (int p = 0; p < 3; ++p)
        std::copy_n(parts[p].begin() + ptrdiff_t(size_t(y) * w * 3), size_t(w) * 3,
                    rgb.begin() + ptrdiff_t((size_t(y) * shownWidth + size_t(p) * w) * 3));
  }
  frame.jpeg = jpeg(rgb, shownWidth, h);
  frame.shownWidth = shownWidth;
  return frame;
}

void ViewSession::publish(Frame frame, uint64_t version, int spp, int target, Clock::time_point changedAt, double mrays) {
  const Json event = {{"version", version},
                      {"spp", spp},
                      {"spp_target", target},
                      {"preview", frame.preview},
                      {"denoise", denoiseModeName(frame.denoised)},
                      {"seconds", std::chrono::duration<double>(Clock::now() - changedAt).count()},
                      {"mrays", mrays},
                      {"display_width", (frame.direct ? 3 : 1) * m_width},  // a preview is shown stretched
                      {"display_height", m_height},
                      {"image", "data:image/jpeg;base64," + base64(frame.jpeg)}};
  frame.version = version;
  frame.spp = spp;
  {
    std::lock_guard<std::mutex> lock(m_mutex);
    if (m_version != version) return;  // a change came in meanwhile: no stale frame
    frame.serial = m_frame.serial + 1;
    frame.event = "event: frame\ndata: " + event.dump() + "\n\n";
    if (m_frame.version != version) m_recent.clear();
    m_recent.emplace_back(frame.serial, frame.event);
    if (m_recent.size() > kRecentFrames) m_recent.pop_front();
    if (!frame.preview) m_saveable = frame;  // the films are shared, not copied
    m_frame = std::move(frame);
  }
  m_framed.notify_all();
}

Json ViewSession::save() {
  std::unique_lock<std::mutex> lock(m_mutex);
  if (!m_saveable.film) throw InputError("save", "", "no image yet");
  const Frame& f = m_saveable;
  Json doc = f.doc;
  // What reproduces this picture with `isotrace render`: its size, samples and camera.
  if (!doc.contains("film") || !doc["film"].is_object()) doc["film"] = Json::object();
  doc["film"]["width"] = m_width;  // (its "denoise" stays: the picture shown went through it)
  doc["film"]["height"] = m_height;
  if (!doc.contains("integrator") || !doc["integrator"].is_object()) doc["integrator"] = Json::object();
  doc["integrator"]["spp"] = f.spp;
  doc["integrator"].erase("noise_threshold");  // the viewer samples every pixel alike
  doc["camera"] = {{"position", vec(f.camera.position)}, {"look_at", vec(f.camera.lookAt)}, {"up", vec(f.camera.up)},
                   {"fov", f.camera.fov}};
  const fs::path scene(m_path);
  const std::string stem = (scene.parent_path() / scene.stem()).string();
  for (int n = 1; n < 100000; ++n) {
    const std::string base = stem + ".view-" + std::to_string(n);
    // The scene file is made with O_EXCL semantics ("x"): two saves never share a number.
    FILE* out = std::fopen((base + ".json").c_str(), "wx");
    if (!out) {
      if (errno == EEXIST) continue;
      throw InputError(base + ".json", "", std::string("cannot write: ") + std::strerror(errno));
    }
    const std::string text = doc.dump(2) + "\n";
    const bool ok = std::fwrite(text.data(), 1, text.size(), out) == text.size();
    if (std::fclose(out) != 0 || !ok) throw InputError(base + ".json", "", "cannot write");
    std::map<std::string, std::string> metadata = {{"Software", "isotrace view"},
                                                   {"isotrace:spp", std::to_string(f.spp)},
                                                   {"isotrace:integrator", doc["integrator"].value("type", "eyelight")}};
    Json written = Json::array({base + ".json"});
    auto write = [&](const std::string& path, const Film& film, bool signedData) {
      writeImage(path, film, signedData, metadata);
      written.push_back(path);
    };
    if (f.direct) {
      const Film indirect = indirectOf(*f.film, *f.direct);
      for (const char* ext : {".exr", ".png"}) {
        write(base + ".direct" + ext, *f.direct, false);
        write(base + ".global" + ext, *f.film, false);
        write(base + ".indirect" + ext, indirect, false);
      }
    } else {
      write(base + ".exr", *f.film, f.signedData);
      write(base + ".png", *f.film, f.signedData);
    }
    return {{"files", written}, {"spp", f.spp}};
  }
  throw InputError(stem + ".view-N.json", "", "no free number left");
}

struct ViewServer::Http {
  httplib::Server server;
};

ViewServer::ViewServer(const std::string& scenePath, const ViewOptions& options)
    : m_options(options), m_session(std::make_unique<ViewSession>(scenePath, options)),
      m_http(std::make_unique<Http>()) {
  httplib::Server& s = m_http->server;
  s.set_payload_max_length(64 * 1024);
  ViewSession* session = m_session.get();
  auto json = [](httplib::Response& res, const std::string& body, int status = 200) {
    res.status = status;
    res.set_header("Cache-Control", "no-store");
    res.set_content(body, "application/json");
  };
  auto badRequest = [json](httplib::Response& res, const std::string& message) {
    json(res, Json({{"error", message}}).dump(), 400);
  };
  s.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-store");
    res.set_content(kViewPage, "text/html; charset=utf-8");
  });
  s.Get("/api/state", [session, json](const httplib::Request&, httplib::Response& res) { json(res, session->stateJson()); });
  s.Post("/api/state", [session, json, badRequest](const httplib::Request& req, httplib::Response& res) {
    try {
      session->apply(req.body);
      json(res, session->stateJson());
    } catch (const InputError& e) {
      badRequest(res, e.what());
    }
  });
  s.Post("/api/save", [session, json, badRequest](const httplib::Request&, httplib::Response& res) {
    try {
      json(res, session->save().dump());
    } catch (const InputError& e) {
      badRequest(res, e.what());
    }
  });
  s.Get("/api/frame.jpg", [session](const httplib::Request&, httplib::Response& res) {
    const std::string image = session->latestJpeg();
    if (image.empty()) {
      res.status = 404;
      return;
    }
    res.set_header("Cache-Control", "no-store");
    res.set_content(image, "image/jpeg");
  });
  s.Get("/api/events", [session](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-store");
    auto seen = std::make_shared<uint64_t>(0);
    res.set_chunked_content_provider("text/event-stream", [session, seen](size_t, httplib::DataSink& sink) {
      if (session->quitting()) {
        sink.done();
        return false;
      }
      std::string event = session->waitFrame(*seen, std::chrono::milliseconds(500));
      if (session->quitting()) {
        sink.done();
        return false;
      }
      if (event.empty()) event = ": waiting\n\n";  // a comment: finds a dropped connection
      return sink.write(event.data(), event.size());
    });
  });
}

ViewServer::~ViewServer() {
  stop();
  m_session.reset();
}

int ViewServer::bind() {
  httplib::Server& s = m_http->server;
  m_port = m_options.port == 0 ? s.bind_to_any_port(m_options.host) : (s.bind_to_port(m_options.host, m_options.port) ? m_options.port : -1);
  if (m_port < 0)
    throw InputError("--port", "", "cannot listen on " + m_options.host + ":" + std::to_string(m_options.port) +
                                       " (in use, or not an address of this machine)");
  return m_port;
}

void ViewServer::serve() { m_http->server.listen_after_bind(); }

void ViewServer::stop() {
  if (m_session) m_session->quit();
  m_http->server.stop();
}

std::string ViewServer::url() const {
  const std::string host = m_options.host == "0.0.0.0" ? "127.0.0.1" : m_options.host;
  return "http://" + host + ":" + std::to_string(m_port) + "/";
}

namespace {
volatile std::sig_atomic_t g_viewStop = 0;
void onViewSignal(int) { g_viewStop = 1; }
}  // namespace

int runView(const std::string& scenePath, const ViewOptions& options) {
  imagePlugin();  // the frames' JPEG encoder: loaded now, so that a broken installation stops here, not mid-frame
  ViewServer server(scenePath, options);
  server.bind();
  if (options.host != "127.0.0.1" && options.host != "localhost")
    std::fprintf(stderr, "isotrace: warning: listening on %s: anyone who can reach this machine there can use the viewer\n",
                 options.host.c_str());
  std::printf("%s\n", server.url().c_str());
  std::fflush(stdout);
  g_viewStop = 0;
  auto previousInt = std::signal(SIGINT, onViewSignal);
  auto previousTerm = std::signal(SIGTERM, onViewSignal);
  std::thread watcher([&server] {
    while (!g_viewStop) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    server.stop();
  });
  server.serve();
  g_viewStop = 1;
  watcher.join();
  std::signal(SIGINT, previousInt == SIG_ERR ? SIG_DFL : previousInt);
  std::signal(SIGTERM, previousTerm == SIG_ERR ? SIG_DFL : previousTerm);
  std::fprintf(stderr, "isotrace: view stopped\n");
  return 0;
}

}  // namespace iso
