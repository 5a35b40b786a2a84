#pragma once
// The volume file formats, one file each (volume/nrrd.cpp, metaimage.cpp, vtk_legacy.cpp,
// nifti.cpp, raw.cpp; DICOM and OpenVDB in dicom.cpp and vdb.cpp), and where their samples lie
// as runs of bytes (sample_runs.cpp), for readVolumeFile (volume/loaders.cpp). Internal to
// volume/: the API is volume/loaders.h. A header reader reads the layout only; given a file's
// first part (`whole` false) it returns nullopt when the header does not end in it.
#include <optional>
#include <string>
#include <vector>

#include "volume/loaders.h"
#include "volume/reader_common.h"

namespace iso::reading {

// File names: a DICOM folder, or a file named .dcm or .dicom; NIfTI (.nii, .hdr, gzip too); a raw
// volume's (lower case): .raw, .bin, .dat, plain or .gz.
bool isDicomPath(const std::string& path);
bool isNiftiName(const std::string& name);
bool isRawName(const std::string& name);

// NRRD (http://teem.sourceforge.net/nrrd/format.html): attached or detached headers, raw, gzip
// and ascii encodings, one data file per slab of slices.
// A NRRD header: the samples' layout and where they are; the data is not read. `bytes`: the whole
// file, or its first part (`whole` false): then nullopt if the header does not end in it.
struct NrrdHeader {
  Vec3i dims;
  ScalarType type = ScalarType::UInt8;
  enum class Enc { Raw, Gzip, Ascii } enc = Enc::Raw;
  bool bigEndian = false;
  Vec3d spacing{1, 1, 1}, origin{0, 0, 0};
  long lineSkip = 0, byteSkip = 0;  // byte skip -1: the data is at the end (raw encoding only)
  size_t dataStart = 0;             // attached data: its first byte in the file
  std::vector<std::string> files;   // the data files (paths); none: the data is attached
};
std::optional<NrrdHeader> readNrrdHeader(const std::string& path, const Bytes& bytes, bool whole);
Grid loadNrrd(const std::string& path);

// MetaImage (.mhd/.mha).
// A MetaImage header: the samples' layout and where they are; the data is not read. `bytes`: the
// whole file, or its first part (`whole` false): then nullopt if the header does not end in it.
struct MetaHeader {
  Vec3i dims;
  ScalarType type = ScalarType::UInt8;
  Vec3d spacing{1, 1, 1}, origin{0, 0, 0};
  bool bigEndian = false, compressed = false;
  std::string dataFile;  // the file holding the data (the header's own for LOCAL)
  size_t dataStart = 0;  // where the data begins in it (LOCAL: after the header)
  long skip = 0;         // HeaderSize: bytes before the samples (-1: the samples are the last bytes)
  std::string skipWhere;
};
std::optional<MetaHeader> readMetaHeader(const std::string& path, const Bytes& bytes, bool whole);
Grid loadMetaImage(const std::string& path);

// Legacy VTK STRUCTURED_POINTS.
// A legacy VTK header: the samples' layout and where they begin (`dataStart`); the data is not
// read. `bytes`: the whole file, or its first part (`whole` false): then nullopt if the header
// does not end in it.
struct VtkHeader {
  Vec3i dims{0, 0, 0};
  ScalarType type = ScalarType::UInt8;
  Vec3d spacing{1, 1, 1}, origin{0, 0, 0};
  bool binary = false;  // BINARY: big-endian samples; else ASCII
  size_t dataStart = 0;
};
std::optional<VtkHeader> readVtkHeader(const std::string& path, const Bytes& bytes, bool whole);
Grid loadVtk(const std::string& path);

// NIfTI-1 and NIfTI-2 (and ANALYZE 7.5) through libnifti2.
// What a NIfTI header says of its samples and where they lie (libnifti reads it: in a child
// process, as it overflows a stack buffer on some malformed headers).
struct NiftiLayout {
  Vec3i dims;
  int datatype = 0;
  size_t sampleSize = 0;  // bytes of one sample in the file
  ScalarType native = ScalarType::Float32;  // the grid's type
  bool direct = true;     // the file's samples are the grid's, no conversion
  double slope = 1, inter = 0;  // applied where not direct
  size_t offset = 0;      // of the samples in the image file (in its inflated stream when gzip)
  int timePoints = 0;     // dim[4] (0: no time axis): 3D frames one after the other from `offset`
  bool gzip = false, swap = false;
  double affine[3][4] = {};
  std::string image, where, format;
  std::vector<std::string> notes;
};
// libnifti reads the header (call it in a child process); the layout crosses back packed.
NiftiLayout readNiftiLayout(const std::string& path);
std::string packNiftiLayout(const NiftiLayout& l);
NiftiLayout unpackNiftiLayout(const std::string& s, const std::string& path);
// readNiftiLayout in a child process, its layout unpacked here.
NiftiLayout niftiLayoutInChild(const std::string& path);
// The file's samples of a type the grid does not hold (or scaled) to float32.
ToFloat niftiToFloat(int datatype);
// Where time point `time` (from 0) of the file's dim[4] begins (an error beyond them), noted in `l`.
size_t timePointOffset(NiftiLayout& l, int time, const std::string& path);
VolumeFile loadNifti(const std::string& path, int time);

// Raw (headerless) files: the layout given, or read from an Open SciVis name.
// A raw file's dims and type: its layout's, else its Open SciVis name's; checked.
void rawLayoutOf(const std::string& path, const RawLayout& layout, Vec3i& dims, ScalarType& type);
// Opens a raw file of `dims` samples of `type`: whether it is gzip (its first two bytes), and
// checked against that size (a plain file exactly, a gzip one for a plausible ratio).
std::ifstream openRawFile(const std::string& path, const Vec3i& dims, ScalarType type, bool& gzip);
Grid loadRaw(const std::string& path, const RawLayout& layout);

// Where a file format keeps a volume's samples, x fastest, as one stretch of bytes or several
// (a NRRD's one file per slab of slices) that follow each other in the volume, each in a file,
// plain or a gzip/zlib stream: what a data-parallel rank reads its window and the bricks' ranges
// from without ever holding the rest. Raw files; NRRD with raw or gzip encoding and no line skip
// (attached data, a data file, or a list or pattern of them); MetaImage but a compressed stream
// whose samples are its last bytes; binary legacy VTK; NIfTI (plain or gzip; frame 0), whose
// samples of a type the grid does not hold, or scaled, are converted to float32 as they are read.
struct SampleRuns {
  struct Run {
    std::string file;
    size_t start = 0;        // the byte of the file where the run (or its compressed stream) begins
    size_t skip = 0;         // compressed: the stream's bytes before the samples
    bool compressed = false;
    bool atEnd = false;      // plain: the samples are the file's last bytes (start is then a least)
    bool moreAfter = false;  // the file (or stream) may hold more bytes after the samples
  };
  std::vector<Run> runs;
  size_t runBytes = 0;  // of samples, in each run
  Vec3i dims;
  ScalarType type = ScalarType::UInt8;  // the grid's
  size_t sampleSize = 0;                // bytes of a sample in the files (0: the grid type's)
  bool bigEndian = false;               // the files' samples are in the other byte order
  ToFloat convert = nullptr;            // the files' samples to the grid's float32 (null: as they are)
  double slope = 1, inter = 0;          // of `convert`
  Vec3d origin{0, 0, 0}, spacing{1, 1, 1};
  Transform toWorld;
  std::string format = "raw";
  std::vector<std::string> notes;
  size_t fileSampleSize() const { return sampleSize ? sampleSize : scalarTypeSize(type); }
};
// The runs of a volume file's samples, or nullopt: another format, a named pipe, or data that is
// not in runs (ASCII, line skips, a compressed MetaImage stream of unknown skip, a header longer
// than 1 MiB). Only the header is read.
std::optional<SampleRuns> sampleRunsOf(const std::string& path, const RawLayout& layout, int time = 0);
// The window's samples of `s`, read without the rest: a plain run's rows of the window by their
// byte ranges, a compressed run inflated whole but only the window's rows kept; a run holding no
// row of the window is not opened. Errors about the samples name `file`.
Grid readRunsWindow(const SampleRuns& s, const SampleWindow& w, const std::string& file);
// The bricks' ranges of `s`, keeping none of the samples: the runs read (or inflated) in order, a
// layer at a time.
BrickGrid runsBrickRanges(const SampleRuns& s);

}  // namespace iso::reading
