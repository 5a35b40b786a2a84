#include "volume/loaders.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <regex>

#include "volume/formats.h"
#include "volume/input_error.h"
#include "volume/input_file.h"

namespace iso {

namespace fs = std::filesystem;

namespace reading {

// A DICOM folder, or a file named .dcm or .dicom.
bool isDicomPath(const std::string& path) {
  std::error_code ec;
  const std::string name = lower(fs::path(path).filename().string());
  return fs::is_directory(path, ec) || endsWith(name, ".dcm") || endsWith(name, ".dicom");
}

bool isNiftiName(const std::string& name) {
  return endsWith(name, ".nii") || endsWith(name, ".nii.gz") || endsWith(name, ".hdr") || endsWith(name, ".hdr.gz");
}

// Whether a (lower-case) file name is a raw volume's: .raw, .bin, .dat, plain or .gz.
bool isRawName(const std::string& name) {
  for (const char* ext : {".raw", ".bin", ".dat"})
    if (endsWith(name, ext) || endsWith(name, std::string(ext) + ".gz")) return true;
  return false;
}

}  // namespace reading

using namespace reading;

std::string describeAffine(const double a[3][4]) {
  char text[300];
  std::snprintf(text, sizeof text, "voxel (i, j, k) at [%g %g %g %g; %g %g %g %g; %g %g %g %g] (i, j, k, 1)", a[0][0],
                a[0][1], a[0][2], a[0][3], a[1][0], a[1][1], a[1][2], a[1][3], a[2][0], a[2][1], a[2][2], a[2][3]);
  return text;
}

void placeByAffine(const double a[3][4], Grid& grid, Transform& toWorld, const std::string& file,
                   const std::string& where) {
  Vec3d spacing;
  bool aligned = true;
  for (int c = 0; c < 3; ++c) {
    spacing[c] = std::sqrt(a[0][c] * a[0][c] + a[1][c] * a[1][c] + a[2][c] * a[2][c]);
    if (!(spacing[c] > 0) || !std::isfinite(spacing[c]))
      throw InputError(file, where, "the affine's column " + std::to_string(c) + " is zero or not finite");
  }
  // Off-diagonal terms below 1e-9 of the voxel size are rounding (a quaternion of a rotation by
  // 0 or 180 degrees gives 1e-17s): such an affine is aligned, and needs no Embree instance.
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r)
      aligned = aligned && (r == c ? a[r][c] > 0 : std::fabs(a[r][c]) <= 1e-9 * spacing[c]);
  for (int r = 0; r < 3; ++r)
    if (!std::isfinite(a[r][3]) || std::fabs(a[r][3]) > 1e15)
      throw InputError(file, where, "the affine's offset is not finite or beyond 1e15");
  grid.setSpacing(spacing);
  const Vec3d offset{a[0][3], a[1][3], a[2][3]};
  if (aligned) {
    grid.setOrigin(offset);
    return;
  }
  double rows[12];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) rows[r * 4 + c] = a[r][c] / spacing[c];
    rows[r * 4 + 3] = a[r][3];
  }
  toWorld = Transform::fromRows(rows);
  if (!(std::fabs(toWorld.determinant()) > 1e-9))
    throw InputError(file, where, "the affine is singular (its axes are not independent)");
}

bool parseSciVisName(const std::string& path, Vec3i& dims, ScalarType& type) {
  static const std::regex pattern(R"(_(\d+)x(\d+)x(\d+)_([a-z0-9]+)\.raw(\.gz)?$)");
  std::smatch m;
  const std::string name = fs::path(path).filename().string();
  if (!std::regex_search(name, m, pattern)) return false;
  if (!parseScalarType(m[4].str(), type)) return false;
  try {
    dims = {std::stoi(m[1].str()), std::stoi(m[2].str()), std::stoi(m[3].str())};
  } catch (const std::exception&) {
    return false;
  }
  return true;
}

const char* volumeExtensions() {
  return ".raw, .bin, .dat (each also .gz), .nrrd, .nhdr, .mhd, .mha, .vtk, .nii, .nii.gz, .hdr, .dcm, .dicom, "
         ".vdb, or a folder of DICOM slices";
}

std::optional<VolumeShape> volumeFileShape(const std::string& path, const RawLayout& layout, const VolumePart& part) {
  const std::string name = lower(fs::path(path).filename().string());
  if (isDicomPath(path) || endsWith(name, ".vdb")) return std::nullopt;
  const std::optional<SampleRuns> runs = sampleRunsOf(path, layout, part.time);
  if (!runs) return std::nullopt;
  return VolumeShape{runs->dims, runs->type};
}

std::vector<std::optional<VolumeShape>> volumeFileShapes(const std::vector<std::string>& paths, const RawLayout& layout,
                                                         const VolumePart& part) {
  std::vector<std::optional<VolumeShape>> shapes(paths.size());
  std::vector<size_t> nifti;
  for (size_t k = 0; k < paths.size(); ++k)
    if (isNiftiName(lower(fs::path(paths[k]).filename().string()))) nifti.push_back(k);
  // The NIfTI headers, in one child: per file a length, then its packed layout ('L') or its
  // error's message ('E').
  std::string report;
  if (nifti.size() > 1) {
    try {
      report = runInChildProcess(paths[nifti[0]], "libnifti", [&](int) {
                 std::string all;
                 for (size_t k : nifti) {
                   std::string one;
                   try {
                     checkInputFile(paths[k], "file", false);
                     one = "L" + packNiftiLayout(readNiftiLayout(paths[k]));
                   } catch (const InputError& e) {
                     one = std::string("E") + e.what();
                   }
                   const uint64_t n = one.size();
                   all.append(reinterpret_cast<const char*>(&n), sizeof n);
                   all += one;
                 }
                 return all;
               }).report;
    } catch (const InputError&) {
      report.clear();  // the child died: each file alone below names the one that kills it
    }
  }
  size_t at = 0;
  for (size_t k = 0; k < paths.size(); ++k) {
    const bool batched = !report.empty() && std::find(nifti.begin(), nifti.end(), k) != nifti.end();
    if (!batched) {
      shapes[k] = volumeFileShape(paths[k], layout, part);
      continue;
    }
    uint64_t n = 0;
    if (report.size() - at < sizeof n) throw InputError(paths[k], "", "libnifti's reader gave back a malformed header");
    std::memcpy(&n, report.data() + at, sizeof n);
    at += sizeof n;
    if (n == 0 || report.size() - at < n) throw InputError(paths[k], "", "libnifti's reader gave back a malformed header");
    const std::string one = report.substr(at, n);
    at += n;
    if (one[0] == 'E') throw InputError(one.substr(1));
    NiftiLayout l = unpackNiftiLayout(one.substr(1), paths[k]);
    timePointOffset(l, part.time, paths[k]);  // (a time point past the file's is an error)
    shapes[k] = VolumeShape{l.dims, l.native};
  }
  return shapes;
}

int volumeTimePoints(const std::string& path) {
  if (!isNiftiName(lower(fs::path(path).filename().string()))) return 0;
  return niftiLayoutInChild(path).timePoints;
}

std::optional<BrickGrid> fileBrickRanges(const std::string& path, const RawLayout& layout, const VolumePart& part) {
  if (isDicomPath(path)) return dicomBrickRanges(path, part.series);
  if (endsWith(lower(fs::path(path).filename().string()), ".vdb")) return vdbBrickRanges(path, part.grid);
  const std::optional<SampleRuns> runs = sampleRunsOf(path, layout, part.time);
  if (!runs) return std::nullopt;
  return runsBrickRanges(*runs);
}

std::optional<FilePlacement> filePlacement(const std::string& path, const RawLayout& layout, const VolumePart& part) {
  const std::optional<SampleRuns> runs = sampleRunsOf(path, layout, part.time);
  if (!runs) return std::nullopt;
  return FilePlacement{runs->origin, runs->spacing, runs->toWorld};
}

void checkWindow(const SampleWindow& w, const Vec3i& dims, const std::string& file) {
  for (int a = 0; a < 3; ++a)
    if (w.first[a] < 0 || w.extent[a] < 2 || w.first[a] > dims[a] - w.extent[a])
      throw InputError(file, "", "the window of samples [" + std::to_string(w.first.x) + ", " + std::to_string(w.first.y) +
                                     ", " + std::to_string(w.first.z) + "] + [" + std::to_string(w.extent.x) + ", " +
                                     std::to_string(w.extent.y) + ", " + std::to_string(w.extent.z) +
                                     "] is not within the volume's " + std::to_string(dims.x) + "x" +
                                     std::to_string(dims.y) + "x" + std::to_string(dims.z));
}

VolumeFile readVolumeFile(const std::string& path, const RawLayout& layout, const VolumePart& part,
                          const SampleWindow* window) {
  const std::string name = lower(fs::path(path).filename().string());
  std::error_code ec;
  const bool folder = fs::is_directory(path, ec);
  if (!part.series.empty() && !folder && !endsWith(name, ".dcm") && !endsWith(name, ".dicom"))
    throw InputError(path, "", "\"series\" applies to DICOM only (a folder or a .dcm file)");
  if (!part.grid.empty() && !endsWith(name, ".vdb")) throw InputError(path, "", "\"grid\" applies to .vdb files only");
  if (part.time != 0 && !isNiftiName(name))
    throw InputError(path, "", "has no time axis (time point " + std::to_string(part.time) + " asked for; a 4D NIfTI has one)");
  if (window && (folder || isDicomPath(path))) return loadDicom(path, part.series, window);
  if (window && endsWith(name, ".vdb")) return loadVdb(path, part.grid, false, window);
  if (window) {
    if (const std::optional<SampleRuns> runs = sampleRunsOf(path, layout, part.time)) {
      checkWindow(*window, runs->dims, path);
      VolumeFile f;
      f.grid = readRunsWindow(*runs, *window, path);
      f.toWorld = runs->toWorld;
      f.format = runs->format;
      f.notes = runs->notes;
      return f;
    }
    // Data not in runs (other formats, ASCII, a pipe...): read whole, keep the window.
    VolumeFile f = readVolumeFile(path, layout, part, nullptr);
    checkWindow(*window, f.grid.dims(), path);
    f.grid = windowOf(f.grid, window->first, window->extent);  // (origin and spacing kept)
    return f;
  }
  if (folder) return loadDicom(path, part.series);  // a folder is a DICOM series
  auto wrap = [](Grid grid, const char* format) {
    VolumeFile f;
    f.grid = std::move(grid);
    f.format = format;
    return f;
  };
  if (endsWith(name, ".nrrd") || endsWith(name, ".nhdr")) return wrap(loadNrrd(path), "NRRD");
  if (endsWith(name, ".mhd") || endsWith(name, ".mha")) return wrap(loadMetaImage(path), "MetaImage");
  if (endsWith(name, ".vtk")) return wrap(loadVtk(path), "VTK");
  if (isNiftiName(name))
    // libnifti overflows a stack buffer on some malformed headers: it reads in a child process.
    return readInChildProcess(path, "libnifti", [&] { return loadNifti(path, part.time); });
  if (isRawName(name)) return wrap(loadRaw(path, layout), "raw");
  if (endsWith(name, ".dcm") || endsWith(name, ".dicom")) return loadDicom(path, part.series);
  if (endsWith(name, ".vdb")) return loadVdb(path, part.grid);
  const std::string ext = fs::path(name).extension().string();
  throw InputError(path, "", (ext.empty() ? std::string("no file extension") : "unknown volume extension '" + ext + "'") +
                                 " (supported: " + volumeExtensions() + ")");
}

}  // namespace iso
