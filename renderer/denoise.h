#pragma once
// The denoiser: a clean image from a few samples per pixel, guided by the feature buffers the
// renderer gathers beside the colour (no neural network: OpenImageDenoise is not packaged in
// Debian 12). Two modes, chosen by measurement (docs/BENCHMARKS.md, "The denoiser"):
//
//   quality  first-order regression of the colour on the features (albedo, normal, depth) in a
//            window around sparse centres, weighted by an NL-means distance measured on the
//            *other* half of the samples, so that the weights do not follow the noise they are
//            meant to remove (cross-filtering; Bitterli et al. 2016, "Nonlinearly Weighted
//            First-order Regression for Denoising Monte Carlo Renderings", NFOR). Each centre's
//            linear model is evaluated at the pixels around it and the predictions blended by
//            the same weights (collaborative filtering, NFOR section 4).
//   fast     an edge-avoiding a-trous wavelet filter over the colour divided by albedo, its
//            edges stopped by depth, normal and a luminance distance scaled by the variance it
//            propagates (Schied et al. 2017, "Spatiotemporal Variance-Guided Filtering", SVGF,
//            without the temporal part): for the live preview.
//
// Deterministic: every pixel's arithmetic is fixed, so the image is the same bits for any
// thread count (threads split rows; none sums into another's pixels). A pixel whose input is not
// finite (NaN or infinity in a sample) takes no part in any neighbour's estimate, and gets the
// estimate its finite neighbours give it.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "scene/scene.h"
#include "volume/vec3.h"

namespace iso {

// DenoiseMode, its names and parser: scene/scene.h (the scene file's "film": {"denoise"}).

// One noisy image of the frame, per pixel.
struct NoisyImage {
  std::vector<Vec3f> mean;      // of all samples (what the raw image shows)
  std::vector<Vec3f> a, b;      // of the even and of the odd samples (b = a where a pixel has one)
  std::vector<Vec3f> variance;  // of `mean`, per channel (0 where a pixel has one sample)
  bool empty() const { return mean.empty(); }
};

// What the denoiser reads, gathered by resolveFrame (renderer/render.h). The features come from
// the first hit that is not a perfect mirror or glass (the camera sees through glass to the bone
// behind it), averaged over the samples.
struct DenoiseInput {
  int width = 0, height = 0;
  NoisyImage color;             // the beauty
  NoisyImage direct, indirect;  // the compare integrator's parts (empty otherwise)
  std::vector<Vec3f> albedo, normal;
  std::vector<float> depth;    // mean over the samples that hit something; infinity where none did
  std::vector<float> samples;  // per pixel (where one: the variance is estimated from neighbours)
  // The variance of the features' means, from the halves' difference ((a - b)^2 / 4, summed over
  // channels): albedo, normal, depth. Large where the features themselves are noisy (seen
  // through glass, at edges partly covered); the denoiser smooths them there first.
  std::vector<Vec3f> featureVariance;
  size_t pixels() const { return size_t(width) * size_t(height); }
};

// Bytes the denoiser needs per pixel while it runs, beyond its input (for the memory check
// before a render starts).
size_t denoiseBytesPerPixel(DenoiseMode mode);
// Bytes per pixel of a DenoiseInput with (or without) the compare integrator's parts.
size_t denoiseInputBytesPerPixel(bool split);

// The memory this machine has free for new work (MemAvailable of /proc/meminfo), 0 if unknown.
uint64_t availableMemoryBytes();

struct DenoiseReport {
  double seconds = 0;
  uint64_t nonFinitePixels = 0;  // pixels left out as neighbours (and filled from theirs)
};

// The denoised `image` (input.color, input.direct or input.indirect) in `mode` (not Off), on
// `threads` threads (0: all cores). Adds its time and findings to `report` if given.
std::vector<Vec3f> denoise(const DenoiseInput& input, const NoisyImage& image, DenoiseMode mode, int threads = 0,
                           DenoiseReport* report = nullptr);

}  // namespace iso
