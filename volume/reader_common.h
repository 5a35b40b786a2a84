#pragma once
// What the volume readers (volume/nrrd.cpp, metaimage.cpp, vtk_legacy.cpp, nifti.cpp, raw.cpp,
// sample_runs.cpp) share: files read whole or in part, gzip streams inflated with limits, sizes
// checked before anything is allocated, samples brought to native order and checked for NaN.
// Internal to volume/: the loaders' API is volume/loaders.h.
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <zlib.h>

#include "volume/grid.h"
#include "volume/input_error.h"

namespace iso::reading {

using Bytes = std::vector<uint8_t>;

// Text of headers and file names.
std::string lower(std::string s);
std::string trim(const std::string& s);
bool endsWith(const std::string& s, const std::string& suffix);
// Opens a regular file for reading and tells its size; errors name the file (a named pipe,
// a device, a directory are refused: the callers seek or read twice).
std::ifstream openFile(const std::string& path, size_t& size);
// Reads `size` bytes from `in` into `out`, or throws.
void readExactly(std::ifstream& in, uint8_t* out, size_t size, const std::string& path);
// Inflates at most `limit` bytes: a stream that grows past what the header asks for is an
// error within 64 KiB of the limit (a gzip bomb is never inflated whole).
Bytes inflateBytes(const Bytes& in, const std::string& file, size_t limit);
// Deflate expands at most about 1032:1, so `compressed` bytes of gzip cannot hold more than
// this: a header asking for more is refused before the grid is allocated (a 200-byte file
// claiming 19 TB of samples).
void checkInflatable(size_t compressed, size_t expected, const std::string& file);
void checkDims(const Vec3i& d, const std::string& file, const std::string& where);
void checkSpacing(const Vec3d& s, const std::string& file, const std::string& where);
// "256x256x133 uint8", for messages.
std::string layoutName(const Vec3i& dims, ScalarType type);
std::string sizeMismatch(const Vec3i& dims, ScalarType type, size_t have, size_t expected);
// Bytes of a grid, or an error if the product does not fit in memory sizes.
size_t checkedBytes(const Vec3i& dims, ScalarType type, const std::string& file);
// An uninitialised buffer for `bytes` bytes of samples: the reader fills it, and the grid takes
// ownership. Large buffers are aligned to 2 MiB and asked for transparent huge pages: reading
// 512 MiB into 4 KiB pages spends most of its time in page faults.
std::shared_ptr<uint8_t[]> allocateSamples(size_t bytes);
// In place, once the bytes are in the buffer: native byte order, and no NaN or Inf in float
// data (the error names the first such voxel).
// `dims`: of the samples in `data` (a window's extent), `at`: where they begin in the volume
// (for the voxel an error names).
void finishSamples(uint8_t* data, ScalarType type, const Vec3i& dims, bool bigEndian, const std::string& file,
                   const Vec3i& at = {0, 0, 0});
// Turns raw little/big-endian bytes into a typed grid; the size must match exactly.
Grid makeGrid(const Vec3i& dims, ScalarType type, const Bytes& bytes, bool bigEndian,
              const std::string& file);
// Inflates a gzip (or zlib) stream straight into `out`, which must come out exactly `expected`
// bytes long: more output is an error within 64 KiB of the first extra byte (a small bomb is
// never inflated whole), less is an error at the end.
void inflateInto(const Bytes& in, uint8_t* out, size_t expected, const Vec3i& dims, ScalarType type,
                 const std::string& file);
// Parses whitespace-separated numbers (ASCII encodings) into the bytes of the scalar type.
// Every value must be a finite number within the range of the type; the count is checked
// against the text's length before anything is allocated (each value takes two characters at
// least, with its separator).
Bytes asciiToBytes(const std::string& text, ScalarType type, size_t count, const std::string& file);
std::vector<double> parseNumbers(const std::string& s, const std::string& file,
                                 const std::string& where, size_t n);
Vec3i toDims(const std::vector<double>& v, const std::string& file, const std::string& where);
// A whole file (or a named pipe, up to a cap that the error states).
Bytes readFile(const std::string& path);

// Inflates gzip or zlib streams (windowBits 32+15 detects either), including concatenated
// gzip members, handing the output to `sink(bytes, count)` in pieces of at most 64 KiB as it
// comes (so a caller can stop a stream that grows past what it expects). Truncated or corrupt
// input is an error, never a short grid.
template <typename Sink>
void inflateStream(const Bytes& in, const std::string& file, Sink&& sink) {
  struct Stream {  // inflateEnd on every way out, the sink's exceptions included
    z_stream zs{};
    bool open = false;
    ~Stream() { if (open) inflateEnd(&zs); }
  };
  size_t consumed = 0;
  while (consumed < in.size()) {
    Stream s;
    if (inflateInit2(&s.zs, 32 + MAX_WBITS) != Z_OK) throw InputError(file, "", "zlib init failed");
    s.open = true;
    s.zs.next_in = const_cast<Bytef*>(in.data() + consumed);
    s.zs.avail_in = uInt(std::min<size_t>(in.size() - consumed, UINT32_MAX));
    int rc = Z_OK;
    uint8_t buffer[1 << 16];
    while (rc != Z_STREAM_END) {
      s.zs.next_out = buffer;
      s.zs.avail_out = sizeof(buffer);
      rc = inflate(&s.zs, Z_NO_FLUSH);
      if (rc != Z_OK && rc != Z_STREAM_END) {
        const std::string msg = rc == Z_BUF_ERROR ? "truncated compressed data" : "corrupt compressed data";
        throw InputError(file, "byte " + std::to_string(consumed + s.zs.total_in), msg);
      }
      sink(buffer, sizeof(buffer) - s.zs.avail_out);
      if (rc == Z_OK && s.zs.avail_in == 0 && s.zs.avail_out != 0)
        throw InputError(file, "byte " + std::to_string(in.size()), "truncated compressed data");
    }
    consumed += s.zs.total_in;
    // Trailing zero padding after the last gzip member is tolerated.
    if (std::all_of(in.begin() + consumed, in.end(), [](uint8_t b) { return b == 0; })) break;
  }
}

// Converts `n` samples of type T (file order of bytes in `swap`) to float32, scaled: a NIfTI's
// samples, and a layer of any file read in runs (slope 1, intercept 0: the exact float value).
template <typename T>
void toFloat(const uint8_t* in, float* out, size_t n, bool swap, double slope, double inter) {
  for (size_t i = 0; i < n; ++i) {
    uint8_t b[sizeof(T)];
    std::memcpy(b, in + i * sizeof(T), sizeof(T));
    if (swap) std::reverse(b, b + sizeof(T));
    T v;
    std::memcpy(&v, b, sizeof(T));
    out[i] = float(double(v) * slope + inter);
  }
}
using ToFloat = void (*)(const uint8_t*, float*, size_t, bool, double, double);
ToFloat toFloatOf(ScalarType type);

}  // namespace iso::reading
