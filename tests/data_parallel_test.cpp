// The groundwork of data-parallel rendering (issue 30): a rank holds only a window of a volume's
// samples (Grid's window, RankBox::windowFirst/Extent), read from the file without the rest, and
// its World answers rays with the hits in its own bricks. The closest of the ranks' answers must
// be the hit a World of the whole volume finds, bit for bit, along whole chains of rays that
// carry their class across the rank seams, and a shadow segment blocked for the whole volume
// exactly when it is for some rank, so that a render split over ranks can give the single
// process's image.
#include <gtest/gtest.h>
#include <zlib.h>

#include <algorithm>
#include <cfloat>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>

#include "accuracy/watertight.h"
#include "renderer/ask_filter.h"
#include "scene/world.h"
#include "volume/bricks.h"
#include "volume/input_error.h"
#include "volume/loaders.h"
#include "volume/partition.h"
#include "volume/procedural.h"
#include "tests/test_util.h"

namespace iso {
namespace {

std::vector<RankBox> boxesOf(const Grid& grid, float iso, int ranks) {
  const BrickGrid bricks(grid);
  std::vector<double> weights(bricks.size(), 0.0);
  for (uint32_t b : bricks.activeBricks(iso)) weights[b] = 1;
  return partitionBricks(bricks, weights, ranks, "test");
}

// Every sample a window holds is the whole grid's, and it holds no more than its window.
void expectWindowOf(const Grid& whole, const Grid& window, const SampleWindow& w) {
  ASSERT_TRUE(window.dims() == whole.dims());
  ASSERT_TRUE(window.windowFirst() == w.first);
  ASSERT_TRUE(window.windowExtent() == w.extent);
  EXPECT_EQ(window.bytes(), size_t(w.extent.x) * w.extent.y * w.extent.z * scalarTypeSize(whole.type()));
  size_t differ = 0;
  for (int z = w.first.z; z < w.first.z + w.extent.z; ++z)
    for (int y = w.first.y; y < w.first.y + w.extent.y; ++y)
      for (int x = w.first.x; x < w.first.x + w.extent.x; ++x) differ += window.value(x, y, z) != whole.value(x, y, z);
  EXPECT_EQ(differ, 0u);
}

TEST(DataParallel, WindowsReadOnlyTheirSamplesAndEqualTheWholeVolume) {
  // A plain raw file (byte ranges), a gzip raw file (one inflated stream) and a format read
  // whole and cut (NRRD).
  for (const char* file : {"volumes/hydrogen_atom_128x128x128_uint8.raw", "volumes/lidc2_chest_ct_256x256x133_uint8.raw.gz",
                           "volumes/nucleon/nucleon.nrrd"}) {
    SCOPED_TRACE(file);
    const std::string path = test::dataPath(file);
    const Grid whole = readVolumeFile(path).grid;
    for (int ranks : {2, 3}) {
      for (const RankBox& box : boxesOf(whole, 40.f, ranks)) {
        const SampleWindow w{box.windowFirst(), box.windowExtent(whole.dims())};
        const Grid window = readVolumeFile(path, {}, {}, &w).grid;
        expectWindowOf(whole, window, w);
        EXPECT_TRUE(window.origin() == whole.origin());
        EXPECT_TRUE(window.spacing() == whole.spacing());
      }
    }
  }
}

// The ranges of a volume's file (fileBrickRanges) are the whole grid's.
void expectRangesOf(const Grid& whole, const std::string& path) {
  const std::optional<BrickGrid> streamed = fileBrickRanges(path);
  ASSERT_TRUE(streamed.has_value());
  const BrickGrid bricks(whole);
  ASSERT_EQ(streamed->size(), bricks.size());
  size_t differ = 0;
  for (uint32_t b = 0; b < bricks.size(); ++b)
    differ += streamed->brickMin(b) != bricks.brickMin(b) || streamed->brickMax(b) != bricks.brickMax(b);
  EXPECT_EQ(differ, 0u);
}

std::string zlibOf(const std::string& bytes) {
  uLongf size = compressBound(uLong(bytes.size()));
  std::string out(size, '\0');
  EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(out.data()), &size, reinterpret_cast<const Bytef*>(bytes.data()),
                      uLong(bytes.size()), 6),
            Z_OK);
  out.resize(size);
  return out;
}

std::string fileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// NRRD, MetaImage and binary VTK files, whose samples lie in runs of bytes, are split like raw
// files: a rank reads only its window, and the ranges from the files in order, a layer at a time.
// Every layout: attached or detached data, one data file or one per slice, raw or compressed, byte
// skips (from the end too), big-endian samples, a MetaImage's LOCAL or compressed data, VTK with
// bytes after the samples, and the real files.
TEST(DataParallel, HeaderFormatWindowsAreReadAlone) {
  const std::string dir = test::scratchDir();
  const std::string neghip = fileBytes(test::dataPath("volumes/neghip_64x64x64_uint8.raw"));
  const std::string head = "dimension: 3\ntype: uchar\nsizes: 64 64 64\nspacings: 1.5 2 2.5\n";
  test::writeText(dir + "/attached.nrrd", "NRRD0004\n" + head + "encoding: raw\nbyte skip: 7\n\n" + std::string(7, 'j') + neghip);
  test::writeText(dir + "/attached_gz.nrrd", "NRRD0004\n" + head + "encoding: gzip\nbyte skip: 5\n\n" + zlibOf("12345" + neghip));
  test::writeText(dir + "/end.raw.data", std::string(13, 'j') + neghip);
  test::writeText(dir + "/end.nhdr", "NRRD0004\n" + head + "encoding: raw\nbyte skip: -1\ndata file: end.raw.data\n");
  // headsq's int16 samples, big-endian, in one detached file.
  const Grid headsq = readVolumeFile(test::dataPath("volumes/headsq/quarter.nhdr")).grid;
  std::string big;
  for (int z = 0; z < headsq.dims().z; ++z)
    for (int y = 0; y < headsq.dims().y; ++y)
      for (int x = 0; x < headsq.dims().x; ++x) {
        const int16_t v = int16_t(headsq.value(x, y, z));
        big += char(uint16_t(v) >> 8);
        big += char(uint16_t(v) & 0xff);
      }
  test::writeText(dir + "/big.bin", big);
  test::writeText(dir + "/big.nhdr", "NRRD0004\ndimension: 3\ntype: short\nsizes: 64 64 93\nendian: big\nencoding: raw\ndata file: big.bin\n");
  const std::string meta = "NDims = 3\nDimSize = 64 64 64\nElementType = MET_UCHAR\nElementSpacing = 1 2 3\nOffset = 10 20 30\n";
  test::writeText(dir + "/local.mhd", meta + "ElementDataFile = LOCAL\n" + neghip);
  test::writeText(dir + "/packed.zraw", zlibOf(neghip));
  test::writeText(dir + "/packed.mhd", meta + "CompressedData = True\nElementDataFile = packed.zraw\n");
  test::writeText(dir + "/skipped.raw", std::string(21, 'j') + neghip);
  test::writeText(dir + "/skipped.mhd", meta + "HeaderSize = -1\nElementDataFile = skipped.raw\n");
  test::writeText(dir + "/trailing.vtk", "# vtk DataFile Version 3.0\nneghip\nBINARY\nDATASET STRUCTURED_POINTS\n"
                                         "DIMENSIONS 64 64 64\nSPACING 1 2 3\nORIGIN 5 6 7\nPOINT_DATA 262144\n"
                                         "SCALARS density unsigned_char 1\nLOOKUP_TABLE default\n" + neghip + "\n");
  for (const std::string& path :
       {dir + "/attached.nrrd", dir + "/attached_gz.nrrd", dir + "/end.nhdr", dir + "/big.nhdr", dir + "/local.mhd",
        dir + "/packed.mhd", dir + "/skipped.mhd", dir + "/trailing.vtk", test::dataPath("volumes/headsq/quarter.nhdr"),
        test::dataPath("volumes/nucleon/nucleon.nrrd"), test::dataPath("volumes/HeadMRVolume.mhd"),
        test::dataPath("volumes/ironProt.vtk")}) {
    SCOPED_TRACE(path);
    const Grid whole = readVolumeFile(path).grid;
    if (path.find(dir) == 0 && path.find("big") == std::string::npos) {  // the neghip ones
      ASSERT_EQ(whole.bytes(), neghip.size());
      EXPECT_EQ(std::memcmp(whole.data(), neghip.data(), neghip.size()), 0);
    }
    expectRangesOf(whole, path);
    for (int ranks : {2, 3})
      for (const RankBox& box : boxesOf(whole, 0.5f * (BrickGrid(whole).minValue() + BrickGrid(whole).maxValue()), ranks)) {
        const SampleWindow w{box.windowFirst(), box.windowExtent(whole.dims())};
        const VolumeFile window = readVolumeFile(path, {}, {}, &w);
        expectWindowOf(whole, window.grid, w);
        EXPECT_TRUE(window.grid.origin() == whole.origin());
        EXPECT_TRUE(window.grid.spacing() == whole.spacing());
      }
  }
  // What is not in runs is read whole and cut, as before: ASCII data, line skips.
  test::writeText(dir + "/ascii.nrrd", "NRRD0004\ndimension: 3\ntype: uchar\nsizes: 2 2 2\nencoding: ascii\n\n1 2 3 4 5 6 7 8\n");
  test::writeText(dir + "/ascii.vtk", "# vtk DataFile Version 3.0\nt\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 2 2\n"
                                      "POINT_DATA 8\nSCALARS s unsigned_char\nLOOKUP_TABLE default\n1 2 3 4 5 6 7 8\n");
  const SampleWindow all{{0, 0, 0}, {2, 2, 2}};
  for (const std::string& path : {dir + "/ascii.nrrd", dir + "/ascii.vtk"}) {
    EXPECT_FALSE(fileBrickRanges(path).has_value()) << path;
    EXPECT_EQ(readVolumeFile(path, {}, {}, &all).grid.value(1, 1, 1), 8.f) << path;
  }
  // A binary VTK file shorter than its DIMENSIONS: one error naming it, nothing allocated first.
  test::writeText(dir + "/short.vtk", "# vtk DataFile Version 3.0\nt\nBINARY\nDATASET STRUCTURED_POINTS\nDIMENSIONS 4000 4000 4000\n"
                                      "SCALARS s float\nLOOKUP_TABLE default\n" + std::string(1000, 'x'));
  const SampleWindow part{{0, 0, 0}, {100, 100, 100}};
  EXPECT_THROW(readVolumeFile(dir + "/short.vtk", {}, {}, &part), InputError);
  EXPECT_THROW(fileBrickRanges(dir + "/short.vtk"), InputError);
}

// NIfTI (libnifti reads the header, in a child process; the samples are read here in runs): a
// window of a NIfTI-1 or -2 file, plain or gzip, 3D or frame 0 of 4D, a .hdr/.img pair, either
// byte order, samples converted (int8/32/64, float64) or scaled by scl_slope into float32, is the
// whole file's window — the same samples, the same placement (spacing, origin, and the affine's
// rotation) and notes —, and its brick ranges are the whole grid's.
TEST(DataParallel, NiftiWindowsAreReadAlone) {
  const std::string nibabel = "/usr/lib/python3/dist-packages/nibabel/tests/data/";
  const std::string dir = test::scratchDir();
  // Hand-made NIfTI-1 files of a real volume's samples (bucky, 32^3) as float64, as int32 (with
  // bytes after them; and as a .hdr/.img pair), and as int16 scaled by scl_slope and scl_inter.
  const std::string bucky = fileBytes(test::dataPath("volumes/bucky_32x32x32_uint8.raw"));
  auto header = [](int datatype, int bitpix, float slope, float inter) {
    std::string h(352, '\0');
    auto put = [&](size_t at, const auto& v) { std::memcpy(h.data() + at, &v, sizeof v); };
    put(0, int32_t(348));
    const int16_t dim[8] = {3, 32, 32, 32, 1, 1, 1, 1};
    put(40, dim);
    put(70, int16_t(datatype));
    put(72, int16_t(bitpix));
    const float pixdim[8] = {1, 0.5f, 0.75f, 1.25f, 1, 1, 1, 1};
    put(76, pixdim);
    put(108, float(352));
    put(112, slope);
    put(116, inter);
    std::memcpy(h.data() + 344, "n+1\0", 4);
    return h;
  };
  std::string f64, i32, i16;
  for (unsigned char c : bucky) {
    const double d = c * 0.25;
    const int32_t i = int32_t(c) * 100000 - 7;
    const int16_t k = int16_t(c - 100);
    f64.append(reinterpret_cast<const char*>(&d), 8);
    i32.append(reinterpret_cast<const char*>(&i), 4);
    i16.append(reinterpret_cast<const char*>(&k), 2);
  }
  test::writeBytes(dir + "/f64.nii", header(64, 64, 0, 0) + f64);
  test::writeBytes(dir + "/i32.nii", header(8, 32, 0, 0) + i32 + std::string(100, 'p'));  // bytes after the samples
  test::writeBytes(dir + "/i16_scaled.nii", header(4, 16, 0.5f, -3) + i16);
  std::string pair = header(8, 32, 0, 0).substr(0, 348);  // a .hdr/.img pair: magic "ni1", samples from byte 0
  std::memcpy(pair.data() + 108, "\0\0\0\0", 4);
  std::memcpy(pair.data() + 344, "ni1\0", 4);
  test::writeBytes(dir + "/pair.hdr", pair);
  test::writeBytes(dir + "/pair.img", i32);
  for (const std::string& path :
       {nibabel + "anatomical.nii", nibabel + "example4d.nii.gz", nibabel + "example_nifti2.nii.gz",
        nibabel + "functional.nii", nibabel + "reoriented_anat_moved.nii", dir + "/pair.hdr",
        test::dataPath("volumes/example4d.nii.gz"), dir + "/f64.nii", dir + "/i32.nii", dir + "/i16_scaled.nii"}) {
    SCOPED_TRACE(path);
    const VolumeFile whole = readVolumeFile(path);
    const Vec3i n = whole.grid.dims();
    expectRangesOf(whole.grid, path);
    const Vec3i half{n.x / 2, n.y / 2, n.z / 2};
    for (const SampleWindow& w : {SampleWindow{{0, 0, 0}, n}, SampleWindow{{0, 0, 0}, {n.x, n.y, half.z + 1}},
                                  SampleWindow{{0, 0, half.z}, {n.x, n.y, n.z - half.z}},
                                  SampleWindow{{1, half.y, 0}, {n.x - 1, n.y - half.y, n.z}}}) {
      const VolumeFile window = readVolumeFile(path, {}, {}, &w);
      expectWindowOf(whole.grid, window.grid, w);
      EXPECT_TRUE(window.grid.origin() == whole.grid.origin());
      EXPECT_TRUE(window.grid.spacing() == whole.grid.spacing());
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c) EXPECT_EQ(window.toWorld.m[r][c], whole.toWorld.m[r][c]);
      EXPECT_EQ(window.format, whole.format);
      EXPECT_EQ(window.notes, whole.notes);
    }
  }
  // The hand-made ones hold bucky's values, converted and scaled as the header says.
  const Grid bucky3 = readVolumeFile(test::dataPath("volumes/bucky_32x32x32_uint8.raw")).grid;
  const SampleWindow upper{{0, 0, 16}, {32, 32, 16}};
  const Grid f = readVolumeFile(dir + "/f64.nii", {}, {}, &upper).grid, s = readVolumeFile(dir + "/i16_scaled.nii", {}, {}, &upper).grid;
  EXPECT_EQ(f.type(), ScalarType::Float32);
  for (int z = 16; z < 32; z += 5)
    for (int y = 0; y < 32; y += 3)
      for (int x = 0; x < 32; x += 7) {
        EXPECT_EQ(f.value(x, y, z), bucky3.value(x, y, z) * 0.25f);
        EXPECT_EQ(s.value(x, y, z), (bucky3.value(x, y, z) - 100) * 0.5f - 3);
      }

  // Bad input, as the whole-file reader reports it: an image file cut short (named, before any
  // allocation), a cut gzip stream, the hostile files the fuzzer found (a stack smash inside
  // libnifti: one line, isotrace lives on; 19 TB asked of 349 bytes).
  test::writeBytes(dir + "/short.nii", header(64, 64, 0, 0) + f64.substr(0, f64.size() / 2));
  const std::string gz = fileBytes(nibabel + "example4d.nii.gz");
  test::writeBytes(dir + "/cut.nii.gz", gz.substr(0, gz.size() / 3));
  const SampleWindow low{{0, 0, 0}, {8, 8, 8}};
  for (const std::string& path : {dir + "/short.nii", dir + "/cut.nii.gz",
                                  std::string(ISOTRACE_SOURCE_DIR) + "/tests/data/hostile/libnifti_stack_smash.nii.gz",
                                  std::string(ISOTRACE_SOURCE_DIR) + "/tests/data/hostile/huge_dims_in_349_bytes.nii.gz"}) {
    SCOPED_TRACE(path);
    EXPECT_THROW(fileBrickRanges(path), InputError);
    EXPECT_THROW(readVolumeFile(path, {}, {}, &low), InputError);
  }
}

// OpenVDB: a rank's part of a sparse grid keeps only the blocks of the bricks that reach into its
// window (read in OpenVDB's child process, the rest dropped there); its samples are the whole
// grid's, its bricks wholly held have the whole grid's ranges and no other is active, and the
// ranges of the file (vdbBrickRanges, through fileBrickRanges) are the whole grid's.
TEST(DataParallel, OpenVdbWindowsKeepOnlyTheirBricks) {
  const std::string path = test::dataPath("volumes/smoke.vdb");
  const VolumeFile whole = readVolumeFile(path);
  ASSERT_NE(whole.grid.sparse(), nullptr);
  expectRangesOf(whole.grid, path);
  const BrickGrid bricks(whole.grid);
  // The ranges read a row of bricks at a time (each row's leaves alone, in a child of its own)
  // are the whole grid's.
  const BrickGrid byRows = vdbBrickRanges(path, "", 1);
  ASSERT_EQ(byRows.size(), bricks.size());
  ASSERT_GT(bricks.count().z, 2);
  size_t rangesDiffer = 0;
  for (uint32_t b = 0; b < bricks.size(); ++b)
    rangesDiffer += byRows.brickMin(b) != bricks.brickMin(b) || byRows.brickMax(b) != bricks.brickMax(b);
  EXPECT_EQ(rangesDiffer, 0u);
  for (int ranks : {2, 3}) {
    std::vector<int> activeOn(bricks.size(), 0);
    for (const RankBox& box : boxesOf(whole.grid, 0.2f, ranks)) {
      const SampleWindow w{box.windowFirst(), box.windowExtent(whole.grid.dims())};
      const VolumeFile part = readVolumeFile(path, {}, {}, &w);
      ASSERT_NE(part.grid.sparse(), nullptr);
      ASSERT_TRUE(part.grid.windowFirst() == w.first);
      ASSERT_TRUE(part.grid.windowExtent() == w.extent);
      EXPECT_LT(part.grid.sparse()->blockCount, whole.grid.sparse()->blockCount);
      EXPECT_TRUE(part.grid.origin() == whole.grid.origin());
      EXPECT_TRUE(part.grid.spacing() == whole.grid.spacing());
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c) EXPECT_EQ(part.toWorld.m[r][c], whole.toWorld.m[r][c]);
      size_t differ = 0;
      for (int z = w.first.z; z < w.first.z + w.extent.z; ++z)
        for (int y = w.first.y; y < w.first.y + w.extent.y; ++y)
          for (int x = w.first.x; x < w.first.x + w.extent.x; ++x)
            differ += part.grid.value(x, y, z) != whole.grid.value(x, y, z);
      EXPECT_EQ(differ, 0u);
      const BrickGrid held(part.grid);
      for (uint32_t b = 0; b < bricks.size(); ++b) {
        if (part.grid.holdsCells(bricks.cellBegin(b), bricks.cellEnd(b))) {
          EXPECT_EQ(held.brickMin(b), bricks.brickMin(b));
          EXPECT_EQ(held.brickMax(b), bricks.brickMax(b));
        } else {
          EXPECT_GT(held.brickMin(b), held.brickMax(b)) << "brick " << b << " is not held but has a range";
        }
      }
      for (uint32_t b : held.activeBricks(0.2f)) ++activeOn[b];
    }
    // Every active brick of the whole grid is active on exactly one rank.
    const std::vector<uint32_t> active = bricks.activeBricks(0.2f);
    ASSERT_FALSE(active.empty());
    for (uint32_t b : active) EXPECT_EQ(activeOn[b], 1) << "brick " << b;
    EXPECT_EQ(std::count(activeOn.begin(), activeOn.end(), 0), long(bricks.size() - active.size()));
  }
  // A window beyond the grid; a file that is not one: one error each.
  const SampleWindow beyond{{0, 0, 0}, {whole.grid.dims().x + 1, 2, 2}};
  EXPECT_THROW(readVolumeFile(path, {}, {}, &beyond), InputError);
  const std::string bad = test::scratchDir() + "/bad.vdb";
  test::writeText(bad, "not a vdb file at all");
  EXPECT_THROW(fileBrickRanges(bad), InputError);
}

// A rank opens only the files that hold its window's rows: a NRRD's slice files outside it may
// even be missing. A file the window needs that is short or corrupt is one error naming it.
TEST(DataParallel, ARankReadsOnlyTheSliceFilesOfItsWindow) {
  namespace fs = std::filesystem;
  const std::string dir = test::scratchDir() + "/headsq";
  fs::create_directories(dir);
  for (const auto& e : fs::directory_iterator(test::dataPath("volumes/headsq")))
    fs::copy_file(e.path(), dir + "/" + e.path().filename().string(), fs::copy_options::overwrite_existing);
  const std::string nhdr = dir + "/quarter.nhdr";
  const Grid whole = readVolumeFile(nhdr).grid;
  fs::remove(dir + "/quarter.93");  // the last slice
  EXPECT_THROW(readVolumeFile(nhdr), InputError);
  EXPECT_THROW(fileBrickRanges(nhdr), InputError);
  const SampleWindow low{{0, 0, 0}, {64, 64, 60}};
  expectWindowOf(whole, readVolumeFile(nhdr, {}, {}, &low).grid, low);
  // Slice 40 cut short: the window that needs it names it; one that does not is read.
  test::writeText(dir + "/quarter.40", std::string(100, 'x'));
  const SampleWindow upper{{0, 0, 30}, {64, 64, 20}};
  try {
    readVolumeFile(nhdr, {}, {}, &upper);
    ADD_FAILURE() << "a short slice file was read";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("quarter.40"), std::string::npos) << e.what();
  }
  const SampleWindow lower{{0, 0, 0}, {64, 64, 39}};
  expectWindowOf(whole, readVolumeFile(nhdr, {}, {}, &lower).grid, lower);
  // A compressed MetaImage stream cut short, a header asking for more than its stream can hold.
  const std::string neghip = fileBytes(test::dataPath("volumes/neghip_64x64x64_uint8.raw"));
  const std::string packed = zlibOf(neghip);
  test::writeText(dir + "/cut.zraw", packed.substr(0, packed.size() / 2));
  test::writeText(dir + "/cut.mhd", "NDims = 3\nDimSize = 64 64 64\nElementType = MET_UCHAR\nCompressedData = True\nElementDataFile = cut.zraw\n");
  const SampleWindow some{{0, 0, 10}, {64, 64, 20}};
  for (const std::string& path : {dir + "/cut.mhd"}) {
    try {
      readVolumeFile(path, {}, {}, &some);
      ADD_FAILURE() << "a cut stream was read";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("cut.zraw"), std::string::npos) << e.what();
    }
    EXPECT_THROW(fileBrickRanges(path), InputError);
  }
  test::writeText(dir + "/bomb.mhd", "NDims = 3\nDimSize = 100000 100000 1000\nElementType = MET_FLOAT\nCompressedData = True\nElementDataFile = cut.zraw\n");
  EXPECT_THROW(fileBrickRanges(dir + "/bomb.mhd"), InputError);
  EXPECT_THROW(readVolumeFile(dir + "/bomb.mhd", {}, {}, &some), InputError);
}

// A procedural field's rank makes only its window, after a pass over the field that keeps only
// the bricks' ranges: both the same bits as from the whole grid.
TEST(DataParallel, ProceduralWindowsAndRangesEqualTheWholeFields) {
  for (Field field : {Field::GyroidBall, Field::MarschnerLobb}) {
    const Vec3i n{41, 34, 27};  // bricks cut short on every axis
    const Grid whole = makeProceduralGrid(field, n);
    const BrickGrid bricks(whole), streamed = proceduralBrickRanges(field, n);
    ASSERT_EQ(streamed.size(), bricks.size());
    for (uint32_t b = 0; b < bricks.size(); ++b) {
      EXPECT_EQ(streamed.brickMin(b), bricks.brickMin(b)) << "brick " << b;
      EXPECT_EQ(streamed.brickMax(b), bricks.brickMax(b)) << "brick " << b;
    }
    EXPECT_EQ(streamed.minValue(), bricks.minValue());
    EXPECT_EQ(streamed.maxValue(), bricks.maxValue());
    for (const RankBox& box : boxesOf(whole, 0.f, 3)) {
      const SampleWindow w{box.windowFirst(), box.windowExtent(n)};
      const Grid window = makeProceduralWindow(field, n, w.first, w.extent);
      expectWindowOf(whole, window, w);
      EXPECT_TRUE(window.origin() == whole.origin());
      EXPECT_TRUE(window.spacing() == whole.spacing());
    }
  }
}

// A plain raw file's ranks read its bricks' ranges a row at a time, then only their window: the
// ranges are the whole grid's, and a rank's World holds its window alone.
TEST(DataParallel, RawFilesAreSplitWithoutBeingHeldWhole) {
  const std::string path = test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw");
  const Grid whole = readVolumeFile(path).grid;
  const BrickGrid bricks(whole);
  const std::optional<BrickGrid> streamed = fileBrickRanges(path);
  ASSERT_TRUE(streamed.has_value());
  ASSERT_EQ(streamed->size(), bricks.size());
  for (uint32_t b = 0; b < bricks.size(); ++b) {
    EXPECT_EQ(streamed->brickMin(b), bricks.brickMin(b)) << "brick " << b;
    EXPECT_EQ(streamed->brickMax(b), bricks.brickMax(b)) << "brick " << b;
  }
  // A gzip file as one stream: the same ranges.
  const std::string gz = test::dataPath("volumes/lidc2_chest_ct_256x256x133_uint8.raw.gz");
  const Grid ct = readVolumeFile(gz).grid;
  const BrickGrid ctBricks(ct);
  const std::optional<BrickGrid> ctStreamed = fileBrickRanges(gz);
  ASSERT_TRUE(ctStreamed.has_value());
  ASSERT_EQ(ctStreamed->size(), ctBricks.size());
  size_t differ = 0;
  for (uint32_t b = 0; b < ctBricks.size(); ++b)
    differ += ctStreamed->brickMin(b) != ctBricks.brickMin(b) || ctStreamed->brickMax(b) != ctBricks.brickMax(b);
  EXPECT_EQ(differ, 0u);
  // Data not in runs (ASCII) is read whole (then cut).
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/ascii.nrrd", "NRRD0004\ndimension: 3\ntype: uchar\nsizes: 2 2 2\nencoding: ascii\n\n1 2 3 4 5 6 7 8\n");
  EXPECT_FALSE(fileBrickRanges(dir + "/ascii.nrrd").has_value());
  // A file shorter than its name says, a gzip stream cut short: one error naming it.
  test::writeText(dir + "/short_16x16x16_uint8.raw", std::string(100, 'x'));
  EXPECT_THROW(fileBrickRanges(dir + "/short_16x16x16_uint8.raw"), InputError);
  {
    std::ifstream in(gz, std::ios::binary);
    const std::string whole((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    test::writeText(dir + "/cut_256x256x133_uint8.raw.gz", whole.substr(0, whole.size() / 2));
  }
  try {
    fileBrickRanges(dir + "/cut_256x256x133_uint8.raw.gz");
    ADD_FAILURE() << "a gzip stream cut short was read";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("cut_256x256x133_uint8.raw.gz"), std::string::npos) << e.what();
  }

  SceneDesc scene = parseSceneText(R"({"volumes": [{"file": ")" + path + R"(", "isosurfaces": [{"value": 20}]}]})", "s.json");
  IntersectorSpec spec;
  size_t held = 0;
  for (int rank = 0; rank < 3; ++rank) {
    scene.dataPart = DataPart{rank, 3};
    const World world(scene, spec);
    const Grid& grid = *world.volumes()[0].grid;
    EXPECT_TRUE(grid.isWindow());
    EXPECT_TRUE(grid.dims() == whole.dims());
    const RankBox box = boxesOf(whole, 20.f, 3)[size_t(rank)];
    EXPECT_TRUE(grid.windowFirst() == box.windowFirst());
    EXPECT_TRUE(grid.windowExtent() == box.windowExtent(whole.dims()));
    EXPECT_LT(grid.bytes(), whole.bytes() / 2);
    held += grid.bytes();
  }
  EXPECT_LT(held, whole.bytes() * 12 / 10);  // the seams' layers twice, little more
}

// `watertight --ranks N`: the checks with each volume split over N parts, each a World of its
// own, at the origin and at 1e5: no error, and the very crossings of the whole volume.
TEST(DataParallel, WatertightAcrossRankSeams) {
  const SceneDesc scene = parseSceneFile(std::string(ISOTRACE_SOURCE_DIR) + "/tests/data/exactness/real_volumes.json");
  IntersectorSpec spec;
  for (const Vec3d offset : {Vec3d{0, 0, 0}, Vec3d{1e5, 1e5, 1e5}}) {
    WatertightOptions options;
    options.rays = 8000;
    options.offset = offset;
    options.rayFlow = RayFlow::Scalar;
    const std::vector<WatertightReport> whole = checkWatertight(scene, spec, options);
    for (int ranks : {2, 3}) {
      options.ranks = ranks;
      const std::vector<WatertightReport> split = checkWatertight(scene, spec, options);
      ASSERT_EQ(split.size(), whole.size());
      for (size_t s = 0; s < split.size(); ++s) {
        EXPECT_EQ(split[s].counts.errors(), 0u) << ranks << " ranks, surface " << s;
        EXPECT_EQ(split[s].counts.crossings, whole[s].counts.crossings) << ranks << " ranks, surface " << s;
        EXPECT_GT(split[s].counts.crossings, 5000u);
      }
    }
  }
  // Seams on faces exactly at the iso value (hydrogen's integer data) add no pair of crossings the
  // double reference does not see (seamClass 0 keeps the class the ray had: a spurious pair per
  // ray that ran inside such a face showed as 17,118 more crossings than the reference at 1e7).
  for (const Vec3d offset : {Vec3d{0, 0, 0}, Vec3d{1e5, 1e5, 1e5}})
    for (int ranks : {1, 3}) {
      WatertightOptions options;
      options.rays = 50000;
      options.offset = offset;
      options.rayFlow = RayFlow::Scalar;
      options.ranks = ranks;
      for (const WatertightReport& r : checkWatertight(scene, spec, options))
        if (r.volume == 0) {
          EXPECT_LE(r.counts.crossings, r.counts.referenceCrossings) << "iso " << r.iso << ", " << ranks << " ranks";
          EXPECT_GE(r.counts.crossings + 10, r.counts.referenceCrossings) << "iso " << r.iso << ", " << ranks << " ranks";
        }
    }
  // A dump says how the volume was split, so that a replay splits it alike.
  const std::string dir = test::scratchDir();
  FailureFile file;
  file.scene = "s.json";
  file.intersector = "isolation:8";
  file.ranks = 3;
  writeFailures(dir + "/f.txt", file);
  EXPECT_EQ(readFailures(dir + "/f.txt").ranks, 3);
  for (const char* bad : {"0", "65", "x"}) {
    test::writeText(dir + "/bad.txt", std::string("# isotrace watertight failures: intersector=isolation:8 ranks=") + bad +
                                          " scene=s.json\n");
    EXPECT_THROW(readFailures(dir + "/bad.txt"), InputError) << bad;
  }
}

// "distribution" in the integrator block: image (the default) or data; anything else is refused.
TEST(DataParallel, DistributionKey) {
  EXPECT_FALSE(parseSceneText(R"({"integrator": {"type": "path"}})", "s.json").settings.dataParallel);
  EXPECT_TRUE(parseSceneText(R"({"integrator": {"distribution": "data"}})", "s.json").settings.dataParallel);
  EXPECT_FALSE(parseSceneText(R"({"integrator": {"distribution": "image"}})", "s.json").settings.dataParallel);
  for (const char* bad : {R"({"integrator": {"distribution": "rays"}})", R"({"integrator": {"distribution": 2}})"}) {
    try {
      parseSceneText(bad, "s.json");
      ADD_FAILURE() << bad;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("s.json: /integrator/distribution"), std::string::npos) << e.what();
    }
  }
}

// "replicate": a fraction in [0, 1]; anything else is refused naming the key, and so is a
// fraction given for a render that is not data-parallel (the flag, or the key) - in one line,
// status 2, no image.
TEST(DataParallel, ReplicateKeyAndFlag) {
  EXPECT_EQ(parseSceneText(R"({"integrator": {"distribution": "data"}})", "s.json").settings.replicate, 0);
  EXPECT_EQ(parseSceneText(R"({"integrator": {"distribution": "data", "replicate": 0.25}})", "s.json").settings.replicate, 0.25);
  for (const char* bad : {R"({"integrator": {"replicate": -0.1}})", R"({"integrator": {"replicate": 1.5}})",
                          R"({"integrator": {"replicate": "all"}})", R"({"integrator": {"replicate": null}})"}) {
    try {
      parseSceneText(bad, "s.json");
      ADD_FAILURE() << bad;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("s.json: /integrator/replicate"), std::string::npos) << e.what();
    }
  }
  const std::string dir = test::scratchDir();
  const std::string volume = test::dataPath("volumes/neghip_64x64x64_uint8.raw");
  const std::string scene = R"({"film": {"width": 16, "height": 12}, "integrator": {"spp": 1},
    "volumes": [{"file": ")" + volume + R"(", "isosurfaces": [{"value": 40}]}]})";
  test::writeText(dir + "/s.json", scene);
  test::writeText(dir + "/image.json", scene.substr(0, scene.find(R"("spp": 1})")) + R"("spp": 1, "replicate": 0.5},)" +
                                           scene.substr(scene.find(R"("spp": 1})") + 10));
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"render " + dir + "/s.json --data-parallel --replicate 1.5", "--replicate"},
      {"render " + dir + "/s.json --data-parallel --replicate -1", "--replicate"},
      {"render " + dir + "/s.json --data-parallel --replicate nan", "--replicate"},
      {"render " + dir + "/s.json --replicate 0.5", "--replicate: copies of other ranks' bricks are for data-parallel"},
      {"render " + dir + "/image.json", "image.json: /integrator/replicate: copies of other ranks' bricks"}};
  for (const auto& [args, what] : cases) {
    SCOPED_TRACE(args);
    const auto r = test::runIsotrace(args + " -o " + dir + "/out.png");
    EXPECT_EQ(r.status, 2) << r.err;
    EXPECT_NE(r.err.find(what), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_FALSE(std::filesystem::exists(dir + "/out.png"));
  }
  // Alone (no launcher) a data-parallel render with copies is the single-process render.
  const auto one = test::runIsotrace("render " + dir + "/s.json --data-parallel --replicate 0.5 --quiet -o " + dir + "/one.png");
  EXPECT_EQ(one.status, 0) << one.err;
}

TEST(DataParallel, WindowsOutsideTheVolumeAreRefusedNamingTheFile) {
  const std::string path = test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw");
  for (const SampleWindow& w : {SampleWindow{{-1, 0, 0}, {10, 10, 10}}, SampleWindow{{0, 0, 0}, {129, 10, 10}},
                                SampleWindow{{120, 0, 0}, {9, 10, 10}}, SampleWindow{{0, 0, 0}, {1, 10, 10}},
                                SampleWindow{{0, 0, 0}, {10, 0, 10}}}) {
    try {
      readVolumeFile(path, {}, {}, &w);
      ADD_FAILURE() << "a window outside the volume was read";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("hydrogen_atom_128x128x128_uint8.raw"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("not within the volume's 128x128x128"), std::string::npos) << e.what();
    }
  }
  // The same for a format cut after reading, and a gzip file that is shorter than its name says.
  const SampleWindow outside{{0, 0, 0}, {500, 2, 2}};
  EXPECT_THROW(readVolumeFile(test::dataPath("volumes/nucleon/nucleon.nrrd"), {}, {}, &outside), InputError);
  const std::string dir = test::scratchDir();
  const std::string truncated = dir + "/short_16x16x16_uint8.raw";
  {
    std::FILE* f = std::fopen(truncated.c_str(), "wb");
    std::vector<uint8_t> bytes(16 * 16 * 15, 7);
    std::fwrite(bytes.data(), 1, bytes.size(), f);
    std::fclose(f);
  }
  const SampleWindow first{{0, 0, 0}, {16, 16, 4}};
  EXPECT_THROW(readVolumeFile(truncated, {}, {}, &first), InputError);  // the size disagrees with the name
}

// The closest of the ranks' hits (their Worlds each hold one window).
bool closestOfRanks(const std::vector<std::unique_ptr<World>>& ranks, const Ray& ray, Hit& best, TraversalStats& stats) {
  bool found = false;
  for (const auto& world : ranks) {
    Hit h;
    if (world->intersect(ray, h, stats) && (!found || h.t < best.t)) {
      best = h;
      found = true;
    }
  }
  return found;
}

TEST(DataParallel, TheClosestOfTheRanksHitsIsTheWholeVolumesHit) {
  // hydrogen: uint8 data and integer iso values put whole edges of exact zeros on the seams.
  const std::string path = test::dataPath("volumes/hydrogen_atom_128x128x128_uint8.raw");
  const char* scene = R"({"volumes": [{"array": 0, "isosurfaces": [{"value": 20}, {"value": 10}, {"value": 40.5}]}]})";
  IntersectorSpec spec;
  for (double offset : {0.0, 1e5}) {
    for (int ranks : {2, 3}) {
      SCOPED_TRACE("offset " + std::to_string(offset) + ", " + std::to_string(ranks) + " ranks");
      Grid whole = readVolumeFile(path).grid;
      whole.setOrigin({offset, offset, offset});
      const SceneArrays wholeArray{std::make_shared<const Grid>(whole)};
      const World single(parseSceneText(scene, "whole.json", {}, &wholeArray), spec);
      std::vector<std::unique_ptr<World>> parts;
      for (const RankBox& box : boxesOf(whole, 20.f, ranks)) {
        SampleWindow w{box.windowFirst(), box.windowExtent(whole.dims())};
        Grid window = readVolumeFile(path, {}, {}, &w).grid;
        window.setOrigin(whole.origin());
        const SceneArrays arrays{std::make_shared<const Grid>(std::move(window))};
        parts.push_back(std::make_unique<World>(parseSceneText(scene, "rank.json", {}, &arrays), spec));
      }
      // Chains of rays from random points in and around the volume: each next ray leaves the
      // last hit carrying its class, as a path's rays do.
      std::mt19937 rng(7);
      std::uniform_real_distribution<double> u(-0.1, 1.1), n(-1, 1);
      size_t hits = 0, differ = 0, blocked = 0, shadowDiffer = 0;
      TraversalStats stats;
      for (int chain = 0; chain < 6000; ++chain) {
        Ray ray;
        ray.org = Vec3f(Vec3d(offset, offset, offset) + Vec3d(u(rng), u(rng), u(rng)) * 127.0);
        // Half in any direction, half towards the middle, where the atom's lobes are.
        Vec3d d;
        if (chain % 2) {
          do d = {n(rng), n(rng), n(rng)}; while (length(d) > 1 || length(d) < 0.1);
        } else {
          const Vec3d target(40 + 48 * (u(rng) + 0.1) / 1.2, 40 + 48 * (u(rng) + 0.1) / 1.2, 40 + 48 * (u(rng) + 0.1) / 1.2);
          d = Vec3d(offset, offset, offset) + target - Vec3d(ray.org);
        }
        if (!(length(d) > 1e-3)) continue;
        ray.dir = Vec3f(normalize(d));
        for (int k = 0; k < 40; ++k) {
          Hit a, b;
          const bool inSingle = single.intersect(ray, a, stats), inParts = closestOfRanks(parts, ray, b, stats);
          const bool same = inSingle == inParts &&
                            (!inSingle || (std::memcmp(&a.position64, &b.position64, sizeof(Vec3d)) == 0 && a.t == b.t &&
                                           a.surface == b.surface && a.insideAfter == b.insideAfter &&
                                           a.normal == b.normal && a.shading == b.shading));
          if (!same) {
            ++differ;
            ADD_FAILURE() << "chain " << chain << " ray " << k << ": single " << inSingle << " t " << a.t << " surface " << a.surface
                          << " after " << a.insideAfter << "; ranks " << inParts << " t " << b.t << " surface " << b.surface
                          << " after " << b.insideAfter << "; from surface " << ray.fromSurface << " inside " << ray.fromInside;
            break;
          }
          // A shadow segment from the ray's origin to a random point: blocked for the whole volume
          // if and only if blocked for some rank.
          Ray shadow = ray;
          shadow.tfar = float(0.05 + 0.9 * (u(rng) + 0.1) / 1.2) * (inSingle ? a.t * 1.5f + 1 : 200.f);
          bool anyRank = false;
          for (const auto& world : parts) anyRank = anyRank || world->occluded(shadow, stats);
          blocked += anyRank;
          shadowDiffer += single.occluded(shadow, stats) != anyRank;
          if (!inSingle) break;
          ++hits;
          ray = spawnRay(a, ray.dir);
        }
      }
      EXPECT_EQ(differ, 0u);
      EXPECT_EQ(shadowDiffer, 0u);
      EXPECT_GT(blocked, 1000u);
      EXPECT_GT(hits, 10000u);  // the chains cross the surfaces and the seams many times
    }
  }
}

// The float test before the double one of whom a rank asks about a ray (renderer/ask_filter.h):
// every ray it calls settled has its segment in the held box, or outside every other box, by a
// test in double with the pad it stands for; and it settles most of the rays that are.
TEST(DataParallel, TheAskFilterSettlesOnlyRaysNobodyIsAsked) {
  // A volume of 64^3 units at 1e3 from the origin, cut across y at 1032: this rank holds y < 1040
  // (its box and a layer of copies), the other's box is y >= 1032.
  const double lo = 1000, hi = 1064, cut = 1032, held = 1040;
  AskFilterVolume v;
  v.held = {{-FLT_MAX, -FLT_MAX, -FLT_MAX}, {FLT_MAX, float(held), FLT_MAX}};
  v.others.push_back({{float(lo), float(cut), float(lo)}, {float(hi), float(hi), float(hi)}});
  const double padPerReach = 1e-5, padFixed = 1e-5 * hi + 1e-4;
  v.padPerReach = float(padPerReach);
  v.padFixed = float(padFixed);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  const size_t n = 20000;
  AskFilterRays rays;
  rays.resize(n);
  for (size_t i = 0; i < n; ++i) {
    // Origins around the volume and on the planes themselves, directions of every kind, ends
    // short, long, at the planes and unbounded.
    Vec3f o{float(lo - 20 + 104 * u(rng)), float(lo - 20 + 104 * u(rng)), float(lo - 20 + 104 * u(rng))};
    if (i % 7 == 0) o.y = float(i % 2 ? cut : held);
    Vec3f d = normalize(Vec3f{float(u(rng) - 0.5), float(u(rng) - 0.5), float(u(rng) - 0.5)});
    if (i % 11 == 0) d.y = 0;
    const float t1 = i % 5 == 0 ? 3.4e38f : float(200 * u(rng) * u(rng));
    rays.ox[i] = o.x, rays.oy[i] = o.y, rays.oz[i] = o.z;
    rays.dx[i] = d.x, rays.dy[i] = d.y, rays.dz[i] = d.z;
    rays.t0[i] = 0, rays.t1[i] = t1;
  }
  std::vector<unsigned char> settled(n, 1);
  filterAsks(rays, n, v, settled.data());
  size_t settledCount = 0, nobody = 0;
  for (size_t i = 0; i < n; ++i) {
    const Vec3d o{rays.ox[i], rays.oy[i], rays.oz[i]}, d{rays.dx[i], rays.dy[i], rays.dz[i]};
    const double t0 = rays.t0[i], t1 = rays.t1[i];
    const double reach = std::max({std::fabs(o.x), std::fabs(o.y), std::fabs(o.z)});
    const double pad = padPerReach * 2 * reach + padFixed;
    const Vec3d p0 = o + d * t0, p1 = o + d * t1;
    // (The held box is open on x and z: the volume ends there, so nothing lies beyond.)
    const bool inHeld = p0.y <= held - pad && p1.y <= held - pad;
    double a0 = -INFINITY, a1 = INFINITY;
    const bool meets = lineInBox(o, d, Vec3d{lo - pad, cut - pad, lo - pad}, Vec3d{hi + pad, hi + pad, hi + pad}, a0, a1) &&
                       std::max(a0, t0) <= std::min(a1, t1);
    const bool askedOfNobody = inHeld || !meets;
    nobody += askedOfNobody;
    if (settled[i]) {
      ++settledCount;
      EXPECT_TRUE(askedOfNobody) << "ray " << i << " settled but reaches the other box";
    }
  }
  EXPECT_GT(settledCount, nobody * 8 / 10) << "the filter should settle most rays asked of nobody";
  EXPECT_LT(settledCount, n);
}

}  // namespace
}  // namespace iso
