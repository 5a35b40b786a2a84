#pragma once
// Random numbers that depend only on (pixel, sample index, dimension, seed), never on which
// thread renders the pixel or in what order: the same seed gives the same image bits with
// any thread count (pbrt-v4's design; the hash is SplitMix64's finaliser).
#include <cstdint>

namespace iso {

inline uint64_t mixBits(uint64_t v) {
  v ^= v >> 30;
  v *= 0xbf58476d1ce4e5b9ull;
  v ^= v >> 27;
  v *= 0x94d049bb133111ebull;
  v ^= v >> 31;
  return v;
}

class Sampler {
 public:
  // The same sampler from its pixel's key: a renderer hashes the seed once and each pixel once,
  // not both again for every sample.
  struct PixelKey {
    uint64_t bits;
  };
  static uint64_t seedKey(uint64_t seed) { return mixBits(seed); }
  static PixelKey pixelKey(uint64_t seedKey, uint32_t x, uint32_t y) { return {mixBits(seedKey ^ (uint64_t(x) << 32 | y))}; }

  Sampler(uint32_t x, uint32_t y, uint32_t sampleIndex, uint64_t seed)
      : Sampler(pixelKey(seedKey(seed), x, y), sampleIndex) {}
  Sampler(PixelKey pixel, uint32_t sampleIndex) : m_key(mixBits(pixel.bits ^ sampleIndex)) {}
  // Uniform in [0, 1): the top 24 bits of the hash of the next dimension.
  float next() {
    const uint64_t bits = mixBits(m_key + 0x9e3779b97f4a7c15ull * ++m_dimension);
    return float(bits >> 40) * 0x1p-24f;
  }

 private:
  uint64_t m_key;
  uint64_t m_dimension = 0;
};

}  // namespace iso
