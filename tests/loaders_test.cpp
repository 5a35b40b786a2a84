#include <gtest/gtest.h>
#include <zlib.h>

#include <cstring>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>

#include "tests/test_util.h"
#include "volume/input_error.h"
#include "volume/loaders.h"
#include "volume/procedural.h"

namespace iso {
namespace {

using test::dataPath;

// Expected sums and one voxel per file were computed independently with Python from the
// raw bytes (struct/gzip modules), not with this loader.
struct RealFile {
  const char* path;
  Vec3i dims;
  ScalarType type;
  double sum;
  Vec3i voxel;
  float value;
  Vec3d spacing;
};

void PrintTo(const RealFile& f, std::ostream* os) { *os << f.path; }

class RealVolumeFiles : public ::testing::TestWithParam<RealFile> {};

TEST_P(RealVolumeFiles, LoadWithTheRightLayoutAndValues) {
  const RealFile& f = GetParam();
  const Grid g = loadVolumeFile(dataPath(std::string("volumes/") + f.path));
  EXPECT_EQ(g.dims(), f.dims);
  EXPECT_EQ(g.type(), f.type);
  EXPECT_DOUBLE_EQ(g.sum(), f.sum);
  EXPECT_EQ(g.value(f.voxel.x, f.voxel.y, f.voxel.z), f.value);
  EXPECT_NEAR(g.spacing().x, f.spacing.x, 1e-12);
  EXPECT_NEAR(g.spacing().y, f.spacing.y, 1e-12);
  EXPECT_NEAR(g.spacing().z, f.spacing.z, 1e-12);
}

INSTANTIATE_TEST_SUITE_P(
    Shared, RealVolumeFiles,
    ::testing::Values(
        RealFile{"bucky_32x32x32_uint8.raw", {32, 32, 32}, ScalarType::UInt8, 1174726, {16, 16, 16}, 1, {1, 1, 1}},
        RealFile{"nucleon/nucleon.nrrd", {41, 41, 41}, ScalarType::UInt8, 2715326, {20, 20, 20}, 8, {1, 1, 1}},
        RealFile{"neghip_64x64x64_uint8.raw", {64, 64, 64}, ScalarType::UInt8, 4824177, {32, 32, 32}, 0, {1, 1, 1}},
        RealFile{"hydrogen_atom_128x128x128_uint8.raw", {128, 128, 128}, ScalarType::UInt8, 5990975, {64, 64, 64}, 62, {1, 1, 1}},
        RealFile{"headsq/quarter.nhdr", {64, 64, 93}, ScalarType::Int16, 193392317, {32, 32, 46}, 122, {3.2, 3.2, 1.5}},
        RealFile{"HeadMRVolume.mhd", {48, 62, 42}, ScalarType::UInt8, 3058332, {24, 31, 21}, 79, {4, 4, 4}},
        RealFile{"ironProt.vtk", {68, 68, 68}, ScalarType::UInt8, 4131089, {34, 34, 34}, 131, {1, 1, 1}},
        RealFile{"lidc2_chest_ct_256x256x133_uint8.raw.gz", {256, 256, 133}, ScalarType::UInt8, 61489178, {128, 128, 66}, 128, {1, 1, 1}}),
    [](const auto& info) {
      std::string n = info.param.path;
      return n.substr(0, n.find_first_of("_./"));
    });

TEST(Loaders, SciVisNamesCarryTheLayout) {
  Vec3i dims;
  ScalarType type;
  ASSERT_TRUE(parseSciVisName("/a/b/name_256x256x128_uint16.raw", dims, type));
  EXPECT_EQ(dims, (Vec3i{256, 256, 128}));
  EXPECT_EQ(type, ScalarType::UInt16);
  ASSERT_TRUE(parseSciVisName("x_2x3x4_float32.raw.gz", dims, type));
  EXPECT_EQ(type, ScalarType::Float32);
  EXPECT_FALSE(parseSciVisName("plain.raw", dims, type));
  EXPECT_FALSE(parseSciVisName("x_2x3x4_complex.raw", dims, type));
}

// Writes a small int16 big-endian volume in several containers and reads it back.
class SyntheticFiles : public ::testing::Test {
 protected:
  void SetUp() override {
    dir = test::scratchDir();
    for (int i = 0; i < 4 * 3 * 2; ++i) values.push_back(int16_t(i * 37 - 300));
    for (int16_t v : values) {
      le.push_back(char(v & 0xff)); le.push_back(char((v >> 8) & 0xff));
      be.push_back(char((v >> 8) & 0xff)); be.push_back(char(v & 0xff));
    }
  }
  void expectValues(const Grid& g) {
    ASSERT_EQ(g.dims(), (Vec3i{4, 3, 2}));
    ASSERT_EQ(g.type(), ScalarType::Int16);
    for (size_t i = 0; i < values.size(); ++i) EXPECT_EQ(g.value(i), float(values[i])) << i;
  }
  static std::string gzip(const std::string& data) {
    z_stream zs{};
    deflateInit2(&zs, 6, Z_DEFLATED, 16 + MAX_WBITS, 8, Z_DEFAULT_STRATEGY);
    std::string out(deflateBound(&zs, uLong(data.size())) + 32, '\0');
    zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
    zs.avail_in = uInt(data.size());
    zs.next_out = reinterpret_cast<Bytef*>(out.data());
    zs.avail_out = uInt(out.size());
    deflate(&zs, Z_FINISH);
    out.resize(zs.total_out);
    deflateEnd(&zs);
    return out;
  }
  std::string dir;
  std::vector<int16_t> values;
  std::string le, be;
};

TEST_F(SyntheticFiles, NrrdAttachedRawBigEndian) {
  test::writeBytes(dir + "/a.nrrd", "NRRD0004\n# comment\ntype: int16\ndimension: 3\nsizes: 4 3 2\n"
                                    "endian: big\nencoding: raw\nspace origin: (1,2,3)\n\n" + be);
  const Grid g = loadVolumeFile(dir + "/a.nrrd");
  expectValues(g);
  EXPECT_EQ(g.origin(), (Vec3d{1, 2, 3}));
}

TEST_F(SyntheticFiles, NrrdAttachedGzipAndAscii) {
  test::writeBytes(dir + "/g.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\n"
                                    "endian: little\nencoding: gzip\n\n" + gzip(le));
  expectValues(loadVolumeFile(dir + "/g.nrrd"));
  std::ostringstream text;
  for (int16_t v : values) text << v << "\n";
  test::writeBytes(dir + "/t.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\n"
                                    "encoding: ascii\n\n" + text.str());
  expectValues(loadVolumeFile(dir + "/t.nrrd"));
}

TEST_F(SyntheticFiles, NrrdDetachedListAndPattern) {
  // Two slices of 4x3 int16 each, named in a LIST and in a %03d pattern.
  test::writeBytes(dir + "/s_001.raw", le.substr(0, 24));
  test::writeBytes(dir + "/s_002.raw", le.substr(24));
  test::writeText(dir + "/list.nhdr", "NRRD0004\ntype: int16\ndimension: 3\nsizes: 4 3 2\n"
                                      "encoding: raw\ndata file: LIST\ns_001.raw\ns_002.raw\n");
  expectValues(loadVolumeFile(dir + "/list.nhdr"));
  test::writeText(dir + "/pat.nhdr", "NRRD0004\ntype: int16\ndimension: 3\nsizes: 4 3 2\n"
                                     "encoding: raw\ndata file: s_%03d.raw 1 2 1 2\n");
  expectValues(loadVolumeFile(dir + "/pat.nhdr"));
}

TEST_F(SyntheticFiles, MetaImageAndVtk) {
  test::writeBytes(dir + "/v.raw", be);
  test::writeText(dir + "/m.mhd", "NDims = 3\nDimSize = 4 3 2\nElementSpacing = 0.5 1 2\n"
                                  "ElementType = MET_SHORT\nElementByteOrderMSB = True\nElementDataFile = v.raw\n");
  const Grid m = loadVolumeFile(dir + "/m.mhd");
  expectValues(m);
  EXPECT_EQ(m.spacing(), (Vec3d{0.5, 1, 2}));
  test::writeBytes(dir + "/b.vtk", "# vtk DataFile Version 3.0\nt\nBINARY\nDATASET STRUCTURED_POINTS\n"
                                   "DIMENSIONS 4 3 2\nSPACING 1 1 1\nORIGIN 0 0 0\nPOINT_DATA 24\n"
                                   "SCALARS s short 1\nLOOKUP_TABLE default\n" + be + "\n");
  expectValues(loadVolumeFile(dir + "/b.vtk"));
  std::ostringstream text;
  for (int16_t v : values) text << v << " ";
  test::writeBytes(dir + "/a.vtk", "# vtk DataFile Version 3.0\nt\nASCII\nDATASET STRUCTURED_POINTS\n"
                                   "DIMENSIONS 4 3 2\nSPACING 1 1 1\nORIGIN 0 0 0\nPOINT_DATA 24\n"
                                   "SCALARS s short\nLOOKUP_TABLE default\n" + text.str() + "\n");
  expectValues(loadVolumeFile(dir + "/a.vtk"));
}

// Bad input is an InputError whose message names the file and the problem.
void expectInputError(const std::string& file, const std::string& fragment, RawLayout layout = {}) {
  test::expectRefusal<InputError>([&] { loadVolumeFile(file, layout); }, file, fragment);
}

TEST_F(SyntheticFiles, BadInputIsNamed) {
  expectInputError(dir + "/missing.raw", "file not found");
  test::writeBytes(dir + "/short_4x3x2_int16.raw", le.substr(0, 40));
  expectInputError(dir + "/short_4x3x2_int16.raw", "needs 48");
  test::writeText(dir + "/type.nrrd", "NRRD0004\ntype: double\ndimension: 3\nsizes: 4 3 2\nencoding: raw\n\n");
  expectInputError(dir + "/type.nrrd", "unsupported type 'double'");
  test::writeText(dir + "/enc.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\nencoding: bzip2\n\n");
  expectInputError(dir + "/enc.nrrd", "line 5: unsupported encoding 'bzip2'");
  test::writeText(dir + "/zero.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 0 3 2\nencoding: raw\n\n");
  expectInputError(dir + "/zero.nrrd", "dimensions must be positive");
  test::writeText(dir + "/spacing.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\n"
                                         "spacings: 1 -1 1\nencoding: raw\n\n" + le);
  expectInputError(dir + "/spacing.nrrd", "spacing must be positive");
  test::writeText(dir + "/spacing.mhd", "NDims = 3\nDimSize = 4 3 2\nElementSpacing = 1 0 1\n"
                                        "ElementType = MET_SHORT\nElementDataFile = v.raw\n");
  expectInputError(dir + "/spacing.mhd", "spacing must be positive");
  const std::string gz = gzip(le);
  test::writeBytes(dir + "/cut_4x3x2_int16.raw.gz", gz.substr(0, gz.size() / 2));
  expectInputError(dir + "/cut_4x3x2_int16.raw.gz", "truncated compressed data");
  test::writeBytes(dir + "/anonymous.raw", le);
  expectInputError(dir + "/anonymous.raw", "needs \"dims\"");
  std::string nan = le;
  const float bad = std::numeric_limits<float>::quiet_NaN();
  std::string floats(4 * 24, '\0');
  std::memcpy(&floats[4 * 5], &bad, 4);
  test::writeBytes(dir + "/nan_4x3x2_float32.raw", floats);
  expectInputError(dir + "/nan_4x3x2_float32.raw", "voxel (1, 1, 0): NaN value");
}

// Raw files are read straight into the grid's buffer: the layout is checked against the file
// before anything is allocated, and gzip output is checked against it while inflating.
TEST_F(SyntheticFiles, RawStraightIntoTheGrid) {
  test::writeBytes(dir + "/v_4x3x2_int16.raw", le);
  expectValues(loadVolumeFile(dir + "/v_4x3x2_int16.raw", {}));
  RawLayout big;
  big.bigEndian = true;
  test::writeBytes(dir + "/b_4x3x2_int16.raw", be);
  expectValues(loadVolumeFile(dir + "/b_4x3x2_int16.raw", big));
  test::writeBytes(dir + "/z_4x3x2_int16.raw.gz", gzip(le));
  expectValues(loadVolumeFile(dir + "/z_4x3x2_int16.raw.gz", {}));
  // A stream that inflates to more than the layout holds stops at the first extra byte.
  test::writeBytes(dir + "/bomb_4x3x2_int16.raw.gz", gzip(std::string(1 << 20, '\0')));
  expectInputError(dir + "/bomb_4x3x2_int16.raw.gz", "decompressed data is larger than 4x3x2 int16 (48 bytes)");
  test::writeBytes(dir + "/v_65536x65536x65536_uint8.raw.gz", gzip(le));
  expectInputError(dir + "/v_65536x65536x65536_uint8.raw.gz", "bytes of gzip data cannot hold more than");
  test::writeBytes(dir + "/small_4x3x2_int16.raw.gz", gzip(le.substr(0, 20)));
  expectInputError(dir + "/small_4x3x2_int16.raw.gz", "data has 20 bytes but 4x3x2 int16 needs 48");
  test::writeBytes(dir + "/long_4x3x2_int16.raw", le + "xx");
  expectInputError(dir + "/long_4x3x2_int16.raw", "data has 50 bytes but 4x3x2 int16 needs 48");
  // Dimensions whose product does not fit are refused before any allocation.
  test::writeBytes(dir + "/huge_2147483647x2147483647x2147483647_float32.raw", le);
  expectInputError(dir + "/huge_2147483647x2147483647x2147483647_float32.raw", "are too large");
  test::writeBytes(dir + "/large_65536x65536x65536_uint8.raw", le);
  expectInputError(dir + "/large_65536x65536x65536_uint8.raw", "data has 48 bytes but 65536x65536x65536 uint8 needs");
  // Plain samples that begin with gzip's magic bytes (1f 8b: a float32 of about -7.45, met in a
  // test's ball of radius 9) are read as samples when the file is exactly their size.
  std::vector<float> floats(8, 1.5f);
  const uint32_t bits = 0xC0EE8B1Fu;  // little-endian bytes 1f 8b ee c0
  std::memcpy(&floats[0], &bits, 4);
  test::writeBytes(dir + "/m_2x2x2_float32.raw", std::string(reinterpret_cast<const char*>(floats.data()), 32));
  const Grid magic = loadVolumeFile(dir + "/m_2x2x2_float32.raw", {});
  EXPECT_EQ(magic.value(size_t(0)), floats[0]);
  EXPECT_EQ(magic.value(size_t(7)), 1.5f);
}

// Hostile headers (issue 14): sizes, counts, skips and file ranges are checked before they
// are used to allocate or loop; compressed streams stop at what the header asks for; ASCII
// values must be finite and fit their type, and the bad one is named.
TEST_F(SyntheticFiles, HostileHeadersAreNamedNotFollowed) {
  auto nrrd = [&](const std::string& name, const std::string& fields, const std::string& data = "") {
    test::writeBytes(dir + "/" + name, "NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\nendian: little\n" + fields +
                                           (data.empty() ? "" : "\n" + data));
    return dir + "/" + name;
  };
  // File ranges: numbers that overflow, that are no numbers, more files than slices, huge widths.
  expectInputError(nrrd("a.nhdr", "encoding: raw\ndata file: s%d.raw 1 2147483647 1\n"),
                   "line 7: '2147483647' is not a whole number from -1e9 to 1e9");
  expectInputError(nrrd("b.nhdr", "encoding: raw\ndata file: s%d.raw a b c\n"), "line 7: 'a' is not a whole number");
  expectInputError(nrrd("c.nhdr", "encoding: raw\ndata file: s%d.raw 1 1000 1\n"), "line 7: 1000 data files for 2 slices");
  expectInputError(nrrd("d.nhdr", "encoding: raw\ndata file: s%0100000000d.raw 1 2 1\n"), "a field width above 32");
  // Found by the fuzzer: a range whose ends are in the wrong order for its step, but within one
  // step (5 3 5: (3 - 5) / 5 truncates to 0), gave no files and a division by zero.
  expectInputError(nrrd("d2.nhdr", "encoding: raw\ndata file: s%d.raw 5 3 5\n"), "empty or endless file range");
  // A 50 KB pattern (std::regex overflowed the stack on it: a fuzzer finding).
  expectInputError(nrrd("d3.nhdr", "encoding: raw\ndata file: s" + std::string(50000, 'x') + "%0100d.raw 1 2 1\n"),
                   "a field width above 32");
  // Skips: a line skip past the data ends (it used to loop 1e12 times), a byte skip of 1e300.
  expectInputError(nrrd("e.nrrd", "encoding: raw\nline skip: 1000000000000\n", le), "line skip runs past the end of the data");
  expectInputError(nrrd("f.nrrd", "encoding: raw\nline skip: 1e20\n", le), "line 7: line skip must be a whole number from 0 to 1e15");
  expectInputError(nrrd("g.nrrd", "encoding: raw\nbyte skip: 1e300\n", le), "line 7: byte skip must be a whole number from -1 to 1e15");
  // A gzip bomb inflates no further than the header's 48 bytes.
  expectInputError(nrrd("h.nrrd", "encoding: gzip\n", gzip(std::string(1 << 22, '\0'))),
                   "decompressed data is larger than the 48 bytes the header asks for");
  // A header asking for 10^15 bytes from small data files allocates nothing.
  test::writeBytes(dir + "/s1.raw", le);
  test::writeBytes(dir + "/huge.nhdr", "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 100000 100000 100000\nencoding: raw\n"
                                       "data file: s%d.raw 1 1 1\n");
  expectInputError(dir + "/huge.nhdr", "s1.raw: data has 48 bytes but the header");
  // ASCII: a NaN, a value out of range for the type, and a count the text cannot hold.
  expectInputError(nrrd("i.nrrd", "encoding: ascii\n", "1 2 nan 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24"),
                   "value 3 of 24: 'nan' is not a finite number");
  expectInputError(nrrd("j.nrrd", "encoding: ascii\n", "1 2 3 40000 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24"),
                   "value 4 of 24: 40000 is out of range for int16");
  test::writeBytes(dir + "/k.vtk", "# vtk DataFile Version 3.0\nx\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 1000 1000 1000\n"
                                   "SPACING 1 1 1\nORIGIN 0 0 0\nPOINT_DATA 1000000000\nSCALARS s float\nLOOKUP_TABLE default\n1 2 3\n");
  expectInputError(dir + "/k.vtk", "ASCII data of 6 bytes cannot hold the 1000000000 values the header asks for");
  // MetaImage: a compressed stream larger than DimSize, a HeaderSize past the data.
  test::writeBytes(dir + "/m.raw.gz", gzip(std::string(1 << 22, '\0')));
  test::writeBytes(dir + "/m.mhd", "ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_SHORT\n"
                                   "CompressedData = True\nElementDataFile = m.raw.gz\n");
  expectInputError(dir + "/m.mhd", "decompressed data is larger than the 48 bytes the header asks for");
  test::writeBytes(dir + "/n.raw", le);
  test::writeBytes(dir + "/n.mhd", "ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_SHORT\n"
                                   "HeaderSize = 1000\nElementDataFile = n.raw\n");
  expectInputError(dir + "/n.mhd", "HeaderSize runs past the end of the data");
}

TEST(Loaders, TruncatedRealGzipIsAnError) {
  const std::string dir = test::scratchDir();
  std::ifstream in(dataPath("volumes/lidc2_chest_ct_256x256x133_uint8.raw.gz"), std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string cut = dir + "/lidc2_chest_ct_256x256x133_uint8.raw.gz";
  test::writeBytes(cut, bytes.substr(0, bytes.size() / 3));
  expectInputError(cut, "truncated compressed data");
}

// Quantiles, which `isotrace info` prints to choose iso values by: exact for integer types,
// within a histogram bin of the range for float32.
TEST(Grid, QuantilesOfKnownValues) {
  // 0, 1, ..., 999 as int16 shifted to -500 ... 499, and the same as float32 times 0.5.
  std::vector<int16_t> ints(1000);
  std::vector<float> floats(1000);
  for (int i = 0; i < 1000; ++i) {
    ints[size_t(i * 7919 % 1000)] = int16_t(i - 500);  // shuffled: order must not matter
    floats[size_t(i * 7919 % 1000)] = 0.5f * float(i - 500);
  }
  const Grid gi({10, 10, 10}, Grid::Storage(ints));
  const Grid gf({10, 10, 10}, Grid::Storage(floats));
  const std::vector<double> q = gi.quantiles({0, 0.25, 0.5, 0.999, 1});
  EXPECT_EQ(q, (std::vector<double>{-500, -250, 0, 499, 499}));
  const std::vector<double> f = gf.quantiles({0, 0.25, 0.5, 1});
  const double bin = 499.5 / 65536;
  EXPECT_NEAR(f[0], -250, bin);
  EXPECT_NEAR(f[1], -125, bin);
  EXPECT_NEAR(f[2], 0, bin);
  EXPECT_NEAR(f[3], 249.5, bin);
}

// The smooth gradient is exact for a linear field everywhere (one-sided differences on the
// grid's faces included) and, away from the faces, for a quadratic one (central differences
// of a quadratic are exact at the samples, and its gradient is linear between them).
TEST(Grid, SmoothGradientIsExactForLinearAndQuadraticFields) {
  const Vec3i d{5, 6, 7};
  std::vector<float> linear, quadratic;
  for (int z = 0; z < d.z; ++z)
    for (int y = 0; y < d.y; ++y)
      for (int x = 0; x < d.x; ++x) {
        linear.push_back(float(2 * x + 3 * y - z));
        quadratic.push_back(float(x * x + 0.5 * y * y - z * z + x * y));
      }
  const Grid gl(d, Grid::Storage(linear)), gq(d, Grid::Storage(quadratic));
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0, 1);
  for (int i = 0; i < 500; ++i) {
    const Vec3d p{u(rng) * (d.x - 1), u(rng) * (d.y - 1), u(rng) * (d.z - 1)};
    const Vec3d g = gl.smoothGradient(p);
    EXPECT_NEAR(g.x, 2, 1e-5);
    EXPECT_NEAR(g.y, 3, 1e-5);
    EXPECT_NEAR(g.z, -1, 1e-5);
    const Vec3d q{1 + u(rng) * (d.x - 3), 1 + u(rng) * (d.y - 3), 1 + u(rng) * (d.z - 3)};  // away from the faces
    const Vec3d h = gq.smoothGradient(q);
    // The gradient (2x + y, y + x, -2z) interpolated trilinearly: exact where it is linear per
    // axis, which it is (each component is linear in the coordinates).
    EXPECT_NEAR(h.x, 2 * q.x + q.y, 1e-4);
    EXPECT_NEAR(h.y, q.y + q.x, 1e-4);
    EXPECT_NEAR(h.z, -2 * q.z, 1e-4);
  }
}

TEST(Procedural, SphereFieldIsTheDistanceToTheCentre) {
  const Grid g = makeProceduralGrid(Field::Sphere, {5, 5, 5});
  EXPECT_EQ(g.value(2, 2, 2), 0.f);
  EXPECT_FLOAT_EQ(g.value(4, 2, 2), 1.f);
  EXPECT_FLOAT_EQ(g.value(0, 0, 0), float(std::sqrt(3.0)));
  EXPECT_EQ(g.origin(), (Vec3d{-1, -1, -1}));
  EXPECT_EQ(g.spacing(), (Vec3d{0.5, 0.5, 0.5}));
  EXPECT_NEAR(evalField(Field::Torus, {0.6, 0, 0}), 0, 1e-12);
  EXPECT_NEAR(evalField(Field::Gyroid, {0, 0, 0}), 0, 1e-12);
  // Marschner-Lobb at the origin: (1 - 0 + 0.25 (1 + cos(12 pi))) / 2.5 = 0.6.
  EXPECT_NEAR(evalField(Field::MarschnerLobb, {0, 0, 0}), 0.6, 1e-12);
}

}  // namespace
}  // namespace iso
