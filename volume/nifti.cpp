#include "volume/formats.h"

#include <cmath>
#include <sstream>

extern "C" {
#include <nifti2_io.h>
}

namespace iso::reading {
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
  // dim[4] is time; dims 5 to 7 (vector components, statistics) are not stepped through: frame 0.
  out.timePoints = nim->dim[0] >= 4 ? int(std::min<int64_t>(nim->dim[4], INT32_MAX)) : 0;
  if (frames > std::max(out.timePoints, 1))
    out.notes.push_back("the first of " + std::to_string(frames / out.timePoints) + " frames per time point (dims 5 to 7)");

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
  put(l.offset), put(l.timePoints), put(l.gzip), put(l.swap), put(l.affine);
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
  get(l.offset), get(l.timePoints), get(l.gzip), get(l.swap), get(l.affine);
  std::istringstream lines(s.substr(at));
  std::getline(lines, l.image);
  std::getline(lines, l.where);
  std::getline(lines, l.format);
  for (std::string line; std::getline(lines, line);) l.notes.push_back(line);
  return l;
}

NiftiLayout niftiLayoutInChild(const std::string& path) {
  return unpackNiftiLayout(
      runInChildProcess(path, "libnifti", [&](int) { return packNiftiLayout(readNiftiLayout(path)); }).report, path);
}

// Where time point `time` begins: frames follow each other from the header's offset. A time point
// past the file's is an error naming dim[4]; one time point of several is noted.
size_t timePointOffset(NiftiLayout& l, int time, const std::string& path) {
  if (time < 0 || time >= std::max(l.timePoints, 1))
    throw InputError(path, "dim[4]", "time point " + std::to_string(time) + " is past the file's " +
                                         std::to_string(std::max(l.timePoints, 1)) + " (counted from 0)");
  if (l.timePoints > 1) l.notes.push_back("time point " + std::to_string(time) + " of " + std::to_string(l.timePoints));
  const unsigned __int128 frame = (unsigned __int128)(uint64_t(l.dims.x) * uint64_t(l.dims.y) * uint64_t(l.dims.z)) * l.sampleSize;
  const unsigned __int128 offset = l.offset + frame * unsigned(time);
  if (offset > (unsigned __int128)(SIZE_MAX / 2)) throw InputError(path, "dim[4]", "time point " + std::to_string(time) + " lies beyond any file size");
  return size_t(offset);
}

// The volume of a NIfTI layout: the samples read here like raw ones, straight into the grid for
// the types the grid holds, through one float32 conversion for the others or where scl_slope
// scales them.
VolumeFile loadNifti(const std::string& path, int time) {
  NiftiLayout l = readNiftiLayout(path);
  l.offset = timePointOffset(l, time, path);
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

}  // namespace iso::reading
