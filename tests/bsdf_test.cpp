// BSDFs and lights: sampling densities integrate to one, agree with their evaluation, and
// importance-sampled estimates agree with uniform ones.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

#include "scene/light.h"
#include "scene/material.h"

namespace iso {
namespace {

struct Config {
  const char* name;
  MaterialType type;
  Vec3f color;
  float metallic, roughness;
};

// Non-delta BSDFs, from rough to fairly glossy.
const Config kConfigs[] = {
    {"diffuse", MaterialType::Diffuse, {0.5f, 0.7f, 0.9f}, 0, 1},
    {"plastic rough", MaterialType::MetallicRoughness, {0.8f, 0.2f, 0.1f}, 0, 0.8f},
    {"plastic glossy", MaterialType::MetallicRoughness, {0.8f, 0.2f, 0.1f}, 0, 0.35f},
    {"half metal", MaterialType::MetallicRoughness, {0.9f, 0.6f, 0.3f}, 0.5f, 0.5f},
    {"metal", MaterialType::MetallicRoughness, {0.95f, 0.9f, 0.8f}, 1, 0.4f},
    {"conductor", MaterialType::Conductor, {0.95f, 0.64f, 0.54f}, 0, 0.5f},
};

Bsdf makeLocal(const Config& c) {
  Frame f{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  return Bsdf(c.type, f, c.color, c.metallic, c.roughness, 1.5f);
}

Vec3f direction(float cosTheta, float phi) {
  const float s = std::sqrt(1 - cosTheta * cosTheta);
  return {s * std::cos(phi), s * std::sin(phi), cosTheta};
}

// A BSDF seen from one outgoing direction (setOutgoing, as a path uses it: world space, a tilted
// frame) answers f, pdf and evaluate with the same bits as the local queries from that direction,
// on either side of the surface, and evaluate's f does not depend on whether the pdf is asked.
TEST(Bsdf, OneOutgoingDirectionAnswersAsTheLocalQueries) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0, 1);
  auto bits = [](float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; };
  auto same = [&](const Vec3f& a, const Vec3f& b) { return bits(a.x, b.x) && bits(a.y, b.y) && bits(a.z, b.z); };
  const Vec3f n = normalize(Vec3f{0.3f, -0.5f, 0.8f});
  const Frame frame = Frame::fromNormal(n, {1, 0, 0});
  int compared = 0;
  for (const Config& c : kConfigs) {
    const Bsdf local(c.type, frame, c.color, c.metallic, c.roughness, 1.5f);
    for (int i = 0; i < 200; ++i) {
      const Vec3f woLocal = direction(2 * u(rng) - 1, 6.2831853f * u(rng));
      const Vec3f wiLocal = direction(2 * u(rng) - 1, 6.2831853f * u(rng));
      const Vec3f wo = frame.toWorld(woLocal), wi = frame.toWorld(wiLocal);
      Bsdf seen = local;
      seen.setOutgoing(wo);
      float pdf = -1;
      const Vec3f f = seen.evaluate(wi, &pdf);
      // The world directions round-trip through the frame: compare with the local queries of
      // exactly the directions the BSDF sees.
      const Vec3f woSeen = frame.toLocal(wo), wiSeen = frame.toLocal(wi);
      ASSERT_TRUE(same(f, local.fLocal(woSeen, wiSeen))) << c.name;
      ASSERT_TRUE(bits(pdf, local.pdfLocal(woSeen, wiSeen))) << c.name;
      ASSERT_TRUE(same(f, seen.f(wi))) << c.name;
      ASSERT_TRUE(bits(pdf, seen.pdf(wi))) << c.name;
      BsdfSample a, b;
      const float u0 = u(rng), u1 = u(rng), u2 = u(rng);
      const bool okA = seen.sample(u0, u1, u2, a), okB = local.sampleLocal(woSeen, u0, u1, u2, b);
      ASSERT_EQ(okA, okB) << c.name;
      if (okA) {
        ASSERT_TRUE(same(a.wi, frame.toWorld(b.wi)) && same(a.f, b.f) && bits(a.pdf, b.pdf)) << c.name;
        ++compared;
      }
    }
  }
  EXPECT_GT(compared, 600);
}

// The density of sample() integrates to 1 over the sphere, less the share of samples that
// fail (a GGX reflection that lands below the horizon is dropped, not moved).
TEST(Bsdf, PdfIntegratesToOneOverTheSphere) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0, 1);
  for (const Config& c : kConfigs) {
    const Bsdf b = makeLocal(c);
    for (float cosO : {0.9f, 0.5f, 0.15f, -0.6f}) {  // below the surface too: materials are two-sided
      const Vec3f wo = direction(cosO, 0.3f);
      int failed = 0;
      const int trials = 200000;
      for (int i = 0; i < trials; ++i) {
        BsdfSample s;
        failed += !b.sampleLocal(wo, u(rng), u(rng), u(rng), s);
      }
      const double kept = 1 - double(failed) / trials;
      // Stratified uniform sphere sampling: integral of pdf d(omega) = 4 pi E[pdf].
      const int n = 400;
      double sum = 0;
      for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) sum += b.pdfLocal(wo, sampleUniformSphere((i + u(rng)) / n, (j + u(rng)) / n));
      const double integral = 4 * M_PI * sum / (double(n) * n);
      EXPECT_NEAR(integral, kept, 0.01) << c.name << " cos(wo) " << cosO;
      if (c.type == MaterialType::Diffuse) {
        EXPECT_EQ(failed, 0);
      }
    }
  }
}

TEST(Bsdf, SamplesAgreeWithEvaluationAndUniformEstimates) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0, 1);
  for (const Config& c : kConfigs) {
    const Bsdf b = makeLocal(c);
    for (float cosO : {0.95f, 0.6f, 0.2f}) {
      const Vec3f wo = direction(cosO, 1.1f);
      const int n = 200000;
      Vec3d importance{0, 0, 0}, uniform{0, 0, 0}, importance2{0, 0, 0}, uniform2{0, 0, 0};
      int failures = 0;
      for (int i = 0; i < n; ++i) {
        // The same integral with cosine-weighted directions, independent of sample().
        const Vec3f wc = sampleCosineHemisphere(u(rng), u(rng));
        const Vec3d bc = Vec3d(b.fLocal(wo, wo.z > 0 ? wc : Vec3f{wc.x, wc.y, -wc.z})) * M_PI;
        uniform += bc;
        uniform2 += bc * bc;
        BsdfSample s;
        if (!b.sampleLocal(wo, u(rng), u(rng), u(rng), s)) { ++failures; continue; }
        ASSERT_FALSE(s.delta);
        // What sample() returns is what f() and pdf() say about the same direction.
        const Vec3f f = b.fLocal(wo, s.wi);
        const float pdf = b.pdfLocal(wo, s.wi);
        ASSERT_NEAR(s.pdf, pdf, 1e-4f * pdf) << c.name;
        ASSERT_NEAR(s.f.x, f.x, 1e-4f * f.x + 1e-7f) << c.name;
        const Vec3d a(s.f * (std::fabs(s.wi.z) / s.pdf));
        importance += a;
        importance2 += a * a;
      }
      // Directional albedo: never above 1, and the two estimators agree within 5 standard errors.
      for (int k = 0; k < 3; ++k) {
        const double m1 = importance[k] / n, m2 = uniform[k] / n;
        const double var1 = importance2[k] / n - m1 * m1, var2 = uniform2[k] / n - m2 * m2;
        const double sigma = std::sqrt(std::max(0.0, var1 + var2) / n);
        EXPECT_LE(m1, 1.0 + 5 * sigma) << c.name;
        EXPECT_NEAR(m1, m2, 5 * sigma + 1e-6) << c.name << " cos " << cosO << " k " << k;
      }
      importance = importance / double(n);
      if (c.type == MaterialType::Diffuse) {
        EXPECT_EQ(failures, 0);
        EXPECT_NEAR(importance.x, c.color.x, 1e-5);  // f cos / pdf is exactly the albedo
      }
    }
  }
}

// White furnace of rough metals (issue 12): a white conductor and a white glTF metal reflect
// all the light at every roughness and angle, to within 5%, once the multiple-scattering lobe
// returns what single-scattering GGX loses (at roughness 1 and normal incidence that is 69%:
// the table must say so); never more than all of it.
TEST(Bsdf, RoughWhiteMetalsPassTheWhiteFurnace) {
  EXPECT_NEAR(ggx::albedo(1, 1), 0.31f, 0.02f);
  EXPECT_GT(ggx::albedo(0.9f, 0.05f), 0.98f);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0, 1);
  const Frame frame{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  for (MaterialType type : {MaterialType::Conductor, MaterialType::MetallicRoughness})
    for (float roughness : {0.3f, 0.6f, 1.0f}) {
      const Bsdf b(type, frame, {1, 1, 1}, 1, roughness, 1.5f);
      for (float cosO : {0.95f, 0.5f, 0.1f}) {
        const Vec3f wo{std::sqrt(1 - cosO * cosO), 0, cosO};
        const int n = 200000;
        double sum = 0;
        for (int i = 0; i < n; ++i) {
          BsdfSample s;
          if (b.sampleLocal(wo, u(rng), u(rng), u(rng), s)) sum += s.f.y * std::fabs(s.wi.z) / s.pdf;
        }
        const double reflected = sum / n;
        std::printf("%s roughness %.1f cos %.2f: reflects %.4f (single scattering %.4f)\n",
                    type == MaterialType::Conductor ? "conductor" : "glTF metal", roughness, cosO, reflected,
                    ggx::albedo(cosO, roughness));
        EXPECT_GE(reflected, 0.95) << (type == MaterialType::Conductor ? "conductor" : "glTF metal") << " roughness "
                                   << roughness << " cos " << cosO;
        EXPECT_LE(reflected, 1.01) << "roughness " << roughness << " cos " << cosO;
      }
    }
}

// A thin sheet reflects R + T^2 R / (1 - R^2) of the light (more than one surface) and lets
// the rest through straight, tinted; nothing is lost.
TEST(Bsdf, ThinGlassTransmitsStraight) {
  const Frame frame{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const Bsdf b(MaterialType::Dielectric, frame, {0.9f, 0.8f, 0.7f}, 0, 0, 1.5f, true);
  EXPECT_TRUE(b.isDelta());
  for (float cosO : {0.9f, 0.4f, -0.6f}) {
    const Vec3f wo{std::sqrt(1 - cosO * cosO), 0, cosO};
    const float R = thinDielectricReflectance(cosO, 1.5f);
    EXPECT_GT(R, fresnelDielectric(std::fabs(cosO), 1.5f));
    double reflected = 0, transmitted = 0;
    const int n = 20000;
    for (int i = 0; i < n; ++i) {
      BsdfSample s;
      ASSERT_TRUE(b.sampleLocal(wo, (i + 0.5f) / n, 0.5f, 0.5f, s));
      const float weight = s.f.y * std::fabs(s.wi.z) / s.pdf;
      if (s.transmission) {
        EXPECT_TRUE(s.straight);
        EXPECT_EQ(s.wi, -wo);
        transmitted += weight;
      } else {
        EXPECT_EQ(s.wi, (Vec3f{-wo.x, -wo.y, wo.z}));
        reflected += weight;
      }
    }
    EXPECT_NEAR(reflected / n, R, 2e-3);
    EXPECT_NEAR(transmitted / n, 0.8 * (1 - R), 2e-3);  // the green tint
  }
}

TEST(Bsdf, SmoothGlassReflectsAndRefractsByFresnel) {
  const float eta = 1.5f;
  Frame f{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const Bsdf glass(MaterialType::Dielectric, f, {1, 1, 1}, 0, 0, eta);
  EXPECT_TRUE(glass.isDelta());
  EXPECT_NEAR(fresnelDielectric(1, eta), std::pow((eta - 1) / (eta + 1), 2), 1e-6);
  for (float cosO : {0.9f, 0.4f, -0.9f, -0.4f}) {
    const Vec3f wo = direction(cosO, 0.7f);
    const float F = fresnelDielectric(cosO, eta);
    int reflected = 0;
    const int n = 20000;
    for (int i = 0; i < n; ++i) {
      BsdfSample s;
      ASSERT_TRUE(glass.sampleLocal(wo, (i + 0.5f) / n, 0.5f, 0.5f, s));
      EXPECT_TRUE(s.delta);
      if (!s.transmission) {
        ++reflected;
        EXPECT_NEAR(s.wi.z, wo.z, 1e-6);
        EXPECT_NEAR(s.f.x * std::fabs(s.wi.z) / s.pdf, 1, 1e-5);
      } else {
        // Snell: eta_i sin(theta_i) = eta_t sin(theta_t), on the other side of the surface.
        EXPECT_LT(s.wi.z * wo.z, 0);
        const float etaI = wo.z > 0 ? 1 : eta, etaT = wo.z > 0 ? eta : 1;
        const float sinI = std::sqrt(1 - wo.z * wo.z), sinT = std::sqrt(1 - s.wi.z * s.wi.z);
        EXPECT_NEAR(etaI * sinI, etaT * sinT, 1e-5);
        // Radiance crossing into the denser medium is scaled by (eta_i / eta_t)^2.
        EXPECT_NEAR(s.f.x * std::fabs(s.wi.z) / s.pdf, (etaI / etaT) * (etaI / etaT), 1e-5);
      }
    }
    EXPECT_NEAR(double(reflected) / n, F, 1e-3) << cosO;
  }
  // Beyond the critical angle from inside, everything reflects.
  BsdfSample s;
  ASSERT_TRUE(glass.sampleLocal(direction(-0.3f, 0), 0.999f, 0, 0, s));
  EXPECT_FALSE(s.transmission);
}

TEST(Bsdf, SmoothConductorIsAMirror) {
  Frame f{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const Bsdf mirror(MaterialType::Conductor, f, {0.9f, 0.5f, 0.2f}, 0, 0, 1.5f);
  EXPECT_TRUE(mirror.isDelta());
  const Vec3f wo = direction(0.6f, 0.2f);
  BsdfSample s;
  ASSERT_TRUE(mirror.sampleLocal(wo, 0.3f, 0.3f, 0.3f, s));
  EXPECT_NEAR(s.wi.x, -wo.x, 1e-6);
  EXPECT_NEAR(s.wi.z, wo.z, 1e-6);
  EXPECT_EQ(mirror.fLocal(wo, s.wi), Vec3f(0, 0, 0));  // delta: only sample() reaches it
  EXPECT_EQ(mirror.pdfLocal(wo, s.wi), 0);
}

TEST(Lights, EnvironmentImageSamplingMatchesItsPdf) {
  // An 16x8 lat-long image with one bright texel and a gradient elsewhere.
  std::vector<Vec4f> texels(16 * 8);
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 16; ++x) texels[y * 16 + x] = {0.1f + x * 0.01f, 0.2f, 0.3f + y * 0.05f, 1};
  texels[3 * 16 + 5] = {40, 30, 20, 1};
  const Texture image = Texture::fromTexels(16, 8, texels);
  LightDesc d;
  d.type = LightType::Environment;
  d.radiance = {1, 1, 1};
  const Light env = Light::fromDesc(d, &image);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0, 1);
  // The density integrates to 1 over the sphere.
  double integral = 0;
  const int n = 400;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) integral += env.pdfEnvironment(sampleUniformSphere((i + u(rng)) / n, (j + u(rng)) / n));
  EXPECT_NEAR(4 * M_PI * integral / (double(n) * n), 1, 0.01);
  // Samples carry the pdf and radiance that the direction has; the bright texel gets its share.
  int bright = 0;
  const int samples = 100000;
  for (int i = 0; i < samples; ++i) {
    LightSample s;
    ASSERT_TRUE(env.sample({0, 0, 0}, u(rng), u(rng), u(rng), s));
    EXPECT_NEAR(s.pdf, env.pdfEnvironment(s.wi), 1e-3f * s.pdf);
    const Vec3f L = env.environment(s.wi);
    EXPECT_EQ(s.L, L);
    float tu, tv;
    Light::latLongFromDirection(s.wi, tu, tv);
    bright += int(tu * 16) == 5 && int(tv * 8) == 3;
  }
  double weightBright = 0, weightAll = 0;
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 16; ++x) {
      const double w = luminance(texels[y * 16 + x].rgb()) * std::sin(M_PI * (y + 0.5) / 8) + 1e-8;
      weightAll += w;
      if (x == 5 && y == 3) weightBright = w;
    }
  const double expected = weightBright / weightAll;
  EXPECT_NEAR(double(bright) / samples, expected, 4 * std::sqrt(expected * (1 - expected) / samples));
}

TEST(Lights, AreaLightSamplesMatchTheirPdf) {
  Material lamp;
  lamp.type = MaterialType::Emissive;
  lamp.emission = {2, 3, 4};
  std::vector<Texture> none;
  // Two triangles of different size, facing -y, above the origin.
  std::vector<Vec3f> tris = {{-1, 2, -1}, {1, 2, -1}, {-1, 2, 1}, {3, 2, 0}, {3, 2, 0.5f}, {3.5f, 2, 0}};
  const Light area = Light::area(tris, {}, lamp, none);
  EXPECT_NEAR(area.area(), 2 + 0.125, 1e-6);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1);
  const Vec3f p{0.2f, 0, 0.1f};
  double irradianceEstimate = 0;
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    LightSample s;
    ASSERT_TRUE(area.sample(p, u(rng), u(rng), u(rng), s));
    const Vec3f y = p + s.wi * s.distance;
    EXPECT_NEAR(y.y, 2, 1e-5);
    EXPECT_NEAR(s.pdf, area.pdfArea(p, y, {0, -1, 0}), 1e-3f * s.pdf);
    irradianceEstimate += s.L.x * std::max(0.f, s.wi.y) / s.pdf;
  }
  // One-sided emission: the first triangle's normal cross((2,0,0), (0,0,2)) = (0,-4,0) faces
  // the point, the second faces away. Irradiance by quadrature over the first:
  // E = integral of L cos(theta_p) cos(theta_l) / d^2 dA, both cosines 2 / d.
  double quadrature = 0;
  const int m = 1000;
  for (int i = 0; i < m; ++i)
    for (int j = 0; j < m; ++j) {
      const double x = -1 + (i + 0.5) * 2.0 / m, z = -1 + (j + 0.5) * 2.0 / m;
      if (x + z > 0) continue;
      const double dx = x - p.x, dz = z - p.z, d2 = dx * dx + 4 + dz * dz;
      quadrature += 2 * 4 / (d2 * d2) * (4.0 / (double(m) * m));
    }
  EXPECT_NEAR(irradianceEstimate / n, quadrature, 0.01 * quadrature);
}

}  // namespace
}  // namespace iso
