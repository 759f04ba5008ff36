// The renderer's own sine, cosine and atan2 (worker/render/trig.h) against
// libm in double: within a few float ulps everywhere they are used (angles
// of up to a few turns, every octant and the axes for atan2).
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "worker/render/trig.h"

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

}  // namespace
}  // namespace dofarm::render
