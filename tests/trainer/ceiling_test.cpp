// The reference ceiling (trainer/ceiling.h): SSIM between the two half-sample
// references of a frame, against values worked out by hand.
#include "trainer/ceiling.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "trainer/metrics.h"

namespace dofarm::trainer {
namespace {

// A frame whose halves are constant images: A = a, R = r, so B = 2r - a.
FrameBuffers constant_halves(int w, int h, float a, float r) {
  FrameBuffers fb;
  fb.allocate(w, h, 1);
  std::fill(fb.reference_half.begin(), fb.reference_half.end(), a);
  std::fill(fb.reference.begin(), fb.reference.end(), r);
  return fb;
}

TEST(ReferenceCeiling, SecondHalfIsTwiceTheReferenceMinusTheFirst) {
  FrameBuffers fb = constant_halves(2, 2, 0.25f, 0.5f);
  fb.reference_half[3] = 1.0f;
  const std::vector<float> b = second_reference_half(fb);
  ASSERT_EQ(b.size(), fb.reference.size());
  EXPECT_EQ(b[0], 0.75f);
  EXPECT_EQ(b[3], 0.0f);
  for (size_t i = 0; i < b.size(); ++i) EXPECT_EQ(0.5f * (fb.reference_half[i] + b[i]), 0.5f);
}

// Two constant images: the contrast-structure term of SSIM is C2 / C2 = 1 and
// the luminance term (2 x y + C1) / (x^2 + y^2 + C1), C1 = 0.01^2, with x and
// y the sRGB-encoded values. Linear 0.002 and 0.001 lie on the curve's linear
// segment (12.92 v below 0.0031308, IEC 61966-2-1).
TEST(ReferenceCeiling, ConstantHalvesGiveTheLuminanceTerm) {
  const FrameBuffers fb = constant_halves(16, 12, 0.002f, 0.0015f);  // B = 0.001
  const double x = 12.92 * 0.002, y = 12.92 * 0.001, c1 = 1e-4;
  const double expected = (2 * x * y + c1) / (x * x + y * y + c1);
  EXPECT_NEAR(reference_ceiling_ssim(fb), expected, 1e-5);
  EXPECT_LT(expected, 0.9);  // the case is not trivially 1
}

TEST(ReferenceCeiling, IdenticalHalvesScoreOne) {
  FrameBuffers fb = constant_halves(16, 16, 0, 0);
  for (size_t i = 0; i < fb.reference.size(); ++i)
    fb.reference[i] = fb.reference_half[i] = float(i % 17) / 17.0f;
  EXPECT_DOUBLE_EQ(reference_ceiling_ssim(fb), 1.0);
}

TEST(ReferenceCeiling, UnmeasurableFramesAreNaN) {
  FrameBuffers small = constant_halves(8, 8, 0.1f, 0.1f);  // below the 11x11 window
  EXPECT_TRUE(std::isnan(reference_ceiling_ssim(small)));
  FrameBuffers none = constant_halves(16, 16, 0.1f, 0.1f);
  none.reference_half.clear();  // e.g. a frame from before the buffer existed
  EXPECT_TRUE(second_reference_half(none).empty());
  EXPECT_TRUE(std::isnan(reference_ceiling_ssim(none)));
}

TEST(ReferenceCeiling, SummarisesMeanAndWorstFrame) {
  ReferenceCeiling c;
  EXPECT_EQ(c.to_json()["mean_ssim"], nullptr);
  EXPECT_NE(c.markdown().find("not measured"), std::string::npos);

  const FrameBuffers same = constant_halves(16, 12, 0.002f, 0.002f);    // 1
  const FrameBuffers apart = constant_halves(16, 12, 0.002f, 0.0015f);  // < 1
  const double low = reference_ceiling_ssim(apart);
  EXPECT_DOUBLE_EQ(c.add(same, "shard-00000.h5", 3), 1.0);
  EXPECT_DOUBLE_EQ(c.add(apart, "shard-00001.h5", 17), low);
  EXPECT_TRUE(std::isnan(c.add(constant_halves(4, 4, 0, 0), "shard-00001.h5", 18)));
  EXPECT_EQ(c.frames(), 2);
  EXPECT_DOUBLE_EQ(c.mean(), 0.5 * (1.0 + low));
  EXPECT_DOUBLE_EQ(c.min(), low);
  const nlohmann::json j = c.to_json();
  EXPECT_EQ(j["frames"], 2);
  EXPECT_EQ(j["min_shard"], "shard-00001.h5");
  EXPECT_EQ(j["min_frame"], 17);
  EXPECT_NE(c.markdown().find("shard-00001.h5 frame 17"), std::string::npos);
}

// The exact-denoiser score against a known answer: a textured noise-free
// image T, two halves A = T + n1 and B = T + n2 with independent Gaussian
// noise, R = (A + B) / 2. The estimate from the halves alone must match the
// SSIM of T itself against R (computed with ssim()), and lie well above
// SSIM(A, B), for noise from slight to heavy. Display space (no encoding), as
// the function sees it. At heavy noise the estimate is low by up to a tenth
// of the gap (the per-window ratio of noisy estimates), so it errs on the
// side of a lower cap.
TEST(ReferenceCeiling, ExactDenoiserScoreMatchesTheTruthAgainstTheReference) {
  const int w = 96, h = 80;
  const size_t n = size_t(w) * h * 3;
  std::vector<float> t(n);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        t[(size_t(c) * h + y) * w + x] =
            0.5f + 0.2f * std::sin(0.3f * x + c) * std::cos(0.21f * y) + (x > 40 ? 0.15f : 0.0f);
  for (float sigma : {0.01f, 0.04f, 0.12f}) {
    std::mt19937 rng(7);
    std::normal_distribution<float> noise(0.0f, sigma);
    std::vector<float> a(n), b(n), r(n);
    for (size_t i = 0; i < n; ++i) {
      a[i] = t[i] + noise(rng);
      b[i] = t[i] + noise(rng);
      r[i] = 0.5f * (a[i] + b[i]);
    }
    const double truth = ssim({t.data(), 3, h, w}, {r.data(), 3, h, w});
    const double estimate = ssim_of_truth_against_mean({a.data(), 3, h, w}, {b.data(), 3, h, w});
    const double halves = ssim({a.data(), 3, h, w}, {b.data(), 3, h, w});
    // Within 15% of the gap the halves leave (measured: 0.2%, 2% and 11%; at heavy
    // noise the per-window ratio of noisy estimates is biased low).
    EXPECT_NEAR(estimate, truth, 0.15 * (truth - halves) + 1e-3)
        << "sigma " << sigma << " halves " << halves;
    EXPECT_GT(truth - halves, 0.02) << sigma;  // the case separates the two
  }
  // Identical halves: no noise, an exact denoiser scores 1.
  EXPECT_NEAR(ssim_of_truth_against_mean({t.data(), 3, h, w}, {t.data(), 3, h, w}), 1.0, 1e-12);
}

TEST(ReferenceCeiling, ReportsTheExactDenoiserScore) {
  FrameBuffers fb = constant_halves(16, 16, 0, 0);
  for (size_t i = 0; i < fb.reference.size(); ++i) {
    fb.reference_half[i] = 0.2f + 0.1f * float(i % 7) / 7.0f;
    fb.reference[i] = 0.2f + 0.1f * float(i % 5) / 5.0f;
  }
  ReferenceCeiling c;
  c.add(fb, "shard-00000.h5", 0);
  const double e = exact_denoiser_ssim(fb);
  EXPECT_GT(e, reference_ceiling_ssim(fb));
  EXPECT_DOUBLE_EQ(c.last_exact(), e);
  EXPECT_DOUBLE_EQ(c.to_json()["exact_denoiser_mean_ssim"].get<double>(), e);
  EXPECT_NE(c.markdown().find("exact denoiser"), std::string::npos);
}

}  // namespace
}  // namespace dofarm::trainer
