// DICOM through GDCM (libgdcm-dev): a folder holding one series of single-frame slices, or one
// multi-frame file. GDCM because it decodes the compressed transfer syntaxes (JPEG, JPEG-LS,
// JPEG 2000, RLE) with what Debian ships with it, gives the image's geometry (origin,
// direction cosines, spacing, rescale) for single and multi-frame files alike, and scans a
// folder's tags without reading pixel data; DCMTK needs separate codec set-up for each of those.
// The only file that sees GDCM.
#include <gdcmDirectory.h>
#include <gdcmBoxRegion.h>
#include <gdcmImageReader.h>
#include <gdcmImageRegionReader.h>
#include <gdcmScanner.h>
#include <gdcmTrace.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <sstream>

#include "volume/input_error.h"
#include "volume/input_file.h"
#include "volume/loaders.h"

namespace iso {
namespace {

namespace fs = std::filesystem;

const gdcm::Tag kSeriesUid(0x0020, 0x000e), kPosition(0x0020, 0x0032), kOrientation(0x0020, 0x0037),
    kModality(0x0008, 0x0060), kRows(0x0028, 0x0010), kColumns(0x0028, 0x0011);

// "a\b\c" -> numbers; false unless exactly `n` finite numbers.
bool parseNumbers(const char* text, size_t n, double* out) {
  if (!text) return false;
  std::string s(text);
  std::replace(s.begin(), s.end(), '\\', ' ');
  std::istringstream in(s);
  size_t k = 0;
  double v;
  while (k < n && in >> v) out[k++] = v;
  if (k != n) return false;
  for (size_t i = 0; i < n; ++i)
    if (!std::isfinite(out[i])) return false;
  return true;
}

std::string trimmed(const char* text) {
  std::string s = text ? text : "";
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
  return s;
}

Vec3d cross3(const double a[3], const double b[3]) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

// Reads one image with GDCM, or says why not (the file and the transfer syntax).
struct Decoded {
  gdcm::ImageReader reader;
  std::vector<char> buffer;
  const gdcm::Image& image() const { return reader.GetImage(); }
};
void decode(const std::string& file, Decoded& d) {
  d.reader.SetFileName(file.c_str());
  if (!d.reader.Read()) throw InputError(file, "", "not a readable DICOM image (or its pixel data is missing)");
  // GDCM reads a file cut short without complaint (the missing bytes come out as whatever the
  // buffer held): the elements it read must fit in the file.
  {
    const gdcm::File& f = d.reader.GetFile();
    const bool deflated = f.GetHeader().GetDataSetTransferSyntax().IsEncoded();  // stored smaller
    const bool explicitVr = f.GetHeader().GetDataSetTransferSyntax().IsExplicit();
    const uint64_t need = uint64_t(explicitVr ? f.GetDataSet().GetLength<gdcm::ExplicitDataElement>()
                                              : f.GetDataSet().GetLength<gdcm::ImplicitDataElement>());
    std::error_code ec;
    const uint64_t have = fs::file_size(file, ec);
    if (!ec && !deflated && have < need)
      throw InputError(file, "", "is " + std::to_string(have) + " bytes, its elements need " + std::to_string(need) +
                                     " (a truncated file)");
  }
  const gdcm::Image& im = d.image();
  const gdcm::PixelFormat& pf = im.GetPixelFormat();
  if (pf.GetSamplesPerPixel() != 1)
    throw InputError(file, "SamplesPerPixel", "colour images are not supported (one sample per pixel)");
  const size_t bytes = im.GetBufferLength();
  const unsigned* dims = im.GetDimensions();
  const size_t frames = im.GetNumberOfDimensions() > 2 ? dims[2] : 1;
  const size_t expected = size_t(dims[0]) * dims[1] * frames * std::max<size_t>(1, pf.GetPixelSize());
  if (bytes == 0 || bytes != expected || bytes > (size_t(1) << 34))
    throw InputError(file, "PixelData", "holds " + std::to_string(bytes) + " bytes, the image's size asks for " +
                                            std::to_string(expected));
  if (!d.reader.GetFile().GetDataSet().FindDataElement(gdcm::Tag(0x7fe0, 0x0010)))
    throw InputError(file, "PixelData", "missing");
  d.buffer.resize(bytes);
  if (!im.GetBuffer(d.buffer.data()))
    throw InputError(file, "PixelData", std::string("cannot decode transfer syntax ") +
                                            gdcm::TransferSyntax::GetTSString(im.GetTransferSyntax()));
}

// Appends decoded samples of `im` (`buffer`), rescaled, to `out` as float32; names the first
// voxel whose value is not finite.
void appendRescaled(const gdcm::Image& im, const std::vector<char>& buffer, const std::string& file, std::vector<float>& out) {
  const double slope = im.GetSlope(), intercept = im.GetIntercept();
  if (!std::isfinite(slope) || !std::isfinite(intercept) || slope == 0)
    throw InputError(file, "RescaleSlope", "rescale slope and intercept must be finite, the slope non-zero");
  const size_t n = buffer.size() / std::max<size_t>(1, im.GetPixelFormat().GetPixelSize());
  const char* p = buffer.data();
  auto put = [&](auto sample) {
    using T = decltype(sample);
    for (size_t i = 0; i < n; ++i) {
      T v;
      std::memcpy(&v, p + i * sizeof(T), sizeof(T));
      const float f = float(double(v) * slope + intercept);
      if (!std::isfinite(f)) throw InputError(file, "sample " + std::to_string(i), "value is not finite after rescaling");
      out.push_back(f);
    }
  };
  switch (im.GetPixelFormat().GetScalarType()) {
    case gdcm::PixelFormat::UINT8: put(uint8_t{}); break;
    case gdcm::PixelFormat::INT8: put(int8_t{}); break;
    case gdcm::PixelFormat::UINT16: put(uint16_t{}); break;
    case gdcm::PixelFormat::INT16: put(int16_t{}); break;
    case gdcm::PixelFormat::UINT32: put(uint32_t{}); break;
    case gdcm::PixelFormat::INT32: put(int32_t{}); break;
    case gdcm::PixelFormat::FLOAT32: put(float{}); break;
    case gdcm::PixelFormat::FLOAT64: put(double{}); break;
    default:
      throw InputError(file, "BitsAllocated", std::string("pixel format ") +
                                                  im.GetPixelFormat().GetScalarTypeAsString() + " is not supported");
  }
}

// The affine of a volume from its first slice's position, the row and column directions, the
// pixel spacing (between columns, between rows) and the slice step along the normal.
void placeDicom(const double position[3], const double orientation[6], double columnSpacing, double rowSpacing,
                const Vec3d& sliceStep, VolumeFile& out, const std::string& file) {
  double a[3][4];
  for (int r = 0; r < 3; ++r) {
    a[r][0] = orientation[r] * columnSpacing;
    a[r][1] = orientation[3 + r] * rowSpacing;
    a[r][2] = sliceStep[r];
    a[r][3] = position[r];
  }
  placeByAffine(a, out.grid, out.toWorld, file, "ImagePositionPatient/ImageOrientationPatient");
  out.notes.push_back("patient space (LPS, mm): " + describeAffine(a));
}

// A multi-frame file's volume placed in patient space, and what its notes say of it.
VolumeFile placeMultiFrame(const gdcm::Image& im, Grid grid, const std::string& file) {
  VolumeFile out;
  out.format = "DICOM";
  out.grid = std::move(grid);
  const double* o = im.GetOrigin();
  const double* dc = im.GetDirectionCosines();
  const double* s = im.GetSpacing();
  const Vec3d normal = cross3(dc, dc + 3);
  placeDicom(o, dc, s[0], s[1], normal * s[2], out, file);
  out.notes.push_back("multi-frame file, " + std::to_string(out.grid.dims().z) + " frames " + std::to_string(s[2]) +
                      " mm apart; values rescaled to float32 (slope " + std::to_string(im.GetSlope()) + ", intercept " +
                      std::to_string(im.GetIntercept()) + ")");
  return out;
}

// A multi-frame file's size, checked: a volume of at least 2 samples on each axis.
Vec3i multiFrameSize(const gdcm::Image& im, const std::string& file) {
  const unsigned* dims = im.GetDimensions();
  if (im.GetNumberOfDimensions() < 3 || dims[2] < 2)
    throw InputError(file, "", "holds a single slice: a volume needs at least 2 (name the folder of its series)");
  if (dims[0] > (1u << 20) || dims[1] > (1u << 20) || dims[2] > (1u << 20))
    throw InputError(file, "Rows/Columns/NumberOfFrames", "more than 2^20 samples on an axis");
  const Vec3i size{int(dims[0]), int(dims[1]), int(dims[2])};
  if (size.x < 2 || size.y < 2) throw InputError(file, "Rows/Columns", "each dimension needs at least 2 samples");
  return size;
}

VolumeFile loadMultiFrame(const std::string& file) {
  Decoded d;
  decode(file, d);
  const Vec3i size = multiFrameSize(d.image(), file);
  std::vector<float> samples;
  samples.reserve(size_t(size.x) * size.y * size.z);
  appendRescaled(d.image(), d.buffer, file, samples);
  return placeMultiFrame(d.image(), Grid(size, std::move(samples)), file);
}

// A multi-frame file read a box of samples at a time (GDCM's ImageRegionReader: the raw, RLE and
// JPEG syntaxes frame by frame), so that a rank's window or the bricks' ranges never decode the
// whole file: the child process that reads holds the box, not the volume.
class FrameRegions {
 public:
  explicit FrameRegions(const std::string& file) : m_file(file) {
    m_reader.SetFileName(file.c_str());
    if (!m_reader.ReadInformation()) throw InputError(file, "", "not a readable DICOM image (or its pixel data is missing)");
    const gdcm::Image& im = image();
    if (im.GetPixelFormat().GetSamplesPerPixel() != 1)
      throw InputError(file, "SamplesPerPixel", "colour images are not supported (one sample per pixel)");
    m_size = multiFrameSize(im, file);
    // GDCM reads a file cut short without complaint: uncompressed samples must fit in the file.
    const size_t pixel = std::max<size_t>(1, im.GetPixelFormat().GetPixelSize());
    const uint64_t need = uint64_t(m_size.x) * uint64_t(m_size.y) * uint64_t(m_size.z) * pixel;
    std::error_code ec;
    const uint64_t have = fs::file_size(file, ec);
    if (!ec && !im.GetTransferSyntax().IsEncapsulated() && have < need)
      throw InputError(file, "PixelData", "the file is " + std::to_string(have) + " bytes, its " + std::to_string(need) +
                                              " bytes of samples cannot be in it (a truncated file)");
  }
  const gdcm::Image& image() const { return m_reader.GetImage(); }
  Vec3i size() const { return m_size; }
  // The samples of the box [first, first + extent), x fastest, rescaled to float32.
  void read(const Vec3i& first, const Vec3i& extent, std::vector<float>& out) {
    gdcm::BoxRegion box;
    box.SetDomain(unsigned(first.x), unsigned(first.x + extent.x - 1), unsigned(first.y), unsigned(first.y + extent.y - 1),
                  unsigned(first.z), unsigned(first.z + extent.z - 1));
    m_reader.SetRegion(box);
    const size_t bytes = m_reader.ComputeBufferLength();
    const size_t pixel = std::max<size_t>(1, image().GetPixelFormat().GetPixelSize());
    if (bytes != size_t(extent.x) * size_t(extent.y) * size_t(extent.z) * pixel)
      throw InputError(m_file, "PixelData", "GDCM cannot read a box of it (" +
                                                std::string(gdcm::TransferSyntax::GetTSString(image().GetTransferSyntax())) + ")");
    m_buffer.resize(bytes);
    if (!m_reader.ReadIntoBuffer(m_buffer.data(), bytes))
      throw InputError(m_file, "PixelData", std::string("cannot decode frames ") + std::to_string(first.z) + " to " +
                                                std::to_string(first.z + extent.z - 1) + " (transfer syntax " +
                                                gdcm::TransferSyntax::GetTSString(image().GetTransferSyntax()) + ")");
    out.clear();
    appendRescaled(image(), m_buffer, m_file, out);
  }

 private:
  std::string m_file;
  gdcm::ImageRegionReader m_reader;
  Vec3i m_size;
  std::vector<char> m_buffer;
};

// A multi-frame file, or only `window` of it (only the window's box decoded).
VolumeFile multiFrameWindow(const std::string& file, const SampleWindow* window) {
  if (!window) return loadMultiFrame(file);
  FrameRegions regions(file);
  checkWindow(*window, regions.size(), file);
  auto samples = std::make_shared<std::vector<float>>();
  regions.read(window->first, window->extent, *samples);
  Grid grid(regions.size(), ScalarType::Float32, std::shared_ptr<const void>(samples, samples->data()), window->first,
            window->extent);
  return placeMultiFrame(regions.image(), std::move(grid), file);
}

// A multi-frame file's brick ranges, a frame at a time.
BrickGrid multiFrameBrickRanges(const std::string& file) {
  FrameRegions regions(file);
  const Vec3i n = regions.size();
  std::vector<float> frame;
  return BrickGrid::fromStream(n, [&](auto&& layerDone) {
    for (int z = 0; z < n.z; ++z) {
      regions.read({0, 0, z}, {n.x, n.y, 1}, frame);
      layerDone(z, frame.data());
    }
  });
}

// A folder's series: its slices ordered along their normal, evenly spaced (checked), and the
// geometry they share; or, when the series is one file, that file (`multiFrame`).
struct Series {
  struct Slice {
    std::string file;
    double position[3];
    double along;
  };
  std::vector<Slice> slices;
  std::string multiFrame;
  double orientation[6];
  Vec3d normal;
  double step = 0;
  std::string uid, modality;
};

Series scanSeries(const std::string& folder, const std::string& wanted) {
  gdcm::Directory directory;
  directory.Load(folder, false);
  std::vector<std::string> files = directory.GetFilenames();
  std::sort(files.begin(), files.end());
  for (const std::string& f : files) checkInputFile(f, "DICOM file", false);  // a pipe or device: refused by name
  gdcm::Scanner scanner;
  for (const gdcm::Tag& t : {kSeriesUid, kPosition, kOrientation, kModality, kRows, kColumns}) scanner.AddTag(t);
  if (!files.empty() && !scanner.Scan(files)) throw InputError(folder, "", "cannot scan the folder's files");
  std::map<std::string, std::vector<std::string>> series;
  for (const std::string& f : files)
    if (scanner.IsKey(f.c_str())) series[trimmed(scanner.GetValue(f.c_str(), kSeriesUid))].push_back(f);
  if (series.empty()) throw InputError(folder, "", "holds no DICOM files (the folder is read, not its subfolders)");
  auto list = [&] {
    std::string s;
    for (const auto& [uid, members] : series)
      s += (s.empty() ? "" : ", ") + (uid.empty() ? std::string("(no UID)") : uid) + " (" + std::to_string(members.size()) + " files)";
    return s;
  };
  if (wanted.empty() && series.size() > 1)
    throw InputError(folder, "", "holds " + std::to_string(series.size()) + " series; choose one with \"series\": " + list());
  if (!wanted.empty() && !series.count(wanted))
    throw InputError(folder, "", "no series '" + wanted + "'; the folder holds " + list());
  Series out;
  out.uid = wanted.empty() ? series.begin()->first : wanted;
  const std::vector<std::string>& members = series[out.uid];
  if (members.size() == 1) {
    out.multiFrame = members[0];
    return out;
  }

  // Geometry of every slice: one orientation and size for all, ordered by the position along
  // the slice normal (never by file name or InstanceNumber).
  double* orientation = out.orientation;
  if (!parseNumbers(scanner.GetValue(members[0].c_str(), kOrientation), 6, orientation))
    throw InputError(members[0], "ImageOrientationPatient", "missing or not 6 numbers");
  const Vec3d normal = out.normal = cross3(orientation, orientation + 3);
  if (!(length(normal) > 0.99 && length(normal) < 1.01))
    throw InputError(members[0], "ImageOrientationPatient", "row and column directions are not unit and orthogonal");
  const std::string rows = trimmed(scanner.GetValue(members[0].c_str(), kRows));
  const std::string columns = trimmed(scanner.GetValue(members[0].c_str(), kColumns));
  std::vector<Series::Slice>& slices = out.slices;
  for (const std::string& f : members) {
    Series::Slice s{f, {}, 0};
    double o[6];
    if (!parseNumbers(scanner.GetValue(f.c_str(), kPosition), 3, s.position))
      throw InputError(f, "ImagePositionPatient", "missing or not 3 numbers");
    if (!parseNumbers(scanner.GetValue(f.c_str(), kOrientation), 6, o))
      throw InputError(f, "ImageOrientationPatient", "missing or not 6 numbers");
    for (int i = 0; i < 6; ++i)
      if (std::fabs(o[i] - orientation[i]) > 1e-4)
        throw InputError(f, "ImageOrientationPatient", "differs from the series' first slice (" + members[0] + ")");
    if (trimmed(scanner.GetValue(f.c_str(), kRows)) != rows || trimmed(scanner.GetValue(f.c_str(), kColumns)) != columns)
      throw InputError(f, "Rows/Columns", "differ from the series' first slice (" + members[0] + ")");
    s.along = s.position[0] * normal.x + s.position[1] * normal.y + s.position[2] * normal.z;
    slices.push_back(s);
  }
  std::sort(slices.begin(), slices.end(), [](const Series::Slice& a, const Series::Slice& b) { return a.along < b.along; });
  std::vector<double> gaps;
  for (size_t i = 0; i + 1 < slices.size(); ++i) {
    gaps.push_back(slices[i + 1].along - slices[i].along);
    if (gaps.back() <= 1e-3)
      throw InputError(folder, "", "slices " + slices[i].file + " and " + slices[i + 1].file + " lie at the same position");
  }
  // The step is the median gap; every gap must be it within 1% (and a micrometre): a missing
  // slice or a series of two interleaved stacks is an error naming where, never a stretched grid.
  std::vector<double> sorted = gaps;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  out.step = sorted[sorted.size() / 2];
  for (size_t i = 0; i < gaps.size(); ++i)
    if (std::fabs(gaps[i] - out.step) > 0.01 * out.step + 1e-3) {
      char text[160];
      std::snprintf(text, sizeof text, "uneven slice gaps: %.4g mm between ", gaps[i]);
      char tail[80];
      std::snprintf(tail, sizeof tail, ", where the others are %.4g mm", out.step);
      throw InputError(folder, "", text + slices[i].file + " and " + slices[i + 1].file + tail);
    }
  out.modality = trimmed(scanner.GetValue(slices[0].file.c_str(), kModality));
  return out;
}

// What the series' first slice tells of all: the volume's size, pixel spacing, transfer syntax.
struct SeriesPixels {
  Vec3i size;
  double spacing[2] = {1, 1};
  std::string syntax;
};

// Slice k of the series decoded and rescaled (Hounsfield units for CT) into `samples`, replacing
// what they held. Slice 0 must come first: it sets `p`, which every later slice must match.
void decodeSlice(const Series& series, size_t k, SeriesPixels& p, std::vector<float>& samples) {
  const std::string& file = series.slices[k].file;
  Decoded d;
  decode(file, d);
  const unsigned* dims = d.image().GetDimensions();
  if (d.image().GetNumberOfDimensions() > 2 && dims[2] > 1)
    throw InputError(file, "NumberOfFrames", "a multi-frame file inside a series of slices");
  if (k == 0) {
    p.size = {int(dims[0]), int(dims[1]), int(series.slices.size())};
    if (p.size.x < 2 || p.size.y < 2) throw InputError(file, "Rows/Columns", "each dimension needs at least 2 samples");
    p.spacing[0] = d.image().GetSpacing()[0];
    p.spacing[1] = d.image().GetSpacing()[1];
    p.syntax = gdcm::TransferSyntax::GetTSString(d.image().GetTransferSyntax());
  } else if (int(dims[0]) != p.size.x || int(dims[1]) != p.size.y) {
    throw InputError(file, "Rows/Columns", "differ from the series' first slice");
  }
  samples.clear();
  appendRescaled(d.image(), d.buffer, file, samples);
}

// The series' volume (its samples in `grid`, whole or a window) placed in patient space.
VolumeFile placeSeries(const Series& series, const SeriesPixels& p, Grid grid) {
  VolumeFile out;
  out.format = "DICOM";
  out.grid = std::move(grid);
  placeDicom(series.slices[0].position, series.orientation, p.spacing[0], p.spacing[1], series.normal * series.step, out,
             series.slices[0].file);
  out.notes.push_back("series " + series.uid + ", modality " + (series.modality.empty() ? "unknown" : series.modality) +
                      ", " + std::to_string(series.slices.size()) + " slices " + std::to_string(series.step) +
                      " mm apart (" + p.syntax + "); values rescaled to float32");
  return out;
}

// A folder's series, or of it only `window` (only the files of its slab decoded, and the first
// slice's, whose spacing places the volume).
VolumeFile loadSeries(const std::string& folder, const std::string& wanted, const SampleWindow* window) {
  const Series series = scanSeries(folder, wanted);
  if (!series.multiFrame.empty()) {
    return multiFrameWindow(series.multiFrame, window);
  }
  SeriesPixels p;
  std::vector<float> slice;
  decodeSlice(series, 0, p, slice);
  const size_t layer = size_t(p.size.x) * size_t(p.size.y);
  if (!window) {
    std::vector<float> samples;
    samples.reserve(layer * size_t(p.size.z));
    for (size_t k = 0; k < series.slices.size(); ++k) {
      if (k > 0) decodeSlice(series, k, p, slice);
      samples.insert(samples.end(), slice.begin(), slice.end());
    }
    return placeSeries(series, p, Grid(p.size, std::move(samples)));
  }
  const SampleWindow& w = *window;
  checkWindow(w, p.size, folder);
  auto samples = std::make_shared<std::vector<float>>(size_t(w.extent.x) * size_t(w.extent.y) * size_t(w.extent.z));
  float* out = samples->data();
  for (int k = w.first.z; k < w.first.z + w.extent.z; ++k) {
    if (k > 0) decodeSlice(series, size_t(k), p, slice);
    for (int y = w.first.y; y < w.first.y + w.extent.y; ++y, out += w.extent.x)
      std::copy_n(slice.data() + size_t(y) * size_t(p.size.x) + size_t(w.first.x), size_t(w.extent.x), out);
  }
  Grid grid(p.size, ScalarType::Float32, std::shared_ptr<const void>(samples, samples->data()), w.first, w.extent);
  return placeSeries(series, p, std::move(grid));
}

// The brick ranges of a folder's series (or multi-frame file), its slices decoded one at a time.
BrickGrid seriesBrickRanges(const std::string& path, const std::string& wanted) {
  std::error_code ec;
  if (!fs::is_directory(path, ec)) return multiFrameBrickRanges(path);
  const Series series = scanSeries(path, wanted);
  if (!series.multiFrame.empty()) return multiFrameBrickRanges(series.multiFrame);
  SeriesPixels p;
  std::vector<float> slice;
  decodeSlice(series, 0, p, slice);
  return BrickGrid::fromStream(p.size, [&](auto&& layerDone) {
    for (size_t k = 0; k < series.slices.size(); ++k) {
      if (k > 0) decodeSlice(series, k, p, slice);
      layerDone(int(k), slice.data());
    }
  });
}

void muteGdcm() {
  // GDCM reports problems on stderr; isotrace reports them itself, in one line.
  gdcm::Trace::SetWarning(false);
  gdcm::Trace::SetError(false);
  gdcm::Trace::SetDebug(false);
}

VolumeFile readHere(const std::string& path, const std::string& series, const SampleWindow* window) {
  muteGdcm();
  std::error_code ec;
  if (fs::is_directory(path, ec)) return loadSeries(path, series, window);
  return multiFrameWindow(path, window);
}

void checkDicomPath(const std::string& path, const std::string& series) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError(path, "", "file not found");
  if (!fs::is_directory(path, ec)) checkInputFile(path, "DICOM file", false);
  if (!fs::is_directory(path, ec) && !series.empty())
    throw InputError(path, "", "\"series\" chooses among the series of a folder; this is one file");
}

}  // namespace

VolumeFile loadDicom(const std::string& path, const std::string& series, const SampleWindow* window) {
  checkDicomPath(path, series);
  // Debian's GDCM aborts on an assertion for some malformed files: it reads in a child process.
  return readInChildProcess(path, "GDCM", [&] { return readHere(path, series, window); });
}

BrickGrid dicomBrickRanges(const std::string& path, const std::string& series) {
  checkDicomPath(path, series);
  return rangesInChildProcess(path, "GDCM", [&] {
    muteGdcm();
    return seriesBrickRanges(path, series);
  });
}

}  // namespace iso
