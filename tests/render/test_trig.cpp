// The renderer's own sine, cosine and atan2 (worker/render/trig.h) against
// libm in double: within a few float ulps everywhere they are used (angles
// of up to a few turns, every octant and the axes for atan2).
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "worker/render/camera.h"
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
