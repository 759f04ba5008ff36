// Sine, cosine and atan2 to float precision without calls into libm, for the
// renderer's hot paths (the lens, BSDF and environment samples, and the
// direction-to-texel mapping of every ray that may escape). Each is within a
// few float ulps of the exact value over its whole domain (tested against
// libm in double, tests/render/test_trig.cpp); like libm's, their results
// are the same on every run of the same build, so renders stay bit-for-bit
// reproducible.
#pragma once

#include <cmath>

#include "common/math.h"

namespace dofarm::render {

// sin(r) and cos(r) for |r| <= pi/4: the Taylor series of sin r to r^9 and
// of cos r to r^10 (remainders below r^11/11! < 2e-9 and r^12/12! < 2e-10).
inline void sincos_quarter(float r, float* s, float* c) {
  const float r2 = r * r;
  *s = r * (1.0f + r2 * (-1.0f / 6.0f +
                         r2 * (1.0f / 120.0f + r2 * (-1.0f / 5040.0f + r2 * (1.0f / 362880.0f)))));
  *c = 1.0f + r2 * (-0.5f +
                    r2 * (1.0f / 24.0f + r2 * (-1.0f / 720.0f + r2 * (1.0f / 40320.0f +
                                                                      r2 * (-1.0f / 3628800.0f)))));
}

// The integer nearest to x, ties to even, as std::nearbyint in the default
// rounding mode, for |x| < 2^22, without a call: adding 1.5 * 2^23 leaves no
// bits below the units, and the float addition rounds to nearest even (the
// compiler may not fold (x + C) - C without -ffast-math). std::nearbyint is
// a call into libm on x86-64 without SSE 4.1.
inline float round_to_integer(float x) {
  constexpr float kShift = 12582912.0f;  // 1.5 * 2^23
  return (x + kShift) - kShift;
}

// sin(a) and cos(a) for |a| up to a few turns. Cody and Waite 1980
// ("Software Manual for the Elementary Functions", ch. 8): a = q pi/2 + r
// with q the nearest integer, the reduction done in double so that r is
// exact to float precision, |r| <= pi/4; then sincos_quarter(r), and the
// quadrant q mod 4 picks and signs the pair.
inline void precise_sincos(float a, float* s, float* c) {
  const float q = round_to_integer(a * (2.0f / kPi));
  const float r = float(double(a) - double(q) * 1.5707963267948966);
  float sr, cr;
  sincos_quarter(r, &sr, &cr);
  switch (int(q) & 3) {
    case 0:
      *s = sr;
      *c = cr;
      break;
    case 1:
      *s = cr;
      *c = -sr;
      break;
    case 2:
      *s = -sr;
      *c = -cr;
      break;
    default:
      *s = -cr;
      *c = sr;
      break;
  }
}

// atan2(y, x). The ratio z = min/max of |x|, |y| is in [0, 1]; above
// tan(pi/12) it is reduced by atan(z) = pi/6 + atan((sqrt(3) z - 1) /
// (z + sqrt(3))) (Cody and Waite 1980, ch. 11), leaving |t| <= tan(pi/12)
// = 0.268, where the Taylor series of atan to t^11 is within t^13/13 < 3e-9
// of it. The octant is then restored as atan2 does (x < 0 mirrors, y < 0
// negates); atan2(0, 0) = 0.
inline float precise_atan2(float y, float x) {
  const float ax = std::fabs(x), ay = std::fabs(y);
  const float hi = std::max(ax, ay), lo = std::min(ax, ay);
  if (!(hi > 0)) return 0.0f;
  float z = lo / hi;
  float base = 0.0f;
  constexpr float kSqrt3 = 1.7320508075688772f, kTanPi12 = 0.2679491924311227f;
  if (z > kTanPi12) {
    z = (z * kSqrt3 - 1.0f) / (z + kSqrt3);
    base = kPi / 6.0f;
  }
  const float z2 = z * z;
  float a = base + z * (1.0f + z2 * (-1.0f / 3.0f +
                                     z2 * (1.0f / 5.0f +
                                           z2 * (-1.0f / 7.0f +
                                                 z2 * (1.0f / 9.0f + z2 * (-1.0f / 11.0f))))));
  if (ay > ax) a = 0.5f * kPi - a;
  if (x < 0) a = kPi - a;
  return y < 0 ? -a : a;
}

}  // namespace dofarm::render
