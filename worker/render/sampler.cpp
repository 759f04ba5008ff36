#include "worker/render/sampler.h"

#include <algorithm>

#include "worker/render/simd.h"

namespace dofarm::render {

namespace {

#ifdef DOFARM_HAVE_AVX2_KERNELS
// The scalar helpers of sampler.h, eight 32-bit lanes at a time (simd.h).
// reverse_bits32: the bytes of each lane reversed (a byte shuffle), then
// the bits of each byte, by two 16-entry nibble tables.
DOFARM_AVX2 inline __m256i reverse_bits8x32(__m256i x) {
  const __m256i bswap = _mm256_setr_epi8(3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8, 15, 14, 13, 12, 3, 2,
                                         1, 0, 7, 6, 5, 4, 11, 10, 9, 8, 15, 14, 13, 12);
  // rev4(n) for n = 0..15, and rev4(n) << 4.
  const __m256i rev_low = _mm256_setr_epi8(0, 8, 4, 12, 2, 10, 6, 14, 1, 9, 5, 13, 3, 11, 7, 15, 0,
                                           8, 4, 12, 2, 10, 6, 14, 1, 9, 5, 13, 3, 11, 7, 15);
  const __m256i rev_high = _mm256_slli_epi16(rev_low, 4);  // no carry: entries < 16
  const __m256i nibble = _mm256_set1_epi8(0x0f);
  x = _mm256_shuffle_epi8(x, bswap);
  const __m256i lo = _mm256_and_si256(x, nibble);
  const __m256i hi = _mm256_and_si256(_mm256_srli_epi16(x, 4), nibble);
  // A byte's low nibble, reversed, becomes its high nibble and vice versa.
  return _mm256_or_si256(_mm256_shuffle_epi8(rev_high, lo), _mm256_shuffle_epi8(rev_low, hi));
}

DOFARM_AVX2 inline __m256i laine_karras8x32(__m256i x, __m256i seed) {
  x = _mm256_add_epi32(x, seed);
  x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(int(0x6c50b47cu))));
  x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(int(0xb82f1e52u))));
  x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(int(0xc7afe638u))));
  x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(int(0x8d22f6e6u))));
  return x;
}

// reverse_bits32(laine_karras_permutation(x, seed)): an Owen-scrambled
// coordinate from its Sobol' bits, or a shuffled index from a reversed one.
DOFARM_AVX2 inline __m256i scramble8x32(__m256i x, __m256i seed) {
  return reverse_bits8x32(laine_karras8x32(x, seed));
}

DOFARM_AVX2 inline __m256i sobol_dim1_reversed8x32(__m256i a) {
  a = _mm256_xor_si256(a, _mm256_and_si256(_mm256_srli_epi32(a, 1), _mm256_set1_epi32(0x55555555)));
  a = _mm256_xor_si256(a, _mm256_and_si256(_mm256_srli_epi32(a, 2), _mm256_set1_epi32(0x33333333)));
  a = _mm256_xor_si256(a, _mm256_and_si256(_mm256_srli_epi32(a, 4), _mm256_set1_epi32(0x0f0f0f0f)));
  a = _mm256_xor_si256(a, _mm256_and_si256(_mm256_srli_epi32(a, 8), _mm256_set1_epi32(0x00ff00ff)));
  a = _mm256_xor_si256(a,
                       _mm256_and_si256(_mm256_srli_epi32(a, 16), _mm256_set1_epi32(0x0000ffff)));
  return a;
}

// sobol_apply(SobolByteTables): four gathers and three XORs.
DOFARM_AVX2 inline __m256i sobol_apply8x32(const SobolByteTables& b, __m256i index) {
  const __m256i byte = _mm256_set1_epi32(0xff);
  const int* t = reinterpret_cast<const int*>(&b.t[0][0]);
  __m256i r = _mm256_i32gather_epi32(t, _mm256_and_si256(index, byte), 4);
  r = _mm256_xor_si256(
      r, _mm256_i32gather_epi32(t + 256, _mm256_and_si256(_mm256_srli_epi32(index, 8), byte), 4));
  r = _mm256_xor_si256(
      r, _mm256_i32gather_epi32(t + 512, _mm256_and_si256(_mm256_srli_epi32(index, 16), byte), 4));
  return _mm256_xor_si256(r, _mm256_i32gather_epi32(t + 768, _mm256_srli_epi32(index, 24), 4));
}

// u32_to_unit_float: the top 24 bits, converted exactly, times 2^-24.
DOFARM_AVX2 inline void store_unit_floats(float* out, __m256i v) {
  _mm256_storeu_ps(
      out, _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32(v, 8)), _mm256_set1_ps(0x1p-24f)));
}

DOFARM_AVX2 inline __m256i load(const uint32_t* p) {
  return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
}

// Five slots of one sample, from the seeds of eight consecutive slots
// (lanes 5-7 are computed and not used): lanes 0-4 shuffle the sample's
// index with each slot's seed; then lanes 0-4 scramble each slot's first
// coordinate and lanes 5-6 the second coordinates of slots 1 and 3 (the 2D
// draws).
DOFARM_AVX2 void vertex_numbers_avx2(uint32_t reversed_index, const uint32_t* seed_index,
                                     const uint32_t* seed_x, const uint32_t* seed_y, float* out) {
  const __m256i s = scramble8x32(_mm256_set1_epi32(int(reversed_index)), load(seed_index));
  const __m256i lanes = _mm256_setr_epi32(0, 0, 0, 0, 0, 1, 3, 0);
  const __m256i in =
      _mm256_blend_epi32(s, _mm256_permutevar8x32_epi32(sobol_dim1_reversed8x32(s), lanes), 0x60);
  const __m256i seeds =
      _mm256_blend_epi32(load(seed_x), _mm256_permutevar8x32_epi32(load(seed_y), lanes), 0x60);
  store_unit_floats(out, scramble8x32(in, seeds));
}

// get4d() of samples first..first+7: slot 0's seeds shuffle the indices and
// scramble dimensions 0 and 1, slot 1's dimensions 2 and 3.
DOFARM_AVX2 void samples4d_avx2(uint32_t first, uint32_t shuffle_seed, uint32_t seed_x,
                                uint32_t seed_y, uint32_t seed_z, uint32_t seed_w, float* x,
                                float* y, float* z, float* w) {
  const __m256i index =
      _mm256_add_epi32(_mm256_set1_epi32(int(first)), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
  const __m256i s = scramble8x32(reverse_bits8x32(index), _mm256_set1_epi32(int(shuffle_seed)));
  store_unit_floats(x, scramble8x32(s, _mm256_set1_epi32(int(seed_x))));
  store_unit_floats(y, scramble8x32(sobol_dim1_reversed8x32(s), _mm256_set1_epi32(int(seed_y))));
  store_unit_floats(
      z, scramble8x32(sobol_apply8x32(kSobolDim2Bytes, s), _mm256_set1_epi32(int(seed_z))));
  store_unit_floats(
      w, scramble8x32(sobol_apply8x32(kSobolDim3Bytes, s), _mm256_set1_epi32(int(seed_w))));
}
#endif

}  // namespace

void PixelSampler::get_vertex(VertexNumbers* out) {
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (simd_ && dim_ + 5 <= kCachedSlots) {
    cache_through(std::min(dim_ + 8, kCachedSlots));  // the lanes past 5 read cached or zero seeds
    alignas(32) float v[8];
    vertex_numbers_avx2(reversed_index_, &seed_index_[dim_], &seed_x_[dim_], &seed_y_[dim_], v);
    dim_ += 5;
    *out = {v[0], {v[1], v[5]}, v[2], {v[3], v[6]}, v[4]};
    return;
  }
#endif
  out->select = get1d();
  out->light = get2d();
  out->lobe = get1d();
  out->bsdf = get2d();
  out->roulette = get1d();
}

void PixelSampler::get4d_samples(uint32_t first, int n, Vec2* firsts, Vec2* seconds) {
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (simd_ && n >= 1 && n <= 8) {
    cache_through(2);
    alignas(32) float x[8], y[8], z[8], w[8];
    samples4d_avx2(first, seed_index_[0], seed_x_[0], seed_y_[0], seed_index_[1], seed_x_[1], x, y,
                   z, w);
    for (int k = 0; k < n; ++k) {
      firsts[k] = {x[k], y[k]};
      seconds[k] = {z[k], w[k]};
    }
    start_sample(first + uint32_t(n - 1));
    dim_ = 2;
    return;
  }
#endif
  for (int k = 0; k < n; ++k) {
    start_sample(first + uint32_t(k));
    get4d(&firsts[k], &seconds[k]);
  }
}

PixelSampler::PixelSampler(SamplerKind kind, uint64_t seed, int frame, int px, int py,
                           Stream stream)
    : kind_(kind) {
  // Pixel coordinates are packed into one word so (px, py) and (py, px) differ;
  // negative values (never expected) still hash deterministically.
  const uint64_t pixel = (uint64_t(uint32_t(px)) << 32) | uint32_t(py);
  uint64_t h = mix64(seed + kGoldenGamma);
  h = hash_combine(h, uint64_t(uint32_t(frame)));
  h = hash_combine(h, pixel);
  h = hash_combine(h, uint64_t(stream));
  pixel_seed_ = h;
  simd_ = kind == SamplerKind::kSobol && use_simd();
  for (uint32_t k = kCachedSlots; k < kCachedSlots + 8; ++k)
    seed_index_[k] = seed_x_[k] = seed_y_[k] = 0;
  start_sample(0);
}

}  // namespace dofarm::render
