// libFuzzer target: the volume readers, whole and as a data-parallel rank reads them (ranges,
// then a window). The first byte picks the container (and, for raw, the layout, and the
// window's place); the rest is the file. Bad input must be an InputError.
#include <cstdint>
#include <string>

#include "fuzz/fuzz_util.h"
#include "volume/input_error.h"
#include "volume/loaders.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  static const char* names[] = {"v.nrrd", "v.nhdr", "v.mhd", "v.vtk", "v_8x4x2_uint8.raw", "v_4x4x4_float32.raw.gz",
                                "v_3x3x3_int16.raw", "v.raw", "v.nii", "v.nii.gz"};
  // DICOM and OpenVDB are left out: GDCM and OpenVDB read in a child process (volume/child_process.cpp)
  // where ASan reports the libraries' own memory errors (as fuzz findings written by the child)
  // and each execution pays a fork. What isotrace does with such a child is tested in
  // tests/formats_test.cpp, and the inputs the fuzzer found are one-line errors (BENCHMARKS.md).
  const std::string name = names[data[0] % 10];
  iso::RawLayout layout;
  if (name == "v.raw") {  // a layout from the scene: small dims, type from the first byte
    layout.dims = iso::Vec3i{2 + (data[0] >> 3 & 3), 3, 2};
    layout.type = data[0] & 0x20 ? iso::ScalarType::UInt16 : iso::ScalarType::Float32;
    layout.bigEndian = data[0] & 0x40;
  }
  const std::string path = iso::fuzz::scratchFile(name, data + 1, size - 1);
  try {
    iso::loadVolumeFile(path, layout);
  } catch (const iso::InputError&) {
  }
  // A data-parallel rank's reads: the brick ranges without the samples, then a window (its
  // place from the first byte) read without the rest.
  try {
    iso::fileBrickRanges(path, layout);
  } catch (const iso::InputError&) {
  }
  const iso::SampleWindow window{{data[0] & 1, data[0] >> 1 & 1, data[0] >> 2 & 3}, {2, 2, 2}};
  try {
    iso::readVolumeFile(path, layout, {}, &window);
  } catch (const iso::InputError&) {
  }
  return 0;
}
