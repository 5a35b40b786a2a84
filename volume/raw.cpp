#include "volume/formats.h"

#include "volume/input_file.h"

namespace iso::reading {

// Raw files are read straight into the grid's storage (one read, no intermediate copy: peak
// memory is the grid itself); gzip-compressed ones are inflated straight into it.
// A raw file's dims and type: its layout's, else its Open SciVis name's; checked.
void rawLayoutOf(const std::string& path, const RawLayout& layout, Vec3i& dims, ScalarType& type) {
  const bool named = parseSciVisName(path, dims, type);
  if (layout.dims) dims = *layout.dims;
  if (layout.type) type = *layout.type;
  if (!layout.dims && !named)
    throw InputError(path, "", "raw volume needs \"dims\" and \"type\" (or an Open SciVis name like name_64x64x64_uint8.raw)");
  if (!layout.type && !named)
    throw InputError(path, "", "raw volume needs \"type\" (uint8, uint16, int16, float32)");
  checkDims(dims, path, "");
}

// Whether a raw file is gzip: its first two bytes (1f 8b), unless the file is exactly the samples'
// size and not named .gz: plain samples may begin with those bytes (a float32 of about -7.45 does).
bool looksGzip(const std::string& path, const uint8_t* head, size_t headSize, size_t fileSize, size_t expected) {
  const bool magic = headSize >= 2 && head[0] == 0x1f && head[1] == 0x8b;
  return magic && (fileSize != expected || endsWith(lower(path), ".gz"));
}

// Opens a raw file of `dims` samples of `type`: whether it is gzip, and checked against that size
// (a plain file exactly, a gzip one for a plausible ratio).
std::ifstream openRawFile(const std::string& path, const Vec3i& dims, ScalarType type, bool& gzip) {
  const size_t expected = checkedBytes(dims, type, path);
  size_t fileSize;
  std::ifstream in = openFile(path, fileSize);
  char magic[2] = {0, 0};
  in.read(magic, 2);
  gzip = looksGzip(path, reinterpret_cast<const uint8_t*>(magic), size_t(in.gcount()), fileSize, expected);
  if (!gzip && fileSize != expected) throw InputError(path, "", sizeMismatch(dims, type, fileSize, expected));
  if (gzip) checkInflatable(fileSize, expected, path);
  return in;
}

Grid loadRaw(const std::string& path, const RawLayout& layout) {
  const bool stream = checkInputFile(path, "file").stream;
  Vec3i dims;
  ScalarType type;
  rawLayoutOf(path, layout, dims, type);
  const size_t expected = checkedBytes(dims, type, path);
  if (stream) {
    // A named pipe is read no further than the samples allow (with room for gzip's few bytes
    // of framing and stored blocks), then checked like a file.
    const Bytes data = readWholeBytes(path, "raw volume of " + layoutName(dims, type) + " (" + std::to_string(expected) + " bytes)",
                                      uint64_t(expected) + expected / 256 + 65536);
    const bool gzip = looksGzip(path, data.data(), data.size(), data.size(), expected);
    if (!gzip && data.size() != expected) throw InputError(path, "", sizeMismatch(dims, type, data.size(), expected));
    std::shared_ptr<uint8_t[]> samples = allocateSamples(expected);
    if (gzip)
      inflateInto(data, samples.get(), expected, dims, type, path);
    else
      std::memcpy(samples.get(), data.data(), expected);
    finishSamples(samples.get(), type, dims, layout.bigEndian, path);
    return Grid(dims, type, std::shared_ptr<const void>(samples, samples.get()));
  }
  bool gzip;
  std::ifstream in = openRawFile(path, dims, type, gzip);
  std::shared_ptr<uint8_t[]> samples = allocateSamples(expected);
  uint8_t* dst = samples.get();
  if (gzip) {
    inflateInto(readFile(path), dst, expected, dims, type, path);
  } else {
    in.seekg(0);
    readExactly(in, dst, expected, path);
  }
  finishSamples(dst, type, dims, layout.bigEndian, path);
  return Grid(dims, type, std::shared_ptr<const void>(samples, dst));
}

}  // namespace iso::reading
