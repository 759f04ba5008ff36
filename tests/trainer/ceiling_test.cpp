// The reference ceiling (trainer/ceiling.h): SSIM between the two half-sample
// references of a frame, against values worked out by hand.
#include "trainer/ceiling.h"

#include <gtest/gtest.h>

#include <cmath>

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

}  // namespace
}  // namespace dofarm::trainer
