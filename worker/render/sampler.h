// Deterministic per-pixel sample streams (DESIGN.md "Sampling is
// deterministic"): every number is a pure function of (seed, frame, pixel,
// stream, sample index, dimension), so tiling and thread count never change
// a pixel.
//
// kSobol: Owen-scrambled Sobol' (Burley 2020, "Practical Hash-based Owen
// Scrambling"): each request takes the next dimension pair, padded with an
// independent hash-based index shuffle and nested-uniform scramble, so every
// 2D request (pixel jitter, lens, BSDF, light) is a well-stratified 0-2 set.
// kIndependent: hashed uniform random numbers, for comparison.
#pragma once

#include <cstdint>

#include "common/jobspec.h"
#include "common/math.h"

namespace dofarm::render {

// Which buffer a sample feeds: streams never share random numbers.
enum class Stream : uint32_t { kNoisy = 1, kReference = 2, kAlbedoRef = 3, kTest = 99 };

class PixelSampler {
 public:
  PixelSampler(SamplerKind kind, uint64_t seed, int frame, int px, int py, Stream stream);
  // Starts sample `index` of this pixel; the dimension counter restarts at 0.
  void start_sample(uint32_t index);
  float get1d();  // in [0, 1)
  Vec2 get2d();   // in [0, 1)^2

 private:
  SamplerKind kind_;
  uint64_t pixel_seed_;  // hash of (seed, frame, pixel, stream)
  uint32_t index_ = 0;
  uint32_t dim_ = 0;
};

// Hash helpers shared by the sampler and by anything else that needs
// reproducible randomness.
uint64_t mix64(uint64_t x);
uint64_t hash_combine(uint64_t a, uint64_t b);
inline float u32_to_unit_float(uint32_t v) {
  return float(v >> 8) * 0x1p-24f;  // exactly representable, < 1
}

}  // namespace dofarm::render
