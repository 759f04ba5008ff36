// Lane arithmetic and trig.h's functions in eight AVX2 lanes, for the
// kernels of simd.h: each lane does the scalar function's operations in its
// order (branches become blends of both sides), with no fused multiply-add,
// so a lane's result is the scalar one bit for bit
// (Trig.LanesAreTheScalarFunctions).
#pragma once

#include <cfloat>

#include "worker/render/simd.h"
#include "worker/render/trig.h"

#ifdef DOFARM_HAVE_AVX2_KERNELS
namespace dofarm::render {

DOFARM_AVX2 inline __m128 remainder4(__m128 a, __m128 q) {  // float(double(a) - double(q) pi/2)
  return _mm256_cvtpd_ps(_mm256_sub_pd(
      _mm256_cvtps_pd(a), _mm256_mul_pd(_mm256_cvtps_pd(q), _mm256_set1_pd(1.5707963267948966))));
}
DOFARM_AVX2 inline __m256 k8(float v) { return _mm256_set1_ps(v); }
DOFARM_AVX2 inline __m256 mul8(__m256 x, __m256 y) { return _mm256_mul_ps(x, y); }
DOFARM_AVX2 inline __m256 add8(__m256 x, __m256 y) { return _mm256_add_ps(x, y); }
DOFARM_AVX2 inline __m256 sub8(__m256 x, __m256 y) { return _mm256_sub_ps(x, y); }
DOFARM_AVX2 inline __m256 div8(__m256 x, __m256 y) { return _mm256_div_ps(x, y); }
// mask ? a : b, lane by lane.
DOFARM_AVX2 inline __m256 select8(__m256 mask, __m256 a, __m256 b) {
  return _mm256_blendv_ps(b, a, mask);
}
DOFARM_AVX2 inline __m256 is_finite8(__m256 v) {  // |v| <= FLT_MAX: false for Inf and NaN
  const __m256 abs = _mm256_andnot_ps(_mm256_set1_ps(-0.0f), v);
  return _mm256_cmp_ps(abs, _mm256_set1_ps(FLT_MAX), _CMP_LE_OQ);
}

// Eight-lane Vec3 arithmetic, each operation the scalar one of common/math.h
// in the same order.
struct V3x8 {
  __m256 x, y, z;
};
DOFARM_AVX2 inline __m256 dot8(V3x8 a, V3x8 b) {
  return _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(a.x, b.x), _mm256_mul_ps(a.y, b.y)),
                       _mm256_mul_ps(a.z, b.z));
}

// precise_sincos (trig.h): the quadrant rounded as round_to_integer does,
// the remainder in double, sincos_quarter's polynomials, the quadrant's
// swap and signs.
DOFARM_AVX2 inline void sincos8(__m256 a, __m256* s, __m256* c) {
  const __m256 shift = _mm256_set1_ps(12582912.0f);
  const __m256 q =
      _mm256_sub_ps(_mm256_add_ps(_mm256_mul_ps(a, _mm256_set1_ps(2.0f / kPi)), shift), shift);
  const __m256 r =
      _mm256_set_m128(remainder4(_mm256_extractf128_ps(a, 1), _mm256_extractf128_ps(q, 1)),
                      remainder4(_mm256_castps256_ps128(a), _mm256_castps256_ps128(q)));
  const __m256 r2 = _mm256_mul_ps(r, r);
  const __m256 sr =
      mul8(r, add8(k8(1.0f),
                   mul8(r2, add8(k8(-1.0f / 6.0f),
                                 mul8(r2, add8(k8(1.0f / 120.0f),
                                               mul8(r2, add8(k8(-1.0f / 5040.0f),
                                                             mul8(r2, k8(1.0f / 362880.0f))))))))));
  const __m256 cr = add8(
      k8(1.0f),
      mul8(r2,
           add8(k8(-0.5f),
                mul8(r2, add8(k8(1.0f / 24.0f),
                              mul8(r2, add8(k8(-1.0f / 720.0f),
                                            mul8(r2, add8(k8(1.0f / 40320.0f),
                                                          mul8(r2, k8(-1.0f / 3628800.0f)))))))))));
  const __m256i quadrant = _mm256_and_si256(_mm256_cvttps_epi32(q), _mm256_set1_epi32(3));
  const __m256 q1 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(quadrant, _mm256_set1_epi32(1)));
  const __m256 q2 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(quadrant, _mm256_set1_epi32(2)));
  const __m256 q3 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(quadrant, _mm256_set1_epi32(3)));
  const __m256 odd = _mm256_or_ps(q1, q3);
  const __m256 sign = _mm256_set1_ps(-0.0f);
  // 0: (sr, cr); 1: (cr, -sr); 2: (-sr, -cr); 3: (-cr, sr).
  *s = _mm256_xor_ps(_mm256_blendv_ps(sr, cr, odd), _mm256_and_ps(_mm256_or_ps(q2, q3), sign));
  *c = _mm256_xor_ps(_mm256_blendv_ps(cr, sr, odd), _mm256_and_ps(_mm256_or_ps(q1, q2), sign));
}

// precise_atan2 (trig.h). std::max(ax, ay) and std::min(ax, ay) as the
// standard library defines them (b if a < b; b if b < a), which _mm256_max_ps
// and _mm256_min_ps do not for NaN; the reduction above tan(pi/12) and the
// octant's mirrors as blends.
DOFARM_AVX2 inline __m256 atan2_8(__m256 y, __m256 x) {
  const __m256 sign = _mm256_set1_ps(-0.0f), zero = _mm256_setzero_ps();
  const __m256 ax = _mm256_andnot_ps(sign, x), ay = _mm256_andnot_ps(sign, y);
  const __m256 ay_above = _mm256_cmp_ps(ax, ay, _CMP_LT_OQ);
  const __m256 hi = _mm256_blendv_ps(ax, ay, ay_above);
  const __m256 lo = _mm256_blendv_ps(ax, ay, _mm256_cmp_ps(ay, ax, _CMP_LT_OQ));
  const __m256 none = _mm256_cmp_ps(hi, zero, _CMP_NGT_UQ);  // !(hi > 0)
  const __m256 z0 = _mm256_div_ps(lo, hi);
  constexpr float kSqrt3 = 1.7320508075688772f, kTanPi12 = 0.2679491924311227f;
  const __m256 reduce = _mm256_cmp_ps(z0, k8(kTanPi12), _CMP_GT_OQ);
  const __m256 zr =
      _mm256_div_ps(_mm256_sub_ps(mul8(z0, k8(kSqrt3)), k8(1.0f)), add8(z0, k8(kSqrt3)));
  const __m256 z = _mm256_blendv_ps(z0, zr, reduce);
  const __m256 base = _mm256_and_ps(k8(kPi / 6.0f), reduce);
  const __m256 z2 = mul8(z, z);
  __m256 a = add8(
      base,
      mul8(z,
           add8(k8(1.0f),
                mul8(z2,
                     add8(k8(-1.0f / 3.0f),
                          mul8(z2, add8(k8(1.0f / 5.0f),
                                        mul8(z2, add8(k8(-1.0f / 7.0f),
                                                      mul8(z2, add8(k8(1.0f / 9.0f),
                                                                    mul8(z2, k8(-1.0f /
                                                                                11.0f)))))))))))));
  a = _mm256_blendv_ps(a, _mm256_sub_ps(k8(0.5f * kPi), a), _mm256_cmp_ps(ay, ax, _CMP_GT_OQ));
  a = _mm256_blendv_ps(a, _mm256_sub_ps(k8(kPi), a), _mm256_cmp_ps(x, zero, _CMP_LT_OQ));
  a = _mm256_xor_ps(a, _mm256_and_ps(sign, _mm256_cmp_ps(y, zero, _CMP_LT_OQ)));
  return _mm256_andnot_ps(none, a);
}

}  // namespace dofarm::render
#endif
