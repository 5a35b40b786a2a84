#include "volume/formats.h"

#include <filesystem>

#include "volume/input_file.h"

namespace iso::reading {

namespace fs = std::filesystem;

// Opens a run's file; the byte where its samples (or stream) begin. Its size is checked first: a
// plain run's file holds exactly its bytes after the start (or at least them, read from the end),
// a compressed one no fewer bytes than deflate needs for the samples.
std::ifstream openRun(const SampleRuns& s, const SampleRuns::Run& r, size_t& start) {
  size_t size;
  std::ifstream in = openFile(r.file, size);
  start = r.start;
  const std::string what = s.runs.size() == 1 ? layoutName(s.dims, s.type) : "a data file of " + layoutName(s.dims, s.type);
  if (r.compressed) {
    if (size < start) throw InputError(r.file, "", "the data begins past the end of the file");
    checkInflatable(size - start, r.skip + s.runBytes, r.file);
  } else if (r.atEnd) {
    if (size < start + s.runBytes)
      throw InputError(r.file, "", "data has " + std::to_string(size - std::min(size, start)) + " bytes but " + what +
                                       " needs " + std::to_string(s.runBytes));
    start = size - s.runBytes;
  } else if (r.moreAfter ? size < start + s.runBytes : size != start + s.runBytes) {
    throw InputError(r.file, "", "data has " + std::to_string(size - std::min(size, start)) + " bytes but " + what +
                                     " needs " + std::to_string(s.runBytes));
  }
  return in;
}

// A compressed run's samples as they are inflated: sink(at, bytes, count), `at` their offset in
// the run. Exactly skip + runBytes bytes must come out of the stream (more is an error within
// 64 KiB of the first extra byte).
template <typename Sink>
void inflateRun(const SampleRuns& s, const SampleRuns::Run& r, size_t start, Sink&& sink) {
  Bytes stream = readFile(r.file);
  stream.erase(stream.begin(), stream.begin() + long(std::min(start, stream.size())));
  const size_t total = r.skip + s.runBytes;
  size_t produced = 0;
  struct Done {};
  try {
    inflateStream(stream, r.file, [&](const uint8_t* p, size_t n) {
      if (n > total - produced && !r.moreAfter)
        throw InputError(r.file, "", "decompressed data is larger than the " + std::to_string(total) + " bytes " +
                                         layoutName(s.dims, s.type) + " needs");
      n = std::min(n, total - produced);
      const size_t a = std::max(produced, r.skip), b = produced + n;
      if (b > a) sink(a - r.skip, p + (a - produced), b - a);
      produced = b;
      if (produced == total && r.moreAfter) throw Done{};  // the rest of the stream is not inflated
    });
  } catch (const Done&) {
  }
  if (produced != total)
    throw InputError(r.file, "", "decompressed data has " + std::to_string(produced) + " bytes but " +
                                     layoutName(s.dims, s.type) + " needs " + std::to_string(total));
}

// The window's samples of `s`, read without the rest: a plain run's rows of the window by their
// byte ranges, a compressed run inflated whole but only the window's rows kept; a run holding no
// row of the window is not opened. Errors about the samples name `file`.
Grid readRunsWindow(const SampleRuns& s, const SampleWindow& w, const std::string& file) {
  const size_t size = s.fileSampleSize();
  const size_t row = size_t(w.extent.x) * size, rows = size_t(w.extent.y) * size_t(w.extent.z);
  // The volume's byte offset of the window's row r (y fastest, then z).
  auto rowStart = [&](size_t r) {
    const size_t y = size_t(w.first.y) + r % size_t(w.extent.y), z = size_t(w.first.z) + r / size_t(w.extent.y);
    return ((z * size_t(s.dims.y) + y) * size_t(s.dims.x) + size_t(w.first.x)) * size;
  };
  // The runs holding rows of the window, with the first such row of each; their files checked
  // before the window's samples are allocated (a header may claim more than its files hold).
  std::vector<std::pair<size_t, size_t>> needed;
  for (size_t k = 0, first = 0; k < s.runs.size() && first < rows; ++k) {
    const size_t lo = k * s.runBytes, hi = lo + s.runBytes;
    while (first < rows && rowStart(first) + row <= lo) ++first;
    if (first == rows || rowStart(first) >= hi) continue;
    size_t start;
    openRun(s, s.runs[k], start);
    needed.emplace_back(k, first);
  }
  std::shared_ptr<uint8_t[]> samples = allocateSamples(row * rows);
  uint8_t* dst = samples.get();
  for (const auto& [k, first] : needed) {
    const SampleRuns::Run& run = s.runs[k];
    const size_t lo = k * s.runBytes, hi = lo + s.runBytes;
    size_t start;
    std::ifstream in = openRun(s, run, start);
    if (run.compressed) {
      // What of the volume's bytes [at, at + n) lies in the rows from r on (rows before it are done).
      size_t r = first;
      inflateRun(s, run, start, [&](size_t offset, const uint8_t* p, size_t n) {
        const size_t at = lo + offset;
        for (; r < rows && rowStart(r) < at + n; ++r) {
          const size_t a = std::max(rowStart(r), at), b = std::min(rowStart(r) + row, at + n);
          if (b > a) std::memcpy(dst + r * row + (a - rowStart(r)), p + (a - at), b - a);
          if (rowStart(r) + row > at + n) break;  // the row goes on in the next piece
        }
      });
      continue;
    }
    for (size_t r = first; r < rows && rowStart(r) < hi; ++r) {
      const size_t a = std::max(rowStart(r), lo), b = std::min(rowStart(r) + row, hi);
      in.seekg(std::streamoff(start + (a - lo)));
      readExactly(in, dst + r * row + (a - rowStart(r)), b - a, run.file);
    }
  }
  if (s.convert) {  // to float32, in a second buffer
    std::shared_ptr<uint8_t[]> floats = allocateSamples(rows * size_t(w.extent.x) * sizeof(float));
    s.convert(dst, reinterpret_cast<float*>(floats.get()), rows * size_t(w.extent.x), s.bigEndian, s.slope, s.inter);
    samples = std::move(floats);
    dst = samples.get();
  }
  finishSamples(dst, s.type, w.extent, s.bigEndian && !s.convert, file, w.first);
  Grid g(s.dims, s.type, std::shared_ptr<const void>(samples, dst), w.first, w.extent);
  g.setOrigin(s.origin);
  g.setSpacing(s.spacing);
  return g;
}

// The bricks' ranges of `s`, keeping none of the samples: the runs read (or inflated) in order, a
// layer at a time.
BrickGrid runsBrickRanges(const SampleRuns& s) {
  for (const SampleRuns::Run& run : s.runs) {  // every file checked before anything is allocated
    size_t start;
    openRun(s, run, start);
  }
  const size_t size = s.fileSampleSize(), layer = size_t(s.dims.x) * size_t(s.dims.y) * size;
  std::vector<uint8_t> bytes;
  std::vector<float> values(layer / size);
  // The layer in `bytes` as float, in native byte order: the grid's values.
  const ToFloat convert = s.convert ? s.convert : toFloatOf(s.type);
  auto toFloats = [&]() {
    convert(bytes.data(), values.data(), values.size(), s.bigEndian, s.slope, s.inter);
    return values.data();
  };
  return BrickGrid::fromStream(s.dims, [&](auto&& layerDone) {
    bytes.reserve(layer);
    int z = 0;
    auto take = [&](const uint8_t* p, size_t n) {
      while (n > 0) {
        const size_t part = std::min(n, layer - bytes.size());
        bytes.insert(bytes.end(), p, p + part);
        p += part;
        n -= part;
        if (bytes.size() == layer) {
          layerDone(z++, toFloats());
          bytes.clear();
        }
      }
    };
    std::vector<uint8_t> chunk(size_t(1) << 20);
    for (const SampleRuns::Run& run : s.runs) {
      size_t start;
      std::ifstream in = openRun(s, run, start);
      if (run.compressed) {
        inflateRun(s, run, start, [&](size_t, const uint8_t* p, size_t n) { take(p, n); });
        continue;
      }
      in.seekg(std::streamoff(start));
      for (size_t done = 0; done < s.runBytes;) {
        const size_t n = std::min(chunk.size(), s.runBytes - done);
        readExactly(in, chunk.data(), n, run.file);
        take(chunk.data(), n);
        done += n;
      }
    }
  });
}

// The first `limit` bytes of a file (all of it when shorter: `whole`).
Bytes readHead(const std::string& path, size_t limit, bool& whole) {
  size_t size;
  std::ifstream in = openFile(path, size);
  whole = size <= limit;
  Bytes head(std::min(size, limit));
  readExactly(in, head.data(), head.size(), path);
  return head;
}

// The runs of a volume file's samples, or nullopt: another format, a named pipe, or data that is
// not in runs (ASCII, line skips, a compressed MetaImage stream of unknown skip, a header longer
// than 1 MiB). Only the header is read.
std::optional<SampleRuns> sampleRunsOf(const std::string& path, const RawLayout& layout, int time) {
  const std::string name = lower(fs::path(path).filename().string());
  const bool nrrd = endsWith(name, ".nrrd") || endsWith(name, ".nhdr"), meta = endsWith(name, ".mhd") || endsWith(name, ".mha");
  const bool vtk = endsWith(name, ".vtk"), nifti = isNiftiName(name);
  if ((!isRawName(name) && !nrrd && !meta && !vtk && !nifti) || checkInputFile(path, "file").stream) return std::nullopt;
  SampleRuns s;
  if (nifti) {
    NiftiLayout l = niftiLayoutInChild(path);
    l.offset = timePointOffset(l, time, path);
    s.dims = l.dims, s.type = l.native, s.sampleSize = l.sampleSize, s.bigEndian = l.swap;
    if (!l.direct) s.convert = niftiToFloat(l.datatype), s.slope = l.slope, s.inter = l.inter;
    s.format = l.format;
    s.notes = l.notes;
    Grid placed;
    placeByAffine(l.affine, placed, s.toWorld, path, l.where);
    s.origin = placed.origin(), s.spacing = placed.spacing();
    s.runBytes = size_t(l.dims.x) * size_t(l.dims.y) * size_t(l.dims.z) * l.sampleSize;  // dims checked: no overflow
    SampleRuns::Run run{l.image, l.gzip ? 0 : l.offset, l.gzip ? l.offset : 0, l.gzip, false};
    run.moreAfter = true;  // more frames, or padding
    s.runs.push_back(run);
    return s;
  }
  if (isRawName(name)) {
    rawLayoutOf(path, layout, s.dims, s.type);
    bool gzip;
    openRawFile(path, s.dims, s.type, gzip);
    s.bigEndian = layout.bigEndian;
    s.runBytes = checkedBytes(s.dims, s.type, path);
    s.runs.push_back({path, 0, 0, gzip, false});
    return s;
  }
  bool whole;
  const Bytes head = readHead(path, size_t(1) << 20, whole);
  if (nrrd) {
    const std::optional<NrrdHeader> h = readNrrdHeader(path, head, whole);
    if (!h || h->enc == NrrdHeader::Enc::Ascii || h->lineSkip != 0) return std::nullopt;
    s.dims = h->dims, s.type = h->type, s.bigEndian = h->bigEndian, s.origin = h->origin, s.spacing = h->spacing;
    s.format = "NRRD";
    const bool gzip = h->enc == NrrdHeader::Enc::Gzip;
    const size_t total = checkedBytes(s.dims, s.type, path), skip = size_t(std::max(h->byteSkip, 0L));
    const std::vector<std::string> files = h->files.empty() ? std::vector<std::string>{path} : h->files;
    s.runBytes = total / files.size();
    for (const std::string& file : files) {
      const size_t start = h->files.empty() ? h->dataStart : 0;  // attached data, or a data file of its own
      s.runs.push_back({file, start + (gzip ? 0 : skip), gzip ? skip : 0, gzip, h->byteSkip == -1});
    }
    return s;
  }
  if (vtk) {
    const std::optional<VtkHeader> h = readVtkHeader(path, head, whole);
    if (!h || !h->binary) return std::nullopt;
    s.dims = h->dims, s.type = h->type, s.bigEndian = true, s.origin = h->origin, s.spacing = h->spacing;
    s.format = "VTK";
    s.runBytes = checkedBytes(s.dims, s.type, path);
    SampleRuns::Run run{path, h->dataStart, 0, false, false};
    run.moreAfter = true;
    s.runs.push_back(run);
    return s;
  }
  const std::optional<MetaHeader> h = readMetaHeader(path, head, whole);
  if (!h || (h->compressed && h->skip == -1)) return std::nullopt;
  s.dims = h->dims, s.type = h->type, s.bigEndian = h->bigEndian, s.origin = h->origin, s.spacing = h->spacing;
  s.format = "MetaImage";
  s.runBytes = checkedBytes(s.dims, s.type, path);
  const size_t skip = size_t(std::max(h->skip, 0L));
  s.runs.push_back({h->dataFile, h->dataStart + (h->compressed ? 0 : skip), h->compressed ? skip : 0, h->compressed, h->skip == -1});
  return s;
}

}  // namespace iso::reading
