#pragma once
// Volume file loaders: raw (layout given, or read from an Open SciVis file name), gzip raw,
// NRRD (attached/detached headers, raw/gzip/ascii encodings, multi-file `data file:`),
// MetaImage (.mhd/.mha) and legacy VTK STRUCTURED_POINTS. Every failure is an InputError
// naming the file and, where there is one, the header line.
#include <optional>
#include <string>

#include "volume/grid.h"

namespace iso {

// What a headerless raw file needs to be read; a header's own fields win over nothing here.
struct RawLayout {
  std::optional<Vec3i> dims;
  std::optional<ScalarType> type;
  bool bigEndian = false;
};

Grid loadVolumeFile(const std::string& path, const RawLayout& layout = {});

// Parses `name_256x256x128_uint8.raw[.gz]`; false if the name does not follow the convention.
bool parseSciVisName(const std::string& path, Vec3i& dims, ScalarType& type);

}  // namespace iso
