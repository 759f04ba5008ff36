// Deterministic per-pixel sample streams (DESIGN.md "Sampling is
// deterministic"): every number is a pure function of (seed, frame, pixel,
// stream, sample index, dimension slot), so tiling, thread count and the order
// in which pixels are visited never change a pixel.
//
// Each get1d()/get2d() call consumes one dimension slot k = 0, 1, 2, ...
//
// kSobol: shuffled, Owen-scrambled Sobol' (Burley 2020, "Practical Hash-based
// Owen Scrambling", sec. 4). Slot k of sample i is the 2D point of Sobol'
// dimensions 0 and 1 (the (0,2)-sequence in base 2) at the index
//   i' = nested_uniform_scramble(i, seed_k),
// and each coordinate is then Owen-scrambled with its own seed. Because an
// Owen scramble of the index maps every aligned block of 2^m indices onto an
// aligned block of 2^m indices, and every such block of the (0,2)-sequence is
// a (0,m,2)-net, the first 2^m samples of every slot are a (0,m,2)-net (for
// any m up to 24, the float resolution): every 2D request (pixel jitter, lens, BSDF, light) is well
// stratified, while the independent per-slot shuffles keep slots uncorrelated
// with each other ("padding"). get1d() is the first coordinate of a slot.
// kIndependent: hashed uniform random numbers (splitmix64), for comparison.
//
// Hot path: no state beyond a few words, no tables, no allocation, no loops;
// the helpers are constexpr so they are usable and testable at compile time.
#pragma once

#include <bit>
#include <cstdint>

#include "common/jobspec.h"
#include "common/math.h"

namespace dofarm::render {

// Which buffer a sample feeds: streams never share random numbers.
enum class Stream : uint32_t { kNoisy = 1, kReference = 2, kAlbedoRef = 3, kTest = 99 };

// ---------------------------------------------------------------------------
// Hash helpers shared by the sampler and by anything else that needs
// reproducible randomness.

inline constexpr uint64_t kGoldenGamma = 0x9e3779b97f4a7c15ull;  // 2^64 / phi, odd

// The splitmix64 finalizer (Steele, Lea, Flood 2014; Stafford's "Mix13"
// constants): a bijection on 64 bits with full avalanche.
constexpr uint64_t mix64(uint64_t x) {
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

// Order-dependent combination; for either argument fixed it is a bijection
// of the other, so distinct (pixel, frame, ...) tuples never collide by
// construction of one step. `b` is mixed first so small structured integers
// (pixel coordinates, frame numbers) never cancel structure left in `a`.
constexpr uint64_t hash_combine(uint64_t a, uint64_t b) {
  return mix64(std::rotl(a, 27) ^ mix64(b + kGoldenGamma));
}

// The 24 top bits give every float in [0, 1) on a 2^-24 grid, exactly, and
// never 1.0f (rounding 32 bits to float would).
constexpr float u32_to_unit_float(uint32_t v) { return float(v >> 8) * 0x1p-24f; }

// ---------------------------------------------------------------------------
// Sobol' and Owen-scrambling building blocks. 32-bit fixed point: bit 31 is
// the first binary digit (1/2) of a coordinate.

constexpr uint32_t reverse_bits32(uint32_t x) {
  x = __builtin_bswap32(x);
  x = ((x & 0x0f0f0f0fu) << 4) | ((x >> 4) & 0x0f0f0f0fu);
  x = ((x & 0x33333333u) << 2) | ((x >> 2) & 0x33333333u);
  x = ((x & 0x55555555u) << 1) | ((x >> 1) & 0x55555555u);
  return x;
}

// A hash-based permutation in the style of Laine and Karras 2011 ("Stratified
// sampling for stochastic transparency"), constants from Burley 2020 (sec. 3).
// Every step (adding a constant, x ^= x * even) changes bit j only as a
// function of bits <= j, so on bit-reversed input it is a nested scramble:
// each digit is flipped depending only on the digits before it.
constexpr uint32_t laine_karras_permutation(uint32_t x, uint32_t seed) {
  x += seed;
  x ^= x * 0x6c50b47cu;
  x ^= x * 0xb82f1e52u;
  x ^= x * 0xc7afe638u;
  x ^= x * 0x8d22f6e6u;
  return x;
}

// Owen scramble (a nested uniform random digit scramble) of a 32-bit
// fixed-point coordinate, or of a sample index (Burley 2020, sec. 4).
constexpr uint32_t nested_uniform_scramble(uint32_t x, uint32_t seed) {
  return reverse_bits32(laine_karras_permutation(reverse_bits32(x), seed));
}

// Sobol' dimension 1 (Joe-Kuo dimension 2: polynomial x + 1, m_1 = 1) with its
// digits in reversed order (bit j = digit j). Its generator matrix is Pascal's
// triangle mod 2: digit j is the parity of the index bits k with C(k, j) odd,
// i.e. (Lucas) of the bits k whose binary digits include those of j. That
// superset parity is a GF(2) zeta transform, five shift-and-xor butterflies:
// no direction-number table and no loop over index bits.
constexpr uint32_t sobol_dim1_reversed(uint32_t index) {
  uint32_t a = index;
  a ^= (a >> 1) & 0x55555555u;
  a ^= (a >> 2) & 0x33333333u;
  a ^= (a >> 4) & 0x0f0f0f0fu;
  a ^= (a >> 8) & 0x00ff00ffu;
  a ^= (a >> 16) & 0x0000ffffu;
  return a;
}

// Unscrambled Sobol' points, 32-bit fixed point; dimension 0 is van der Corput.
constexpr uint32_t sobol_dim0(uint32_t index) { return reverse_bits32(index); }
constexpr uint32_t sobol_dim1(uint32_t index) { return reverse_bits32(sobol_dim1_reversed(index)); }

// ---------------------------------------------------------------------------

class PixelSampler {
 public:
  PixelSampler(SamplerKind kind, uint64_t seed, int frame, int px, int py, Stream stream);
  // Starts sample `index` of this pixel; the dimension counter restarts at 0.
  void start_sample(uint32_t index);
  float get1d();  // in [0, 1); the first coordinate of get2d() in this slot
  Vec2 get2d();   // in [0, 1)^2
  // Consumes `slots` slots as get1d()/get2d() would, without computing their
  // values (for numbers a path turns out not to need): the later slots are
  // the same either way.
  void skip(uint32_t slots) { dim_ += slots; }

  uint64_t pixel_seed() const { return pixel_seed_; }

 private:
  // Scramble seeds of one Sobol' slot: index shuffle and first coordinate.
  uint64_t slot_hash(uint32_t slot, uint32_t which) const {
    return mix64(pixel_seed_ + kGoldenGamma * (2 * uint64_t(slot) + which + 1));
  }
  // i' = nested_uniform_scramble(index, seed), from the bit-reversed index
  // that start_sample() keeps, so a slot pays for one reversal, not two.
  static uint32_t shuffled_index(uint32_t reversed_index, uint32_t seed) {
    return reverse_bits32(laine_karras_permutation(reversed_index, seed));
  }

  SamplerKind kind_;
  uint64_t pixel_seed_;  // hash of (seed, frame, pixel, stream)
  uint32_t index_ = 0;
  uint32_t dim_ = 0;
  // Per sample: kSobol keeps reverse_bits32(index_), kIndependent a hash of
  // (pixel_seed_, index_) that seeds a splitmix64 stream over slots.
  uint32_t reversed_index_ = 0;
  uint64_t sample_seed_ = 0;
};

// ---------------------------------------------------------------------------
// Inline hot path (called per bounce in the integrator).

inline void PixelSampler::start_sample(uint32_t index) {
  index_ = index;
  dim_ = 0;
  if (kind_ == SamplerKind::kSobol) {
    reversed_index_ = reverse_bits32(index);
  } else {
    sample_seed_ = hash_combine(pixel_seed_, index);
  }
}

inline float PixelSampler::get1d() {
  const uint32_t slot = dim_++;
  if (kind_ == SamplerKind::kIndependent) {
    const uint64_t h = mix64(sample_seed_ + kGoldenGamma * (uint64_t(slot) + 1));
    return u32_to_unit_float(uint32_t(h >> 32));
  }
  const uint64_t h = slot_hash(slot, 0);
  // Owen scramble of vdC(i') = reverse(i'): reverse(LK(i', seed)).
  const uint32_t s = shuffled_index(reversed_index_, uint32_t(h));
  return u32_to_unit_float(reverse_bits32(laine_karras_permutation(s, uint32_t(h >> 32))));
}

inline Vec2 PixelSampler::get2d() {
  const uint32_t slot = dim_++;
  if (kind_ == SamplerKind::kIndependent) {
    const uint64_t h = mix64(sample_seed_ + kGoldenGamma * (uint64_t(slot) + 1));
    return {u32_to_unit_float(uint32_t(h >> 32)), u32_to_unit_float(uint32_t(h))};
  }
  const uint64_t h = slot_hash(slot, 0);
  const uint32_t seed_y = uint32_t(slot_hash(slot, 1));
  const uint32_t s = shuffled_index(reversed_index_, uint32_t(h));
  const uint32_t x = reverse_bits32(laine_karras_permutation(s, uint32_t(h >> 32)));
  const uint32_t y = reverse_bits32(laine_karras_permutation(sobol_dim1_reversed(s), seed_y));
  return {u32_to_unit_float(x), u32_to_unit_float(y)};
}

}  // namespace dofarm::render
