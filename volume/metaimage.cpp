#include "volume/formats.h"

#include <cmath>
#include <filesystem>
#include <map>

namespace iso::reading {

namespace fs = std::filesystem;
// MetaImage (https://itk.org/Wiki/ITK/MetaIO/Documentation)

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

}  // namespace iso::reading
