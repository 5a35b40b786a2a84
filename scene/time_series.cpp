#include "scene/time_series.h"

#include <fnmatch.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <map>
#include <mutex>
#include <sstream>

#include "volume/input_error.h"
#include "volume/loaders.h"

namespace iso {
namespace {
namespace fs = std::filesystem;

// Natural order: runs of digits compare as numbers ("t2" < "t10"), the rest as text; equal
// numbers with more leading zeros first, then plain text order, so the order is total.
bool naturalLess(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    if (std::isdigit((unsigned char)a[i]) && std::isdigit((unsigned char)b[j])) {
      size_t ie = i, je = j;
      while (ie < a.size() && std::isdigit((unsigned char)a[ie])) ++ie;
      while (je < b.size() && std::isdigit((unsigned char)b[je])) ++je;
      size_t is = i, js = j;  // leading zeros aside
      while (is + 1 < ie && a[is] == '0') ++is;
      while (js + 1 < je && b[js] == '0') ++js;
      if (ie - is != je - js) return ie - is < je - js;
      const int c = a.compare(is, ie - is, b, js, je - js);
      if (c != 0) return c < 0;
      if (ie - i != je - j) return ie - i > je - j;
      i = ie, j = je;
      continue;
    }
    if (a[i] != b[j]) return (unsigned char)a[i] < (unsigned char)b[j];
    ++i, ++j;
  }
  return a.size() - i < b.size() - j;
}

std::string stepName(const VolumeDesc& v, int step) {
  if (!v.time.files.empty()) return "'" + v.time.files[size_t(step)] + "'";
  if (!v.time.arrays.empty()) return "array";
  return "'" + v.file + "'";
}

std::string shapeText(const Vec3i& d, ScalarType t) {
  return std::to_string(d.x) + "x" + std::to_string(d.y) + "x" + std::to_string(d.z) + " " + scalarTypeName(t);
}

// What a file's header says (its time points, or its shape), remembered by the file's name, size
// and modification time: a scene is parsed again on every change in `isotrace view` and every
// frame from Python, and a NIfTI header is read in a child process (about a millisecond each).
// What a file's header says (its time points, or its shape), remembered by the file's name, size
// and modification time: a scene is parsed again on every change in `isotrace view` and every
// frame from Python, and a NIfTI header is read in a child process (~17 ms a fork here).
class HeaderMemory {
 public:
  template <typename T>
  std::optional<T> find(const std::string& key) {
    std::lock_guard<std::mutex> lock(m_mutex);
    auto it = known<T>().find(key);
    if (it == known<T>().end()) return std::nullopt;
    return it->second;
  }
  template <typename T>
  void keep(const std::string& key, const T& value) {
    std::lock_guard<std::mutex> lock(m_mutex);
    if (known<T>().size() < 100000) known<T>()[key] = value;
  }

 private:
  template <typename T>
  std::map<std::string, T>& known() {
    static std::map<std::string, T> values;
    return values;
  }
  std::mutex m_mutex;
};
HeaderMemory g_headers;

// The key of what `how` asks of `file` now; empty when the file cannot be stat'ed (not remembered).
std::string headerKey(const std::string& file, const std::string& how) {
  std::error_code ec, ec2;
  const auto size = fs::file_size(file, ec);
  const auto time = fs::last_write_time(file, ec2).time_since_epoch().count();
  if (ec || ec2) return "";
  return file + '\n' + how + '\n' + std::to_string(size) + '\n' + std::to_string(time);
}

int timePointsOf(const std::string& file) {
  const std::string key = headerKey(file, "time points");
  if (!key.empty())
    if (const std::optional<int> known = g_headers.find<int>(key)) return *known;
  const int points = volumeTimePoints(file);
  if (!key.empty()) g_headers.keep(key, points);
  return points;
}

// The shapes of a series' files by their headers (nullopt: no cheap header), those not remembered
// read together.
std::vector<std::optional<VolumeShape>> shapesOf(const VolumeDesc& v, const std::vector<std::string>& files) {
  std::string how = "shape " + std::to_string(v.part.time) + (v.layout.bigEndian ? " big" : "");
  if (v.layout.dims) how += " " + shapeText(*v.layout.dims, ScalarType::UInt8);
  if (v.layout.type) how += std::string(" ") + scalarTypeName(*v.layout.type);
  using Shape = std::optional<VolumeShape>;
  std::vector<Shape> shapes(files.size());
  std::vector<std::string> keys(files.size()), unknown;
  std::vector<size_t> where;
  for (size_t k = 0; k < files.size(); ++k) {
    keys[k] = headerKey(files[k], how);
    const std::optional<Shape> known = keys[k].empty() ? std::nullopt : g_headers.find<Shape>(keys[k]);
    if (known) {
      shapes[k] = *known;
    } else {
      unknown.push_back(files[k]);
      where.push_back(k);
    }
  }
  if (unknown.empty()) return shapes;
  const std::vector<Shape> read = volumeFileShapes(unknown, v.layout, v.part);
  for (size_t i = 0; i < where.size(); ++i) {
    shapes[where[i]] = read[i];
    if (!keys[where[i]].empty()) g_headers.keep(keys[where[i]], read[i]);
  }
  return shapes;
}
}  // namespace

bool isFilePattern(const std::string& file) {
  const std::string name = fs::path(file).filename().string();
  return name.find_first_of("*?") != std::string::npos;
}

std::vector<std::string> expandFilePattern(const std::string& pattern, const std::string& sceneFile,
                                           const std::string& where) {
  const fs::path p(pattern);
  const fs::path dir = p.parent_path().empty() ? fs::path(".") : p.parent_path();
  const std::string glob = p.filename().string();
  if (fs::path(p.parent_path()).string().find_first_of("*?") != std::string::npos)
    throw InputError(sceneFile, where, "'" + pattern + "': * and ? are matched in the file name only, not in folders");
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw InputError(sceneFile, where, "'" + pattern + "': the folder '" + dir.string() + "' does not exist");
  std::vector<std::string> names;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name[0] != '.' && fnmatch(glob.c_str(), name.c_str(), FNM_PERIOD) == 0) names.push_back(name);
    if (names.size() > 100000) throw InputError(sceneFile, where, "'" + pattern + "' matches more than 100000 files");
  }
  if (ec) throw InputError(sceneFile, where, "'" + pattern + "': cannot list '" + dir.string() + "': " + ec.message());
  if (names.empty()) throw InputError(sceneFile, where, "'" + pattern + "' matches no file");
  std::sort(names.begin(), names.end(), naturalLess);
  std::vector<std::string> files;
  for (const std::string& n : names) files.push_back((p.parent_path() / n).string());
  return files;
}

void resolveTimeSeries(SceneDesc& scene) {
  for (VolumeDesc& v : scene.volumes) {
    VolumeDesc::TimeSeries& t = v.time;
    if (t.fileAxis) {
      t.steps = timePointsOf(v.file);
      if (t.steps < 2)
        throw InputError(scene.path, t.where, "\"time\": \"all\", but '" + v.file + "' has " +
                                                  (t.steps == 1 ? "one time step" : "no time axis") + ": nothing to step through");
      continue;
    }
    if (t.files.empty()) continue;
    t.steps = int(t.files.size());
    // Every file there before any frame (the first missing one named, with its index).
    for (size_t k = 0; k < t.files.size(); ++k) {
      std::error_code ec;
      if (!fs::exists(t.files[k], ec))
        throw InputError(scene.path, t.where, "time step " + std::to_string(k) + " of " + std::to_string(t.files.size()) +
                                                  ": '" + t.files[k] + "' does not exist");
    }
    // Shapes and types from the headers where they are cheap to read (those not remembered read
    // together: one child process for all NIfTI headers).
    std::vector<std::optional<VolumeShape>> shapes;
    try {
      shapes = shapesOf(v, t.files);
    } catch (const InputError& e) {
      // A step's own error (it names the file) with its place in the series.
      const std::string what = e.what();
      for (size_t k = 0; k < t.files.size(); ++k)
        if (what.rfind(t.files[k] + ":", 0) == 0)
          throw InputError(scene.path, t.where, "time step " + std::to_string(k) + " of " + std::to_string(t.files.size()) +
                                                    ": " + what);
      throw;
    }
    const std::optional<VolumeShape>& first = shapes[0];
    if (!first) continue;
    for (size_t k = 1; k < t.files.size(); ++k) {
      const std::optional<VolumeShape>& s = shapes[k];
      if (s && (!(s->dims == first->dims) || s->type != first->type))
        throw InputError(scene.path, t.where, "time step " + std::to_string(k) + " ('" + t.files[k] + "') is " +
                                                  shapeText(s->dims, s->type) + ", step 0 ('" + t.files[0] + "') " +
                                                  shapeText(first->dims, first->type) + ": the steps of a series must agree");
    }
  }
}

int sceneTimeSteps(const SceneDesc& scene) {
  int steps = 1;
  for (const VolumeDesc& v : scene.volumes)
    if (v.time.varying()) steps = std::max(steps, v.time.steps);
  return steps;
}

int timeStepOfFrame(int frame, int frames, int steps) {
  if (frames <= 1 || steps <= 1) return 0;
  return std::min(steps - 1, int(int64_t(frame) * steps / frames));
}

void selectTimeStep(VolumeDesc& v, int step) {
  if (!v.time.varying()) return;
  step = std::clamp(step, 0, v.time.steps - 1);
  if (!v.time.files.empty()) v.file = v.time.files[size_t(step)];
  else if (!v.time.arrays.empty()) v.array = v.time.arrays[size_t(step)];
  else v.part.time = step;
}

int currentTimeStep(const VolumeDesc& v) {
  if (!v.time.files.empty())
    return int(std::find(v.time.files.begin(), v.time.files.end(), v.file) - v.time.files.begin());
  if (!v.time.arrays.empty())
    return int(std::find(v.time.arrays.begin(), v.time.arrays.end(), v.array) - v.time.arrays.begin());
  return v.part.time;
}

std::string volumeSourceKey(const VolumeDesc& v) {
  std::ostringstream key;
  key.precision(17);
  if (v.array) key << "array " << v.array.get();
  else if (v.field) key << "field " << int(*v.field) << ' ' << shapeText(v.resolution, ScalarType::Float32);
  else key << "file " << v.file << '\n' << v.part.series << '\n' << v.part.grid << '\n' << v.part.time;
  if (v.layout.dims) key << "\ndims " << shapeText(*v.layout.dims, ScalarType::UInt8);
  if (v.layout.type) key << "\ntype " << scalarTypeName(*v.layout.type);
  if (v.layout.bigEndian) key << "\nbig";
  // (The placement is applied as the volume loads: part of what it loads.)
  if (v.origin) key << "\norigin " << v.origin->x << ' ' << v.origin->y << ' ' << v.origin->z;
  if (v.spacing) key << "\nspacing " << v.spacing->x << ' ' << v.spacing->y << ' ' << v.spacing->z;
  key << "\ntransform";
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 4; ++j) key << ' ' << v.transform.m[i][j];
  return key.str();
}

void checkSameShape(const SceneDesc& scene, const VolumeDesc& v, const VolumeShape& first, const Grid& step) {
  if (first.dims == step.dims() && first.type == step.type()) return;
  const int k = currentTimeStep(v);
  throw InputError(scene.path, v.time.where, "time step " + std::to_string(k) + " (" + stepName(v, k) + ") is " +
                                                 shapeText(step.dims(), step.type()) + ", step 0 " +
                                                 shapeText(first.dims, first.type) + ": the steps of a series must agree");
}

}  // namespace iso
