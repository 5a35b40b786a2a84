// Volume and mesh formats people hold their data in: NIfTI (nibabel's test files, which
// Debian's python3-nibabel ships), DICOM (pydicom's test files from python3-pydicom, and a
// series written here from a real CT volume), OBJ (the Cornell box tinyobjloader ships), and
// malformed variants of them.
#include <gdcmAttribute.h>
#include <gdcmReader.h>
#include <gdcmTrace.h>
#include <gdcmWriter.h>
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <zlib.h>

#include <signal.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <filesystem>

#include <cstring>
#include <fstream>
#include <sstream>

#include "scene/gltf.h"
#include "scene/world.h"
#include "tests/test_util.h"
#include "volume/bricks.h"
#include "volume/input_error.h"
#include "volume/iso_surface.h"
#include "volume/loaders.h"

namespace iso {
namespace {

const std::string kNibabel = "/usr/lib/python3/dist-packages/nibabel/tests/data/";

std::string readAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string gunzip(const std::string& data) {
  z_stream zs{};
  inflateInit2(&zs, 16 + MAX_WBITS);
  std::string out;
  char buf[1 << 16];
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
  zs.avail_in = uInt(data.size());
  int rc;
  do {
    zs.next_out = reinterpret_cast<Bytef*>(buf);
    zs.avail_out = sizeof buf;
    rc = inflate(&zs, Z_NO_FLUSH);
    out.append(buf, sizeof buf - zs.avail_out);
  } while (rc == Z_OK);
  inflateEnd(&zs);
  return out;
}

// Expected values come from nibabel (an independent reader), for the first 3D frame:
// nib.load(f); d = get_fdata()[..., 0]; d.sum(), d[1, 2, 1], and the affine.
struct NiftiCase {
  const char* file;
  const char* format;
  Vec3i dims;
  double sum;
  float voxel121;
  double affine[3][4];
  bool instanced;  // rotated, mirrored or sheared: placed by a transform, not origin/spacing
};

void PrintTo(const NiftiCase& c, std::ostream* os) { *os << c.file; }

class NiftiFiles : public ::testing::TestWithParam<NiftiCase> {};

TEST_P(NiftiFiles, ReadLikeNibabel) {
  const NiftiCase& c = GetParam();
  const VolumeFile v = readVolumeFile(kNibabel + c.file);
  EXPECT_EQ(v.format, c.format);
  ASSERT_EQ(v.grid.dims(), c.dims);
  EXPECT_NEAR(v.grid.sum(), c.sum, 1e-6 * std::fabs(c.sum) + 1e-6);
  EXPECT_NEAR(v.grid.value(1, 2, 1), c.voxel121, 1e-3);
  EXPECT_EQ(!v.toWorld.isIdentity(), c.instanced);
  // Voxel (i, j, k) lands where the affine puts it.
  for (Vec3i ijk : {Vec3i{0, 0, 0}, Vec3i{1, 2, 1}, c.dims - Vec3i{1, 1, 1}}) {
    const Vec3d p = v.toWorld.point(v.grid.origin() + Vec3d(ijk) * v.grid.spacing());
    for (int r = 0; r < 3; ++r) {
      const double want = c.affine[r][0] * ijk.x + c.affine[r][1] * ijk.y + c.affine[r][2] * ijk.z + c.affine[r][3];
      EXPECT_NEAR(p[r], want, 1e-3) << "voxel " << ijk.x << " " << ijk.y << " " << ijk.z << " row " << r;
    }
  }
}

const double kOblique[3][4] = {{-2, 0, 0, 117.8551025390625},
                               {0, 1.9737114906311035, -0.35552823543548584, -35.72294235229492},
                               {0, 0.3232076168060303, 2.171081781387329, -7.248798370361328}};

INSTANTIATE_TEST_SUITE_P(
    Nibabel, NiftiFiles,
    ::testing::Values(
        // big-endian int16, x mirrored
        NiftiCase{"anatomical.nii", "NIfTI-1", {33, 41, 25}, 284166082.0, 5215, {{-2, 0, 0, 32}, {0, 2, 0, -40}, {0, 0, 2, -16}}, true},
        // 4D gzip, oblique sform: frame 0
        NiftiCase{"example4d.nii.gz", "NIfTI-1", {128, 96, 24}, 50994397.0, 0,
                  {{kOblique[0][0], kOblique[0][1], kOblique[0][2], kOblique[0][3]},
                   {kOblique[1][0], kOblique[1][1], kOblique[1][2], kOblique[1][3]},
                   {kOblique[2][0], kOblique[2][1], kOblique[2][2], kOblique[2][3]}}, true},
        NiftiCase{"example_nifti2.nii.gz", "NIfTI-2", {32, 20, 12}, 3461748.0, 332,
                  {{kOblique[0][0], kOblique[0][1], kOblique[0][2], kOblique[0][3]},
                   {kOblique[1][0], kOblique[1][1], kOblique[1][2], kOblique[1][3]},
                   {kOblique[2][0], kOblique[2][1], kOblique[2][2], kOblique[2][3]}}, true},
        // int16 scaled by scl_slope/scl_inter into float32
        NiftiCase{"functional.nii", "NIfTI-1", {17, 21, 3}, 3883746.552329719, 3524.096440434456f,
                  {{-4, 0, 0, 32}, {0, 4, 0, -40}, {0, 0, 8, 0}}, true},
        NiftiCase{"standard.nii.gz", "NIfTI-1", {4, 5, 7}, 7650.0, 255, {{1, 0, 0, 0}, {0, 3, 0, 0}, {0, 0, 2, 0}}, false},
        // big-endian float32, axis-aligned: origin and spacing only
        NiftiCase{"reoriented_anat_moved.nii", "NIfTI-1", {21, 26, 22}, 32739769.449157715, 0,
                  {{4, 0, 0, -35.29789733886719}, {0, 4, 0, -47.97758483886719}, {0, 0, 4, -27.599409103393555}}, false}),
    [](const auto& info) {
      std::string n = info.param.file;
      return n.substr(0, n.find('.'));
    });

// Bad input: one line naming the file (or the folder) and what is wrong.
void expectVolumeError(const std::string& path, const std::string& fragment, const VolumePart& part = {}) {
  test::expectRefusal<InputError>([&] { readVolumeFile(path, {}, part); }, path, fragment);
}

// Malformed variants of a real file: each is refused with the place named, nothing crashes.
TEST(NiftiFiles, MalformedVariantsAreNamed) {
  const std::string dir = test::scratchDir();
  const std::string good = gunzip(readAll(kNibabel + "standard.nii.gz"));  // 348-byte header, uint8 4x5x7
  ASSERT_EQ(good.size(), 352u + 140u);
  auto variant = [&](const std::string& name, size_t offset, const std::string& bytes, size_t cut = 0) {
    std::string s = good;
    s.replace(offset, bytes.size(), bytes);
    if (cut) s.resize(cut);
    test::writeBytes(dir + "/" + name, s);
    return dir + "/" + name;
  };
  auto i16 = [](int v) { return std::string{char(v & 0xff), char((v >> 8) & 0xff)}; };
  auto f32 = [](float v) { std::string s(4, '\0'); std::memcpy(s.data(), &v, 4); return s; };
  expectVolumeError(variant("short.nii", 0, "", 400), "bytes of samples after byte 352");
  expectVolumeError(variant("magic.nii", 0, std::string("\x01\x02\x03\x04", 4)), "not a readable NIfTI");
  expectVolumeError(variant("complex.nii", 70, i16(32) + i16(64)), "is not supported");
  expectVolumeError(variant("rgb.nii", 70, i16(128) + i16(24)), "is not supported");
  expectVolumeError(variant("flat.nii", 40, i16(3) + i16(4) + i16(5) + i16(1)), "at least 2 samples");
  expectVolumeError(variant("huge.nii", 40, i16(3) + i16(32767) + i16(32767) + i16(32767)), "bytes of samples");
  // Scaled past float: the first overflowing voxel is named (slope 1e38 times a value of 255).
  expectVolumeError(variant("slope.nii", 112, f32(1e38f)), "infinite value in the data");
  // A float32 file with a NaN: the voxel is named.
  std::string nan = good.substr(0, 352);
  nan.replace(70, 4, i16(16) + i16(32));
  for (int i = 0; i < 4 * 5 * 7; ++i) nan += f32(i == 5 ? std::nanf("") : float(i));
  test::writeBytes(dir + "/nan.nii", nan);
  expectVolumeError(dir + "/nan.nii", "voxel (1, 1, 0): NaN value");
  // A fuzzer finding: 349 bytes of gzip whose header asks for 19 TB (refused before allocating).
  expectVolumeError(std::string(ISOTRACE_SOURCE_DIR) + "/tests/data/hostile/huge_dims_in_349_bytes.nii.gz",
                   "349 bytes of gzip data cannot hold more than");
  // A fuzzer finding: a header on which libnifti overflows a stack buffer; it reads in a child
  // process, so this is one line and isotrace lives on. Whether the overflow trips libnifti's
  // stack protector (the child aborts: "stopped reading it") or libnifti returns no header
  // depends on what the stack held (the sanitizer build sees the second): either is one line.
  const std::string smash = std::string(ISOTRACE_SOURCE_DIR) + "/tests/data/hostile/libnifti_stack_smash.nii.gz";
  try {
    readVolumeFile(smash);
    ADD_FAILURE() << "no error for " << smash;
  } catch (const InputError& e) {
    const std::string msg = e.what();
    EXPECT_EQ(msg.find(smash), 0u) << msg;
    EXPECT_TRUE(msg.find("libnifti stopped reading it") != std::string::npos ||
                msg.find("not a readable NIfTI-1 or NIfTI-2 header") != std::string::npos)
        << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
  // Truncated gzip.
  const std::string gz = readAll(kNibabel + "example4d.nii.gz");
  test::writeBytes(dir + "/cut.nii.gz", gz.substr(0, gz.size() / 3));
  expectVolumeError(dir + "/cut.nii.gz", "compressed data");
}

// ---------------------------------------------------------------------------------------
// DICOM

const std::string kPydicom = "/usr/lib/python3/dist-packages/pydicom/data/test_files/";

// A series written from a real CT volume (headsq, int16 64x64x93): the first `count` slices,
// each a copy of pydicom's CT_small.dcm with its pixels, geometry and UIDs replaced. The
// slices stand tilted (rows along (0.8, 0.6, 0), columns along -z), 1.5 mm apart; file names
// and InstanceNumber are in an order unrelated to the positions, which alone must order them.
struct TestSeries {
  static constexpr double kRow[3] = {0.8, 0.6, 0}, kColumn[3] = {0, 0, -1}, kNormal[3] = {-0.6, 0.8, 0};
  static constexpr double kOrigin[3] = {-40, 25, 110}, kPixel = 3.2, kGap = 1.5;
  Grid source = loadVolumeFile(test::dataPath("volumes/headsq/quarter.nhdr"));
  int count = 12;
  std::string name(int k, const std::string& prefix = "im") const {
    return prefix + std::to_string((k * 7) % count) + ".dcm";
  }
  // Writes slice k (position k along the normal, plus `shift` mm) into `dir` as name(k, prefix).
  void write(const std::string& dir, int k, const std::string& seriesUid = "1.2.826.0.1.3680043.2.1125.1",
             double shift = 0, const std::string& prefix = "im") const {
    std::filesystem::create_directories(dir);
    gdcm::Reader reader;
    reader.SetFileName((kPydicom + "CT_small.dcm").c_str());
    ASSERT_TRUE(reader.Read());
    gdcm::DataSet& ds = reader.GetFile().GetDataSet();
    auto put = [&](const auto& attribute) { ds.Replace(attribute.GetAsDataElement()); };
    gdcm::Attribute<0x0028, 0x0010> rows{uint16_t(source.dims().y)};
    gdcm::Attribute<0x0028, 0x0011> columns{uint16_t(source.dims().x)};
    put(rows);
    put(columns);
    gdcm::Attribute<0x0028, 0x0030> spacing = {{kPixel, kPixel}};
    put(spacing);
    gdcm::Attribute<0x0020, 0x0037> orientation = {{kRow[0], kRow[1], kRow[2], kColumn[0], kColumn[1], kColumn[2]}};
    put(orientation);
    const double along = k * kGap + shift;
    gdcm::Attribute<0x0020, 0x0032> position = {{kOrigin[0] + kNormal[0] * along, kOrigin[1] + kNormal[1] * along,
                                                 kOrigin[2] + kNormal[2] * along}};
    put(position);
    gdcm::Attribute<0x0020, 0x0013> instance{count - k};
    put(instance);
    gdcm::Attribute<0x0028, 0x1052> intercept{-1024};
    gdcm::Attribute<0x0028, 0x1053> slope{1};
    put(intercept);
    put(slope);
    gdcm::DataElement uid(gdcm::Tag(0x0020, 0x000e));
    std::string text = seriesUid;
    if (text.size() % 2) text += '\0';
    uid.SetVR(gdcm::VR::UI);
    uid.SetByteValue(text.data(), uint32_t(text.size()));
    ds.Replace(uid);
    std::vector<int16_t> pixels(size_t(source.dims().x) * source.dims().y);
    for (int y = 0; y < source.dims().y; ++y)
      for (int x = 0; x < source.dims().x; ++x) pixels[size_t(y) * source.dims().x + x] = int16_t(source.value(x, y, k));
    gdcm::DataElement data(gdcm::Tag(0x7fe0, 0x0010));
    data.SetVR(gdcm::VR::OW);
    data.SetByteValue(reinterpret_cast<const char*>(pixels.data()), uint32_t(pixels.size() * 2));
    ds.Replace(data);
    gdcm::Writer writer;
    writer.SetFile(reader.GetFile());
    writer.CheckFileMetaInformationOff();
    writer.SetFileName((dir + "/" + name(k, prefix)).c_str());
    ASSERT_TRUE(writer.Write());
  }
  void writeAll(const std::string& dir) const {
    for (int k = 0; k < count; ++k) write(dir, k);
  }
};

TEST(DicomFiles, ASeriesIsOrderedByPositionAndPlacedInPatientSpace) {
  gdcm::Trace::SetWarning(false);
  const std::string dir = test::scratchDir();
  const TestSeries series;
  series.writeAll(dir);
  test::writeText(dir + "/README.txt", "not a DICOM file: skipped\n");
  const VolumeFile v = readVolumeFile(dir);
  EXPECT_EQ(v.format, "DICOM");
  ASSERT_EQ(v.grid.dims(), (Vec3i{64, 64, series.count}));
  for (int z = 0; z < series.count; ++z)
    for (int y = 0; y < 64; y += 3)
      for (int x = 0; x < 64; x += 3)
        ASSERT_EQ(v.grid.value(x, y, z), series.source.value(x, y, z) - 1024) << x << " " << y << " " << z;
  for (Vec3i ijk : {Vec3i{0, 0, 0}, Vec3i{5, 9, 3}, Vec3i{63, 63, series.count - 1}}) {
    const Vec3d p = v.toWorld.point(v.grid.origin() + Vec3d(ijk) * v.grid.spacing());
    for (int r = 0; r < 3; ++r)
      EXPECT_NEAR(p[r], TestSeries::kOrigin[r] + TestSeries::kRow[r] * TestSeries::kPixel * ijk.x +
                            TestSeries::kColumn[r] * TestSeries::kPixel * ijk.y + TestSeries::kNormal[r] * TestSeries::kGap * ijk.z,
                  1e-6);
  }
}

TEST(DicomFiles, SeriesProblemsAreNamed) {
  gdcm::Trace::SetWarning(false);
  const TestSeries series;
  const std::string dir = test::scratchDir();
  // Two series in one folder: listed; "series" chooses.
  series.writeAll(dir + "/two");
  for (int k = 0; k < 3; ++k) series.write(dir + "/two", k, "1.2.3.4", 0, "other");
  expectVolumeError(dir + "/two", "holds 2 series; choose one with \"series\": 1.2.3.4 (3 files), 1.2.826.0.1.3680043.2.1125.1");
  EXPECT_EQ(readVolumeFile(dir + "/two", {}, VolumePart{"1.2.826.0.1.3680043.2.1125.1", ""}).grid.dims().z, series.count);
  EXPECT_EQ(readVolumeFile(dir + "/two", {}, VolumePart{"1.2.3.4", ""}).grid.dims().z, 3);
  expectVolumeError(dir + "/two", "no series '9.9'; the folder holds 1.2.3.4 (3 files)", {"9.9", ""});
  // A missing slice: uneven gaps, naming the two slices around the hole.
  series.writeAll(dir + "/gap");
  std::filesystem::remove(dir + "/gap/" + series.name(5));
  expectVolumeError(dir + "/gap", "uneven slice gaps: 3 mm between " + dir + "/gap/" + series.name(4) + " and " + dir +
                                     "/gap/" + series.name(6) + ", where the others are 1.5 mm");
  // Two slices at one position.
  series.writeAll(dir + "/dup");
  series.write(dir + "/dup", 3, "1.2.826.0.1.3680043.2.1125.1", 0, "copy");
  expectVolumeError(dir + "/dup", "lie at the same position");
  // A truncated slice: named.
  series.writeAll(dir + "/cut");
  const std::string victim = dir + "/cut/" + series.name(2);
  std::filesystem::resize_file(victim, std::filesystem::file_size(victim) - 3000);
  expectVolumeError(dir + "/cut", series.name(2));
  // Folders without DICOM, single slices, a series key on a non-DICOM file.
  std::filesystem::create_directories(dir + "/empty");
  expectVolumeError(dir + "/empty", "holds no DICOM files");
  expectVolumeError(kPydicom + "CT_small.dcm", "holds a single slice");
  expectVolumeError(kPydicom + "MR_small_RLE.dcm", "holds a single slice");  // RLE decoded, then refused
  // Files on which Debian's GDCM aborts on an assertion (BitsAllocated 1; a broken RT dose):
  // GDCM runs in a child process, so isotrace reports them and lives on.
  expectVolumeError(kPydicom + "liver_1frame.dcm", "GDCM stopped reading it");
  expectVolumeError(kPydicom + "rtdose_1frame.dcm", "GDCM stopped reading it");
  expectVolumeError(kPydicom + "SC_rgb_rle_2frame.dcm", "colour images are not supported");
  expectVolumeError(test::dataPath("volumes/bucky_32x32x32_uint8.raw"), "\"series\" applies to DICOM only", {"1.2", ""});
}

// A data-parallel rank's part of a DICOM volume (loadDicom's window, dicomBrickRanges through
// fileBrickRanges): of a series only the slab's files are decoded (and the first slice's, which
// places the volume); the window is the whole volume's, samples and placement, and the ranges
// are the whole grid's. Of a multi-frame file only the window's box is decoded (GDCM's region
// reader), and its ranges frame by frame.
TEST(DicomFiles, WindowsDecodeOnlyTheirSlab) {
  gdcm::Trace::SetWarning(false);
  const std::string dir = test::scratchDir();
  const TestSeries series;
  series.writeAll(dir + "/s");
  for (int k = 0; k < 3; ++k) series.write(dir + "/s", k, "1.2.3.4", 0, "other");  // a second series beside it
  const VolumePart part{"1.2.826.0.1.3680043.2.1125.1", ""};
  auto expectSame = [](const VolumeFile& whole, const VolumeFile& part, const SampleWindow& w) {
    ASSERT_EQ(part.grid.dims(), whole.grid.dims());
    ASSERT_EQ(part.grid.windowFirst(), w.first);
    ASSERT_EQ(part.grid.windowExtent(), w.extent);
    EXPECT_EQ(part.grid.bytes(), size_t(w.extent.x) * w.extent.y * w.extent.z * 4);
    size_t differ = 0;
    for (int z = w.first.z; z < w.first.z + w.extent.z; ++z)
      for (int y = w.first.y; y < w.first.y + w.extent.y; ++y)
        for (int x = w.first.x; x < w.first.x + w.extent.x; ++x) differ += part.grid.value(x, y, z) != whole.grid.value(x, y, z);
    EXPECT_EQ(differ, 0u);
    EXPECT_EQ(part.grid.origin(), whole.grid.origin());
    EXPECT_EQ(part.grid.spacing(), whole.grid.spacing());
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) EXPECT_EQ(part.toWorld.m[r][c], whole.toWorld.m[r][c]);
    EXPECT_EQ(part.notes, whole.notes);
  };
  auto expectRanges = [](const Grid& whole, const std::optional<BrickGrid>& streamed) {
    ASSERT_TRUE(streamed.has_value());
    const BrickGrid bricks(whole);
    ASSERT_EQ(streamed->size(), bricks.size());
    ASSERT_EQ(streamed->dims(), bricks.dims());
    for (uint32_t b = 0; b < bricks.size(); ++b) {
      EXPECT_EQ(streamed->brickMin(b), bricks.brickMin(b)) << b;
      EXPECT_EQ(streamed->brickMax(b), bricks.brickMax(b)) << b;
    }
  };
  const VolumeFile whole = readVolumeFile(dir + "/s", {}, part);
  expectRanges(whole.grid, fileBrickRanges(dir + "/s", {}, part));
  const int n = series.count;
  const SampleWindow low{{0, 0, 0}, {64, 64, 6}}, high{{0, 0, 5}, {64, 64, n - 5}}, inner{{3, 10, 2}, {40, 30, 4}};
  for (const SampleWindow& w : {low, high, inner}) expectSame(whole, readVolumeFile(dir + "/s", {}, part, &w), w);
  // A rank's World of the series: a window of the whole.
  SceneDesc scene = parseSceneText(R"({"volumes": [{"file": ")" + dir + "/s" +
                                       R"(", "series": "1.2.826.0.1.3680043.2.1125.1", "isosurfaces": [{"value": 0}]}]})",
                                   "s.json");
  scene.dataPart = DataPart{0, 2};
  const World world(scene, IntersectorSpec{});
  const Grid& held = *world.volumes()[0].grid;
  EXPECT_TRUE(held.isWindow());
  EXPECT_LT(held.bytes(), whole.grid.bytes());
  // Slice 9's pixels cut short: the whole volume, its ranges and a window holding it fail naming
  // the file; a window below it decodes only its slab and is read.
  const std::string victim = dir + "/s/" + series.name(9);
  std::filesystem::resize_file(victim, std::filesystem::file_size(victim) - 3000);
  expectVolumeError(dir + "/s", series.name(9), part);
  test::expectRefusal<InputError>([&] { fileBrickRanges(dir + "/s", {}, part); }, dir + "/s/", series.name(9));
  test::expectRefusal<InputError>([&] { readVolumeFile(dir + "/s", {}, part, &high); }, dir + "/s/", series.name(9));
  expectSame(whole, readVolumeFile(dir + "/s", {}, part, &low), low);
  // A window beyond the volume, the other series chosen, no series chosen: named.
  const SampleWindow beyond{{0, 0, 0}, {64, 64, n + 1}};
  test::expectRefusal<InputError>([&] { readVolumeFile(dir + "/s", {}, part, &beyond); }, dir + "/s", "not within the volume's 64x64x12");
  EXPECT_EQ(fileBrickRanges(dir + "/s", {}, VolumePart{"1.2.3.4", ""})->dims(), (Vec3i{64, 64, 3}));
  test::expectRefusal<InputError>([&] { fileBrickRanges(dir + "/s"); }, dir + "/s", "holds 2 series");

  // Multi-frame files, raw and RLE: a window is the whole volume's box, the ranges the whole's.
  for (const char* name : {"rtdose.dcm", "rtdose_rle.dcm"}) {
    SCOPED_TRACE(name);
    const VolumeFile dose = readVolumeFile(kPydicom + name);
    expectRanges(dose.grid, fileBrickRanges(kPydicom + name));
    for (const SampleWindow& w : {SampleWindow{{0, 0, 4}, {10, 10, 6}}, SampleWindow{{2, 3, 0}, {5, 7, 15}}})
      expectSame(dose, readVolumeFile(kPydicom + name, {}, {}, &w), w);
  }
  // A raw multi-frame file cut short: its window and ranges refused, naming it.
  const std::string cut = dir + "/cut.dcm";
  std::filesystem::copy_file(kPydicom + "rtdose.dcm", cut);
  std::filesystem::resize_file(cut, std::filesystem::file_size(cut) - 2000);
  const SampleWindow top{{0, 0, 9}, {10, 10, 6}};
  test::expectRefusal<InputError>([&] { readVolumeFile(cut, {}, {}, &top); }, cut, "a truncated file");
  test::expectRefusal<InputError>([&] { fileBrickRanges(cut); }, cut, "a truncated file");
  // A file of one frame on whose pixels GDCM aborts: its header says enough (one line).
  test::expectRefusal<InputError>([&] { fileBrickRanges(kPydicom + "liver_1frame.dcm"); }, kPydicom + "liver_1frame.dcm",
                                  "holds a single slice");
}

// pydicom's RT dose: 15 frames of 10x10 uint32, scaled by DoseGridScaling 1e-6. Expected
// values from pydicom: (pixel_array * DoseGridScaling).sum() and [frame 1, row 2, column 1].
TEST(DicomFiles, MultiFrameRtDoseMatchesPydicom) {
  for (const char* name : {"rtdose.dcm", "rtdose_rle.dcm"}) {
    const VolumeFile v = readVolumeFile(kPydicom + name);
    ASSERT_EQ(v.grid.dims(), (Vec3i{10, 10, 15})) << name;
    EXPECT_NEAR(v.grid.sum(), 1519.91, 1e-3) << name;
    EXPECT_NEAR(v.grid.value(1, 2, 1), 1.138, 1e-6) << name;
    EXPECT_EQ(v.grid.origin(), (Vec3d{189.43125, 199.43125, -761.87})) << name;
    EXPECT_EQ(v.grid.spacing(), (Vec3d{10, 10, 5})) << name;
    EXPECT_TRUE(v.toWorld.isIdentity()) << name;
  }
}

// ---------------------------------------------------------------------------------------
// OpenVDB

// The Blender smoke frame: one float grid 'density', 71,983 active voxels. Loaded sparse (the
// default) and dense, every sample holds the tree's value at its index and lands where the
// grid's transform puts it.
TEST(VdbFiles, SmokeIsReadAndPlacedByItsTransform) {
  const std::string file = test::dataPath("volumes/smoke.vdb");
  openvdb::initialize();
  openvdb::io::File f(file);
  f.open(false);
  const openvdb::FloatGrid::Ptr grid = openvdb::gridPtrCast<openvdb::FloatGrid>(f.readGrid("density"));
  f.close();
  ASSERT_TRUE(grid);
  auto accessor = grid->getConstAccessor();
  for (bool dense : {false, true}) {
    const VolumeFile v = loadVdb(file, "", dense);
    EXPECT_EQ(v.format, "OpenVDB");
    EXPECT_EQ(v.grid.sparse() != nullptr, !dense);
    // The index of sample (0, 0, 0), from where the placement puts it.
    const openvdb::Vec3d i0 = grid->transform().worldToIndex(
        [&] { const Vec3d p = v.toWorld.point(v.grid.origin()); return openvdb::Vec3d(p.x, p.y, p.z); }());
    const openvdb::Coord first(int(std::lround(i0.x())), int(std::lround(i0.y())), int(std::lround(i0.z())));
    const openvdb::CoordBBox active = grid->evalActiveVoxelBoundingBox();
    for (int a = 0; a < 3; ++a) {
      EXPECT_LT(first[a], active.min()[a]) << "a voxel of background before the active box";
      EXPECT_GT(first[a] + v.grid.dims()[a] - 1, active.max()[a]) << "and after it";
    }
    double sum = 0;
    for (int z = 0; z < v.grid.dims().z; ++z)
      for (int y = 0; y < v.grid.dims().y; ++y)
        for (int x = 0; x < v.grid.dims().x; ++x) {
          const float want = accessor.getValue(first + openvdb::Coord(x, y, z));
          ASSERT_EQ(v.grid.value(x, y, z), want) << x << " " << y << " " << z << (dense ? " dense" : " sparse");
          sum += want;
        }
    EXPECT_GT(sum, 1000.0);  // a real plume, not an empty copy
    for (Vec3i ijk : {Vec3i{0, 0, 0}, Vec3i{10, 20, 30}, v.grid.dims() - Vec3i{1, 1, 1}}) {
      const Vec3d p = v.toWorld.point(v.grid.origin() + Vec3d(ijk) * v.grid.spacing());
      const openvdb::Vec3d want = grid->transform().indexToWorld(first + openvdb::Coord(ijk.x, ijk.y, ijk.z));
      for (int r = 0; r < 3; ++r) EXPECT_NEAR(p[r], want[r], 1e-9);
    }
  }
}

// OpenVDB reads in a forked child (volume/child_process.cpp). fork() copies TBB's scheduler and
// allocator state but not its worker threads: a parallel algorithm in the child could wait for
// ever for a worker that is not there, or for a lock a parent thread held at the fork (it did, in
// CI: Packets.PacketWalk... hung loading smoke.vdb right after a parallel surface build). The child
// enters no TBB (OpenVDB's serial calls, an unregistered accessor, the grid never freed). Here the
// parent's TBB workers are kept busy stealing small tasks while the file is read again and again,
// so that forks land at every moment of their work (before the fix: a hang in 2 of 4 runs).
TEST(VdbFiles, ReadsWhileTheParentsTbbWorkersRun) {
  const std::string file = test::dataPath("volumes/smoke.vdb");
  const Vec3i dims[2] = {loadVdb(file, "", false).grid.dims(), loadVdb(file, "", true).grid.dims()};
  std::atomic<bool> stop{false};
  std::thread busy([&] {
    std::atomic<uint64_t> sink{0};
    while (!stop)
      tbb::parallel_for(tbb::blocked_range<int>(0, 256, 1), [&](const tbb::blocked_range<int>& r) {
        uint64_t x = uint64_t(r.begin());
        for (int i = 0; i < 2000; ++i) x = x * 6364136223846793005ull + 1442695040888963407ull;
        sink += x & 1;
      });
  });
  // A safety net, not a timing assumption: a reader child still there after 300 s is killed, so
  // that its read fails and the test reports it instead of hanging.
  std::mutex m;
  std::condition_variable finished;
  bool done = false;
  std::thread watchdog([&] {
    std::unique_lock<std::mutex> lock(m);
    if (finished.wait_for(lock, std::chrono::seconds(300), [&] { return done; })) return;
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator("/proc", ec)) {
      std::ifstream stat(entry.path() / "stat");
      long pid = 0, parent = 0;
      std::string name, state;
      if (stat >> pid >> name >> state >> parent && parent == long(getpid())) kill(pid_t(pid), SIGKILL);
    }
  });
  int failed = 0;
  for (int i = 0; i < 200 && failed == 0; ++i) {
    try {
      const VolumeFile again = loadVdb(file, "", i % 2 == 1);
      failed += !(again.grid.dims() == dims[i % 2]);
      EXPECT_EQ(again.grid.dims(), dims[i % 2]) << "load " << i;
    } catch (const InputError& e) {
      ADD_FAILURE() << "load " << i << ": " << e.what();
      ++failed;
    }
  }
  {
    std::lock_guard<std::mutex> lock(m);
    done = true;
  }
  finished.notify_one();
  watchdog.join();
  stop = true;
  busy.join();
}

// The sparse grid's traversal against a dense copy of the same samples: the same crossings,
// bit for bit, closest and any hit, across brick seams and against the constant bricks.
TEST(VdbFiles, SparseTraversalIsTheDenseOneBitForBit) {
  const VolumeFile sparse = loadVdb(test::dataPath("volumes/smoke.vdb"));
  ASSERT_TRUE(sparse.grid.sparse());
  const Vec3i d = sparse.grid.dims();
  std::vector<float> copy(sparse.grid.sampleCount());
  for (int z = 0; z < d.z; ++z)
    for (int y = 0; y < d.y; ++y)
      for (int x = 0; x < d.x; ++x) copy[sparse.grid.index(x, y, z)] = sparse.grid.value(x, y, z);
  const Grid dense(d, std::move(copy), sparse.grid.origin(), sparse.grid.spacing());
  const BrickGrid sparseBricks(sparse.grid), denseBricks(dense);
  EXPECT_EQ(sparseBricks.minValue(), denseBricks.minValue());
  EXPECT_EQ(sparseBricks.maxValue(), denseBricks.maxValue());
  for (double iso : {0.05, 0.2, 0.5}) {
    const IsoSurface a(sparse.grid, sparseBricks, iso, IntersectorSpec{}), b(dense, denseBricks, iso, IntersectorSpec{});
    ASSERT_EQ(a.activeBricks(), b.activeBricks());
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(0, 1);
    const Vec3d lo = dense.origin(), size = Vec3d(d - Vec3i{1, 1, 1}) * dense.spacing();
    int hits = 0;
    for (int r = 0; r < 3000; ++r) {
      const Vec3d from = lo + Vec3d{u(rng), u(rng), u(rng)} * size, to = lo + Vec3d{u(rng), u(rng), u(rng)} * size;
      const Vec3d dir = to - from;
      SurfaceHit ha, hb;
      TraversalStats sa, sb;
      const bool fa = a.intersect(from, dir, 0, 1e30, ha, sa), fb = b.intersect(from, dir, 0, 1e30, hb, sb);
      ASSERT_EQ(fa, fb) << r;
      if (fa) {
        ++hits;
        EXPECT_EQ(ha.t, hb.t) << r;
        EXPECT_EQ(ha.normal, hb.normal) << r;
      }
      for (uint32_t p = 0; p < a.activeBricks().size(); p += 7)
        ASSERT_EQ(a.occludedBrick(p, from, dir, 0, 1e30, sa), b.occludedBrick(p, from, dir, 0, 1e30, sb)) << r;
    }
    EXPECT_GT(hits, 100) << iso;
    // Shading normals and values agree as well.
    for (int r = 0; r < 200; ++r) {
      const Vec3d p{u(rng) * (d.x - 1), u(rng) * (d.y - 1), u(rng) * (d.z - 1)};
      EXPECT_EQ(sparse.grid.smoothGradient(p), dense.smoothGradient(p));
      EXPECT_EQ(sparse.grid.interpolate(p), dense.interpolate(p));
    }
  }
}

// A level-set sphere written here beside a vector grid: the first scalar grid is the default,
// "grid" picks by name, and the wrong names are listed.
TEST(VdbFiles, GridsAreChosenByNameAndTheirErrorsNamed) {
  openvdb::initialize();
  const std::string dir = test::scratchDir();
  openvdb::FloatGrid::Ptr sphere = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(2.0f, {1, 2, 3}, 0.1f);
  sphere->setName("ball");
  openvdb::Vec3SGrid::Ptr velocity = openvdb::Vec3SGrid::create();
  velocity->setName("vel");
  velocity->tree().setValue(openvdb::Coord(0, 0, 0), openvdb::Vec3s(1, 0, 0));
  openvdb::GridPtrVec grids{velocity, sphere};
  openvdb::io::File(dir + "/two.vdb").write(grids);

  const VolumeFile v = readVolumeFile(dir + "/two.vdb");
  EXPECT_TRUE(v.grid.sparse());
  EXPECT_TRUE(v.toWorld.isIdentity());  // a uniform scale: origin and spacing
  EXPECT_NEAR(v.grid.spacing().x, 0.1, 1e-8);  // the voxel size is a float
  // The centre is inside (negative), the band's far side outside (the background, positive).
  EXPECT_LT(v.grid.interpolate((Vec3d{1, 2, 3} - v.grid.origin()) / v.grid.spacing()), -0.25);
  EXPECT_GT(v.grid.interpolate((Vec3d{1, 2, 0.5} - v.grid.origin()) / v.grid.spacing()), 0.25);
  EXPECT_EQ(readVolumeFile(dir + "/two.vdb", {}, VolumePart{"", "ball"}).grid.dims(), v.grid.dims());
  expectVolumeError(dir + "/two.vdb", "no grid 'smoke'; the file holds ball (float), vel (vec3s)", {"", "smoke"});
  expectVolumeError(dir + "/two.vdb", "grid 'vel': is of type vec3s; float or double grids only", {"", "vel"});
  // Two active voxels 1,200 apart: the dense copy would be 1200^3 samples.
  openvdb::FloatGrid::Ptr far = openvdb::FloatGrid::create(0.f);
  far->tree().setValue(openvdb::Coord(0, 0, 0), 1.f);
  far->tree().setValue(openvdb::Coord(1200, 1200, 1200), 1.f);
  openvdb::io::File(dir + "/far.vdb").write({far});
  // Sparse, two far voxels cost two bricks and a table; dense, the copy is refused.
  const VolumeFile farSparse = readVolumeFile(dir + "/far.vdb");
  // Each voxel is a corner of 8 bricks' blocks (a block holds its far faces too).
  EXPECT_EQ(farSparse.grid.sparse()->blockCount, 16u);
  EXPECT_EQ(farSparse.grid.value(8, 8, 8), 1.f);  // sample 0 is index (-1, -1, -1) moved down to -8
  EXPECT_EQ(farSparse.grid.value(9, 8, 8), 0.f);
  try {
    loadVdb(dir + "/far.vdb", "", true);
    FAIL() << "no error for the dense copy";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("is above 2^30 samples as a dense grid"), std::string::npos) << e.what();
  }
  // Cut and garbage files.
  const std::string bytes = readAll(test::dataPath("volumes/smoke.vdb"));
  test::writeBytes(dir + "/cut.vdb", bytes.substr(0, bytes.size() / 2));
  expectVolumeError(dir + "/cut.vdb", "not a readable OpenVDB file");
  test::writeBytes(dir + "/junk.vdb", std::string(1000, 'x'));
  expectVolumeError(dir + "/junk.vdb", "not a readable OpenVDB file");
  expectVolumeError(test::dataPath("volumes/bucky_32x32x32_uint8.raw"), "\"grid\" applies to .vdb files only", {"", "density"});
}

TEST(VolumeFormats, UnknownExtensionsAreErrorsNotRaw) {
  const std::string dir = test::scratchDir();
  test::writeBytes(dir + "/scan.xyz", std::string(64, '\0'));
  expectVolumeError(dir + "/scan.xyz", "unknown volume extension '.xyz' (supported: .raw");
  test::writeBytes(dir + "/scan", std::string(64, '\0'));
  expectVolumeError(dir + "/scan", "no file extension");
}

// The measured Cornell box as tinyobjloader ships it: 5 MTL materials, the lamp given as an
// ambient colour of 20 (no Ke), the front wall's face commented out.
TEST(ObjFiles, CornellBoxReadsWithItsMaterialsAndLamp) {
  const std::string file = test::dataPath("meshes/cornell/cornell_box.obj");
  const GltfModel m = loadObj(file);
  ASSERT_EQ(m.meshes.size(), 1u);
  size_t triangles = 0;
  Vec3f lo{1e30f, 1e30f, 1e30f}, hi = -lo;
  for (const TriangleMesh& prim : m.meshes[0]) {
    triangles += prim.triangleCount();
    for (const Vec3f& p : prim.positions) lo = min(lo, p), hi = max(hi, p);
    for (uint32_t i : prim.indices) ASSERT_LT(i, prim.positions.size());
  }
  EXPECT_EQ(triangles, 36u);  // 17 quads and 2 triangles
  EXPECT_EQ(lo, (Vec3f{0, 0, 0}));
  EXPECT_EQ(hi, (Vec3f{556, 548.8f, 559.2f}));
  ASSERT_EQ(m.materials.size(), 5u);
  for (const GltfMaterial& g : m.materials) {
    EXPECT_EQ(g.type, MaterialType::Diffuse);
    if (g.name == "red") {
      EXPECT_EQ(g.baseColor, (Vec3f{1, 0, 0}));
    }
    EXPECT_EQ(g.emissive, g.name == "light" ? (Vec3f{20, 20, 20}) : (Vec3f{0, 0, 0})) << g.name;
  }
  ASSERT_EQ(m.warnings.size(), 1u);
  EXPECT_NE(m.warnings[0].find("'light': Ka above 1 without Ke, read as emission"), std::string::npos);
  // In a scene the lamp's two triangles are an area light, the only light.
  const SceneDesc scene = parseSceneText(R"({"meshes": [{"file": ")" + file + R"("}]})", "cornell.json");
  const World world(scene, IntersectorSpec{});
  ASSERT_EQ(world.lights().size(), 1u);
  EXPECT_EQ(world.lights()[0].kind(), Light::Kind::Area);
  EXPECT_EQ(world.lights()[0].triangleCount(), 2u);
}

TEST(ObjFiles, MalformedFilesAreNamed) {
  const std::string dir = test::scratchDir();
  auto expectRefused = [&](const std::string& name, const std::string& text, const std::string& fragment) {
    test::writeText(dir + "/" + name, text);
    test::expectRefusal<InputError>([&] { loadObj(dir + "/" + name); }, dir + "/" + name, fragment);
  };
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  expectRefused("index.obj", tri + "f 1 2 9\n", "face 1: vertex index out of range");
  expectRefused("negative.obj", tri + "f 1 2 -7\n", "face 1: vertex index out of range");
  expectRefused("normal.obj", tri + "vn 0 0 1\nf 1//1 2//1 3//5\n", "face 1: normal index out of range");
  expectRefused("uv.obj", tri + "vt 0 0\no part\nf 1/1 2/1 3/4\n", "shape 'part' face 1: texture index out of range");
  expectRefused("inf.obj", "v 0 0 0\nv 1 1e400 0\nv 0 1 0\nf 1 2 3\n", "vertex 2: coordinate is not finite");
  expectRefused("far.obj", "v 0 0 0\nv 1 2e15 0\nv 0 1 0\nf 1 2 3\n", "vertex 2: coordinate is not finite or beyond 1e15");
  expectRefused("empty.obj", tri, "no faces");
  test::writeText(dir + "/t.mtl", "newmtl m\nKd 0.5 0.5 0.5\nmap_Kd nothere.png\n");
  expectRefused("texture.obj", "mtllib t.mtl\n" + tri + "usemtl m\nf 1 2 3\n", "map_Kd 'nothere.png': file not found");
  test::writeText(dir + "/neg.mtl", "newmtl m\nKd -1 0.5 0.5\n");
  expectRefused("negcolour.obj", "mtllib neg.mtl\n" + tri + "usemtl m\nf 1 2 3\n", "colours must be finite and non-negative");
  // Through the command line: exit status 2, one line, no image.
  test::writeText(dir + "/scene.json", R"({"meshes": [{"file": "index.obj"}]})");
  const test::CommandResult r = test::runIsotrace("render " + dir + "/scene.json -o " + dir + "/out.png");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("index.obj: face 1: vertex index out of range"), std::string::npos) << r.err;
  EXPECT_FALSE(std::ifstream(dir + "/out.png").good());
}

}  // namespace
}  // namespace iso
