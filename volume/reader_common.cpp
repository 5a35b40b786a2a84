#include "volume/reader_common.h"

#include <sys/mman.h>

#include <cmath>
#include <cstdlib>
#include <sstream>

#include "volume/input_file.h"

namespace iso::reading {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r\n");
  return s.substr(b, e - b + 1);
}

bool endsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// Opens a regular file for reading and tells its size; errors name the file (a named pipe,
// a device, a directory are refused: the callers seek or read twice).
std::ifstream openFile(const std::string& path, size_t& size) {
  size = size_t(checkInputFile(path, "file", false).size);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, "", "cannot open file");
  return in;
}

// Reads `size` bytes from `in` into `out`, or throws.
void readExactly(std::ifstream& in, uint8_t* out, size_t size, const std::string& path) {
  in.read(reinterpret_cast<char*>(out), std::streamsize(size));
  if (in.bad() || size_t(in.gcount()) != size) throw InputError(path, "", "read error");
}

// A whole file (or a named pipe, up to a cap that the error states).
Bytes readFile(const std::string& path) { return readWholeBytes(path, "file", kVolumeStreamCap); }


// Inflates at most `limit` bytes: a stream that grows past what the header asks for is an
// error within 64 KiB of the limit (a gzip bomb is never inflated whole).
Bytes inflateBytes(const Bytes& in, const std::string& file, size_t limit) {
  Bytes out;
  inflateStream(in, file, [&](const uint8_t* p, size_t n) {
    if (n > limit - out.size())
      throw InputError(file, "", "decompressed data is larger than the " + std::to_string(limit) + " bytes the header asks for");
    out.insert(out.end(), p, p + n);
  });
  return out;
}

// Deflate expands at most about 1032:1, so `compressed` bytes of gzip cannot hold more than
// this: a header asking for more is refused before the grid is allocated (a 200-byte file
// claiming 19 TB of samples).
void checkInflatable(size_t compressed, size_t expected, const std::string& file) {
  const double most = double(compressed) * 1032.0 + 65536.0;
  if (double(expected) > most)
    throw InputError(file, "", "the header asks for " + std::to_string(expected) + " bytes of samples; " +
                                   std::to_string(compressed) + " bytes of gzip data cannot hold more than " +
                                   std::to_string(size_t(most)));
}

void checkDims(const Vec3i& d, const std::string& file, const std::string& where) {
  if (d.x <= 0 || d.y <= 0 || d.z <= 0)
    throw InputError(file, where, "dimensions must be positive, got " + std::to_string(d.x) +
                                      "x" + std::to_string(d.y) + "x" + std::to_string(d.z));
  if (d.x < 2 || d.y < 2 || d.z < 2)
    throw InputError(file, where, "each dimension needs at least 2 samples to form a cell");
}

void checkSpacing(const Vec3d& s, const std::string& file, const std::string& where) {
  if (!(s.x > 0 && s.y > 0 && s.z > 0) || !isFinite(s))
    throw InputError(file, where, "spacing must be positive and finite");
}

// "256x256x133 uint8", for messages.
std::string layoutName(const Vec3i& dims, ScalarType type) {
  return std::to_string(dims.x) + "x" + std::to_string(dims.y) + "x" + std::to_string(dims.z) + " " +
         scalarTypeName(type);
}

std::string sizeMismatch(const Vec3i& dims, ScalarType type, size_t have, size_t expected) {
  return "data has " + std::to_string(have) + " bytes but " + layoutName(dims, type) + " needs " +
         std::to_string(expected);
}

// Bytes of a grid, or an error if the product does not fit in memory sizes.
size_t checkedBytes(const Vec3i& dims, ScalarType type, const std::string& file) {
  const unsigned __int128 n = (unsigned __int128)(uint64_t(dims.x)) * uint64_t(dims.y) * uint64_t(dims.z);
  const unsigned __int128 bytes = n * scalarTypeSize(type);
  if (bytes > (unsigned __int128)(SIZE_MAX / 2))
    throw InputError(file, "", "dimensions " + std::to_string(dims.x) + "x" + std::to_string(dims.y) + "x" +
                                   std::to_string(dims.z) + " are too large");
  return size_t(bytes);
}

// An uninitialised buffer for `bytes` bytes of samples: the reader fills it, and the grid takes
// ownership. Large buffers are aligned to 2 MiB and asked for transparent huge pages: reading
// 512 MiB into 4 KiB pages spends most of its time in page faults.
std::shared_ptr<uint8_t[]> allocateSamples(size_t bytes) {
  constexpr size_t kHuge = size_t(2) << 20;
  if (bytes < kHuge) return std::shared_ptr<uint8_t[]>(new uint8_t[std::max<size_t>(bytes, 1)]);
  const size_t rounded = (bytes + kHuge - 1) / kHuge * kHuge;
  void* p = std::aligned_alloc(kHuge, rounded);
  if (!p) throw std::bad_alloc();
  madvise(p, rounded, MADV_HUGEPAGE);  // a hint: without THP it changes nothing
  return std::shared_ptr<uint8_t[]>(static_cast<uint8_t*>(p), [](uint8_t* q) { std::free(q); });
}

// In place, once the bytes are in the buffer: native byte order, and no NaN or Inf in float
// data (the error names the first such voxel).
// `dims`: of the samples in `data` (a window's extent), `at`: where they begin in the volume
// (for the voxel an error names).
void finishSamples(uint8_t* data, ScalarType type, const Vec3i& dims, bool bigEndian, const std::string& file,
                   const Vec3i& at) {
  const size_t n = size_t(dims.x) * dims.y * dims.z;
  const size_t size = scalarTypeSize(type);
  if (bigEndian && size > 1)
    for (size_t i = 0; i < n; ++i) std::reverse(data + i * size, data + (i + 1) * size);
  if (type != ScalarType::Float32) return;
  const float* v = reinterpret_cast<const float*>(data);
  // Exponent bits all set is NaN or Inf. Blocks are OR-reduced without a branch (the compiler
  // vectorises that); only a block with a hit is searched.
  size_t first = n;
  for (size_t b = 0; b < n && first == n; b += 4096) {
    const size_t e = std::min(n, b + 4096);
    uint32_t bad = 0;
    for (size_t i = b; i < e; ++i) {
      uint32_t bits;
      std::memcpy(&bits, &v[i], 4);
      bad |= uint32_t((bits & 0x7f800000u) == 0x7f800000u);
    }
    if (bad) first = b;
  }
  for (size_t i = first; i < n; ++i) {
    if (!std::isfinite(v[i])) {
      const size_t x = at.x + i % dims.x, y = at.y + (i / dims.x) % dims.y, z = at.z + i / (size_t(dims.x) * dims.y);
      throw InputError(file, "voxel (" + std::to_string(x) + ", " + std::to_string(y) + ", " + std::to_string(z) + ")",
                       std::string(std::isnan(v[i]) ? "NaN" : "infinite") + " value in the data");
    }
  }
}

// Turns raw little/big-endian bytes into a typed grid; the size must match exactly.
Grid makeGrid(const Vec3i& dims, ScalarType type, const Bytes& bytes, bool bigEndian,
              const std::string& file) {
  const size_t expected = checkedBytes(dims, type, file);
  if (bytes.size() != expected) throw InputError(file, "", sizeMismatch(dims, type, bytes.size(), expected));
  std::shared_ptr<uint8_t[]> samples = allocateSamples(expected);
  std::memcpy(samples.get(), bytes.data(), expected);
  finishSamples(samples.get(), type, dims, bigEndian, file);
  return Grid(dims, type, std::shared_ptr<const void>(samples, samples.get()));
}

// Inflates a gzip (or zlib) stream straight into `out`, which must come out exactly `expected`
// bytes long: more output is an error within 64 KiB of the first extra byte (a small bomb is
// never inflated whole), less is an error at the end.
void inflateInto(const Bytes& in, uint8_t* out, size_t expected, const Vec3i& dims, ScalarType type,
                 const std::string& file) {
  size_t produced = 0;
  inflateStream(in, file, [&](const uint8_t* p, size_t n) {
    if (n > expected - produced)
      throw InputError(file, "", "decompressed data is larger than " + layoutName(dims, type) + " (" +
                                     std::to_string(expected) + " bytes)");
    std::memcpy(out + produced, p, n);
    produced += n;
  });
  if (produced != expected) throw InputError(file, "", sizeMismatch(dims, type, produced, expected));
}

// Parses whitespace-separated numbers (ASCII encodings) into the bytes of the scalar type.
// Every value must be a finite number within the range of the type; the count is checked
// against the text's length before anything is allocated (each value takes two characters at
// least, with its separator).
Bytes asciiToBytes(const std::string& text, ScalarType type, size_t count, const std::string& file) {
  if (count > text.size() / 2 + 1)
    throw InputError(file, "", "ASCII data of " + std::to_string(text.size()) + " bytes cannot hold the " +
                                   std::to_string(count) + " values the header asks for");
  Bytes out(count * scalarTypeSize(type));
  std::istringstream in(text);
  double lo = 0, hi = 0;
  switch (type) {
    case ScalarType::UInt8: hi = 255; break;
    case ScalarType::UInt16: hi = 65535; break;
    case ScalarType::Int16: lo = -32768, hi = 32767; break;
    case ScalarType::Float32: lo = -3.4028234663852886e38, hi = 3.4028234663852886e38; break;
  }
  for (size_t i = 0; i < count; ++i) {
    std::string token;
    if (!(in >> token))
      throw InputError(file, "", "ASCII data ends after " + std::to_string(i) + " of " +
                                     std::to_string(count) + " values");
    char* end = nullptr;
    const double v = std::strtod(token.c_str(), &end);
    const std::string at = "value " + std::to_string(i + 1) + " of " + std::to_string(count);
    if (end == token.c_str() || *end != 0) throw InputError(file, at, "'" + token.substr(0, 32) + "' is not a number");
    if (!std::isfinite(v)) throw InputError(file, at, "'" + token.substr(0, 32) + "' is not a finite number");
    if (v < lo || v > hi)
      throw InputError(file, at, token.substr(0, 32) + " is out of range for " + scalarTypeName(type));
    switch (type) {
      case ScalarType::UInt8: out[i] = uint8_t(v); break;
      case ScalarType::UInt16: { uint16_t x = uint16_t(v); std::memcpy(&out[2 * i], &x, 2); break; }
      case ScalarType::Int16: { int16_t x = int16_t(v); std::memcpy(&out[2 * i], &x, 2); break; }
      case ScalarType::Float32: { float x = float(v); std::memcpy(&out[4 * i], &x, 4); break; }
    }
  }
  return out;
}

std::vector<double> parseNumbers(const std::string& s, const std::string& file,
                                 const std::string& where, size_t n) {
  std::string clean = s;
  for (char& c : clean) if (c == '(' || c == ')' || c == ',') c = ' ';
  std::istringstream in(clean);
  std::vector<double> v;
  std::string tok;
  while (in >> tok) {
    char* end = nullptr;
    const double d = std::strtod(tok.c_str(), &end);
    if (end == tok.c_str() || *end != 0)
      throw InputError(file, where, "'" + tok + "' is not a number");
    v.push_back(d);
  }
  if (n && v.size() != n)
    throw InputError(file, where, "expected " + std::to_string(n) + " numbers, got " +
                                      std::to_string(v.size()));
  return v;
}

Vec3i toDims(const std::vector<double>& v, const std::string& file, const std::string& where) {
  for (double d : v)
    if (d != std::floor(d) || d > 1e9)
      throw InputError(file, where, "dimensions must be whole numbers");
  Vec3i dims{int(v[0]), int(v[1]), int(v[2])};
  checkDims(dims, file, where);
  return dims;
}

ToFloat toFloatOf(ScalarType type) {
  switch (type) {
    case ScalarType::UInt8: return toFloat<uint8_t>;
    case ScalarType::UInt16: return toFloat<uint16_t>;
    case ScalarType::Int16: return toFloat<int16_t>;
    case ScalarType::Float32: break;
  }
  return toFloat<float>;
}

}  // namespace iso::reading
