#include "volume/formats.h"

#include <cerrno>
#include <cmath>
#include <filesystem>
#include <map>
#include <sstream>

namespace iso::reading {

namespace fs = std::filesystem;
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

}  // namespace iso::reading
