// The denoiser (renderer/denoise.h): on images whose truth is known (noise of a known size over
// albedo and shadow edges), then through `isotrace render --denoise`.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <random>

#include "renderer/denoise.h"
#include "test_util.h"

namespace iso {
namespace {

using test::readExr;
using test::runIsotrace;

// A synthetic frame of w x h: the true colour is albedo x light, albedo 0.2 left of column
// `albedoEdge` and 0.8 right of it, light 1 above row `shadowEdge` and 0.25 below it (a shadow
// the features do not show). Each pixel has `spp` samples of the truth times (1 + 0.6 n), n
// standard normal: the even and odd samples' means, the mean and its variance, as the renderer
// gives them. Features are exact (albedo, a constant normal and depth).
struct Synthetic {
  DenoiseInput in;
  std::vector<Vec3f> truth;
};

Synthetic synthetic(int w, int h, int spp, uint32_t seed, int albedoEdge = 40, int shadowEdge = 30) {
  Synthetic s;
  DenoiseInput& in = s.in;
  in.width = w, in.height = h;
  const size_t n = size_t(w) * size_t(h);
  for (auto* v : {&in.color.mean, &in.color.a, &in.color.b, &in.color.variance, &in.albedo, &in.normal, &s.truth})
    v->resize(n);
  in.depth.assign(n, 2.f);
  in.samples.assign(n, float(spp));
  in.featureVariance.assign(n, Vec3f(0, 0, 0));
  std::mt19937 rng(seed);
  std::normal_distribution<float> normal(0.f, 1.f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const size_t i = size_t(y) * size_t(w) + size_t(x);
      const float albedo = x < albedoEdge ? 0.2f : 0.8f, light = y < shadowEdge ? 1.f : 0.25f;
      const Vec3f truth(albedo * light, albedo * light * 0.9f, albedo * light * 0.8f);
      s.truth[i] = truth;
      in.albedo[i] = Vec3f(albedo, albedo * 0.9f, albedo * 0.8f);
      in.normal[i] = Vec3f(0, 0, 1);
      Vec3d sum, odd, sum2;
      for (int k = 0; k < spp; ++k) {
        const float f = 1 + 0.6f * normal(rng);
        const Vec3d v(truth * f);
        sum += v;
        sum2 += v * v;
        if (k & 1) odd += v;
      }
      const int nodd = spp / 2, neven = spp - nodd;
      const Vec3d mean = sum / double(spp);
      in.color.mean[i] = Vec3f(mean);
      in.color.a[i] = Vec3f((sum - odd) / double(neven));
      in.color.b[i] = nodd ? Vec3f(odd / double(nodd)) : in.color.a[i];
      Vec3d var{0, 0, 0};
      if (spp > 1)
        for (int c = 0; c < 3; ++c) var[c] = std::max(0.0, sum2[c] / spp - mean[c] * mean[c]) / (spp - 1);
      in.color.variance[i] = Vec3f(var);
    }
  return s;
}

double relMse(const std::vector<Vec3f>& x, const std::vector<Vec3f>& truth) {
  double e = 0;
  for (size_t i = 0; i < x.size(); ++i)
    for (int c = 0; c < 3; ++c) e += double(x[i][c] - truth[i][c]) * (x[i][c] - truth[i][c]) / (truth[i][c] * truth[i][c] + 1e-2);
  return e / double(3 * x.size());
}

double meanLuminance(const std::vector<Vec3f>& x) {
  double s = 0;
  for (const Vec3f& v : x) s += 0.2126 * v.x + 0.7152 * v.y + 0.0722 * v.z;
  return s / double(x.size());
}

// The mean of channel 0 over columns [x0, x1) and rows [y0, y1).
double regionMean(const std::vector<Vec3f>& img, int w, int x0, int x1, int y0, int y1) {
  double s = 0;
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) s += img[size_t(y) * size_t(w) + size_t(x)].x;
  return s / double((x1 - x0) * (y1 - y0));
}

TEST(Denoise, RemovesNoiseAndKeepsAlbedoAndShadowEdges) {
  const int w = 96, h = 64;
  const Synthetic s = synthetic(w, h, 16, 7);
  const double raw = relMse(s.in.color.mean, s.truth);
  for (DenoiseMode mode : {DenoiseMode::Quality, DenoiseMode::Fast}) {
    SCOPED_TRACE(denoiseModeName(mode));
    const std::vector<Vec3f> out = denoise(s.in, s.in.color, mode, 2);
    ASSERT_EQ(out.size(), s.truth.size());
    const double err = relMse(out, s.truth);
    // Quality must beat 8x the samples (raw relMSE falls as 1/spp); fast at least 4x.
    EXPECT_LT(err, raw / (mode == DenoiseMode::Quality ? 8 : 4)) << "raw " << raw;
    // The albedo edge (the features show it): the two columns beside it keep their own side's
    // value within 10% of the step, in the lit part.
    const double leftTruth = 0.2, rightTruth = 0.8;
    EXPECT_NEAR(regionMean(out, w, 38, 40, 4, 26), leftTruth, 0.1 * (rightTruth - leftTruth));
    EXPECT_NEAR(regionMean(out, w, 40, 42, 4, 26), rightTruth, 0.1 * (rightTruth - leftTruth));
    // The shadow edge (only the colour shows it): the two rows beside it within 25% of the step,
    // on the bright side of the albedo edge.
    const double lit = 0.8, shadow = 0.2;
    EXPECT_NEAR(regionMean(out, w, 50, 90, 28, 30), lit, 0.25 * (lit - shadow));
    EXPECT_NEAR(regionMean(out, w, 50, 90, 30, 32), shadow, 0.25 * (lit - shadow));
  }
}

TEST(Denoise, KeepsTheImageMean) {
  const Synthetic s = synthetic(96, 64, 4, 11);
  const double raw = meanLuminance(s.in.color.mean);
  for (DenoiseMode mode : {DenoiseMode::Quality, DenoiseMode::Fast}) {
    const double den = meanLuminance(denoise(s.in, s.in.color, mode, 2));
    EXPECT_NEAR(den / raw, 1.0, 0.01) << denoiseModeName(mode);
  }
}

TEST(Denoise, SameBitsForAnyThreadCount) {
  const Synthetic s = synthetic(77, 53, 8, 3);  // sizes that no tile or lane count divides
  for (DenoiseMode mode : {DenoiseMode::Quality, DenoiseMode::Fast}) {
    const std::vector<Vec3f> one = denoise(s.in, s.in.color, mode, 1);
    for (int threads : {2, 3, 5}) {
      const std::vector<Vec3f> many = denoise(s.in, s.in.color, mode, threads);
      ASSERT_EQ(one.size(), many.size());
      EXPECT_EQ(0, std::memcmp(one.data(), many.data(), one.size() * sizeof(Vec3f)))
          << denoiseModeName(mode) << ", " << threads << " threads";
    }
  }
}

TEST(Denoise, NonFiniteSamplesNeverSpread) {
  Synthetic s = synthetic(64, 48, 8, 5);
  const size_t nan = 20 * 64 + 20, inf = 10 * 64 + 50;  // away from the edges
  s.in.color.mean[nan] = s.in.color.a[nan] = Vec3f(NAN, 0.5f, 0.5f);
  s.in.color.mean[inf] = s.in.color.b[inf] = Vec3f(INFINITY, INFINITY, 1);
  s.in.albedo[inf + 1] = Vec3f(NAN, NAN, NAN);  // a feature, too
  for (DenoiseMode mode : {DenoiseMode::Quality, DenoiseMode::Fast}) {
    DenoiseReport report;
    const std::vector<Vec3f> out = denoise(s.in, s.in.color, mode, 2, &report);
    EXPECT_EQ(report.nonFinitePixels, 3u);
    for (size_t i = 0; i < out.size(); ++i) ASSERT_TRUE(isFinite(out[i])) << denoiseModeName(mode) << " pixel " << i;
    // The broken pixels are filled from their neighbours: near the truth, not 0.
    for (size_t i : {nan, inf, inf + 1}) EXPECT_NEAR(out[i].x, s.truth[i].x, 0.25 * s.truth[i].x) << i;
  }
}

TEST(Denoise, OneSamplePerPixelEstimatesItsVariance) {
  const Synthetic s = synthetic(96, 64, 1, 9);
  const double raw = relMse(s.in.color.mean, s.truth);
  for (DenoiseMode mode : {DenoiseMode::Quality, DenoiseMode::Fast}) {
    const std::vector<Vec3f> out = denoise(s.in, s.in.color, mode, 2);
    EXPECT_LT(relMse(out, s.truth), raw / 3) << denoiseModeName(mode);
  }
}

TEST(Denoise, ParsesItsModes) {
  DenoiseMode m;
  EXPECT_TRUE(parseDenoiseMode("quality", m) && m == DenoiseMode::Quality);
  EXPECT_TRUE(parseDenoiseMode("fast", m) && m == DenoiseMode::Fast);
  EXPECT_TRUE(parseDenoiseMode("off", m) && m == DenoiseMode::Off);
  EXPECT_FALSE(parseDenoiseMode("Quality", m));
  EXPECT_FALSE(parseDenoiseMode("", m));
}

// ---- Through the command line ------------------------------------------------------------------

nlohmann::json readJson(const std::string& path) {
  std::ifstream in(path);
  return nlohmann::json::parse(in, nullptr, false);
}

// The channels `name.R/G/B` (or the main R, G, B when name is empty) of an EXR, per pixel.
std::vector<float> layer(const std::string& path, const std::string& name) {
  std::vector<std::string> channels;
  const std::vector<float> data = readExr(path, &channels);
  std::vector<int> at;
  for (const char* c : {"R", "G", "B"}) {
    const std::string want = name.empty() ? c : name + "." + c;
    for (size_t k = 0; k < channels.size(); ++k)
      if (channels[k] == want) at.push_back(int(k));
  }
  std::vector<float> out;
  if (at.size() != 3 || channels.empty()) return out;
  for (size_t p = 0; p < data.size() / channels.size(); ++p)
    for (int k : at) out.push_back(data[p * channels.size() + size_t(k)]);
  return out;
}

TEST(DenoiseCli, WritesTheDenoisedImageAndKeepsTheRawOne) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  const std::string common = "render " + dir + "/s.json --integrator path --spp 8 --quiet ";
  ASSERT_EQ(runIsotrace(common + "-o " + dir + "/raw.exr").status, 0);
  const auto r = runIsotrace(common + "--denoise -o " + dir + "/d.exr --stats " + dir + "/d.json");
  ASSERT_EQ(r.status, 0) << r.err;
  const std::vector<float> raw = layer(dir + "/raw.exr", ""), kept = layer(dir + "/d.exr", "raw"),
                           den = layer(dir + "/d.exr", "");
  ASSERT_FALSE(raw.empty());
  EXPECT_EQ(kept, raw) << "the raw layer is the render without --denoise, bit for bit";
  ASSERT_EQ(den.size(), raw.size());
  EXPECT_NE(den, raw);
  const nlohmann::json stats = readJson(dir + "/d.json");
  EXPECT_EQ(stats["denoise"], "quality");
  EXPECT_GT(stats["seconds"]["denoise"].get<double>(), 0);
  // The mode by name, and from the scene file.
  ASSERT_EQ(runIsotrace(common + "--denoise fast -o " + dir + "/f.exr --stats " + dir + "/f.json").status, 0);
  EXPECT_EQ(readJson(dir + "/f.json")["denoise"], "fast");
  ASSERT_EQ(runIsotrace(common + "--set /film/denoise='\"fast\"' -o " + dir + "/g.exr").status, 0);
  EXPECT_EQ(layer(dir + "/g.exr", ""), layer(dir + "/f.exr", ""));
  // `off` on the command line wins over the file.
  ASSERT_EQ(runIsotrace(common + "--set /film/denoise='\"fast\"' --denoise off -o " + dir + "/o.exr").status, 0);
  EXPECT_EQ(layer(dir + "/o.exr", ""), raw);
}

TEST(DenoiseCli, SameImageForAnyThreadCountAndRayFlow) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  const std::string common = "render " + dir + "/s.json --integrator path --spp 6 --denoise --quiet ";
  ASSERT_EQ(runIsotrace(common + "--threads 1 -o " + dir + "/1.exr").status, 0);
  ASSERT_EQ(runIsotrace(common + "--threads 3 -o " + dir + "/3.exr").status, 0);
  ASSERT_EQ(runIsotrace(common + "--threads 2 --ray-flow scalar -o " + dir + "/s.exr").status, 0);
  const std::vector<float> one = readExr(dir + "/1.exr");
  ASSERT_FALSE(one.empty());
  EXPECT_EQ(readExr(dir + "/3.exr"), one);
  EXPECT_EQ(readExr(dir + "/s.exr"), one);
}

TEST(DenoiseCli, CompareDenoisesDirectAndIndirectApart) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  ASSERT_EQ(runIsotrace("render " + dir + "/s.json --integrator compare --spp 8 --quiet -o " + dir + "/raw.exr").status, 0);
  const auto r = runIsotrace("render " + dir + "/s.json --integrator compare --spp 8 --denoise --quiet -o " + dir + "/d.exr");
  ASSERT_EQ(r.status, 0) << r.err;
  const std::vector<float> g = layer(dir + "/d.global.exr", ""), d = layer(dir + "/d.direct.exr", ""),
                           i = layer(dir + "/d.indirect.exr", "");
  ASSERT_FALSE(g.empty());
  ASSERT_EQ(g.size(), d.size());
  ASSERT_EQ(g.size(), i.size());
  for (size_t k = 0; k < g.size(); ++k) ASSERT_FLOAT_EQ(g[k], d[k] + i[k]) << k;
  for (const char* part : {"direct", "global", "indirect"}) {
    const std::vector<float> raw = layer(dir + "/raw." + std::string(part) + ".exr", "");
    EXPECT_EQ(layer(dir + "/d." + std::string(part) + ".exr", "raw"), raw) << part;
    EXPECT_NE(layer(dir + "/d." + std::string(part) + ".exr", ""), raw) << part;
  }
}

TEST(DenoiseCli, NormalsAndEyelightPassThrough) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  for (const char* integrator : {"normals", "eyelight"}) {
    const std::string common = "render " + dir + "/s.json --spp 2 --quiet --integrator " + integrator;
    ASSERT_EQ(runIsotrace(common + " -o " + dir + "/a.exr").status, 0);
    ASSERT_EQ(runIsotrace(common + " --denoise -o " + dir + "/b.exr").status, 0);
    EXPECT_EQ(readExr(dir + "/b.exr"), readExr(dir + "/a.exr")) << integrator;
  }
}

TEST(DenoiseCli, BadInputIsOneLineAndStatus2) {
  const std::string dir = test::scratchDir();
  test::writeText(dir + "/s.json", test::mixedScene());
  struct Case {
    std::string flags, fragment;
  };
  const std::vector<Case> cases = {
      {"--denoise sharp", "--denoise: unknown mode 'sharp' (known: quality, fast, off)"},
      {"--set /film/denoise='\"sharp\"'", "/film/denoise: unknown denoiser mode 'sharp'"},
      {"--set /film/denoise=3", "/film/denoise: expected a string"},
      {"--resolution 16384x16384 --allow-large --denoise", "GiB"},
  };
  for (const Case& c : cases) {
    const std::string out = dir + "/x.png";
    const auto r = runIsotrace("render " + dir + "/s.json --integrator path --spp 1 " + c.flags + " -o " + out);
    EXPECT_EQ(r.status, 2) << c.flags << "\n" << r.err;
    EXPECT_NE(r.err.find(c.fragment), std::string::npos) << c.flags << "\n" << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_FALSE(std::ifstream(out).good()) << "no image for " << c.flags;
  }
}

}  // namespace
}  // namespace iso
