#include "volume/loaders.h"

#include <sys/mman.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include "volume/input_error.h"
#include "volume/input_file.h"

extern "C" {
#include <nifti2_io.h>
}

namespace iso {
namespace {

namespace fs = std::filesystem;
using Bytes = std::vector<uint8_t>;

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
                   const Vec3i& at = {0, 0, 0}) {
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

// ---------------------------------------------------------------------------------------
// NRRD (http://teem.sourceforge.net/nrrd/format.html)

bool nrrdType(const std::string& t, ScalarType& type) {
  static const std::map<std::string, ScalarType> names = {
      {"uchar", ScalarType::UInt8},          {"unsigned char", ScalarType::UInt8},
      {"uint8", ScalarType::UInt8},          {"uint8_t", ScalarType::UInt8},
      {"ushort", ScalarType::UInt16},        {"unsigned short", ScalarType::UInt16},
      {"unsigned short int", ScalarType::UInt16}, {"uint16", ScalarType::UInt16},
      {"uint16_t", ScalarType::UInt16},      {"short", ScalarType::Int16},
      {"short int", ScalarType::Int16},      {"signed short", ScalarType::Int16},
      {"signed short int", ScalarType::Int16}, {"int16", ScalarType::Int16},
      {"int16_t", ScalarType::Int16},        {"float", ScalarType::Float32}};
  auto it = names.find(t);
  if (it == names.end()) return false;
  type = it->second;
  return true;
}

// Expands the `%d` form of `data file:` safely: exactly one integer conversion, no other '%'.
// Scanned by hand: std::regex recurses per character and overflows the stack on a long line
// (found by the fuzzer on a 47 KB pattern).
std::string formatSliceName(const std::string& pattern, long index, const std::string& file,
                            const std::string& where) {
  const size_t percent = pattern.find('%');
  size_t end = percent == std::string::npos ? percent : percent + 1;
  while (end < pattern.size() && std::isdigit(static_cast<unsigned char>(pattern[end]))) ++end;
  if (percent == std::string::npos || end >= pattern.size() || pattern[end] != 'd' ||
      std::count(pattern.begin(), pattern.end(), '%') != 1)
    throw InputError(file, where, "data file pattern '" + pattern.substr(0, 64) + "' needs exactly one %d");
  std::string number = std::to_string(index);
  const std::string width = pattern.substr(percent + 1, end - percent - 1);
  if (!width.empty()) {
    if (width.size() > 2 || std::stoul(width) > 32)
      throw InputError(file, where, "data file pattern '" + pattern.substr(0, 64) + "': a field width above 32");
    const size_t w = size_t(std::stoul(width));
    const char pad = width[0] == '0' ? '0' : ' ';
    if (number.size() < w) number = std::string(w - number.size(), pad) + number;
  }
  return pattern.substr(0, percent) + number + pattern.substr(end + 1);
}

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

std::optional<NrrdHeader> readNrrdHeader(const std::string& path, const Bytes& bytes, bool whole) {
  // The header ends at the first empty line (attached data follows) or at the end of file.
  size_t pos = 0, lineNo = 0, dataStart = bytes.size();
  bool attached = false;
  std::vector<std::pair<size_t, std::string>> lines;
  while (pos < bytes.size()) {
    size_t nl = pos;
    while (nl < bytes.size() && bytes[nl] != '\n') ++nl;
    std::string line(bytes.begin() + pos, bytes.begin() + nl);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    ++lineNo;
    pos = nl + 1;
    if (line.empty()) { attached = true; dataStart = std::min(pos, bytes.size()); break; }
    lines.emplace_back(lineNo, line);
  }
  if (!attached && !whole) return std::nullopt;
  if (lines.empty() || lines[0].second.rfind("NRRD000", 0) != 0)
    throw InputError(path, "line 1", "not a NRRD file (missing 'NRRD000x' magic)");

  std::map<std::string, std::pair<size_t, std::string>> fields;
  std::vector<std::string> listFiles;
  bool inList = false;
  for (size_t i = 1; i < lines.size(); ++i) {
    const auto& [no, line] = lines[i];
    if (inList) { listFiles.push_back(trim(line)); continue; }
    if (line[0] == '#') continue;
    if (line.find(":=") != std::string::npos) continue;  // key/value pairs carry no layout
    const auto colon = line.find(':');
    if (colon == std::string::npos)
      throw InputError(path, "line " + std::to_string(no), "expected 'field: value'");
    std::string key = lower(trim(line.substr(0, colon)));
    const std::string value = trim(line.substr(colon + 1));
    if (key == "datafile") key = "data file";  // spelling seen in the wild (Voreen)
    fields[key] = {no, value};
    if (key == "data file" && lower(value).rfind("list", 0) == 0) inList = true;
  }
  auto where = [&](const std::string& key) { return "line " + std::to_string(fields[key].first); };
  auto require = [&](const std::string& key) -> std::string {
    if (!fields.count(key)) throw InputError(path, "header", "missing required field '" + key + "'");
    return fields[key].second;
  };

  NrrdHeader h;
  const std::string dimension = require("dimension");
  if (dimension != "3")
    throw InputError(path, where("dimension"), "only 3-dimensional NRRD volumes are supported");
  const std::string typeName = lower(require("type"));
  if (!nrrdType(typeName, h.type))
    throw InputError(path, where("type"), "unsupported type '" + typeName +
                                              "' (supported: uchar, ushort, short, float)");
  h.dims = toDims(parseNumbers(require("sizes"), path, where("sizes"), 3), path, where("sizes"));
  const std::string encoding = lower(require("encoding"));
  using Enc = NrrdHeader::Enc;
  if (encoding == "raw") h.enc = Enc::Raw;
  else if (encoding == "gzip" || encoding == "gz") h.enc = Enc::Gzip;
  else if (encoding == "ascii" || encoding == "text" || encoding == "txt") h.enc = Enc::Ascii;
  else throw InputError(path, where("encoding"), "unsupported encoding '" + encoding +
                                                     "' (supported: raw, gzip, ascii)");
  if (fields.count("endian")) {
    const std::string e = lower(fields["endian"].second);
    if (e != "little" && e != "big")
      throw InputError(path, where("endian"), "endian must be 'little' or 'big'");
    h.bigEndian = e == "big";
  }
  if (fields.count("spacings")) {
    auto s = parseNumbers(fields["spacings"].second, path, where("spacings"), 3);
    h.spacing = {s[0], s[1], s[2]};
  } else if (fields.count("space directions")) {
    auto s = parseNumbers(fields["space directions"].second, path, where("space directions"), 9);
    h.spacing = {std::hypot(s[0], s[1], s[2]), std::hypot(s[3], s[4], s[5]), std::hypot(s[6], s[7], s[8])};
  }
  checkSpacing(h.spacing, path, fields.count("spacings") ? where("spacings") : "header");
  if (fields.count("space origin")) {
    auto o = parseNumbers(fields["space origin"].second, path, where("space origin"), 3);
    h.origin = {o[0], o[1], o[2]};
  }
  // Skips are whole numbers no larger than a file can be (-1 for byte skip: the data is at the end).
  auto skip = [&](const char* key, double lowest) -> long {
    if (!fields.count(key)) return 0;
    const double v = parseNumbers(fields[key].second, path, where(key), 1)[0];
    if (!(v >= lowest && v <= 1e15) || v != std::floor(v))
      throw InputError(path, where(key), std::string(key) + " must be a whole number from " +
                                             (lowest < 0 ? "-1" : "0") + " to 1e15");
    return long(v);
  };
  h.lineSkip = skip("line skip", 0);
  h.byteSkip = skip("byte skip", -1);
  if (h.byteSkip == -1 && h.enc != Enc::Raw)
    throw InputError(path, where("byte skip"), "'byte skip: -1' is only valid with raw encoding");
  const size_t totalBytes = checkedBytes(h.dims, h.type, path);

  if (!fields.count("data file")) {
    if (!attached) throw InputError(path, "header", "no attached data and no 'data file' field");
    h.dataStart = dataStart;
    return h;
  }
  const std::string value = fields["data file"].second;
  const std::string w = where("data file");
  std::vector<std::string> files;
  std::istringstream in(value);
  std::vector<std::string> tokens;
  for (std::string t; in >> t;) tokens.push_back(t);
  if (!tokens.empty() && lower(tokens[0]) == "list") {
    files = listFiles;
    if (files.empty()) throw InputError(path, w, "'data file: LIST' is followed by no file names");
  } else if (tokens.size() >= 4 && value.find('%') != std::string::npos) {
    // "PATTERN MIN MAX STEP": whole numbers, and no more files than slices.
    long long range[3];
    for (int k = 0; k < 3; ++k) {
      char* end = nullptr;
      errno = 0;
      range[k] = std::strtoll(tokens[size_t(k) + 1].c_str(), &end, 10);
      if (end == tokens[size_t(k) + 1].c_str() || *end != 0 || errno == ERANGE || std::llabs(range[k]) > 1000000000LL)
        throw InputError(path, w, "'" + tokens[size_t(k) + 1].substr(0, 32) +
                                      "' is not a whole number from -1e9 to 1e9 (data file: PATTERN MIN MAX STEP)");
    }
    const long long first = range[0], last = range[1], step = range[2];
    // (last - first) / step truncates towards 0: a range like 5 3 5 must be caught by its ends.
    if (step == 0 || (step > 0 ? last < first : last > first)) throw InputError(path, w, "empty or endless file range");
    const long long n = (last - first) / step + 1;
    if (n > h.dims.z) throw InputError(path, w, std::to_string(n) + " data files for " + std::to_string(h.dims.z) + " slices");
    for (long long i = first; step > 0 ? i <= last : i >= last; i += step)
      files.push_back(formatSliceName(tokens[0], long(i), path, w));
  } else {
    files.push_back(value);
  }
  if (totalBytes % files.size() != 0)
    throw InputError(path, w, std::to_string(files.size()) + " data files do not divide the " +
                                  std::to_string(totalBytes) + " bytes of the volume evenly");
  const fs::path dir = fs::path(path).parent_path();
  for (const std::string& f : files) h.files.push_back((dir / f).lexically_normal().string());
  return h;
}

Grid loadNrrd(const std::string& path) {
  const Bytes bytes = readFile(path);
  const NrrdHeader h = *readNrrdHeader(path, bytes, true);
  using Enc = NrrdHeader::Enc;
  const size_t totalBytes = checkedBytes(h.dims, h.type, path);

  // Decodes one data chunk (the attached data, or one data file) after its skips.
  auto decode = [&](Bytes chunk, const std::string& chunkName, size_t expectBytes) -> Bytes {
    size_t p = 0;
    for (long l = 0; l < h.lineSkip; ++l) {
      if (p >= chunk.size()) throw InputError(chunkName, "", "line skip runs past the end of the data");
      while (p < chunk.size() && chunk[p] != '\n') ++p;
      if (p < chunk.size()) ++p;
    }
    chunk.erase(chunk.begin(), chunk.begin() + std::min(p, chunk.size()));
    if (h.enc == Enc::Gzip) chunk = inflateBytes(chunk, chunkName, expectBytes + size_t(std::max(h.byteSkip, 0L)));
    if (h.byteSkip == -1) {
      if (chunk.size() < expectBytes)
        throw InputError(chunkName, "", "data has " + std::to_string(chunk.size()) +
                                            " bytes, header needs " + std::to_string(expectBytes));
      chunk.erase(chunk.begin(), chunk.end() - long(expectBytes));
    } else if (h.byteSkip > 0) {
      if (size_t(h.byteSkip) > chunk.size())
        throw InputError(chunkName, "", "byte skip runs past the end of the data");
      chunk.erase(chunk.begin(), chunk.begin() + h.byteSkip);
    }
    if (h.enc == Enc::Ascii) {
      const size_t n = expectBytes / scalarTypeSize(h.type);
      return asciiToBytes(std::string(chunk.begin(), chunk.end()), h.type, n, chunkName);
    }
    if (chunk.size() != expectBytes)
      throw InputError(chunkName, "", "data has " + std::to_string(chunk.size()) +
                                          " bytes but the header (" + path + ") needs " +
                                          std::to_string(expectBytes));
    return chunk;
  };

  Bytes data;
  if (h.files.empty()) {
    data = decode(Bytes(bytes.begin() + long(h.dataStart), bytes.end()), path, totalBytes);
  } else {
    const size_t per = totalBytes / h.files.size();
    for (const std::string& full : h.files) {
      Bytes part = decode(readFile(full), full, per);
      // Reserved once a file has proved its size: the header alone allocates nothing.
      if (data.empty()) data.reserve(totalBytes);
      data.insert(data.end(), part.begin(), part.end());
    }
  }
  Grid g = makeGrid(h.dims, h.type, data, h.bigEndian, path);
  g.setOrigin(h.origin);
  g.setSpacing(h.spacing);
  return g;
}

// ---------------------------------------------------------------------------------------
// MetaImage (https://itk.org/Wiki/ITK/MetaIO/Documentation)

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

std::optional<MetaHeader> readMetaHeader(const std::string& path, const Bytes& bytes, bool whole) {
  std::map<std::string, std::pair<size_t, std::string>> fields;
  size_t pos = 0, lineNo = 0;
  bool ended = false;
  while (pos < bytes.size()) {
    size_t nl = pos;
    while (nl < bytes.size() && bytes[nl] != '\n') ++nl;
    if (nl == bytes.size() && !whole) return std::nullopt;  // a line cut where the part ends
    const std::string line = trim(std::string(bytes.begin() + pos, bytes.begin() + nl));
    pos = nl + 1;
    ++lineNo;
    if (line.empty()) continue;
    const auto eq = line.find('=');
    if (eq == std::string::npos)
      throw InputError(path, "line " + std::to_string(lineNo), "expected 'Key = Value'");
    const std::string key = trim(line.substr(0, eq));
    fields[key] = {lineNo, trim(line.substr(eq + 1))};
    if (key == "ElementDataFile") {  // by the format, the last header field
      ended = true;
      break;
    }
  }
  if (!ended && !whole) return std::nullopt;
  auto where = [&](const std::string& key) { return "line " + std::to_string(fields[key].first); };
  auto require = [&](const std::string& key) -> std::string {
    if (!fields.count(key)) throw InputError(path, "header", "missing required field '" + key + "'");
    return fields[key].second;
  };
  MetaHeader h;
  if (require("NDims") != "3")
    throw InputError(path, where("NDims"), "only 3-dimensional images are supported");
  h.dims = toDims(parseNumbers(require("DimSize"), path, where("DimSize"), 3), path, where("DimSize"));
  const std::string typeName = require("ElementType");
  if (typeName == "MET_UCHAR") h.type = ScalarType::UInt8;
  else if (typeName == "MET_USHORT") h.type = ScalarType::UInt16;
  else if (typeName == "MET_SHORT") h.type = ScalarType::Int16;
  else if (typeName == "MET_FLOAT") h.type = ScalarType::Float32;
  else throw InputError(path, where("ElementType"), "unsupported element type '" + typeName +
                                                        "' (supported: MET_UCHAR, MET_USHORT, MET_SHORT, MET_FLOAT)");
  if (fields.count("ElementNumberOfChannels") && fields["ElementNumberOfChannels"].second != "1")
    throw InputError(path, where("ElementNumberOfChannels"), "only single-channel images are supported");
  for (const char* key : {"ElementSpacing", "ElementSize"}) {
    if (fields.count(key)) {
      auto s = parseNumbers(fields[key].second, path, where(key), 3);
      h.spacing = {s[0], s[1], s[2]};
      checkSpacing(h.spacing, path, where(key));
      break;
    }
  }
  for (const char* key : {"Offset", "Origin", "Position"}) {
    if (fields.count(key)) {
      auto o = parseNumbers(fields[key].second, path, where(key), 3);
      h.origin = {o[0], o[1], o[2]};
      break;
    }
  }
  for (const char* key : {"ElementByteOrderMSB", "BinaryDataByteOrderMSB"})
    if (fields.count(key)) h.bigEndian = lower(fields[key].second) == "true";
  h.compressed = fields.count("CompressedData") && lower(fields["CompressedData"].second) == "true";
  const std::string dataFile = require("ElementDataFile");
  if (dataFile == "LOCAL") {
    h.dataFile = path;
    h.dataStart = std::min(pos, bytes.size());
  } else if (dataFile.rfind("LIST", 0) == 0 || dataFile.find('%') != std::string::npos) {
    throw InputError(path, where("ElementDataFile"), "multi-file MetaImage data is not supported");
  } else {
    h.dataFile = (fs::path(path).parent_path() / dataFile).lexically_normal().string();
  }
  checkedBytes(h.dims, h.type, path);
  if (fields.count("HeaderSize") && dataFile != "LOCAL") {
    h.skipWhere = where("HeaderSize");
    const double v = parseNumbers(fields["HeaderSize"].second, path, h.skipWhere, 1)[0];
    if (!(v >= -1 && v <= 1e15) || v != std::floor(v))
      throw InputError(path, h.skipWhere, "HeaderSize must be a whole number from -1 to 1e15");
    h.skip = long(v);
  }
  return h;
}

Grid loadMetaImage(const std::string& path) {
  const Bytes bytes = readFile(path);
  const MetaHeader h = *readMetaHeader(path, bytes, true);
  Bytes data;
  if (h.dataFile == path)
    data.assign(bytes.begin() + long(h.dataStart), bytes.end());
  else
    data = readFile(h.dataFile);
  const size_t need = checkedBytes(h.dims, h.type, path);
  // A compressed stream may hold at most the header's bytes (after a known skip).
  if (h.compressed) data = inflateBytes(data, path, h.skip == -1 ? need * 2 + (1 << 20) : need + size_t(h.skip));
  if (h.skip != 0) {
    if (h.skip == -1 && data.size() >= need) data.erase(data.begin(), data.end() - long(need));
    else if (h.skip > 0 && size_t(h.skip) > data.size()) throw InputError(path, h.skipWhere, "HeaderSize runs past the end of the data");
    else if (h.skip > 0) data.erase(data.begin(), data.begin() + h.skip);
  }
  Grid g = makeGrid(h.dims, h.type, data, h.bigEndian, path);
  g.setOrigin(h.origin);
  g.setSpacing(h.spacing);
  return g;
}

// ---------------------------------------------------------------------------------------
// Legacy VTK STRUCTURED_POINTS (https://vtk.org/wp-content/uploads/2015/04/file-formats.pdf).
// Binary data is big-endian by the VTK convention.

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

std::optional<VtkHeader> readVtkHeader(const std::string& path, const Bytes& bytes, bool whole) {
  struct PartEnded {};
  size_t pos = 0, lineNo = 0;
  auto nextLine = [&]() -> std::string {
    if (pos >= bytes.size()) {
      if (!whole) throw PartEnded{};
      throw InputError(path, "line " + std::to_string(lineNo + 1), "unexpected end of file in header");
    }
    size_t nl = pos;
    while (nl < bytes.size() && bytes[nl] != '\n') ++nl;
    if (nl == bytes.size() && !whole) throw PartEnded{};
    std::string line(bytes.begin() + pos, bytes.begin() + nl);
    pos = nl + 1;
    ++lineNo;
    return trim(line);
  };
  auto here = [&]() { return "line " + std::to_string(lineNo); };
  VtkHeader h;
  try {
    if (nextLine().rfind("# vtk DataFile", 0) != 0)
      throw InputError(path, "line 1", "not a legacy VTK file (missing '# vtk DataFile' line)");
    nextLine();  // title
    std::string format;
    do { format = nextLine(); } while (format.empty());
    h.binary = format == "BINARY";
    if (!h.binary && format != "ASCII") throw InputError(path, here(), "expected ASCII or BINARY");
    std::string line;
    do { line = nextLine(); } while (line.empty());
    if (line != "DATASET STRUCTURED_POINTS")
      throw InputError(path, here(), "only 'DATASET STRUCTURED_POINTS' is supported, found '" + line + "'");
    bool haveDims = false;
    for (;;) {
      line = nextLine();
      if (line.empty()) continue;
      std::istringstream in(line);
      std::string key;
      in >> key;
      const std::string rest = trim(line.substr(key.size()));
      if (key == "DIMENSIONS") {
        h.dims = toDims(parseNumbers(rest, path, here(), 3), path, here());
        haveDims = true;
      } else if (key == "SPACING" || key == "ASPECT_RATIO") {
        auto s = parseNumbers(rest, path, here(), 3);
        h.spacing = {s[0], s[1], s[2]};
        checkSpacing(h.spacing, path, here());
      } else if (key == "ORIGIN") {
        auto o = parseNumbers(rest, path, here(), 3);
        h.origin = {o[0], o[1], o[2]};
      } else if (key == "POINT_DATA") {
        if (!haveDims) throw InputError(path, here(), "POINT_DATA before DIMENSIONS");
        const double n = parseNumbers(rest, path, here(), 1)[0];
        if (n != double(h.dims.x) * h.dims.y * h.dims.z)
          throw InputError(path, here(), "POINT_DATA count disagrees with DIMENSIONS");
      } else if (key == "SCALARS") {
        std::string name, t;
        int components = 1;
        in >> name >> t;
        if (in >> components && components != 1)
          throw InputError(path, here(), "only single-component scalars are supported");
        if (t == "unsigned_char") h.type = ScalarType::UInt8;
        else if (t == "unsigned_short") h.type = ScalarType::UInt16;
        else if (t == "short") h.type = ScalarType::Int16;
        else if (t == "float") h.type = ScalarType::Float32;
        else throw InputError(path, here(), "unsupported scalar type '" + t +
                                                "' (supported: unsigned_char, unsigned_short, short, float)");
      } else if (key == "LOOKUP_TABLE") {
        break;  // the data follows this line
      } else if (key == "CELL_DATA" || key == "VECTORS" || key == "FIELD") {
        throw InputError(path, here(), "'" + key + "' is not supported; expected SCALARS point data");
      } else {
        throw InputError(path, here(), "unexpected keyword '" + key + "'");
      }
    }
    if (!haveDims) throw InputError(path, here(), "missing DIMENSIONS");
  } catch (const PartEnded&) {
    return std::nullopt;
  }
  checkedBytes(h.dims, h.type, path);
  h.dataStart = std::min(pos, bytes.size());
  return h;
}

Grid loadVtk(const std::string& path) {
  const Bytes bytes = readFile(path);
  const VtkHeader h = *readVtkHeader(path, bytes, true);
  const size_t count = size_t(h.dims.x) * h.dims.y * h.dims.z;
  Bytes data;
  if (h.binary) {
    const size_t need = count * scalarTypeSize(h.type);
    if (bytes.size() - h.dataStart < need)
      throw InputError(path, "", "binary data has " + std::to_string(bytes.size() - h.dataStart) +
                                     " bytes but DIMENSIONS need " + std::to_string(need));
    data.assign(bytes.begin() + long(h.dataStart), bytes.begin() + long(h.dataStart + need));
  } else {
    data = asciiToBytes(std::string(bytes.begin() + long(h.dataStart), bytes.end()), h.type, count, path);
  }
  // ASCII values were converted to native order already.
  Grid g = makeGrid(h.dims, h.type, data, h.binary, path);
  g.setOrigin(h.origin);
  g.setSpacing(h.spacing);
  return g;
}

// ---------------------------------------------------------------------------------------
// NIfTI-1 and NIfTI-2 (https://nifti.nimh.nih.gov/nifti-1, nifti-2): the header through
// libnifti2 (either version, either byte order, single .nii, .hdr/.img pairs, gzip, qform as
// a quaternion), the samples read here like raw ones: straight into the grid for the types the
// grid holds, through one float32 conversion for the others or where scl_slope scales them.

std::string niftiTypeName(int datatype) { return nifti_datatype_string(datatype); }


// The file's samples of one 3D frame, in the file's byte order: `count` bytes from `offset` of
// the image file (inflated as it goes when gzip; the rest of a 4D stream is not inflated).
void readNiftiBytes(const std::string& image, bool gzip, size_t offset, uint8_t* out, size_t count,
                    const std::string& file) {
  if (!gzip) {
    size_t fileSize;
    std::ifstream in = openFile(image, fileSize);  // its size was checked before allocating
    in.seekg(std::streamoff(offset));
    readExactly(in, out, count, image);
    return;
  }
  struct Done {};
  size_t seen = 0, produced = 0;
  try {
    inflateStream(readFile(image), image, [&](const uint8_t* p, size_t n) {
      const size_t skip = seen < offset ? std::min(n, offset - seen) : 0;
      seen += n;
      const size_t take = std::min(n - skip, count - produced);
      std::memcpy(out + produced, p + skip, take);
      produced += take;
      if (produced == count) throw Done{};
    });
  } catch (const Done&) {
  }
  if (produced != count)
    throw InputError(image, "", "decompressed data holds " + std::to_string(produced) + " bytes of samples after byte " +
                                    std::to_string(offset) + ", the header of " + file + " asks for " + std::to_string(count));
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

ToFloat toFloatOf(ScalarType type) {
  switch (type) {
    case ScalarType::UInt8: return toFloat<uint8_t>;
    case ScalarType::UInt16: return toFloat<uint16_t>;
    case ScalarType::Int16: return toFloat<int16_t>;
    case ScalarType::Float32: break;
  }
  return toFloat<float>;
}

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
  bool gzip = false, swap = false;
  double affine[3][4] = {};
  std::string image, where, format;
  std::vector<std::string> notes;
};

ToFloat niftiToFloat(int datatype) {
  switch (datatype) {
    case DT_UINT8: return toFloat<uint8_t>;
    case DT_INT8: return toFloat<int8_t>;
    case DT_INT16: return toFloat<int16_t>;
    case DT_UINT16: return toFloat<uint16_t>;
    case DT_INT32: return toFloat<int32_t>;
    case DT_UINT32: return toFloat<uint32_t>;
    case DT_INT64: return toFloat<int64_t>;
    case DT_UINT64: return toFloat<uint64_t>;
    case DT_FLOAT32: return toFloat<float>;
  }
  return toFloat<double>;
}

NiftiLayout readNiftiLayout(const std::string& path) {
  size_t fileSize;
  openFile(path, fileSize);  // missing file or a directory: the usual errors
  nifti_set_debug_level(0);
  int version = 0;
  // (In a child process whose stderr is muted: libnifti prints some errors whatever its debug
  // level, and isotrace says what is wrong itself, in one line.)
  std::unique_ptr<nifti_image, void (*)(nifti_image*)> nim(nifti_image_read(path.c_str(), 0), nifti_image_free);
  if (nim) std::free(nifti_read_header(path.c_str(), &version, 0));  // nifti_type tells the layout, not the version
  if (!nim)
    throw InputError(path, "header", "not a readable NIfTI-1 or NIfTI-2 header (or its image file is missing)");
  NiftiLayout out;
  out.format = nim->nifti_type == NIFTI_FTYPE_ANALYZE ? "ANALYZE 7.5" : version == 2 ? "NIfTI-2" : "NIfTI-1";
  int64_t frames = 1;
  for (int d = 4; d <= 7 && d <= nim->dim[0]; ++d) {
    if (nim->dim[d] < 1) throw InputError(path, "dim[" + std::to_string(d) + "]", "must be at least 1");
    if (frames > (int64_t(1) << 40) / nim->dim[d]) throw InputError(path, "dim", "too many frames");
    frames *= nim->dim[d];
  }
  for (int64_t n : {nim->nx, nim->ny, nim->nz})
    if (n < 1 || n > (1 << 20)) throw InputError(path, "dim", "each of the first three sizes must be 1 to 2^20");
  out.dims = Vec3i{int(nim->nx), int(nim->ny), int(nim->nz)};
  checkDims(out.dims, path, "dim");
  if (frames > 1) out.notes.push_back("frame 0 of " + std::to_string(frames) + " (a volume is one 3D frame)");

  out.datatype = nim->datatype;
  switch (nim->datatype) {
    case DT_UINT8: out.native = ScalarType::UInt8; break;
    case DT_INT16: out.native = ScalarType::Int16; break;
    case DT_UINT16: out.native = ScalarType::UInt16; break;
    case DT_FLOAT32: out.native = ScalarType::Float32; break;
    case DT_INT8: case DT_INT32: case DT_UINT32: case DT_INT64: case DT_UINT64: case DT_FLOAT64:
      out.native = ScalarType::Float32;
      out.direct = false;
      break;
    default:
      throw InputError(path, "datatype", "NIfTI type " + niftiTypeName(nim->datatype) +
                                             " is not supported (one scalar per voxel: integers or floats)");
  }
  int nbyper = 0, swapsize = 0;
  nifti_datatype_sizes(nim->datatype, &nbyper, &swapsize);
  out.sampleSize = size_t(nbyper);
  // scl_slope 0 means "not scaled" (the standard); otherwise every value is slope * v + inter.
  const double slope = nim->scl_slope, inter = nim->scl_inter;
  const bool scaled = slope != 0 && std::isfinite(slope) && !(slope == 1 && inter == 0);
  if (slope != 0 && (!std::isfinite(slope) || !std::isfinite(inter)))
    throw InputError(path, "scl_slope", "scaling is not finite");
  if (scaled) {
    out.direct = false;
    out.native = ScalarType::Float32;
    out.slope = slope;
    out.inter = inter;
    out.notes.push_back("values scaled by scl_slope " + std::to_string(slope) + ", scl_inter " + std::to_string(inter));
  } else if (!out.direct) {
    out.notes.push_back(niftiTypeName(nim->datatype) + " samples held as float32");
  }
  if (nim->iname_offset < 0) throw InputError(path, "vox_offset", "is negative");
  out.offset = size_t(nim->iname_offset);
  out.image = nim->iname ? nim->iname : path;
  out.gzip = nifti_is_gzfile(out.image.c_str());
  out.swap = nim->byteorder != nifti_short_order();

  // Where the voxels are: the sform if it has a code, else the qform, else the voxel sizes
  // alone (ANALYZE's convention, and NIfTI's "method 1").
  const bool sform = nim->sform_code > 0, qform = !sform && nim->qform_code > 0;
  if (sform || qform) {
    const nifti_dmat44& m = sform ? nim->sto_xyz : nim->qto_xyz;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) out.affine[r][c] = m.m[r][c];
  } else {
    out.affine[0][0] = nim->dx > 0 ? nim->dx : 1;
    out.affine[1][1] = nim->dy > 0 ? nim->dy : 1;
    out.affine[2][2] = nim->dz > 0 ? nim->dz : 1;
  }
  out.where = sform ? "srow_x/y/z" : qform ? "quatern_b/c/d, qoffset" : "pixdim";
  out.notes.push_back(std::string(sform ? "sform" : qform ? "qform" : "no affine, pixdim only") + " (" +
                      (sform ? nifti_xform_string(nim->sform_code) : qform ? nifti_xform_string(nim->qform_code) : "voxel sizes") +
                      "): " + describeAffine(out.affine));
  return out;
}

// A NiftiLayout through a child process's report: its numbers, then its strings one per line
// (a file name holding a line break is refused).
std::string packNiftiLayout(const NiftiLayout& l) {
  std::string s;
  auto put = [&](const auto& v) { s.append(reinterpret_cast<const char*>(&v), sizeof v); };
  put(l.dims), put(l.datatype), put(l.sampleSize), put(l.native), put(l.direct), put(l.slope), put(l.inter);
  put(l.offset), put(l.gzip), put(l.swap), put(l.affine);
  for (const std::string* text : {&l.image, &l.where, &l.format}) {
    if (text->find('\n') != std::string::npos) throw InputError(l.image, "", "a file name with a line break");
    s += *text + '\n';
  }
  for (const std::string& note : l.notes) s += note + '\n';
  return s;
}

NiftiLayout unpackNiftiLayout(const std::string& s, const std::string& path) {
  NiftiLayout l;
  size_t at = 0;
  auto get = [&](auto& v) {
    if (s.size() - at < sizeof v) throw InputError(path, "", "libnifti's reader gave back a malformed header");
    std::memcpy(&v, s.data() + at, sizeof v);
    at += sizeof v;
  };
  get(l.dims), get(l.datatype), get(l.sampleSize), get(l.native), get(l.direct), get(l.slope), get(l.inter);
  get(l.offset), get(l.gzip), get(l.swap), get(l.affine);
  std::istringstream lines(s.substr(at));
  std::getline(lines, l.image);
  std::getline(lines, l.where);
  std::getline(lines, l.format);
  for (std::string line; std::getline(lines, line);) l.notes.push_back(line);
  return l;
}

// The volume of a NIfTI layout: the samples read here like raw ones, straight into the grid for
// the types the grid holds, through one float32 conversion for the others or where scl_slope
// scales them.
VolumeFile loadNifti(const std::string& path) {
  const NiftiLayout l = readNiftiLayout(path);
  VolumeFile out;
  out.format = l.format;
  out.notes = l.notes;
  const Vec3i dims = l.dims;
  const size_t voxels = size_t(dims.x) * size_t(dims.y) * size_t(dims.z);
  const size_t fileBytes = voxels * l.sampleSize;
  const size_t gridBytes = checkedBytes(dims, l.native, path);
  size_t imageSize;
  openFile(l.image, imageSize);
  if (l.gzip) checkInflatable(imageSize, fileBytes, path);
  if (!l.gzip) {  // the size is known before anything is allocated
    if (imageSize < l.offset || imageSize - l.offset < fileBytes)
      throw InputError(l.image, "", "holds " + std::to_string(imageSize > l.offset ? imageSize - l.offset : 0) +
                                        " bytes of samples after byte " + std::to_string(l.offset) + ", the header of " +
                                        path + " asks for " + std::to_string(fileBytes));
  }
  std::shared_ptr<uint8_t[]> samples = allocateSamples(gridBytes);
  if (l.direct) {
    readNiftiBytes(l.image, l.gzip, l.offset, samples.get(), fileBytes, path);
    finishSamples(samples.get(), l.native, dims, l.swap, path);
  } else {
    Bytes raw(fileBytes);
    readNiftiBytes(l.image, l.gzip, l.offset, raw.data(), fileBytes, path);
    niftiToFloat(l.datatype)(raw.data(), reinterpret_cast<float*>(samples.get()), voxels, l.swap, l.slope, l.inter);
    finishSamples(samples.get(), l.native, dims, false, path);  // NaN, Inf and float overflow are errors
  }
  out.grid = Grid(dims, l.native, std::shared_ptr<const void>(samples, samples.get()));
  placeByAffine(l.affine, out.grid, out.toWorld, path, l.where);
  return out;
}

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

// Opens a raw file of `dims` samples of `type`: whether it is gzip (its first two bytes), and
// checked against that size (a plain file exactly, a gzip one for a plausible ratio).
std::ifstream openRawFile(const std::string& path, const Vec3i& dims, ScalarType type, bool& gzip) {
  const size_t expected = checkedBytes(dims, type, path);
  size_t fileSize;
  std::ifstream in = openFile(path, fileSize);
  char magic[2] = {0, 0};
  in.read(magic, 2);
  gzip = in.gcount() == 2 && uint8_t(magic[0]) == 0x1f && uint8_t(magic[1]) == 0x8b;
  if (!gzip && fileSize != expected) throw InputError(path, "", sizeMismatch(dims, type, fileSize, expected));
  if (gzip) checkInflatable(fileSize, expected, path);
  return in;
}

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
std::optional<SampleRuns> sampleRunsOf(const std::string& path, const RawLayout& layout) {
  const std::string name = lower(fs::path(path).filename().string());
  const bool nrrd = endsWith(name, ".nrrd") || endsWith(name, ".nhdr"), meta = endsWith(name, ".mhd") || endsWith(name, ".mha");
  const bool vtk = endsWith(name, ".vtk"), nifti = isNiftiName(name);
  if ((!isRawName(name) && !nrrd && !meta && !vtk && !nifti) || checkInputFile(path, "file").stream) return std::nullopt;
  SampleRuns s;
  if (nifti) {
    const NiftiLayout l = unpackNiftiLayout(
        runInChildProcess(path, "libnifti", [&](int) { return packNiftiLayout(readNiftiLayout(path)); }).report, path);
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
    const bool gzip = data.size() >= 2 && data[0] == 0x1f && data[1] == 0x8b;
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

}  // namespace

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

std::optional<BrickGrid> fileBrickRanges(const std::string& path, const RawLayout& layout, const VolumePart& part) {
  if (isDicomPath(path)) return dicomBrickRanges(path, part.series);
  if (endsWith(lower(fs::path(path).filename().string()), ".vdb")) return vdbBrickRanges(path, part.grid);
  const std::optional<SampleRuns> runs = sampleRunsOf(path, layout);
  if (!runs) return std::nullopt;
  return runsBrickRanges(*runs);
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
  if (window && (folder || isDicomPath(path))) return loadDicom(path, part.series, window);
  if (window && endsWith(name, ".vdb")) return loadVdb(path, part.grid, false, window);
  if (window) {
    if (const std::optional<SampleRuns> runs = sampleRunsOf(path, layout)) {
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
    return readInChildProcess(path, "libnifti", [&] { return loadNifti(path); });
  if (isRawName(name)) return wrap(loadRaw(path, layout), "raw");
  if (endsWith(name, ".dcm") || endsWith(name, ".dicom")) return loadDicom(path, part.series);
  if (endsWith(name, ".vdb")) return loadVdb(path, part.grid);
  const std::string ext = fs::path(name).extension().string();
  throw InputError(path, "", (ext.empty() ? std::string("no file extension") : "unknown volume extension '" + ext + "'") +
                                 " (supported: " + volumeExtensions() + ")");
}

}  // namespace iso
