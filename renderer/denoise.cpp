#include "renderer/denoise.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <initializer_list>
#include <memory>

// The hot loops are written lane by lane over rows (no reductions across a loop), so that the
// compiler vectorises them; they are compiled twice, for AVX2+FMA and for plain x86-64, and the
// CPU picks one at load time. (Which one runs changes rounding, so images are bit-identical on
// one machine for any thread count, not across CPUs of different kinds.)
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
#define ISO_DENOISE_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define ISO_DENOISE_CLONES
#endif

namespace iso {

namespace {

// e^x for x <= 0 (0 below -80), relative error below 3e-5: 2^x split into an integer part, put
// into the exponent bits, and a polynomial for the fraction. std::exp does not vectorise here
// (no -ffast-math: see CMakeLists.txt), and the filters' weights need a few per pixel and tap.
inline float expNegative(float x) {
  x = std::max(x, -80.f) * 1.44269504f;  // log2(e)
  const int i = int(x);                   // rounds towards 0: i >= x, so f in (-1, 0]
  const float f = x - float(i);
  const int bits = (i + 127) << 23;
  // 2^f = e^(f ln 2), Taylor to the 6th power (|f ln 2| < 0.7).
  const float t = f * 0.69314718f;
  const float p = 1.f + t * (1.f + t * (0.5f + t * (1.f / 6 + t * (1.f / 24 + t * (1.f / 120 + t * (1.f / 720))))));
  return p * __builtin_bit_cast(float, bits);
}

inline float luminance(float r, float g, float b) { return 0.2126f * r + 0.7152f * g + 0.0722f * b; }

// Planar images with a border of `pad` pixels on every side (zero, and not valid), so that the
// filters' taps never test the image's edges. Rows are `stride` floats apart.
struct Planes {
  int width = 0, height = 0, pad = 0, stride = 0;
  int count = 0;
  std::unique_ptr<float[]> data;
  // Zeroed by the threads in slices (a 1080p frame's planes are ~10 MB each: one thread alone
  // spends longer on their first touch than the filter on its work).
  void init(int w, int h, int p, int n) {
    width = w, height = h, pad = p, count = n;
    stride = (w + 2 * p + 7) & ~7;
    const size_t total = size_t(stride) * size_t(h + 2 * p) * size_t(n);
    data.reset(new float[total]);
    constexpr size_t kSlice = size_t(1) << 16;
    tbb::parallel_for(size_t(0), (total + kSlice - 1) / kSlice, [&](size_t k) {
      std::fill(data.get() + k * kSlice, data.get() + std::min(total, (k + 1) * kSlice), 0.f);
    });
  }
  float* plane(int k) { return data.get() + size_t(k) * size_t(stride) * size_t(height + 2 * pad); }
  const float* plane(int k) const { return data.get() + size_t(k) * size_t(stride) * size_t(height + 2 * pad); }
  // Pixel (x, y) of the image (x, y may reach into the border).
  size_t at(int x, int y) const { return size_t(y + pad) * size_t(stride) + size_t(x + pad); }
};

template <typename F>
void parallelRows(int rows, F&& f) {
  tbb::parallel_for(tbb::blocked_range<int>(0, rows, 4), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) f(y);
  });
}

// ---- What both modes read ---------------------------------------------------------------------

// Validity, features and colours in planes; non-finite pixels marked and zeroed.
struct Prepared {
  int width = 0, height = 0;
  // Features: 0-2 albedo, 3-5 normal, 6 depth (over the farthest depth: background 1.25), 7 valid.
  static constexpr int kFeatures = 7, kValid = 7;
  Planes features;
  uint64_t nonFinite = 0;
};

inline bool finite3(const Vec3f& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

// A pixel takes part when its colours, variance and features are finite (depth may be infinite:
// background).
bool pixelValid(const DenoiseInput& in, const NoisyImage& image, size_t i) {
  return finite3(image.mean[i]) && finite3(image.a[i]) && finite3(image.b[i]) && finite3(image.variance[i]) &&
         finite3(in.albedo[i]) && finite3(in.normal[i]) && !std::isnan(in.depth[i]) && in.depth[i] >= 0;
}

// Features are noisy where a pixel's samples see different things (glass that reflects or
// transmits, partly covered edges): a regression on them would keep the noise it should remove.
// NFOR (section 5.2) first filters them by NL-means on their own half buffers; here each noisy
// pixel's features become the average over the 5x5 pixels around it that differ from it by no
// more than their variances explain (per group: albedo, normal, depth). Pixels whose features
// have no variance keep them as they are.
void smoothNoisyFeatures(Prepared& p, const Planes& spread) {
  Planes& F = p.features;
  const float* valid = F.plane(Prepared::kValid);
  constexpr float kFloor = 1e-5f;
  std::vector<float> out(size_t(p.width) * size_t(p.height) * Prepared::kFeatures);
  std::vector<uint8_t> changed(size_t(p.width) * size_t(p.height), 0);
  static constexpr int kGroup[Prepared::kFeatures] = {0, 0, 0, 1, 1, 1, 2};
  parallelRows(p.height, [&](int y) {
    for (int x = 0; x < p.width; ++x) {
      const size_t c = F.at(x, y), i = size_t(y) * size_t(p.width) + size_t(x);
      if (valid[c] == 0) continue;
      const float vc[3] = {spread.plane(0)[c], spread.plane(1)[c], spread.plane(2)[c]};
      if (!(vc[0] + vc[1] + vc[2] > 3 * kFloor)) continue;
      float sum[Prepared::kFeatures] = {}, wsum = 0;
      for (int dy = -2; dy <= 2; ++dy)
        for (int dx = -2; dx <= 2; ++dx) {
          const size_t q = F.at(x + dx, y + dy);
          if (valid[q] == 0) continue;
          float d[3] = {0, 0, 0};
          for (int k = 0; k < Prepared::kFeatures; ++k) {
            const float diff = F.plane(k)[c] - F.plane(k)[q];
            d[kGroup[k]] += diff * diff;
          }
          float e = 0;
          for (int g = 0; g < 3; ++g) {
            const float v = vc[g] + spread.plane(g)[q];
            e += std::max(0.f, d[g] - v) / (v + kFloor);
          }
          const float w = expNegative(-e);
          for (int k = 0; k < Prepared::kFeatures; ++k) sum[k] += w * F.plane(k)[q];
          wsum += w;
        }
      for (int k = 0; k < Prepared::kFeatures; ++k) out[i * Prepared::kFeatures + size_t(k)] = sum[k] / wsum;
      changed[i] = 1;
    }
  });
  for (int y = 0; y < p.height; ++y)
    for (int x = 0; x < p.width; ++x) {
      const size_t i = size_t(y) * size_t(p.width) + size_t(x);
      if (!changed[i]) continue;
      for (int k = 0; k < Prepared::kFeatures; ++k) F.plane(k)[F.at(x, y)] = out[i * Prepared::kFeatures + size_t(k)];
    }
}

Prepared prepare(const DenoiseInput& in, const NoisyImage& image, int pad) {
  Prepared p;
  p.width = in.width, p.height = in.height;
  p.features.init(in.width, in.height, pad, Prepared::kFeatures + 1);
  float far = 0;
  for (size_t i = 0; i < in.pixels(); ++i)
    if (std::isfinite(in.depth[i])) far = std::max(far, in.depth[i]);
  const float toUnit = far > 0 ? 1.f / far : 1.f;
  // Feature variances in the planes' units (depth over the farthest).
  Planes spread;
  spread.init(in.width, in.height, pad, 3);
  std::vector<uint32_t> badPerRow(size_t(in.height), 0);
  parallelRows(in.height, [&](int y) {
    for (int x = 0; x < in.width; ++x) {
      const size_t i = size_t(y) * size_t(in.width) + size_t(x), o = p.features.at(x, y);
      if (!pixelValid(in, image, i)) {
        ++badPerRow[size_t(y)];
        continue;  // features 0, not valid
      }
      for (int c = 0; c < 3; ++c) {
        p.features.plane(c)[o] = in.albedo[i][c];
        p.features.plane(3 + c)[o] = in.normal[i][c];
      }
      p.features.plane(6)[o] = std::isfinite(in.depth[i]) ? in.depth[i] * toUnit : 1.25f;
      p.features.plane(Prepared::kValid)[o] = 1;
      if (!in.featureVariance.empty() && finite3(in.featureVariance[i])) {
        spread.plane(0)[o] = in.featureVariance[i].x;
        spread.plane(1)[o] = in.featureVariance[i].y;
        spread.plane(2)[o] = in.featureVariance[i].z * toUnit * toUnit;
      }
    }
  });
  for (uint32_t n : badPerRow) p.nonFinite += n;
  smoothNoisyFeatures(p, spread);
  return p;
}

// A colour (3 planes) and its per-channel variance (3 planes), padded; non-valid pixels 0.
void colourPlanes(const Prepared& p, const std::vector<Vec3f>& colour, const std::vector<Vec3f>& variance,
                  float varianceScale, int pad, Planes& out) {
  out.init(p.width, p.height, pad, 6);
  const float* valid = p.features.plane(Prepared::kValid);
  parallelRows(p.height, [&](int y) {
    for (int x = 0; x < p.width; ++x) {
      const size_t i = size_t(y) * size_t(p.width) + size_t(x), o = out.at(x, y);
      if (valid[p.features.at(x, y)] == 0) continue;
      for (int c = 0; c < 3; ++c) {
        out.plane(c)[o] = colour[i][c];
        out.plane(3 + c)[o] = variance[i][c] * varianceScale;
      }
    }
  });
}

// Where a pixel has a single sample its variance is unknown (0): each variance plane
// `pairs[k].second` gets the spread of its value plane `pairs[k].first` over the 7x7 valid pixels
// around (a pessimistic estimate: edges count as noise). `planes` is laid out as the features.
void fillUnknownVariance(const Prepared& p, const std::vector<float>& samples, Planes& planes,
                         std::initializer_list<std::pair<int, int>> pairs) {
  const float* valid = p.features.plane(Prepared::kValid);
  bool any = false;
  for (float s : samples) any = any || s < 2;
  if (!any) return;
  const size_t count = pairs.size();
  std::vector<float> estimate(size_t(p.width) * size_t(p.height) * count, 0.f);
  parallelRows(p.height, [&](int y) {
    for (int x = 0; x < p.width; ++x) {
      const size_t i = size_t(y) * size_t(p.width) + size_t(x);
      if (samples[i] >= 2) continue;
      size_t k = 0;
      for (const auto& [value, variance] : pairs) {
        double s = 0, s2 = 0;
        int n = 0;
        for (int dy = -3; dy <= 3; ++dy)
          for (int dx = -3; dx <= 3; ++dx) {
            const size_t q = planes.at(x + dx, y + dy);
            if (valid[q] == 0) continue;  // (the border is not valid)
            const double v = planes.plane(value)[q];
            s += v, s2 += v * v, ++n;
          }
        estimate[i * count + k++] = n > 1 ? float(std::max(0.0, s2 / n - (s / n) * (s / n))) : 0.f;
      }
    }
  });
  for (int y = 0; y < p.height; ++y)
    for (int x = 0; x < p.width; ++x) {
      const size_t i = size_t(y) * size_t(p.width) + size_t(x);
      if (samples[i] >= 2) continue;
      size_t k = 0;
      for (const auto& pair : pairs) planes.plane(pair.second)[planes.at(x, y)] = estimate[i * count + k++];
    }
}

// ---- Quality: cross-filtered first-order regression -------------------------------------------

struct QualityParams {
  int stride = 3;     // centres every `stride` pixels in x and y
  int radius = 7;     // each centre fits the (2 radius + 1)^2 pixels around it
  // NL-means bandwidth: larger averages more. Measured on ct_chest, cornell_torus and color_by at
  // 16 spp (k 0.2-2, radius 3-10): k 1 with radius 7 had the lowest relMSE on all three but
  // ct_chest (radius 4 there: 0.0092 against 0.0100); docs/BENCHMARKS.md, "The denoiser".
  float k = 1.0f;
  float ridge = 1e-3f;  // regularisation of the slopes, relative to the weights' sum
};

constexpr int kD = 1 + Prepared::kFeatures;  // the regression's unknowns: intercept and slopes
constexpr int kLanes = 8;

// The guide the weights are measured on: the half's colour averaged over 3x3 valid pixels, and
// the variance of that average (the half's variance, already scaled, / the count).
void boxGuide(const Prepared& p, const Planes& half, int pad, Planes& guide) {
  guide.init(p.width, p.height, pad, 6);
  const float* valid = p.features.plane(Prepared::kValid);
  parallelRows(p.height, [&](int y) {
    for (int x = 0; x < p.width; ++x) {
      const size_t o = guide.at(x, y);
      if (valid[p.features.at(x, y)] == 0) continue;
      for (int c = 0; c < 3; ++c) {
        // Weighted by inverse variance (floored at half the 3x3 mean): a partly covered
        // pixel at a lamp's edge (variance 45 beside 0.01) would otherwise make its neighbours'
        // guides look like the lamp and pull its radiance into them.
        float mean = 0, n = 0;
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const float v = valid[p.features.at(x + dx, y + dy)];
            mean += v * half.plane(3 + c)[half.at(x + dx, y + dy)];
            n += v;
          }
        const float floor = 0.5f * mean / n + 1e-12f;
        float sw = 0, sx = 0, sv = 0;
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const size_t q = half.at(x + dx, y + dy);
            const float var = half.plane(3 + c)[q];
            const float w = valid[p.features.at(x + dx, y + dy)] / (var + floor);
            sw += w, sx += w * half.plane(c)[q], sv += w * w * var;
          }
        guide.plane(c)[o] = sx / sw;
        guide.plane(3 + c)[o] = sv / (sw * sw);
      }
    }
  });
}

// The NL-means weight of pixel q seen from pixel c on the guide (Rousselle et al. 2012, with the
// variance cancellation of NFOR's eq. 11): e^-max(0, d^2), d^2 the per-channel squared difference
// less what the variance explains, over the variance, averaged over channels.
struct WeightFn {
  const float *g0, *g1, *g2, *v0, *v1, *v2;
  float k2;
  explicit WeightFn(const Planes& guide, float k)
      : g0(guide.plane(0)), g1(guide.plane(1)), g2(guide.plane(2)), v0(guide.plane(3)), v1(guide.plane(4)),
        v2(guide.plane(5)), k2(k * k) {}
  static float term(float gc, float gq, float vc, float vq, float k2) {
    const float d = gc - gq;
    return (d * d - (vc + std::min(vc, vq))) / (1e-8f + k2 * (vc + vq));
  }
  float operator()(size_t c, size_t q) const {
    const float d = (term(g0[c], g0[q], v0[c], v0[q], k2) + term(g1[c], g1[q], v1[c], v1[q], k2) +
                     term(g2[c], g2[q], v2[c], v2[q], k2)) * (1.f / 3);
    return expNegative(-std::max(d, 0.f));
  }
};

// The model of one centre: the intercept and slopes per channel, and the features it was
// centred on.
struct CentreModel {
  float beta[kD][3];
  float f[Prepared::kFeatures];
  float lo[3], hi[3];  // the colours it was fitted on (weight above 1%): predictions stay inside
};

// Weighted least squares at one centre: sum over the window of w (y - beta . x)^2 with x = (1,
// features - the centre's), plus ridge * sum w * |slopes|^2. Normal equations accumulated 8 lanes
// at a time (window columns), in a fixed order; solved by Cholesky in double.
ISO_DENOISE_CLONES
void fitCentre(const Prepared& p, const Planes& y, const WeightFn& weight, int cx, int cy, const QualityParams& q,
               CentreModel& model) {
  const Planes& F = p.features;
  const size_t c = F.at(cx, cy);
  float fc[Prepared::kFeatures];
  for (int j = 0; j < Prepared::kFeatures; ++j) fc[j] = F.plane(j)[c];
  float G[kD][kD][kLanes] = {};
  float Rhs[kD][3][kLanes] = {};
  float lo[3][kLanes], hi[3][kLanes];
  for (int ch = 0; ch < 3; ++ch)
    for (int l = 0; l < kLanes; ++l) lo[ch][l] = INFINITY, hi[ch][l] = -INFINITY;
  const float* valid = F.plane(Prepared::kValid);
  const int width = 2 * q.radius + 1;
  for (int dy = -q.radius; dy <= q.radius; ++dy) {
    for (int x0 = 0; x0 < width; x0 += kLanes) {
      const size_t row = F.at(cx - q.radius + x0, cy + dy);
      float w[kLanes], xs[kD][kLanes], ys[3][kLanes], lane[kLanes];
      // Lanes past the window's width weigh 0 (and so does the border: it is not valid).
      for (int l = 0; l < kLanes; ++l) lane[l] = x0 + l < width ? 1.f : 0.f;
      for (int l = 0; l < kLanes; ++l) {
        const size_t at = row + size_t(l);
        w[l] = lane[l] * valid[at] * weight(c, at);
        xs[0][l] = 1;
        for (int j = 0; j < Prepared::kFeatures; ++j) xs[1 + j][l] = F.plane(j)[at] - fc[j];
        for (int ch = 0; ch < 3; ++ch) ys[ch][l] = y.plane(ch)[at];
      }
      for (int ch = 0; ch < 3; ++ch)
        for (int l = 0; l < kLanes; ++l) {
          const bool counts = w[l] > 0.01f;
          lo[ch][l] = counts ? std::min(lo[ch][l], ys[ch][l]) : lo[ch][l];
          hi[ch][l] = counts ? std::max(hi[ch][l], ys[ch][l]) : hi[ch][l];
        }
      for (int i = 0; i < kD; ++i) {
        float wx[kLanes];
        for (int l = 0; l < kLanes; ++l) wx[l] = w[l] * xs[i][l];
        for (int j = i; j < kD; ++j)
          for (int l = 0; l < kLanes; ++l) G[i][j][l] += wx[l] * xs[j][l];
        for (int ch = 0; ch < 3; ++ch)
          for (int l = 0; l < kLanes; ++l) Rhs[i][ch][l] += wx[l] * ys[ch][l];
      }
    }
  }
  double A[kD][kD], B[kD][3];
  for (int i = 0; i < kD; ++i) {
    for (int j = i; j < kD; ++j) {
      double s = 0;
      for (int l = 0; l < kLanes; ++l) s += G[i][j][l];
      A[i][j] = A[j][i] = s;
    }
    for (int ch = 0; ch < 3; ++ch) {
      double s = 0;
      for (int l = 0; l < kLanes; ++l) s += Rhs[i][ch][l];
      B[i][ch] = s;
    }
  }
  for (int j = 0; j < Prepared::kFeatures; ++j) model.f[j] = fc[j];
  for (int ch = 0; ch < 3; ++ch) {
    model.lo[ch] = INFINITY, model.hi[ch] = -INFINITY;
    for (int l = 0; l < kLanes; ++l) model.lo[ch] = std::min(model.lo[ch], lo[ch][l]), model.hi[ch] = std::max(model.hi[ch], hi[ch][l]);
  }
  const double total = A[0][0];
  if (!(total > 0)) {  // nothing valid around (or all weights 0): no model, predicted as 0
    for (auto& b : model.beta) b[0] = b[1] = b[2] = 0;
    return;
  }
  for (int i = 1; i < kD; ++i) A[i][i] += q.ridge * total + 1e-12 * total;
  // Cholesky A = L L^T in place (lower triangle); a pivot that is not positive drops that
  // feature (its slope 0): features constant over the window make A singular.
  double L[kD][kD] = {};
  bool used[kD];
  for (int i = 0; i < kD; ++i) {
    used[i] = true;
    for (int j = 0; j <= i; ++j) {
      double s = A[i][j];
      for (int k = 0; k < j; ++k) s -= L[i][k] * L[j][k];
      if (i == j) {
        if (!(s > 1e-9 * total)) {
          used[i] = false;
          for (int k = 0; k < i; ++k) L[i][k] = 0;
          L[i][i] = 1;
        } else {
          L[i][i] = std::sqrt(s);
        }
      } else {
        L[i][j] = used[j] ? s / L[j][j] : 0;
      }
    }
  }
  for (int ch = 0; ch < 3; ++ch) {
    double z[kD], beta[kD];
    for (int i = 0; i < kD; ++i) {
      double s = used[i] ? B[i][ch] : 0;
      for (int k = 0; k < i; ++k) s -= L[i][k] * z[k];
      z[i] = used[i] ? s / L[i][i] : 0;
    }
    for (int i = kD - 1; i >= 0; --i) {
      double s = z[i];
      for (int k = i + 1; k < kD; ++k) s -= L[k][i] * beta[k];
      beta[i] = used[i] ? s / L[i][i] : 0;
    }
    for (int i = 0; i < kD; ++i) model.beta[i][ch] = float(beta[i]);
  }
}

// One half filtered: models at the centres fitted to `half` with weights on `guide` (the other
// half), then every pixel the weighted blend of the predictions of the centres within `stride`.
//
// A pixel whose guide matches no centre around it (a pixel on an edge: its 3x3 guide mixes both
// sides) would blend the centres by weights that are all ~0 and so alike: both sides' models.
// Each prediction is therefore also weighed by how well it agrees with the other half's own
// value at the pixel (within twice its noise): the model of the pixel's side wins there.
std::vector<Vec3f> filterHalf(const Prepared& p, const Planes& half, const Planes& guide, const Planes& other,
                              const QualityParams& q) {
  const int S = q.stride;
  const int nx = (p.width + S - 1) / S, ny = (p.height + S - 1) / S;
  auto centreX = [&](int i) { return std::min(p.width - 1, S / 2 + i * S); };
  auto centreY = [&](int j) { return std::min(p.height - 1, S / 2 + j * S); };
  const WeightFn weight(guide, q.k);
  std::vector<CentreModel> models(size_t(nx) * size_t(ny));
  parallelRows(ny, [&](int j) {
    for (int i = 0; i < nx; ++i) fitCentre(p, half, weight, centreX(i), centreY(j), q, models[size_t(j) * nx + i]);
  });
  std::vector<Vec3f> out(size_t(p.width) * size_t(p.height));
  const Planes& F = p.features;
  const float* valid = F.plane(Prepared::kValid);
  parallelRows(p.height, [&](int y) {
    const int j0 = std::max(0, (y - S - S / 2 + S - 1) / S), j1 = std::min(ny - 1, (y + S - S / 2) / S);
    for (int x = 0; x < p.width; ++x) {
      const int i0 = std::max(0, (x - S - S / 2 + S - 1) / S), i1 = std::min(nx - 1, (x + S - S / 2) / S);
      const size_t at = F.at(x, y);
      const bool ok = valid[at] != 0;
      // Up to 3 x 3 centres (stride 3, reach 3): their predictions, guide weights and
      // disagreements; the least disagreement is the scale (a pixel no model fits well, e.g. a
      // dark one of almost no variance, takes the one that fits best, not all alike).
      float pv[17][3], pw[17], pe[17], least = INFINITY;
      int n = 0;
      for (int j = j0; j <= j1; ++j)
        for (int i = i0; i <= i1 && n < 16; ++i) {
          const CentreModel& m = models[size_t(j) * nx + i];
          const size_t c = F.at(centreX(i), centreY(j));
          if (valid[c] == 0) continue;
          // A pixel that is not valid has no features: it takes the centres' intercepts alike.
          float disagree = 0;
          for (int ch = 0; ch < 3; ++ch) {
            float v = m.beta[0][ch];
            if (ok)
              for (int k = 0; k < Prepared::kFeatures; ++k) v += m.beta[1 + k][ch] * (F.plane(k)[at] - m.f[k]);
            // Not beyond the colours the model was fitted on (a linear model extrapolated past its
            // data bled a lamp's radiance into the ceiling beside it), and not negative.
            pv[n][ch] = std::max(std::min(std::max(v, m.lo[ch]), m.hi[ch]), 0.f);
            const float d = pv[n][ch] - other.plane(ch)[at];
            disagree += d * d / (2 * other.plane(3 + ch)[at] + 18 * guide.plane(3 + ch)[at] + 1e-6f);
          }
          pw[n] = ok ? weight(c, at) + 1e-3f : 1.f;
          pe[n] = ok ? disagree * (1.f / 3) : 0.f;
          least = std::min(least, pe[n]);
          ++n;
        }
      // Where no model agrees with the other half beyond two standard deviations (a one-pixel
      // dark gap the features do not show), the pixel's own value is a candidate too, of small
      // prior weight; offered everywhere, it kept fireflies and 4-spp noise (ct_chest at 4 spp
      // 0.020 -> 0.044 relMSE). The noise it is judged by is the mean of the pixel's variance and
      // the 3x3-smoothed one (a 4-sample variance alone is too noisy a yardstick). Measured
      // against plain blending (16 spp relMSE): cornell_torus 0.035 -> 0.024, ct_chest 0.0086 ->
      // 0.0090, default 0.0191 -> 0.0204, engine_volume 0.0144 -> 0.0155: kept for the first.
      if (ok && least > 4) {
        float disagree = 0;
        for (int ch = 0; ch < 3; ++ch) {
          pv[n][ch] = half.plane(ch)[at];
          const float d = pv[n][ch] - other.plane(ch)[at];
          disagree += d * d / (2 * other.plane(3 + ch)[at] + 18 * guide.plane(3 + ch)[at] + 1e-6f);
        }
        pw[n] = 1e-3f;
        pe[n] = disagree * (1.f / 3);
        least = std::min(least, pe[n]);
        ++n;
      }
      double sum[3] = {0, 0, 0}, wsum = 0;
      for (int k = 0; k < n; ++k) {
        const float w = pw[k] * expNegative(least - pe[k]);
        for (int ch = 0; ch < 3; ++ch) sum[ch] += double(w) * pv[k][ch];
        wsum += w;
      }
      Vec3f v{0, 0, 0};
      if (wsum > 0) v = Vec3f(float(sum[0] / wsum), float(sum[1] / wsum), float(sum[2] / wsum));
      else if (ok) v = Vec3f(half.plane(0)[half.at(x, y)], half.plane(1)[half.at(x, y)], half.plane(2)[half.at(x, y)]);
      out[size_t(y) * size_t(p.width) + size_t(x)] = v;
    }
  });
  return out;
}

std::vector<Vec3f> denoiseQuality(const DenoiseInput& in, const NoisyImage& image, Prepared& p,
                                  const std::vector<float>& samples) {
  const QualityParams q;
  // The halves' variance: each half has half the samples, so twice the variance of the mean.
  Planes A, B, guideA, guideB;
  colourPlanes(p, image.a, image.variance, 2.f, p.features.pad, A);
  colourPlanes(p, image.b, image.variance, 2.f, p.features.pad, B);
  fillUnknownVariance(p, samples, A, {{0, 3}, {1, 4}, {2, 5}});
  fillUnknownVariance(p, samples, B, {{0, 3}, {1, 4}, {2, 5}});
  boxGuide(p, A, p.features.pad, guideA);
  boxGuide(p, B, p.features.pad, guideB);
  const std::vector<Vec3f> fa = filterHalf(p, A, guideB, B, q);
  const std::vector<Vec3f> fb = filterHalf(p, B, guideA, A, q);
  std::vector<Vec3f> out(in.pixels());
  for (size_t i = 0; i < out.size(); ++i) out[i] = (fa[i] + fb[i]) * 0.5f;
  return out;
}

// ---- Fast: variance-guided a-trous -------------------------------------------------------------

struct FastParams {
  int iterations = 5;  // steps 1, 2, 4, 8, 16: a reach of 31 pixels
  float sigmaLuminance = 4, sigmaDepth = 1;  // (normals: the cosine to the 64th, by squaring)
  // Albedo edges stop the filter too: dividing by the albedo makes a dark channel's irradiance
  // large (a colour-mapped cap of albedo 0.005 in green), and mixed into a neighbour of another
  // albedo it came back 20x too bright (ct_chest_cut, relMSE rising with spp).
  float sigmaAlbedo = 0.05f;
};

// The variance the weights read (plane 4): plane 3 blurred 3x3 over valid pixels (SVGF, section
// 4.4: steadier than one pixel's).
ISO_DENOISE_CLONES
void blurVarianceRow(int y, const Planes& geo, Planes& src) {
  const int w = src.width;
  thread_local std::vector<float> acc;
  acc.assign(size_t(w) * 2, 0.f);
  float *s = acc.data(), *n = s + w;
  const size_t base = src.at(0, y);
  for (int dy = -1; dy <= 1; ++dy)
    for (int dx = -1; dx <= 1; ++dx) {
      const ptrdiff_t off = ptrdiff_t(dy) * src.stride + dx;
      const float k = (dx == 0 ? 0.5f : 0.25f) * (dy == 0 ? 0.5f : 0.25f);
      const float* v = src.plane(3) + base + off;
      const float* ok = geo.plane(6) + base + off;
      for (int x = 0; x < w; ++x) {
        s[x] += k * ok[x] * v[x];
        n[x] += k * ok[x];
      }
    }
  float* out = src.plane(4) + base;
  for (int x = 0; x < w; ++x) out[x] = n[x] > 0 ? s[x] / n[x] : 0.f;
}

// One tap of the a-trous kernel over a row: the weight of q = p + offset for every p, accumulated.
[[gnu::always_inline]] inline void atrousTap(
    int w, float h, const float* __restrict n0, const float* __restrict n1, const float* __restrict n2,
    const float* __restrict hn, const float* __restrict z, const float* __restrict lum, const float* __restrict invL,
    const float* __restrict invZ, const float* __restrict qn0, const float* __restrict qn1,
    const float* __restrict qn2, const float* __restrict qhn, const float* __restrict qz,
    const float* __restrict ql, const float* __restrict qv, const float* __restrict qr, const float* __restrict qg,
    const float* __restrict qb, const float* __restrict qvar, const float* __restrict a0,
    const float* __restrict a1, const float* __restrict a2, const float* __restrict qa0, const float* __restrict qa1,
    const float* __restrict qa2, float invAlbedo, float* __restrict s0, float* __restrict s1, float* __restrict s2,
    float* __restrict ws, float* __restrict vs) {
  for (int x = 0; x < w; ++x) {
    const float d = std::fabs(lum[x] - ql[x]) * invL[x] + std::fabs(z[x] - qz[x]) * invZ[x] +
                    (std::fabs(a0[x] - qa0[x]) + std::fabs(a1[x] - qa1[x]) + std::fabs(a2[x] - qa2[x])) * invAlbedo;
    // Normals alike (or background meeting background: neither has one).
    const float dot = std::max(0.f, n0[x] * qn0[x] + n1[x] * qn1[x] + n2[x] * qn2[x]);
    const float c = dot * hn[x] * qhn[x] + (1 - hn[x]) * (1 - qhn[x]);
    float cn = c * c;  // c^2, then c^64 by squaring
    cn = cn * cn;
    cn = cn * cn;
    cn = cn * cn;
    cn = cn * cn;
    cn = cn * cn;
    const float wt = h * qv[x] * cn * expNegative(-d);
    s0[x] += wt * qr[x];
    s1[x] += wt * qg[x];
    s2[x] += wt * qb[x];
    ws[x] += wt;
    vs[x] += wt * wt * qvar[x];
  }
}

ISO_DENOISE_CLONES
void atrousRow(int y, int step, const Planes& src, const Planes& geo, const Planes& feat, const FastParams& fp,
               Planes& dst) {
  // src planes: 0-2 irradiance, 3 luminance variance, 4 its blur (for the weights), 5 luminance.
  // geo planes: 0-2 unit normal, 3 has-normal, 4 depth, 5 depth gradient, 6 valid; feat: the
  // features (0-2 albedo), laid out alike.
  static constexpr float kKernel[3] = {0.25f, 0.5f, 0.25f};
  const int w = src.width;
  thread_local std::vector<float> acc;
  acc.assign(size_t(w) * 8, 0.f);
  float* __restrict s0 = acc.data();
  float *__restrict s1 = s0 + w, *__restrict s2 = s1 + w, *__restrict ws = s2 + w, *__restrict vs = ws + w,
                    *__restrict invL = vs + w, *__restrict invZ1 = invL + w, *__restrict invZ2 = invZ1 + w;
  const size_t base = src.at(0, y);
  const float *__restrict n0 = geo.plane(0) + base, *__restrict n1 = geo.plane(1) + base,
                          *__restrict n2 = geo.plane(2) + base, *__restrict hn = geo.plane(3) + base,
                          *__restrict z = geo.plane(4) + base, *__restrict gz = geo.plane(5) + base,
                          *__restrict lum = src.plane(5) + base, *__restrict varf = src.plane(4) + base;
  // What depends on the pixel alone: the luminance and depth scales (taps one and two steps away).
  const float sigmaL = fp.sigmaLuminance, z1 = fp.sigmaDepth * float(step), z2 = 2 * z1;
  for (int x = 0; x < w; ++x) {
    invL[x] = 1.f / (sigmaL * std::sqrt(varf[x]) + 1e-6f);
    invZ1[x] = 1.f / (z1 * gz[x] + 1e-3f);
    invZ2[x] = 1.f / (z2 * gz[x] + 1e-3f);
  }
  for (int dy = -1; dy <= 1; ++dy)
    for (int dx = -1; dx <= 1; ++dx) {
      const ptrdiff_t off = ptrdiff_t(dy * step) * src.stride + dx * step;
      const float h = kKernel[dx + 1] * kKernel[dy + 1];
      const float* __restrict invZ = std::abs(dx) + std::abs(dy) == 2 ? invZ2 : invZ1;
      atrousTap(w, h, n0, n1, n2, hn, z, lum, invL, invZ, n0 + off, n1 + off, n2 + off, hn + off, z + off, lum + off,
                geo.plane(6) + base + off, src.plane(0) + base + off, src.plane(1) + base + off,
                src.plane(2) + base + off, src.plane(3) + base + off, feat.plane(0) + base, feat.plane(1) + base,
                feat.plane(2) + base, feat.plane(0) + base + off, feat.plane(1) + base + off, feat.plane(2) + base + off,
                1.f / (3 * fp.sigmaAlbedo), s0, s1, s2, ws, vs);
    }
  float *r = dst.plane(0) + base, *g = dst.plane(1) + base, *b = dst.plane(2) + base, *v = dst.plane(3) + base,
        *l = dst.plane(5) + base;
  for (int x = 0; x < w; ++x) {
    const float inv = ws[x] > 0 ? 1.f / ws[x] : 0.f;
    r[x] = s0[x] * inv;
    g[x] = s1[x] * inv;
    b[x] = s2[x] * inv;
    v[x] = vs[x] * inv * inv;
    l[x] = luminance(r[x], g[x], b[x]);
  }
}

std::vector<Vec3f> denoiseFast(const DenoiseInput& in, const NoisyImage& image, Prepared& p,
                               const std::vector<float>& samples) {
  const FastParams fp;
  const int pad = p.features.pad;
  const Planes& F = p.features;
  const float* valid = F.plane(Prepared::kValid);
  // The colour over the albedo (where there is one), so that texture is not blurred; its
  // luminance and the luminance's variance (channels move together: their deviations add).
  auto demodulator = [&](int c, size_t o) {
    const float al = F.plane(c)[o];
    return al > 1e-3f ? std::max(al, 0.05f) : 1.f;
  };
  Planes src, dst, geo;
  src.init(p.width, p.height, pad, 6);
  geo.init(p.width, p.height, pad, 7);
  parallelRows(p.height, [&](int y) {
    for (int x = 0; x < p.width; ++x) {
      const size_t i = size_t(y) * size_t(p.width) + size_t(x), o = F.at(x, y);
      if (valid[o] == 0) continue;
      float sd = 0;
      for (int c = 0; c < 3; ++c) {
        const float a = demodulator(c, o);
        src.plane(c)[o] = image.mean[i][c] / a;
        sd += (c == 0 ? 0.2126f : c == 1 ? 0.7152f : 0.0722f) * std::sqrt(image.variance[i][c]) / a;
      }
      src.plane(3)[o] = sd * sd;
      src.plane(5)[o] = luminance(src.plane(0)[o], src.plane(1)[o], src.plane(2)[o]);
      const float nx = F.plane(3)[o], ny = F.plane(4)[o], nz = F.plane(5)[o];
      const float len = std::sqrt(nx * nx + ny * ny + nz * nz);
      if (len > 1e-6f) {
        geo.plane(0)[o] = nx / len, geo.plane(1)[o] = ny / len, geo.plane(2)[o] = nz / len;
        geo.plane(3)[o] = 1;
      }
      geo.plane(4)[o] = F.plane(6)[o];
      geo.plane(6)[o] = 1;
    }
  });
  // One sample: no variance of its own; the spread of the luminance around instead.
  fillUnknownVariance(p, samples, src, {{5, 3}});
  // Depth gradient per pixel (the larger difference to a valid neighbour).
  parallelRows(p.height, [&](int y) {
    for (int x = 0; x < p.width; ++x) {
      const size_t o = F.at(x, y);
      if (valid[o] == 0) continue;
      const float zc = geo.plane(4)[o];
      float g = 0;
      for (const auto& [dx, dy] : {std::pair{1, 0}, std::pair{-1, 0}, std::pair{0, 1}, std::pair{0, -1}}) {
        const size_t q = F.at(x + dx, y + dy);
        if (valid[q] != 0) g = std::max(g, std::fabs(geo.plane(4)[q] - zc));
      }
      geo.plane(5)[o] = g;
    }
  });
  dst.init(p.width, p.height, pad, 6);
  for (int it = 0; it < fp.iterations; ++it) {
    // The weights' variance: the current one blurred 3x3 (SVGF, section 4.4), steadier than one
    // pixel's.
    parallelRows(p.height, [&](int y) { blurVarianceRow(y, geo, src); });
    const int step = 1 << it;
    parallelRows(p.height, [&](int y) { atrousRow(y, step, src, geo, F, fp, dst); });
    std::swap(src, dst);
  }
  std::vector<Vec3f> out(in.pixels());
  parallelRows(p.height, [&](int y) {
    for (int x = 0; x < p.width; ++x) {
      const size_t i = size_t(y) * size_t(p.width) + size_t(x), o = src.at(x, y);
      out[i] = Vec3f(src.plane(0)[o] * demodulator(0, o), src.plane(1)[o] * demodulator(1, o),
                     src.plane(2)[o] * demodulator(2, o));
    }
  });
  return out;
}

// Neither filter's weights sum to one over the pixels a pixel gives to (only over those it takes
// from), so light moves: measured, the image mean shifted by up to 2.5% (quality) and 18% (fast,
// whose luminance test turns fireflies' energy away) on the Cornell box at 4-16 spp. What the
// filter took away or added is put back at a scale far above its own: the raw image's residual
// (raw - denoised), averaged over a (2 kRadius + 1)^2 box twice (a tent of reach 2 kRadius),
// is added. Its noise is that of a ~4,000-pixel mean; the image mean is then the raw's.
void restoreLocalMean(const Prepared& p, const std::vector<Vec3f>& raw, std::vector<Vec3f>& out) {
  constexpr int kRadius = 16;
  const int w = p.width, h = p.height;
  const Planes& F = p.features;
  const float* valid = F.plane(Prepared::kValid);
  // Residual and weight (valid pixels), then box passes: rows, columns, rows, columns.
  std::vector<float> r(size_t(w) * size_t(h) * 4, 0.f), t(r.size(), 0.f);
  parallelRows(h, [&](int y) {
    for (int x = 0; x < w; ++x) {
      const size_t i = size_t(y) * size_t(w) + size_t(x);
      if (valid[F.at(x, y)] == 0) continue;
      for (int c = 0; c < 3; ++c) r[4 * i + size_t(c)] = raw[i][c] - out[i][c];
      r[4 * i + 3] = 1;
    }
  });
  auto boxRows = [&](const std::vector<float>& src, std::vector<float>& dst) {
    parallelRows(h, [&](int y) {
      const float* row = src.data() + size_t(y) * size_t(w) * 4;
      float* o = dst.data() + size_t(y) * size_t(w) * 4;
      double acc[4] = {0, 0, 0, 0};
      for (int x = -kRadius; x < w; ++x) {
        const int add = x + kRadius, drop = x - kRadius - 1;
        for (int c = 0; c < 4; ++c) {
          if (add < w) acc[c] += row[4 * add + c];
          if (drop >= 0) acc[c] -= row[4 * drop + c];
          if (x >= 0) o[4 * x + c] = float(acc[c]);
        }
      }
    });
  };
  auto boxColumns = [&](const std::vector<float>& src, std::vector<float>& dst) {
    tbb::parallel_for(tbb::blocked_range<int>(0, w, 16), [&](const tbb::blocked_range<int>& range) {
      for (int x = range.begin(); x < range.end(); ++x) {
        double acc[4] = {0, 0, 0, 0};
        for (int y = -kRadius; y < h; ++y) {
          const int add = y + kRadius, drop = y - kRadius - 1;
          for (int c = 0; c < 4; ++c) {
            if (add < h) acc[c] += src[(size_t(add) * size_t(w) + size_t(x)) * 4 + size_t(c)];
            if (drop >= 0) acc[c] -= src[(size_t(drop) * size_t(w) + size_t(x)) * 4 + size_t(c)];
            if (y >= 0) dst[(size_t(y) * size_t(w) + size_t(x)) * 4 + size_t(c)] = float(acc[c]);
          }
        }
      }
    });
  };
  boxRows(r, t);
  boxColumns(t, r);
  boxRows(r, t);
  boxColumns(t, r);
  parallelRows(h, [&](int y) {
    for (int x = 0; x < w; ++x) {
      const size_t i = size_t(y) * size_t(w) + size_t(x);
      if (valid[F.at(x, y)] == 0 || !(r[4 * i + 3] > 0)) continue;
      for (int c = 0; c < 3; ++c) out[i][c] += r[4 * i + size_t(c)] / r[4 * i + 3];
    }
  });
}

// A pixel that took no part (not finite) gets the mean of its valid neighbours' results, from the
// nearest ring (3x3, then 5x5, ...) that has any; 0 if none within 7x7.
void fillFromNeighbours(const Prepared& p, std::vector<Vec3f>& out) {
  if (p.nonFinite == 0) return;
  const Planes& F = p.features;
  const float* valid = F.plane(Prepared::kValid);
  for (int y = 0; y < p.height; ++y)
    for (int x = 0; x < p.width; ++x) {
      if (valid[F.at(x, y)] != 0) continue;
      Vec3f sum{0, 0, 0};
      int n = 0;
      for (int r = 1; r <= 3 && n == 0; ++r)
        for (int dy = -r; dy <= r; ++dy)
          for (int dx = -r; dx <= r; ++dx) {
            const int qx = x + dx, qy = y + dy;
            if (qx < 0 || qy < 0 || qx >= p.width || qy >= p.height || valid[F.at(qx, qy)] == 0) continue;
            sum += out[size_t(qy) * size_t(p.width) + size_t(qx)];
            ++n;
          }
      out[size_t(y) * size_t(p.width) + size_t(x)] = n ? sum / float(n) : Vec3f(0, 0, 0);
    }
}

}  // namespace

size_t denoiseBytesPerPixel(DenoiseMode mode) {
  // Planes (floats): quality 8 features + 4 x 6 colour + guide, models per centre, two halves'
  // results; fast 8 features + 6 colour + 2 x 6 + 7 + albedo.
  return mode == DenoiseMode::Quality ? (8 + 24 + 6) * 4 + 2 * 12 + 120 : (8 + 6 + 12 + 7 + 3) * 4 + 12;
}

uint64_t availableMemoryBytes() {
  FILE* f = std::fopen("/proc/meminfo", "r");
  if (!f) return 0;
  char line[256];
  unsigned long long kib = 0;
  while (std::fgets(line, sizeof line, f))
    if (std::sscanf(line, "MemAvailable: %llu kB", &kib) == 1) break;
  std::fclose(f);
  return uint64_t(kib) * 1024;
}

size_t denoiseInputBytesPerPixel(bool split) { return (split ? 3 : 1) * 4 * 12 + 2 * 12 + 4 + 4; }

std::vector<Vec3f> denoise(const DenoiseInput& in, const NoisyImage& image, DenoiseMode mode, int threads,
                           DenoiseReport* report) {
  const auto start = std::chrono::steady_clock::now();
  std::vector<Vec3f> out;
  if (mode == DenoiseMode::Off || in.pixels() == 0) return image.mean;
  tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
  arena.execute([&] {
    const int pad = std::max(QualityParams().radius + QualityParams().stride + 2, 1 << (FastParams().iterations - 1)) + 1;
   
    Prepared p = prepare(in, image, pad);
    std::vector<float> samples(in.pixels(), 2.f);
    if (!in.samples.empty()) samples = in.samples;
    out = mode == DenoiseMode::Quality ? denoiseQuality(in, image, p, samples) : denoiseFast(in, image, p, samples);
    restoreLocalMean(p, image.mean, out);
    fillFromNeighbours(p, out);
    if (report) report->nonFinitePixels += p.nonFinite;
  });
  if (report) report->seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

}  // namespace iso
