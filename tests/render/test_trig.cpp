// The renderer's own sine, cosine and atan2 (worker/render/trig.h) against
// libm in double: within a few float ulps everywhere they are used (angles
// of up to a few turns, every octant and the axes for atan2).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "worker/render/camera.h"
#include "worker/render/simd.h"
#include "worker/render/trig.h"
#include "worker/render/trig8.h"

namespace dofarm::render {
namespace {

TEST(Trig, SinCosWithinFloatPrecision) {
  std::mt19937_64 rng(41);
  std::uniform_real_distribution<float> uni(-4.0f * kTwoPi, 4.0f * kTwoPi);
  double worst = 0;
  for (int i = 0; i < 1000000; ++i) {
    float a = uni(rng);
    if (i < 64) a = float(i - 32) * (kPi / 4.0f);  // quadrant boundaries and octants
    float s, c;
    precise_sincos(a, &s, &c);
    const double es = std::sin(double(a)), ec = std::cos(double(a));
    worst = std::max({worst, std::fabs(s - es), std::fabs(c - ec)});
    ASSERT_NEAR(s, es, 2.5e-7) << "a = " << a;
    ASSERT_NEAR(c, ec, 2.5e-7) << "a = " << a;
  }
  RecordProperty("worst_abs_error", std::to_string(worst));
  float s, c;
  precise_sincos(0.0f, &s, &c);
  EXPECT_EQ(s, 0.0f);
  EXPECT_EQ(c, 1.0f);
}

TEST(Trig, Atan2WithinFloatPrecision) {
  std::mt19937_64 rng(43);
  std::normal_distribution<float> normal;
  for (int i = 0; i < 1000000; ++i) {
    float y = normal(rng), x = normal(rng);
    if (i < 9) {  // the axes and diagonals
      x = float(i % 3 - 1);
      y = float(i / 3 - 1);
    }
    const double want = std::atan2(double(y), double(x));
    const float got = precise_atan2(y, x);
    if (x == 0 && y == 0) {
      EXPECT_EQ(got, 0.0f);
      continue;
    }
    // 2 ulps of pi, plus the rounding of the reduced argument.
    ASSERT_NEAR(got, want, 3e-7) << "atan2(" << y << ", " << x << ")";
  }
  // Very unequal magnitudes: the small angle keeps its relative precision.
  EXPECT_NEAR(precise_atan2(1e-20f, 1.0f), 1e-20f, 1e-26f);
  EXPECT_NEAR(precise_atan2(1.0f, 1e-20f), kPi / 2, 1e-7f);
}

#ifdef DOFARM_HAVE_AVX2_KERNELS
// atan2_8 and sincos8 (trig8.h) in eight lanes at once, run only on a CPU
// with AVX2.
DOFARM_AVX2 void lanes_atan2(const float* y, const float* x, float* out) {
  _mm256_storeu_ps(out, atan2_8(_mm256_loadu_ps(y), _mm256_loadu_ps(x)));
}
DOFARM_AVX2 void lanes_sincos(const float* a, float* s, float* c) {
  __m256 vs, vc;
  sincos8(_mm256_loadu_ps(a), &vs, &vc);
  _mm256_storeu_ps(s, vs);
  _mm256_storeu_ps(c, vc);
}
#endif

bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// The lanes are the scalar functions bit for bit: every octant, the axes
// and diagonals with both signs of zero, the reduction's threshold
// tan(pi/12) on either side, tiny, huge, infinite and NaN arguments.
TEST(Trig, LanesAreTheScalarFunctions) {
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (!simd_available()) GTEST_SKIP() << "this CPU has no AVX2";
  const float inf = std::numeric_limits<float>::infinity(),
              nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<float> special = {0.0f,        -0.0f,       1.0f,   -1.0f,   0.2679491924311227f,
                                0.26794916f, 0.26794922f, 1e-30f, -1e-30f, 1e-45f,
                                3e38f,       -3e38f,      inf,    -inf,    nan,
                                0.5f,        2.0f,        -7.25f};
  std::mt19937_64 rng(53);
  std::normal_distribution<float> normal;
  std::vector<float> ys, xs;
  for (float y : special)
    for (float x : special) {
      ys.push_back(y);
      xs.push_back(x);
    }
  for (int i = 0; i < 200000; ++i) {
    ys.push_back(normal(rng));
    xs.push_back(i % 2 ? normal(rng) : ys.back() * 3.7320508f);  // near tan(pi/12) too
  }
  while (ys.size() % 8) {
    ys.push_back(1.0f);
    xs.push_back(1.0f);
  }
  int differ = 0;
  for (size_t i = 0; i < ys.size(); i += 8) {
    float got[8];
    lanes_atan2(&ys[i], &xs[i], got);
    for (int k = 0; k < 8; ++k) differ += !same_bits(got[k], precise_atan2(ys[i + k], xs[i + k]));
  }
  EXPECT_EQ(differ, 0) << "atan2";
  std::uniform_real_distribution<float> uni(-4.0f * kTwoPi, 4.0f * kTwoPi);
  differ = 0;
  for (int i = 0; i < 200000; i += 8) {
    float a[8], s[8], c[8];
    for (int k = 0; k < 8; ++k) a[k] = i < 64 ? float(i + k - 32) * (kPi / 4.0f) : uni(rng);
    lanes_sincos(a, s, c);
    for (int k = 0; k < 8; ++k) {
      float es, ec;
      precise_sincos(a[k], &es, &ec);
      differ += !same_bits(s[k], es) || !same_bits(c[k], ec);
    }
  }
  EXPECT_EQ(differ, 0) << "sincos";
#else
  GTEST_SKIP() << "no AVX2 kernels in this build";
#endif
}

TEST(Trig, RoundToIntegerIsNearbyintTiesToEven) {
  std::mt19937_64 rng(47);
  std::uniform_real_distribution<float> uni(-20.0f, 20.0f);
  for (int i = 0; i < 1000000; ++i) {
    const float x = uni(rng);
    ASSERT_EQ(round_to_integer(x), std::nearbyint(x)) << "x = " << x;
  }
  // Ties go to the even neighbour, and values next to a tie go their way.
  for (int k = -40; k <= 40; ++k) {
    const float tie = float(k) + 0.5f;
    EXPECT_EQ(round_to_integer(tie), std::nearbyint(tie)) << tie;
    EXPECT_EQ(round_to_integer(std::nextafter(tie, 1e9f)),
              std::nearbyint(std::nextafter(tie, 1e9f)));
    EXPECT_EQ(round_to_integer(std::nextafter(tie, -1e9f)),
              std::nearbyint(std::nextafter(tie, -1e9f)));
  }
  EXPECT_EQ(round_to_integer(2.5f), 2.0f);
  EXPECT_EQ(round_to_integer(-3.5f), -4.0f);
  EXPECT_EQ(round_to_integer(0.49999997f), 0.0f);
}

// Shirley and Chiu's concentric map computed in double with libm, as the
// paper writes it (the angle of the second case is pi/2 - pi/4 (a / b)).
void concentric_in_double(double ux, double uy, double* x, double* y) {
  const double a = 2 * ux - 1, b = 2 * uy - 1;
  if (a == 0 && b == 0) {
    *x = *y = 0;
    return;
  }
  double r, theta;
  if (std::fabs(a) > std::fabs(b)) {
    r = a;
    theta = M_PI / 4 * (b / a);
  } else {
    r = b;
    theta = M_PI / 2 - M_PI / 4 * (a / b);
  }
  *x = r * std::cos(theta);
  *y = r * std::sin(theta);
}

TEST(Trig, ConcentricDiskIsShirleyChiusMap) {
  std::mt19937_64 rng(53);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (int i = 0; i < 1000000; ++i) {
    Vec2 u(uni(rng), uni(rng));
    // The centre, the corners, the diagonals |a| = |b| where the two cases
    // meet, and the axes.
    const float edges[] = {0.0f, 0.25f, 0.5f, 0.75f, 1.0f};
    if (i < 25) u = Vec2(edges[i % 5], edges[i / 5]);
    const Vec2 d = sample_concentric_disk(u);
    double x, y;
    concentric_in_double(u.x, u.y, &x, &y);
    ASSERT_NEAR(d.x, x, 4e-7) << "u = " << u.x << ", " << u.y;
    ASSERT_NEAR(d.y, y, 4e-7) << "u = " << u.x << ", " << u.y;
    ASSERT_LE(double(d.x) * d.x + double(d.y) * d.y, 1.0 + 1e-6);
  }
}

}  // namespace
}  // namespace dofarm::render
