// The scene format is parsed here and nowhere else (gltf.cpp is the other user of nlohmann/json).
#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <algorithm>
#include <cmath>
#include <set>
#include <tuple>
#include <optional>
#include <sstream>

#include "scene/scene.h"
#include "scene/time_series.h"
#include "volume/input_error.h"
#include "volume/input_file.h"

namespace iso {
namespace {

using Json = nlohmann::json;
namespace fs = std::filesystem;

const char* typeName(const Json& j) {
  switch (j.type()) {
    case Json::value_t::object: return "an object";
    case Json::value_t::array: return "an array";
    case Json::value_t::string: return "a string";
    case Json::value_t::boolean: return "a boolean";
    case Json::value_t::null: return "null";
    default: return "a number";
  }
}

// The known name closest to `key` by edit distance, if it is close enough to be a typo
// (at most 2 edits, and fewer than half the key's letters); empty otherwise.
std::string closestKey(const std::string& key, const std::vector<std::string>& known) {
  std::string best;
  size_t bestDistance = 3;
  for (const std::string& k : known) {
    // Optimal string alignment distance: insertions, deletions, substitutions and swaps of
    // neighbouring letters ("flie" is one edit from "file").
    std::vector<std::vector<size_t>> d(key.size() + 1, std::vector<size_t>(k.size() + 1));
    for (size_t i = 0; i <= key.size(); ++i) d[i][0] = i;
    for (size_t j = 0; j <= k.size(); ++j) d[0][j] = j;
    for (size_t i = 1; i <= key.size(); ++i)
      for (size_t j = 1; j <= k.size(); ++j) {
        d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + (key[i - 1] == k[j - 1] ? 0 : 1)});
        if (i > 1 && j > 1 && key[i - 1] == k[j - 2] && key[i - 2] == k[j - 1])
          d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
      }
    const size_t distance = d[key.size()][k.size()];
    if (distance < bestDistance && 2 * distance < key.size()) {
      bestDistance = distance;
      best = k;
    }
  }
  return best;
}

const std::vector<std::string> kTransformKeys = {"matrix", "translate", "rotate", "scale"};

// Reads one JSON object, remembering which keys were used: finish() rejects the rest, so
// a misspelled key is an error instead of a silently ignored setting. With the list of keys
// the object may hold, a key outside it is reported at once, before any missing key (a
// misspelled "flie" is named, not reported as a missing "file"), with the closest known key.
class ObjectReader {
 public:
  ObjectReader(const Json& j, std::string path, const std::string& file, std::vector<std::string> known = {})
      : m_json(j), m_path(std::move(path)), m_file(file), m_known(std::move(known)) {
    if (!j.is_object()) fail(m_path, std::string("expected an object, found ") + typeName(j));
    if (!m_known.empty())
      for (auto it = m_json.begin(); it != m_json.end(); ++it)
        if (std::find(m_known.begin(), m_known.end(), it.key()) == m_known.end()) unknownKey(it.key());
  }

  [[noreturn]] void fail(const std::string& path, const std::string& what) const {
    throw InputError(m_file, path.empty() ? "/" : path, what);
  }
  std::string at(const std::string& key) const { return m_path + "/" + key; }
  bool has(const std::string& key) const { return m_json.contains(key); }
  const Json* get(const std::string& key) {
    m_used.insert(key);
    auto it = m_json.find(key);
    return it == m_json.end() ? nullptr : &*it;
  }
  const Json& require(const std::string& key) {
    const Json* j = get(key);
    if (!j) fail(at(key), "required key is missing");
    return *j;
  }

  double number(const std::string& key, double fallback, double lo = -1e300, double hi = 1e300) {
    const Json* j = get(key);
    return j ? toNumber(*j, at(key), lo, hi) : fallback;
  }
  double toNumber(const Json& j, const std::string& path, double lo = -1e300, double hi = 1e300) const {
    if (!j.is_number()) fail(path, std::string("expected a number, found ") + typeName(j));
    const double v = j.get<double>();
    if (!(v >= lo && v <= hi)) {
      std::ostringstream msg;
      msg << "value " << v << " is out of range [" << lo << ", " << hi << "]";
      fail(path, msg.str());
    }
    return v;
  }
  int integer(const std::string& key, int fallback, int lo, int hi) {
    const Json* j = get(key);
    if (!j) return fallback;
    if (!j->is_number_integer()) fail(at(key), std::string("expected a whole number, found ") + typeName(*j));
    return int(toNumber(*j, at(key), lo, hi));
  }
  std::string string(const std::string& key, const std::string& fallback) {
    const Json* j = get(key);
    if (!j) return fallback;
    if (!j->is_string()) fail(at(key), std::string("expected a string, found ") + typeName(*j));
    return j->get<std::string>();
  }
  std::optional<Vec3d> vec3(const std::string& key) {
    const Json* j = get(key);
    if (!j) return std::nullopt;
    if (!j->is_array() || j->size() != 3) fail(at(key), "expected an array of 3 numbers");
    return Vec3d{toNumber((*j)[0], at(key) + "/0"), toNumber((*j)[1], at(key) + "/1"),
                 toNumber((*j)[2], at(key) + "/2")};
  }
  // A colour: three numbers, or one number for grey.
  std::optional<Vec3d> rgb(const std::string& key, double lo = 0, double hi = 1e30) {
    const Json* j = get(key);
    if (!j) return std::nullopt;
    if (j->is_number()) {
      const double v = toNumber(*j, at(key), lo, hi);
      return Vec3d{v, v, v};
    }
    if (!j->is_array() || j->size() != 3) fail(at(key), "expected a number or an array of 3 numbers");
    return Vec3d{toNumber((*j)[0], at(key) + "/0", lo, hi), toNumber((*j)[1], at(key) + "/1", lo, hi),
                 toNumber((*j)[2], at(key) + "/2", lo, hi)};
  }
  bool boolean(const std::string& key, bool fallback) {
    const Json* j = get(key);
    if (!j) return fallback;
    if (!j->is_boolean()) fail(at(key), std::string("expected true or false, found ") + typeName(*j));
    return j->get<bool>();
  }
  // A string that must be one of `choices` (listed in the message otherwise).
  std::string choice(const std::string& key, const std::string& fallback,
                     std::initializer_list<const char*> choices) {
    const std::string v = string(key, fallback);
    std::string list;
    for (const char* c : choices) {
      if (v == c) return v;
      list += std::string(list.empty() ? "" : ", ") + c;
    }
    fail(at(key), "unknown value '" + v + "' (expected one of: " + list + ")");
  }
  const std::string& path() const { return m_path; }
  const std::string& file() const { return m_file; }
  void finish() const {
    for (auto it = m_json.begin(); it != m_json.end(); ++it)
      if (!m_used.count(it.key())) unknownKey(it.key());
  }
  [[noreturn]] void unknownKey(const std::string& key) const {
    std::vector<std::string> candidates;
    for (const std::string& k : m_known)
      if (k != key) candidates.push_back(k);
    for (const std::string& k : m_used)
      if (k != key) candidates.push_back(k);
    const std::string close = closestKey(key, candidates);
    fail(at(key), "unknown key '" + key + "'" + (close.empty() ? "" : " (did you mean '" + close + "'?)"));
  }

 private:
  const Json& m_json;
  std::string m_path;
  const std::string& m_file;
  std::vector<std::string> m_known;
  std::set<std::string> m_used;
};

void parseCamera(ObjectReader r, CameraDesc& c) {
  if (const Json* g = r.get("gltf_camera")) {
    if (g->is_string()) c.gltfCamera = g->get<std::string>();
    else if (g->is_number_integer() && g->get<long long>() >= 0) c.gltfCamera = "#" + std::to_string(g->get<long long>());
    else r.fail(r.at("gltf_camera"), "expected a camera name or a camera index (a whole number >= 0)");
    if (c.gltfCamera.empty()) r.fail(r.at("gltf_camera"), "empty camera name");
    for (const char* key : {"position", "look_at", "up", "fov"})
      if (r.has(key)) r.fail(r.at(key), "not allowed together with gltf_camera");
    r.finish();
    return;
  }
  if (auto v = r.vec3("position")) c.position = *v;
  if (auto v = r.vec3("look_at")) c.lookAt = *v;
  if (auto v = r.vec3("up")) c.up = *v;
  c.fov = r.number("fov", c.fov, 1e-3, 179);
  if (length(c.lookAt - c.position) == 0) r.fail(r.at("look_at"), "camera looks at its own position");
  if (length(cross(c.lookAt - c.position, c.up)) == 0) r.fail(r.at("up"), "up is parallel to the viewing direction");
  r.finish();
}

// {"matrix": [16 numbers, row-major]} or any of {"translate", "rotate", "scale"}, applied as
// scale first, then rotate, then translate.
Transform parseTransform(ObjectReader r) {
  if (const Json* m = r.get("matrix")) {
    for (const char* key : {"translate", "rotate", "scale"})
      if (r.has(key)) r.fail(r.at(key), "not allowed together with matrix");
    if (!m->is_array() || m->size() != 16) r.fail(r.at("matrix"), "expected an array of 16 numbers (row-major 4x4)");
    double v[16];
    for (int i = 0; i < 16; ++i) v[i] = r.toNumber((*m)[i], r.at("matrix") + "/" + std::to_string(i));
    if (v[12] != 0 || v[13] != 0 || v[14] != 0 || v[15] != 1)
      r.fail(r.at("matrix"), "the last row must be [0, 0, 0, 1] (an affine transform)");
    const Transform t = Transform::fromRows(v);
    if (!t.isFiniteInvertible()) r.fail(r.at("matrix"), "the matrix is not invertible");
    r.finish();
    return t;
  }
  Transform t;
  if (const Json* s = r.get("scale")) {
    Vec3d sv;
    if (s->is_number()) {
      const double k = r.toNumber(*s, r.at("scale"));
      sv = {k, k, k};
    } else {
      auto v = r.vec3("scale");
      sv = *v;
    }
    if (sv.x == 0 || sv.y == 0 || sv.z == 0) r.fail(r.at("scale"), "a scale of 0 flattens the object");
    t = Transform::scale(sv);
  }
  if (const Json* j = r.get("rotate")) {
    ObjectReader rot(*j, r.at("rotate"), r.file(), {"axis", "degrees"});
    const auto axis = rot.vec3("axis");
    if (!axis) rot.fail(rot.at("axis"), "required key is missing");
    if (length(*axis) == 0) rot.fail(rot.at("axis"), "the rotation axis is zero");
    const double degrees = rot.toNumber(rot.require("degrees"), rot.at("degrees"));
    rot.finish();
    t = Transform::rotate(degrees, *axis) * t;
  }
  if (auto v = r.vec3("translate")) t = Transform::translate(*v) * t;
  r.finish();
  return t;
}

MaterialDesc parseMaterial(ObjectReader r) {
  MaterialDesc m;
  m.where = r.path();
  if (!r.has("type")) r.fail(r.at("type"), "required key is missing");
  const std::string type =
      r.choice("type", "diffuse", {"diffuse", "metallic_roughness", "conductor", "dielectric", "emissive"});
  if (type == "diffuse") {
    m.type = MaterialType::Diffuse;
    m.color = r.rgb("color", 0, 1).value_or(m.color);
  } else if (type == "metallic_roughness") {
    m.type = MaterialType::MetallicRoughness;
    m.color = r.rgb("color", 0, 1).value_or(m.color);
    m.metallic = r.number("metallic", 0, 0, 1);
    m.roughness = r.number("roughness", 0.5, 0, 1);
  } else if (type == "conductor") {
    m.type = MaterialType::Conductor;
    m.color = r.rgb("color", 0, 1).value_or(Vec3d{0.95, 0.93, 0.88});
    m.roughness = r.number("roughness", 0, 0, 1);
  } else if (type == "dielectric") {
    m.type = MaterialType::Dielectric;
    m.color = r.rgb("color", 0, 1).value_or(Vec3d{1, 1, 1});
    m.ior = r.number("ior", 1.5, 1.0001, 4);
    m.thin = r.boolean("thin", false);
  } else {
    m.type = MaterialType::Emissive;
    m.color = {0, 0, 0};
    m.emission = r.rgb("radiance", 0).value_or(Vec3d{1, 1, 1});
    m.twoSided = r.boolean("two_sided", false);
  }
  r.finish();
  return m;
}

LightDesc parseLight(ObjectReader r, const fs::path& dir) {
  LightDesc l;
  l.where = r.path();
  if (!r.has("type")) r.fail(r.at("type"), "required key is missing");
  const std::string type = r.choice("type", "", {"point", "spot", "directional", "environment"});
  auto direction = [&](const char* key) {
    const auto d = r.vec3(key);
    if (!d) r.fail(r.at(key), "required key is missing");
    if (length(*d) == 0) r.fail(r.at(key), "the direction is zero");
    return normalize(*d);
  };
  if (type == "point" || type == "spot") {
    l.type = type == "point" ? LightType::Point : LightType::Spot;
    l.position = r.vec3("position").value_or(l.position);
    l.intensity = r.rgb("intensity").value_or(l.intensity);
    if (l.type == LightType::Spot) {
      l.direction = direction("direction");
      l.outerAngle = r.number("outer_angle", 45, 0.01, 90);
      l.innerAngle = r.number("inner_angle", 0, 0, l.outerAngle);
    }
  } else if (type == "directional") {
    l.type = LightType::Directional;
    l.direction = direction("direction");
    l.irradiance = r.rgb("irradiance").value_or(l.irradiance);
  } else {
    l.type = LightType::Environment;
    l.radiance = r.rgb("radiance").value_or(l.radiance);
    const std::string file = r.string("file", "");
    if (r.has("file") && file.empty()) r.fail(r.at("file"), "empty file name");
    if (!file.empty()) l.file = fs::path(file).is_absolute() ? file : (dir / file).lexically_normal().string();
  }
  r.finish();
  return l;
}

// A material reference by name; checked against the scene's materials once all are read.
std::string materialRef(ObjectReader& r, std::string& where) {
  where = r.at("material");
  const std::string name = r.string("material", "");
  if (r.has("material") && name.empty()) r.fail(where, "empty material name");
  return name;
}

}  // namespace

const char* rayFlowName(RayFlow f) { return f == RayFlow::Scalar ? "scalar" : "wavefront"; }
bool parseRayFlow(const std::string& name, RayFlow& flow) {
  if (name == "wavefront") flow = RayFlow::Wavefront;
  else if (name == "scalar") flow = RayFlow::Scalar;
  else return false;
  return true;
}

const char* denoiseModeName(DenoiseMode mode) {
  switch (mode) {
    case DenoiseMode::Quality: return "quality";
    case DenoiseMode::Fast: return "fast";
    case DenoiseMode::Off: break;
  }
  return "off";
}
bool parseDenoiseMode(const std::string& name, DenoiseMode& mode) {
  if (name == "quality") mode = DenoiseMode::Quality;
  else if (name == "fast") mode = DenoiseMode::Fast;
  else if (name == "off") mode = DenoiseMode::Off;
  else return false;
  return true;
}
const char* denoiseModeList() { return "quality, fast, off"; }

const char* integratorList() { return "normals, eyelight, ao, direct, path, compare"; }
bool isKnownIntegrator(const std::string& name) {
  for (const char* known : {"normals", "eyelight", "ao", "direct", "path", "compare"})
    if (name == known) return true;
  return false;
}

void checkJsonNesting(const std::string& text, const std::string& file, int limit) {
  int depth = 0;
  bool inString = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (inString) {
      if (c == '\\') ++i;
      else if (c == '"') inString = false;
      continue;
    }
    if (c == '"') inString = true;
    else if (c == '[' || c == '{') {
      if (++depth > limit)
        throw InputError(file, "byte " + std::to_string(i + 1), "JSON nested more than " + std::to_string(limit) + " levels deep");
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
}

void throwJsonError(const std::string& file, const std::string& what) {
  const auto bracket = what.find("] ");
  throw InputError(file, "", "JSON: " + (bracket == std::string::npos ? what : what.substr(bracket + 2)));
}

namespace {

// The scene file's JSON tree; a syntax error names its line and column.
Json parseJsonText(const std::string& text, const std::string& path) {
  checkJsonNesting(text, path);
  Json root;
  try {
    root = Json::parse(text);
  } catch (const Json::out_of_range& e) {
    throwJsonError(path, e.what());  // a number beyond double (1e400): nlohmann says which, not where
  } catch (const Json::parse_error& e) {
    // e.byte is the 1-based offset of the error; report it as line and column.
    size_t line = 1, col = 1;
    for (size_t i = 0; i + 1 < e.byte && i < text.size(); ++i) {
      if (text[i] == '\n') { ++line; col = 1; } else { ++col; }
    }
    // "[json.exception.parse_error.101] parse error at line 1, column 18: syntax error while
    // parsing value - invalid literal; last read: '"fov":N'": keep what follows the position.
    std::string what = e.what();
    const auto column = what.find("column ");
    const auto colon = what.find(": ", column == std::string::npos ? 0 : column);
    if (colon != std::string::npos) what = what.substr(colon + 2);
    throw InputError(path, "line " + std::to_string(line) + ", column " + std::to_string(col),
                     "JSON syntax error: " + what);
  }
  return root;
}

// --set's value: JSON, or a bare word that is not JSON (a name, a path) as a string. Text that
// starts like JSON but is not (3O0, [1, 2) is refused rather than guessed at.
Json overrideValue(const std::string& value, const std::string& flag) {
  if (value.empty()) throw InputError(flag, "", "no value after '=' (a string is written \"\" or as a bare word)");
  checkJsonNesting(value, flag);  // as deep as a scene file may be, no deeper
  Json v = Json::parse(value, nullptr, false);
  if (!v.is_discarded()) return v;
  if (std::string("{[\"-0123456789").find(value[0]) != std::string::npos)
    throw InputError(flag, "", "'" + value + "' is not a JSON value");
  return Json(value);
}

// `text` as a whole number below 10^9 (digits only); false otherwise.
bool wholeNumber(const std::string& text, size_t& n) {
  if (text.empty() || text.size() >= 10 || text.find_first_not_of("0123456789") != std::string::npos) return false;
  n = std::stoul(text);
  return true;
}

// Sets `value` at `pointer` in `root`, step by step: an object takes any key (a missing one
// becomes an empty object on the way, as a block the file left out: /integrator/type in a scene
// without "integrator"; the parser then refuses keys it does not know), an array only an index it
// has, and nothing goes under a number, string or boolean.
void setAt(Json& root, const std::string& pointer, Json value, const std::string& flag) {
  if (pointer.empty() || pointer[0] != '/')
    throw InputError(flag, "", "'" + pointer + "' is not a JSON pointer into the scene (it starts with '/', e.g. /camera/fov)");
  Json::json_pointer ptr;
  try {
    ptr = Json::json_pointer(pointer);
  } catch (const Json::exception& e) {
    throw InputError(flag, "", "'" + pointer + "' is not a JSON pointer: " + std::string(e.what()).substr(std::string(e.what()).find("] ") + 2));
  }
  std::vector<std::string> tokens;
  for (Json::json_pointer p = ptr; !p.empty(); p = p.parent_pointer()) tokens.insert(tokens.begin(), p.back());
  Json* at = &root;
  Json::json_pointer where;  // the steps so far
  for (size_t i = 0; i < tokens.size(); ++i) {
    const std::string& key = tokens[i];
    const bool last = i + 1 == tokens.size();
    const std::string here = where.empty() ? "the scene" : where.to_string();
    if (at->is_object()) {
      if (!last && !at->contains(key)) (*at)[key] = Json::object();
      at = &(*at)[key];
    } else if (at->is_array()) {
      size_t index = 0;
      if (!wholeNumber(key, index) || (key[0] == '0' && key != "0") || index >= at->size())
        throw InputError(flag, "", here + " is an array of " + std::to_string(at->size()) + ": no entry '" + key + "'");
      at = &(*at)[index];
    } else {
      throw InputError(flag, "", here + " is a " + std::string(at->type_name()) + ": nothing goes under it");
    }
    where /= key;
  }
  *at = std::move(value);
}

// The overrides applied to the scene's tree, each recorded in `applied` as POINTER=VALUE.
void applyOverrides(Json& root, const SceneOverrides& overrides, std::vector<std::string>& applied) {
  if (overrides.empty()) return;
  if (!root.is_object()) return;  // the parser says what is wrong with the file itself
  for (const std::string& text : overrides.iso) {
    const std::string flag = "--iso " + text;
    const auto eq = text.find('=');
    if (eq == std::string::npos) throw InputError(flag, "", "expected SURFACE=VALUE, e.g. 0=300 (SURFACE counts all iso-surfaces from 0)");
    const std::string index = text.substr(0, eq), number = text.substr(eq + 1);
    double value = 0;
    size_t used = 0;
    try {
      value = std::stod(number, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != number.size() || !std::isfinite(value))
      throw InputError(flag, "", "'" + number + "' is not a finite number");
    // The surfaces as the parser will number them: every volume's list, in order.
    std::vector<std::string> pointers;
    const auto volumes = root.find("volumes");
    if (volumes != root.end() && volumes->is_array())
      for (size_t v = 0; v < volumes->size(); ++v) {
        const Json& vol = (*volumes)[v];
        const auto isos = vol.is_object() ? vol.find("isosurfaces") : vol.end();
        if (vol.is_object() && isos != vol.end() && isos->is_array())
          for (size_t k = 0; k < isos->size(); ++k)
            pointers.push_back("/volumes/" + std::to_string(v) + "/isosurfaces/" + std::to_string(k) + "/value");
      }
    size_t surface = 0;
    if (!wholeNumber(index, surface) || surface >= pointers.size())
      throw InputError(flag, "", "no iso-surface '" + index + "' (the scene has " + std::to_string(pointers.size()) +
                                     ", numbered from 0 over all volumes)");
    const std::string& pointer = pointers[surface];
    setAt(root, pointer, Json(value), flag);
    applied.push_back(pointer + "=" + Json(value).dump());
  }
  for (const std::string& text : overrides.set) {
    const std::string flag = "--set " + text;
    const auto eq = text.find('=');
    if (eq == std::string::npos) throw InputError(flag, "", "expected POINTER=VALUE, e.g. /camera/fov=30");
    Json value = overrideValue(text.substr(eq + 1), flag);
    const std::string dumped = value.dump();
    setAt(root, text.substr(0, eq), std::move(value), flag);
    applied.push_back(text.substr(0, eq) + "=" + dumped);
  }
}

// A named colour map at `key` (default `fallback`), refused by name if unknown; `stops`: the
// place also takes a list of stops (said in the message).
ColorMap namedMap(ObjectReader& r, const std::string& key, const std::string& fallback, bool stops) {
  const std::string name = r.string(key, fallback);
  ColorMap map;
  if (!ColorMap::named(name, map))
    r.fail(r.at(key), "unknown colour map '" + name + "' (known: " + ColorMap::list() +
                          (stops ? ", or a list of [value, [r, g, b]] stops)" : ")"));
  return map;
}

// "range": [low, high] with low < high, if given.
std::optional<std::pair<double, double>> valueRange(ObjectReader& r) {
  const Json* range = r.get("range");
  if (!range) return std::nullopt;
  if (!range->is_array() || range->size() != 2) r.fail(r.at("range"), "expected [low, high]");
  const double lo = r.toNumber((*range)[0], r.at("range") + "/0"), hi = r.toNumber((*range)[1], r.at("range") + "/1");
  if (!(lo < hi)) r.fail(r.at("range"), "an empty range: low must be below high");
  return std::make_pair(lo, hi);
}

// "color_by": {"field": NAME, "map": NAME or [[value, [r, g, b]], ...], "range": [lo, hi],
// "nan_color": [r, g, b]}. The field's name is resolved once every volume is read.
ColorByDesc parseColorBy(ObjectReader r) {
  ColorByDesc c;
  if (!r.has("field")) r.fail(r.at("field"), "required key is missing (a volume's \"name\", or \"gradient_magnitude\")");
  c.fieldName = r.string("field", "");
  if (c.fieldName.empty()) r.fail(r.at("field"), "empty field name");
  const Json* map = r.get("map");
  if (!map || map->is_string()) {
    c.map = namedMap(r, "map", "viridis", true);
  } else {
    // A user's map: stops [value, [r, g, b]] (field values rising, sRGB in [0, 1]); the first and
    // last values are the range.
    if (!map->is_array() || map->size() < 2 || map->size() > 1024)
      r.fail(r.at("map"), "expected a map name or a list of 2 to 1024 stops [value, [r, g, b]]");
    std::vector<std::pair<double, Vec3d>> stops;
    for (size_t i = 0; i < map->size(); ++i) {
      const std::string at = r.at("map") + "/" + std::to_string(i);
      const Json& s = (*map)[i];
      if (!s.is_array() || s.size() != 2 || !s[1].is_array() || s[1].size() != 3)
        r.fail(at, "expected a stop [value, [r, g, b]]");
      const double value = r.toNumber(s[0], at + "/0", -1e300, 1e300);
      Vec3d rgb;
      for (int k = 0; k < 3; ++k) rgb[k] = r.toNumber(s[1][size_t(k)], at + "/1/" + std::to_string(k), 0, 1);
      if (!stops.empty() && !(value > stops.back().first))
        r.fail(at + "/0", "stop values must rise strictly (this one is not above the one before)");
      stops.push_back({value, rgb});
    }
    const double span = stops.back().first - stops.front().first;
    std::vector<ColorMap::Stop> normalised;
    for (const auto& [value, rgb] : stops)
      normalised.push_back({float((value - stops.front().first) / span), Vec3f(rgb)});
    normalised.back().position = 1;
    for (size_t i = 1; i < normalised.size(); ++i)
      if (!(normalised[i].position > normalised[i - 1].position))
        r.fail(r.at("map"), "stops too close together to tell apart in float");
    c.map = ColorMap::fromStops(std::move(normalised));
    c.lo = stops.front().first;
    c.hi = stops.back().first;
  }
  if (map && map->is_array() && r.has("range"))
    r.fail(r.at("range"), "a map of stops takes its range from their values: give one or the other");
  if (const auto range = valueRange(r)) {
    std::tie(c.lo, c.hi) = *range;
  } else if (!map || map->is_string()) {
    r.fail(r.at("range"), "required key is missing ([low, high] of the field's values, mapped onto the map)");
  }
  if (const auto nan = r.rgb("nan_color", 0, 1)) c.nanColor = *nan;
  r.finish();
  return c;
}

// "point" and "normal" of a plane (a slice, a clip plane): finite, the normal not zero (unit).
std::pair<Vec3d, Vec3d> readPlane(ObjectReader& r) {
  if (!r.has("point")) r.fail(r.at("point"), "required key is missing");
  if (!r.has("normal")) r.fail(r.at("normal"), "required key is missing");
  const Vec3d point = *r.vec3("point");
  const Vec3d normal = *r.vec3("normal");
  const double len = length(normal);
  if (!(len > 1e-30) || !std::isfinite(len)) r.fail(r.at("normal"), "the normal has zero length");
  for (int a = 0; a < 3; ++a)
    if (!(std::fabs(point[a]) <= 1e30)) r.fail(r.at("point"), "the point is not finite");
  return {point, normal / len};
}

// "clip": a list of at most 64 entries, each {"plane": {"point": [...], "normal": [...]}} (keeps
// the side the normal points away from) or {"box": {"min": [...], "max": [...]}} (keeps the
// inside); the region kept is what every entry keeps.
ClipRegion parseClip(const Json& j, const std::string& where, const std::string& file) {
  if (!j.is_array() || j.size() > 64) throw InputError(file, where, "expected an array of at most 64 planes and boxes");
  ClipRegion clip;
  for (size_t i = 0; i < j.size(); ++i) {
    ObjectReader entry(j[i], where + "/" + std::to_string(i), file, {"plane", "box"});
    if (entry.has("plane") == entry.has("box"))
      entry.fail(entry.path(), "a clip entry is either {\"plane\": {\"point\", \"normal\"}} or {\"box\": {\"min\", \"max\"}}");
    if (const Json* plane = entry.get("plane")) {
      ObjectReader r(*plane, entry.at("plane"), file, {"point", "normal"});
      const auto [point, normal] = readPlane(r);
      r.finish();
      clip.addPlane(point, normal);
    } else {
      ObjectReader r(*entry.get("box"), entry.at("box"), file, {"min", "max"});
      for (const char* key : {"min", "max"})
        if (!r.has(key)) r.fail(r.at(key), "required key is missing");
      const Vec3d lo = *r.vec3("min"), hi = *r.vec3("max");
      for (int a = 0; a < 3; ++a) {
        if (!(std::fabs(lo[a]) <= 1e30 && std::fabs(hi[a]) <= 1e30)) r.fail(r.path(), "a corner is not finite");
        if (!(lo[a] < hi[a])) r.fail(r.at("max"), std::string("max is not above min on ") + "xyz"[a]);
      }
      r.finish();
      clip.addBox(lo, hi);
    }
    entry.finish();
  }
  return clip;
}

// "slices[k]": {"axis": "x"|"y"|"z", "position": p} or {"point": [...], "normal": [...]} (world
// space), "map" (default grey), "range" (default: the volume's values), "emit" (false).
SliceDesc parseSlice(ObjectReader r) {
  SliceDesc s;
  s.where = r.path();
  const bool byAxis = r.has("axis") || r.has("position"), byPlane = r.has("point") || r.has("normal");
  if (byAxis == byPlane) r.fail(r.path(), "a slice needs either \"axis\" and \"position\" or \"point\" and \"normal\"");
  if (byAxis) {
    if (!r.has("axis")) r.fail(r.at("axis"), "required key is missing (x, y or z)");
    if (!r.has("position")) r.fail(r.at("position"), "required key is missing (the plane's world coordinate on that axis)");
    const std::string axis = r.choice("axis", "z", {"x", "y", "z"});
    const int a = axis[0] - 'x';
    s.normal = {0, 0, 0};
    s.normal[a] = 1;
    s.point = {0, 0, 0};
    s.point[a] = r.number("position", 0, -1e30, 1e30);
  } else {
    std::tie(s.point, s.normal) = readPlane(r);
  }
  s.map = namedMap(r, "map", "grey", false);
  if (const auto range = valueRange(r)) std::tie(s.lo, s.hi) = *range;
  s.emit = r.boolean("emit", false);
  r.finish();
  return s;
}

SceneDesc parseSceneJson(const Json& root, const std::string& path, const SceneArrays* arrays) {
  const fs::path dir = fs::path(path).parent_path();
  SceneDesc scene;
  scene.path = path;
  ObjectReader r(root, "", path,
                 {"camera", "film", "integrator", "intersector", "meshes", "volumes", "materials", "lights", "clip"});
  if (const Json* j = r.get("camera")) parseCamera(ObjectReader(*j, "/camera", path, {"position", "look_at", "up", "fov", "gltf_camera"}), scene.camera);
  else scene.camera.frameScene = true;
  if (const Json* j = r.get("film")) {
    ObjectReader f(*j, "/film", path, {"width", "height", "denoise"});
    scene.settings.width = f.integer("width", scene.settings.width, 1, 16384);
    scene.settings.height = f.integer("height", scene.settings.height, 1, 16384);
    const std::string denoise = f.string("denoise", denoiseModeName(scene.settings.denoise));
    if (!parseDenoiseMode(denoise, scene.settings.denoise))
      f.fail("/film/denoise", "unknown denoiser mode '" + denoise + "' (known: " + denoiseModeList() + ")");
    f.finish();
  }
  if (const Json* j = r.get("integrator")) {
    ObjectReader in(*j, "/integrator", path,
                    {"type", "spp", "max_depth", "ao_distance", "seed", "clamp", "noise_threshold", "ray_flow", "distribution", "replicate"});
    scene.settings.integrator = in.string("type", scene.settings.integrator);
    if (!isKnownIntegrator(scene.settings.integrator))
      in.fail("/integrator/type", "unknown integrator '" + scene.settings.integrator +
                                      "' (known: " + integratorList() + ")");
    scene.settings.spp = in.integer("spp", scene.settings.spp, 1, 1 << 20);
    scene.settings.maxDepth = in.integer("max_depth", scene.settings.maxDepth, 1, 1000);
    scene.settings.aoDistance = in.number("ao_distance", scene.settings.aoDistance, 1e-30, 1e30);
    scene.settings.seed = uint64_t(in.integer("seed", 0, 0, 1 << 30));
    scene.settings.clampIndirect = in.number("clamp", 0, 0, 1e30);
    scene.settings.noiseThreshold = in.number("noise_threshold", 0, 0, 1);
    const std::string flow = in.string("ray_flow", rayFlowName(scene.settings.rayFlow));
    if (!parseRayFlow(flow, scene.settings.rayFlow))
      in.fail("/integrator/ray_flow", "unknown ray flow '" + flow + "' (known: wavefront, scalar)");
    const std::string distribution = in.string("distribution", scene.settings.dataParallel ? "data" : "image");
    if (distribution != "data" && distribution != "image")
      in.fail("/integrator/distribution", "unknown distribution '" + distribution + "' (known: image, data)");
    scene.settings.dataParallel = distribution == "data";
    scene.settings.replicate = in.number("replicate", scene.settings.replicate, 0, 1);
    in.finish();
  }
  if (const Json* j = r.get("intersector")) {
    if (!j->is_string()) r.fail("/intersector", std::string("expected a string, found ") + typeName(*j));
    std::string error;
    if (!parseIntersector(j->get<std::string>(), scene.settings.intersector, error))
      r.fail("/intersector", error);
  }
  if (const Json* j = r.get("meshes")) {
    if (!j->is_array()) r.fail("/meshes", std::string("expected an array, found ") + typeName(*j));
    for (size_t i = 0; i < j->size(); ++i) {
      MeshDesc m;
      m.where = "/meshes/" + std::to_string(i);
      ObjectReader mr((*j)[i], m.where, path, {"file", "shape", "transform", "material"});
      const bool hasFile = mr.has("file"), hasShape = mr.has("shape");
      if (hasFile == hasShape) mr.fail(m.where, "a mesh needs exactly one of \"file\" (glTF) and \"shape\"");
      if (hasFile) {
        const std::string file = mr.string("file", "");
        if (file.empty()) mr.fail(mr.at("file"), "empty file name");
        m.file = fs::path(file).is_absolute() ? file : (dir / file).lexically_normal().string();
      } else {
        m.shape = mr.choice("shape", "", {"sphere", "quad"}) == "sphere" ? MeshShape::Sphere : MeshShape::Quad;
      }
      if (const Json* t = mr.get("transform")) m.transform = parseTransform(ObjectReader(*t, mr.at("transform"), path, kTransformKeys));
      m.material = materialRef(mr, m.materialWhere);
      mr.finish();
      scene.meshes.push_back(std::move(m));
    }
  }
  if (const Json* j = r.get("materials")) {
    if (!j->is_object()) r.fail("/materials", std::string("expected an object of named materials, found ") + typeName(*j));
    for (auto it = j->begin(); it != j->end(); ++it) {
      if (it.key().empty()) r.fail("/materials", "a material needs a non-empty name");
      scene.materials[it.key()] = parseMaterial(ObjectReader(it.value(), "/materials/" + it.key(), path,
                                                             {"type", "color", "metallic", "roughness", "ior", "thin",
                                                              "radiance", "two_sided"}));
    }
  }
  if (const Json* j = r.get("lights")) {
    if (!j->is_array()) r.fail("/lights", std::string("expected an array, found ") + typeName(*j));
    for (size_t i = 0; i < j->size(); ++i)
      scene.lights.push_back(parseLight(ObjectReader((*j)[i], "/lights/" + std::to_string(i), path,
                                                          {"type", "position", "direction", "intensity", "irradiance",
                                                           "radiance", "inner_angle", "outer_angle", "file"}),
                                             dir));
  }
  if (const Json* j = r.get("volumes")) {
    if (!j->is_array()) r.fail("/volumes", std::string("expected an array, found ") + typeName(*j));
    for (size_t i = 0; i < j->size(); ++i) {
      const std::string vp = "/volumes/" + std::to_string(i);
      ObjectReader vr((*j)[i], vp, path,
                      {"file", "procedural", "array", "time", "dims", "type", "endian", "series", "grid", "origin",
                       "spacing", "transform", "name", "isosurfaces", "slices", "clip"});
      VolumeDesc v;
      v.where = vp;
      const bool hasFile = vr.has("file"), hasProc = vr.has("procedural"), hasArray = vr.has("array");
      if (int(hasFile) + int(hasProc) + int(hasArray) != 1)
        vr.fail(vp, "a volume needs exactly one of \"file\" and \"procedural\" (or, from Python, \"array\")");
      if (hasArray) {
        // An in-memory grid (isotrace.Volume in Python): its index among the arrays handed over.
        // A list of indices: a time series, one array per step.
        const size_t count = arrays ? arrays->size() : 0;
        if (count == 0)
          vr.fail(vr.at("array"), "no arrays here: \"array\" names a volume given from Python (isotrace.Volume)");
        const Json& a = *vr.get("array");
        const int most = int(std::min<size_t>(count, 1u << 30)) - 1;
        auto arrayAt = [&](const Json& j, const std::string& where) {
          if (!j.is_number_integer()) vr.fail(where, std::string("expected a whole number, found ") + typeName(j));
          const int k = int(vr.toNumber(j, where, 0, most));
          if (!(*arrays)[size_t(k)]) vr.fail(where, "array " + std::to_string(k) + " is empty");
          return (*arrays)[size_t(k)];
        };
        if (a.is_array()) {
          if (a.empty()) vr.fail(vr.at("array"), "an empty list of arrays");
          for (size_t k = 0; k < a.size(); ++k) v.time.arrays.push_back(arrayAt(a[k], vr.at("array") + "/" + std::to_string(k)));
          v.time.steps = int(v.time.arrays.size());
          v.time.where = vr.at("array");
          v.array = v.time.arrays[0];
        } else {
          v.array = arrayAt(a, vr.at("array"));
        }
        for (const char* key : {"dims", "type", "endian", "series", "grid", "time"})
          if (vr.has(key)) vr.fail(vr.at(key), std::string("\"") + key + "\" applies to volume files, not to an array");
      } else if (hasFile) {
        // One file; a list of files or a pattern: a time series, one file per step.
        auto resolve = [&](const std::string& file) {
          return fs::path(file).is_absolute() ? file : (dir / file).lexically_normal().string();
        };
        const Json& f = *vr.get("file");
        if (f.is_array()) {
          if (f.empty() || f.size() > 100000) vr.fail(vr.at("file"), "expected a list of 1 to 100000 file names");
          for (size_t k = 0; k < f.size(); ++k) {
            const std::string kp = vr.at("file") + "/" + std::to_string(k);
            if (!f[k].is_string()) vr.fail(kp, std::string("expected a file name, found ") + typeName(f[k]));
            if (f[k].get<std::string>().empty()) vr.fail(kp, "empty file name");
            v.time.files.push_back(resolve(f[k].get<std::string>()));
          }
        } else {
          const std::string file = vr.string("file", "");
          if (file.empty()) vr.fail(vr.at("file"), "empty file name");
          if (isFilePattern(file)) v.time.files = expandFilePattern(resolve(file), path, vr.at("file"));
          else v.file = resolve(file);
        }
        if (!v.time.files.empty()) {
          v.time.steps = int(v.time.files.size());
          v.time.where = vr.at("file");
          v.file = v.time.files[0];
        }
        if (const Json* t = vr.get("time")) {
          // A file's time axis: "all" steps through it, a whole number picks one time point.
          if (!v.time.files.empty())
            vr.fail(vr.at("time"), "\"time\" picks time points of one file with a time axis; a list or pattern of files is a series already");
          if (t->is_string() && t->get<std::string>() == "all") {
            v.time.fileAxis = true;
            v.time.steps = 0;  // read from the header (resolveTimeSeries)
            v.time.where = vr.at("time");
          } else if (t->is_number_integer()) {
            v.part.time = int(vr.toNumber(*t, vr.at("time"), 0, 1 << 30));
          } else {
            vr.fail(vr.at("time"), "expected \"all\" (every time point) or a whole number (one time point, from 0)");
          }
        }
        if (const Json* d = vr.get("dims")) {
          if (!d->is_array() || d->size() != 3) vr.fail(vr.at("dims"), "expected an array of 3 whole numbers");
          Vec3i dims;
          for (int k = 0; k < 3; ++k) {
            const std::string kp = vr.at("dims") + "/" + std::to_string(k);
            if (!(*d)[k].is_number_integer()) vr.fail(kp, "expected a whole number");
            dims[k] = int(vr.toNumber((*d)[k], kp, 2, 1 << 20));
          }
          v.layout.dims = dims;
        }
        if (vr.has("type")) {
          ScalarType t;
          const std::string name = vr.string("type", "");
          if (!parseScalarType(name, t))
            vr.fail(vr.at("type"), "unknown type '" + name + "' (uint8, uint16, int16, float32)");
          v.layout.type = t;
        }
        v.part.series = vr.string("series", "");
        if (vr.has("series") && v.part.series.empty()) vr.fail(vr.at("series"), "empty series UID");
        v.part.grid = vr.string("grid", "");
        if (vr.has("grid") && v.part.grid.empty()) vr.fail(vr.at("grid"), "empty grid name");
        const std::string endian = vr.string("endian", "little");
        if (endian != "little" && endian != "big") vr.fail(vr.at("endian"), "expected \"little\" or \"big\"");
        v.layout.bigEndian = endian == "big";
      } else {
        for (const char* key : {"dims", "type", "endian", "series", "grid", "time"})
          if (vr.has(key)) vr.fail(vr.at(key), std::string("\"") + key + "\" applies to volume files, not to a procedural field");
        ObjectReader pr(*vr.get("procedural"), vr.at("procedural"), path, {"field", "resolution"});
        const std::string name = pr.string("field", "");
        Field field;
        if (!pr.has("field")) pr.fail(pr.at("field"), "required key is missing");
        if (!parseField(name, field))
          pr.fail(pr.at("field"), "unknown field '" + name + "' (sphere, torus, gyroid, marschner_lobb, gyroid_ball)");
        v.field = field;
        if (const Json* res = pr.get("resolution")) {
          if (!res->is_array() || res->size() != 3) pr.fail(pr.at("resolution"), "expected an array of 3 whole numbers");
          for (int k = 0; k < 3; ++k) {
            const std::string kp = pr.at("resolution") + "/" + std::to_string(k);
            if (!(*res)[k].is_number_integer()) pr.fail(kp, "expected a whole number");
            v.resolution[k] = int(pr.toNumber((*res)[k], kp, 2, 4096));
          }
          // A procedural grid is float32 in memory: at most 2^30 samples (4 GiB).
          if (double(v.resolution.x) * v.resolution.y * v.resolution.z > double(1 << 30))
            pr.fail(pr.at("resolution"), "more than 2^30 samples (4 GiB of float32); e.g. 1024^3 is the most");
        }
        pr.finish();
      }
      v.origin = vr.vec3("origin");
      v.spacing = vr.vec3("spacing");
      if (v.spacing && !(v.spacing->x > 0 && v.spacing->y > 0 && v.spacing->z > 0))
        vr.fail(vr.at("spacing"), "spacing must be positive");
      if (const Json* t = vr.get("transform")) v.transform = parseTransform(ObjectReader(*t, vr.at("transform"), path, kTransformKeys));
      v.name = vr.string("name", "");
      if (vr.has("name")) {
        if (v.name.empty() || v.name == "gradient_magnitude")
          vr.fail(vr.at("name"), v.name.empty() ? "empty name" : "'gradient_magnitude' names the gradient, not a volume");
        for (const VolumeDesc& other : scene.volumes)
          if (other.name == v.name) vr.fail(vr.at("name"), "the name '" + v.name + "' is taken by " + other.where);
      }
      // No iso-surfaces: a data field (it colours others' surfaces and is not drawn).
      const Json* isosJson = vr.get("isosurfaces");
      static const Json kNone = Json::array();
      const Json& isos = isosJson ? *isosJson : kNone;
      if (!isos.is_array()) vr.fail(vr.at("isosurfaces"), std::string("expected an array of iso-surfaces, found ") + typeName(isos));
      for (size_t k = 0; k < isos.size(); ++k) {
        ObjectReader ir(isos[k], vr.at("isosurfaces") + "/" + std::to_string(k), path,
                        {"value", "color", "material", "inside", "normals", "color_by", "cap_color_by"});
        IsoSurfaceDesc iso;
        iso.value = ir.toNumber(ir.require("value"), ir.at("value"));
        iso.color = ir.rgb("color", 0, 1);
        iso.material = materialRef(ir, iso.materialWhere);
        iso.solidAbove = ir.choice("inside", "above", {"above", "below"}) == "above";
        iso.smoothNormals = ir.choice("normals", "smooth", {"smooth", "cell"}) == "smooth";
        if (const Json* c = ir.get("color_by")) iso.colorBy = parseColorBy(ObjectReader(*c, ir.at("color_by"), path,
                                                                                        {"field", "map", "range", "nan_color"}));
        if (const Json* c = ir.get("cap_color_by"))
          iso.capColorBy = parseColorBy(ObjectReader(*c, ir.at("cap_color_by"), path, {"field", "map", "range", "nan_color"}));
        ir.finish();
        v.isosurfaces.push_back(iso);
      }
      if (const Json* slices = vr.get("slices")) {
        if (!slices->is_array() || slices->size() > 64) vr.fail(vr.at("slices"), "expected an array of at most 64 slices");
        for (size_t k = 0; k < slices->size(); ++k)
          v.slices.push_back(parseSlice(ObjectReader((*slices)[k], vr.at("slices") + "/" + std::to_string(k), path,
                                                     {"axis", "position", "point", "normal", "map", "range", "emit"})));
      }
      if (const Json* c = vr.get("clip")) v.clip = parseClip(*c, vr.at("clip"), path);
      vr.finish();
      scene.volumes.push_back(std::move(v));
    }
  }
  if (const Json* c = r.get("clip")) scene.clip = parseClip(*c, "/clip", path);
  r.finish();
  auto checkMaterial = [&](const std::string& name, const std::string& where) {
    if (!name.empty() && !scene.materials.count(name))
      throw InputError(path, where, "undefined material '" + name + "'");
  };
  for (const MeshDesc& m : scene.meshes) checkMaterial(m.material, m.materialWhere);
  for (const VolumeDesc& v : scene.volumes)
    for (const IsoSurfaceDesc& iso : v.isosurfaces) checkMaterial(iso.material, iso.materialWhere);
  // "color_by" fields name volumes anywhere in the list.
  for (VolumeDesc& v : scene.volumes)
    for (size_t k = 0; k < v.isosurfaces.size(); ++k)
      for (const char* key : {"color_by", "cap_color_by"}) {
        std::optional<ColorByDesc>& c = std::string(key) == "color_by" ? v.isosurfaces[k].colorBy : v.isosurfaces[k].capColorBy;
        if (!c || c->fieldName == "gradient_magnitude") continue;
        std::string names;
        for (size_t i = 0; i < scene.volumes.size(); ++i) {
          if (scene.volumes[i].name == c->fieldName) c->volume = int(i);
          if (!scene.volumes[i].name.empty()) names += (names.empty() ? "" : ", ") + scene.volumes[i].name;
        }
        if (c->volume < 0)
          throw InputError(path, v.where + "/isosurfaces/" + std::to_string(k) + "/" + key + "/field",
                           "no volume is named '" + c->fieldName + "' (named: " + (names.empty() ? "none" : names) +
                               "; or \"gradient_magnitude\")");
      }
  return scene;
}

}  // namespace

SceneDesc parseSceneText(const std::string& text, const std::string& path, const SceneOverrides& overrides,
                         const SceneArrays* arrays) {
  Json root = parseJsonText(text, path);
  std::vector<std::string> applied;
  applyOverrides(root, overrides, applied);
  SceneDesc scene = parseSceneJson(root, path, arrays);
  scene.overrides = std::move(applied);
  resolveTimeSeries(scene);  // (reads the headers of time series, checks their steps)
  return scene;
}

std::string overriddenSceneText(const std::string& text, const std::string& path, const SceneOverrides& overrides) {
  if (overrides.empty()) return text;
  Json root = parseJsonText(text, path);
  std::vector<std::string> applied;
  applyOverrides(root, overrides, applied);
  return root.dump(2);
}

SceneDesc parseSceneFile(const std::string& path, const SceneOverrides& overrides) {
  return parseSceneText(readWholeFile(path, "scene file", kSceneStreamCap), path, overrides);
}

}  // namespace iso
