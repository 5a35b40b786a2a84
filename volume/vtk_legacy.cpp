#include "volume/formats.h"

#include <sstream>

namespace iso::reading {
// Legacy VTK STRUCTURED_POINTS (https://vtk.org/wp-content/uploads/2015/04/file-formats.pdf).
// Binary data is big-endian by the VTK convention.

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

}  // namespace iso::reading
