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
// Hot path: no allocation; the only table is the per-pixel cache of the
// first 32 slots' scramble seeds (they do not depend on the sample), filled
// on first use. The helpers are constexpr so they are usable and testable
// at compile time.
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

// Sobol' dimensions 2 and 3 (Joe and Kuo 2008, "Constructing Sobol'
// sequences with better two-dimensional projections", their dimensions 3 and
// 4: primitive polynomials x^2 + x + 1 with m = 1, 3 and x^3 + x + 1 with
// m = 1, 3, 1). Their 32 direction numbers come from the Bratley-Fox
// recurrence at compile time, stored with the digits reversed like
// sobol_dim1_reversed() (entry k: the column of index bit k; bit j: digit j),
// so that the Owen scramble applies to them directly.
struct SobolColumns {
  uint32_t v[32] = {};
};

constexpr SobolColumns sobol_reversed_columns(int degree, uint32_t a, const uint32_t* m_init) {
  uint32_t m[33] = {};
  for (int k = 1; k <= degree; ++k) m[k] = m_init[k - 1];
  for (int k = degree + 1; k <= 32; ++k) {
    uint32_t x = m[k - degree] ^ (m[k - degree] << degree);
    for (int j = 1; j < degree; ++j)
      if ((a >> (degree - 1 - j)) & 1u) x ^= m[k - j] << j;
    m[k] = x;
  }
  SobolColumns c;
  for (int k = 1; k <= 32; ++k) c.v[k - 1] = reverse_bits32(m[k] << (32 - k));
  return c;
}

inline constexpr uint32_t kSobolM2[] = {1, 3};
inline constexpr uint32_t kSobolM3[] = {1, 3, 1};
inline constexpr SobolColumns kSobolDim2Reversed = sobol_reversed_columns(2, 1, kSobolM2);
inline constexpr SobolColumns kSobolDim3Reversed = sobol_reversed_columns(3, 1, kSobolM3);

// The digit-reversed Sobol' coordinate of `index` for generator columns c.
constexpr uint32_t sobol_apply(const SobolColumns& c, uint32_t index) {
  uint32_t r = 0;
  for (; index; index &= index - 1) r ^= c.v[std::countr_zero(index)];
  return r;
}
// sobol_apply() a byte at a time: entry [b][v] is the XOR of the columns of
// the set bits of byte value v at byte b of the index, so a coordinate is
// four table reads and three XORs (4 KB a dimension, kept in L1) instead of
// a loop over the index's set bits (about 16 for a shuffled index). The same
// numbers (SobolBits.ByteTablesAreTheColumns).
struct SobolByteTables {
  uint32_t t[4][256] = {};
};

constexpr SobolByteTables sobol_byte_tables(const SobolColumns& c) {
  SobolByteTables b;
  for (int byte = 0; byte < 4; ++byte)
    for (uint32_t v = 0; v < 256; ++v) {
      uint32_t r = 0;
      for (int bit = 0; bit < 8; ++bit)
        if ((v >> bit) & 1u) r ^= c.v[byte * 8 + bit];
      b.t[byte][v] = r;
    }
  return b;
}

inline constexpr SobolByteTables kSobolDim2Bytes = sobol_byte_tables(kSobolDim2Reversed);
inline constexpr SobolByteTables kSobolDim3Bytes = sobol_byte_tables(kSobolDim3Reversed);

constexpr uint32_t sobol_apply(const SobolByteTables& b, uint32_t index) {
  return b.t[0][index & 0xffu] ^ b.t[1][(index >> 8) & 0xffu] ^ b.t[2][(index >> 16) & 0xffu] ^
         b.t[3][index >> 24];
}

constexpr uint32_t sobol_dim2(uint32_t index) {
  return reverse_bits32(sobol_apply(kSobolDim2Reversed, index));
}
constexpr uint32_t sobol_dim3(uint32_t index) {
  return reverse_bits32(sobol_apply(kSobolDim3Reversed, index));
}

// ---------------------------------------------------------------------------

class PixelSampler {
 public:
  PixelSampler(SamplerKind kind, uint64_t seed, int frame, int px, int py, Stream stream);
  // Starts sample `index` of this pixel; the dimension counter restarts at 0.
  void start_sample(uint32_t index);
  float get1d();  // in [0, 1); the first coordinate of get2d() in this slot
  Vec2 get2d();   // in [0, 1)^2
  // Two 2D points from one 4D Sobol' point (dimensions 0-3 at one shuffled
  // index, each coordinate Owen-scrambled with its own seed), consuming two
  // slots: `first` is exactly what get2d() would give in the first slot.
  // For integrands that couple two 2D inputs, such as the pixel jitter and
  // the lens of a defocused edge, the pair is stratified jointly, where two
  // get2d() calls are independently shuffled ("padded") and stratify each
  // only on its own. kIndependent: two get2d() calls.
  void get4d(Vec2* first, Vec2* second);
  // Consumes `slots` slots as get1d()/get2d() would, without computing their
  // values (for numbers a path turns out not to need): the later slots are
  // the same either way.
  void skip(uint32_t slots) { dim_ += slots; }
  // Where the sampler stands: a sample, a slot, and what start_sample()
  // derived from the sample's index. Paths traced together (trace_paths)
  // share one sampler; each keeps its own Position and returns to it before
  // it draws, without deriving anything again.
  struct Position {
    uint32_t index = 0, slot = 0;
    uint32_t reversed_index = 0;  // kSobol
    uint64_t sample_seed = 0;     // kIndependent
  };
  Position position() const { return {index_, dim_, reversed_index_, sample_seed_}; }
  void seek(const Position& p) {
    index_ = p.index;
    dim_ = p.slot;
    reversed_index_ = p.reversed_index;
    sample_seed_ = p.sample_seed;
  }

  // The five numbers a path vertex draws (integrator.cpp), from five
  // consecutive slots: exactly get1d(), get2d(), get1d(), get2d(), get1d()
  // in that order, computed together. kSobol on a CPU with AVX2 scrambles
  // the slots in 8-wide integer lanes (sampler.cpp, simd.h); the arithmetic
  // is integer and the conversion to float exact, so the numbers are
  // bit-identical on every CPU (Sampler.BatchedDrawsAreTheSingleDraws).
  struct VertexNumbers {
    float select;    // which light
    Vec2 light;      // the point on it
    float lobe;      // which BSDF lobe
    Vec2 bsdf;       // the direction within it
    float roulette;  // Russian roulette
  };
  void get_vertex(VertexNumbers* out);
  // get4d() of samples first, ..., first + n - 1 (1 <= n <= 8), each
  // drawn as the first thing of its sample: start_sample(first + k) then
  // get4d(). Afterwards the sampler stands where the last of those left it
  // (sample first + n - 1, past its two slots).
  void get4d_samples(uint32_t first, int n, Vec2* firsts, Vec2* seconds);

  uint64_t pixel_seed() const { return pixel_seed_; }
  // Slots the present sample has consumed so far.
  uint32_t slots_used() const { return dim_; }

 private:
  // Scramble seeds of one Sobol' slot: index shuffle and first coordinate.
  uint64_t slot_hash(uint32_t slot, uint32_t which) const {
    return mix64(pixel_seed_ + kGoldenGamma * (2 * uint64_t(slot) + which + 1));
  }
  // A slot's seeds: slot_hash(slot, 0) (index shuffle, first coordinate)
  // and the low word of slot_hash(slot, 1) (second coordinate). They depend
  // on the pixel and the slot only, not on the sample, so the first
  // kCachedSlots slots' are computed once per PixelSampler, on first use,
  // and every further sample of the pixel reads them (the same numbers,
  // without their two hashes per slot). The cache keeps the three 32-bit
  // seeds of a slot in three arrays (index shuffle, first and second
  // coordinate), so that the batched draws load eight slots' seeds at once.
  struct SlotSeeds {
    uint64_t first;
    uint32_t second;
  };
  SlotSeeds slot_seeds(uint32_t slot) {
    if (slot >= kCachedSlots) return {slot_hash(slot, 0), uint32_t(slot_hash(slot, 1))};
    cache_through(slot + 1);
    return {(uint64_t(seed_x_[slot]) << 32) | seed_index_[slot], seed_y_[slot]};
  }
  // Fills the cache for slots [cached_, end) (end <= kCachedSlots).
  void cache_through(uint32_t end) {
    for (; cached_ < end; ++cached_) {
      const uint64_t h = slot_hash(cached_, 0);
      seed_index_[cached_] = uint32_t(h);
      seed_x_[cached_] = uint32_t(h >> 32);
      seed_y_[cached_] = uint32_t(slot_hash(cached_, 1));
    }
  }
  // i' = nested_uniform_scramble(index, seed), from the bit-reversed index
  // that start_sample() keeps, so a slot pays for one reversal, not two.
  static uint32_t shuffled_index(uint32_t reversed_index, uint32_t seed) {
    return reverse_bits32(laine_karras_permutation(reversed_index, seed));
  }
  // kSobol: Sobol' dimensions 0 and 1 of slot `slot`, Owen-scrambled, at
  // the slot's shuffled index, which is also returned in *shuffled (get4d()
  // continues with dimensions 2 and 3 at the same index).
  Vec2 sobol_pair(uint32_t slot, uint32_t* shuffled);

  SamplerKind kind_;
  bool simd_ = false;    // kSobol, and the batched draws may use AVX2 (decided at construction)
  uint64_t pixel_seed_;  // hash of (seed, frame, pixel, stream)
  uint32_t index_ = 0;
  uint32_t dim_ = 0;
  // Per sample: kSobol keeps reverse_bits32(index_), kIndependent a hash of
  // (pixel_seed_, index_) that seeds a splitmix64 stream over slots.
  uint32_t reversed_index_ = 0;
  uint64_t sample_seed_ = 0;
  // kSobol: slot_seeds() of slots [0, cached_); a path uses about five
  // slots per bounce after the camera's four.
  // Each array has 8 entries more than it caches, zero: a batch of five
  // slots loads eight lanes.
  static constexpr uint32_t kCachedSlots = 32;
  uint32_t cached_ = 0;
  uint32_t seed_index_[kCachedSlots + 8];  // written by cache_through before read
  uint32_t seed_x_[kCachedSlots + 8];
  uint32_t seed_y_[kCachedSlots + 8];
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
  const uint64_t h = slot_seeds(slot).first;
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
  uint32_t unused;
  return sobol_pair(slot, &unused);
}

inline Vec2 PixelSampler::sobol_pair(uint32_t slot, uint32_t* shuffled) {
  const SlotSeeds seeds = slot_seeds(slot);
  const uint64_t h = seeds.first;
  const uint32_t seed_y = seeds.second;
  const uint32_t s = shuffled_index(reversed_index_, uint32_t(h));
  const uint32_t x = reverse_bits32(laine_karras_permutation(s, uint32_t(h >> 32)));
  const uint32_t y = reverse_bits32(laine_karras_permutation(sobol_dim1_reversed(s), seed_y));
  *shuffled = s;
  return {u32_to_unit_float(x), u32_to_unit_float(y)};
}

inline void PixelSampler::get4d(Vec2* first, Vec2* second) {
  if (kind_ == SamplerKind::kIndependent) {
    *first = get2d();
    *second = get2d();
    return;
  }
  const uint32_t slot = dim_;
  dim_ += 2;
  uint32_t s;
  *first = sobol_pair(slot, &s);
  // Dimensions 2 and 3 at the same index, scrambled with the seeds of the
  // second slot (which get4d() consumes).
  const uint64_t h2 = slot_seeds(slot + 1).first;
  const uint32_t z =
      reverse_bits32(laine_karras_permutation(sobol_apply(kSobolDim2Bytes, s), uint32_t(h2)));
  const uint32_t w =
      reverse_bits32(laine_karras_permutation(sobol_apply(kSobolDim3Bytes, s), uint32_t(h2 >> 32)));
  *second = {u32_to_unit_float(z), u32_to_unit_float(w)};
}

}  // namespace dofarm::render
