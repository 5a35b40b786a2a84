#pragma once
// Volume file loaders: raw (layout given, or read from an Open SciVis file name), gzip raw,
// NRRD (attached/detached headers, raw/gzip/ascii encodings, multi-file `data file:`),
// MetaImage (.mhd/.mha), legacy VTK STRUCTURED_POINTS, NIfTI-1/2 (.nii, .nii.gz, .hdr/.img) and
// DICOM (a folder of slices or a multi-frame file).
// Every failure is an InputError naming the file and, where there is one, the header line.
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "volume/bricks.h"
#include "volume/child_process.h"
#include "volume/grid.h"
#include "volume/transform.h"

namespace iso {

// What a headerless raw file needs to be read; a header's own fields win over nothing here.
struct RawLayout {
  std::optional<Vec3i> dims;
  std::optional<ScalarType> type;
  bool bigEndian = false;
};

// A volume as its file holds it: the samples (with the file's origin and spacing, if it has
// them), where the file puts them, and what `isotrace info` tells about it.
struct VolumeFile {
  Grid grid;
  // Grid space (after the grid's origin and spacing) to the file's world, where the file's axes
  // are rotated, mirrored or sheared against the world's (a NIfTI affine): identity otherwise.
  Transform toWorld;
  std::string format;               // "raw", "NRRD", "MetaImage", "VTK", "NIfTI-1", "NIfTI-2"
  std::vector<std::string> notes;   // e.g. the affine and where it came from, frames skipped
};

// The format is chosen by the file name's extension; an unknown one is an error that lists the
// supported ones (never a silent guess of raw).
// Which volume of a file that holds several: a DICOM folder's series, a VDB file's grid (empty:
// the only series; the first float or double grid).
struct VolumePart {
  std::string series;  // SeriesInstanceUID
  std::string grid;    // VDB grid name
  int time = 0;        // the time point of a file with a time axis (a 4D NIfTI's dim[4]), from 0
};
// The samples a reader keeps of a volume split over ranks (Grid's window constructor):
// [first, first + extent) on each axis, at least 2 samples on each.
struct SampleWindow {
  Vec3i first, extent;
};
// `window` (a data-parallel rank's part): only those samples are kept. Where the samples lie in
// the files as runs of bytes — raw files (plain or gzip), NRRD with raw or gzip encoding (attached,
// a data file, or one file per slab of slices; no line skip), MetaImage (plain, or compressed with a
// known HeaderSize) — only the window's are read: a plain file's rows of the window by their byte
// ranges, a compressed stream inflated whole keeping only the window's rows, a file holding none of
// the window's rows not opened. Binary legacy VTK and NIfTI (its header through libnifti in a child
// process; samples of types the grid does not hold, or scaled, converted to float32 as they are
// read) too. Other formats and layouts are read whole and the window cut from
// them. A window not within the volume is an InputError naming the file; OpenVDB volumes have no
// window yet.
VolumeFile readVolumeFile(const std::string& path, const RawLayout& layout = {}, const VolumePart& part = {},
                          const SampleWindow* window = nullptr);
void checkWindow(const SampleWindow& window, const Vec3i& dims, const std::string& file);
// The brick ranges (BrickGrid) of a file's volume, keeping none of the samples: the files read (or
// inflated) in order, a layer at a time. What a data-parallel rank needs to split the volume
// before it reads its window. For the files whose window readVolumeFile reads alone (above);
// nullopt for any other (a pipe, another format or layout).
std::optional<BrickGrid> fileBrickRanges(const std::string& path, const RawLayout& layout = {}, const VolumePart& part = {});
// Where a file puts its samples (the origin, spacing and affine VolumeFile has after loading), from
// its header alone: for the files whose samples lie in runs of bytes (raw, NRRD, MetaImage, binary
// VTK, NIfTI); nullopt for any other (DICOM, OpenVDB, ASCII data, a pipe).
struct FilePlacement {
  Vec3d origin, spacing;
  Transform toWorld;
};
std::optional<FilePlacement> filePlacement(const std::string& path, const RawLayout& layout = {}, const VolumePart& part = {});
// The grid alone (tests, benchmarks): a file's placement other than origin and spacing is dropped.
inline Grid loadVolumeFile(const std::string& path, const RawLayout& layout = {}) {
  return readVolumeFile(path, layout).grid;
}
// A volume file's dims and sample type from its header alone, for files whose samples lie in runs
// (raw, NRRD but ASCII, MetaImage, binary VTK, NIfTI); nullopt for others (DICOM, OpenVDB, ...).
struct VolumeShape {
  Vec3i dims;
  ScalarType type = ScalarType::UInt8;
};
std::optional<VolumeShape> volumeFileShape(const std::string& path, const RawLayout& layout = {}, const VolumePart& part = {});
// The same for many files (a time series' steps): the NIfTI headers among them read in one child
// process (one fork, not one each; if that child dies, each is read alone, to name the culprit).
// The first error, in the files' order, is thrown.
std::vector<std::optional<VolumeShape>> volumeFileShapes(const std::vector<std::string>& paths, const RawLayout& layout = {},
                                                         const VolumePart& part = {});
// The time points of a volume file: a NIfTI's dim[4] (its header read in a child process; 0 when
// it has no time axis), 0 for any other file. Errors as readVolumeFile's.
int volumeTimePoints(const std::string& path);
// The extensions readVolumeFile knows, for messages.
const char* volumeExtensions();

// DICOM (volume/dicom.cpp, GDCM): a folder is one series of single-frame slices (`series`
// chooses when it holds several), a file one multi-frame volume. With `window`, only those
// samples come back: of a series only the slab's files are decoded (and the first slice's, which
// places the volume); of a multi-frame file only the window's box (GDCM's region reader), in
// the reader's child process; its brick ranges a frame at a time.
VolumeFile loadDicom(const std::string& path, const std::string& series = "", const SampleWindow* window = nullptr);
// A DICOM volume's brick ranges, its slices decoded one at a time (in a child process).
BrickGrid dicomBrickRanges(const std::string& path, const std::string& series = "");
// OpenVDB (volume/vdb.cpp): one float or double grid (`grid`: its name) over its active
// bounding box plus one voxel, placed by the grid's transform; sparse (Grid::sparse()), or a
// dense copy when `dense` (tests compare the two). With `window`, only the bricks whose blocks
// reach into it keep their samples, and only their leaves are read (the grid read clipped to
// them, in the reader's child process, laid out by the whole grid's bounding-box metadata; a file
// without that metadata is read whole).
VolumeFile loadVdb(const std::string& path, const std::string& grid = "", bool dense = false,
                   const SampleWindow* window = nullptr);
// The sparse grid's brick ranges: rows of bricks along z, each run of rows in a child process
// that reads only their leaves (at most about `samplesPerChild` samples' worth of rows; at least
// one row), so that no process holds the whole grid (a file without bounding-box metadata: read
// whole, in one child).
BrickGrid vdbBrickRanges(const std::string& path, const std::string& grid = "", int64_t samplesPerChild = int64_t(1) << 24);

// Splits an index-to-world affine (3x4: voxel (i, j, k, 1) -> world) into the grid's spacing
// (the columns' lengths), its origin (when the axes are the world's) and what is left as
// `toWorld` (rotation, mirroring, shear). Throws InputError (file, where) for a degenerate one.
void placeByAffine(const double a[3][4], Grid& grid, Transform& toWorld, const std::string& file,
                   const std::string& where);

// "voxel (i, j, k) at [...] (i, j, k, 1)": an affine for `isotrace info`.
std::string describeAffine(const double a[3][4]);

// Parses `name_256x256x128_uint8.raw[.gz]`; false if the name does not follow the convention.
bool parseSciVisName(const std::string& path, Vec3i& dims, ScalarType& type);

}  // namespace iso
