#include "trainer/prefilter.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "trainer/augment.h"
#include "trainer/config.h"

namespace dofarm::trainer {
namespace {

// Hand-computed small case: a 5 x 1 row of albedo 0, 0, 1, 0, 0. The middle
// pixel's CoC of 2 px (scale 0.25) asks for sigma 0.5, exactly the level
// kPrefilterSigmas[1], so it gets the sigma-0.5 Gaussian's centre weight,
// 1 / (1 + 2 e^-2 + 2 e^-8) (radius ceil(1.5) = 2, the column pass of a
// one-row image replicates the row: weight 1). Pixels of CoC 0 keep their
// value exactly; NaN and negative CoCs count as 0.
TEST(AlbedoPrefilter, SharpPixelsKeepTheirAlbedoAndBlurFollowsTheCoc) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<float> in = {0, 0, 1, 0, 0};
  const std::vector<float> coc = {0, nan, 2, -3, 0};
  std::vector<float> out(5);
  prefilter_by_coc(in.data(), 1, coc.data(), 5, 1, 0.25f, out.data());
  const double centre = 1.0 / (1.0 + 2.0 * std::exp(-2.0) + 2.0 * std::exp(-8.0));
  EXPECT_NEAR(out[2], centre, 1e-6);
  EXPECT_EQ(out[0], 0.0f);
  EXPECT_EQ(out[1], 0.0f);  // NaN CoC: kept
  EXPECT_EQ(out[3], 0.0f);  // negative CoC: kept
  EXPECT_EQ(out[4], 0.0f);
  // Between levels: CoC 3 px is sigma 0.75, halfway from 0.5 to 1.
  const std::vector<float> coc3 = {0, 0, 3, 0, 0};
  prefilter_by_coc(in.data(), 1, coc3.data(), 5, 1, 0.25f, out.data());
  double sum1 = 0;
  for (int i = -3; i <= 3; ++i) sum1 += std::exp(-0.5 * i * i);
  EXPECT_NEAR(out[2], 0.5 * centre + 0.5 / sum1, 1e-6);
  // Scale 0 turns the filter off.
  prefilter_by_coc(in.data(), 1, coc3.data(), 5, 1, 0.0f, out.data());
  EXPECT_EQ(out, in);
}

// A constant albedo stays constant under any CoC (each level's kernel sums
// to 1 and the border replicates), in every plane.
TEST(AlbedoPrefilter, ConstantAlbedoStaysConstant) {
  const int w = 40, h = 24;
  std::vector<float> in(3 * w * h), coc(w * h), out(in.size());
  for (int c = 0; c < 3; ++c)
    for (int p = 0; p < w * h; ++p) in[size_t(c) * w * h + p] = 0.2f + 0.3f * c;
  for (int p = 0; p < w * h; ++p) coc[p] = float(p % 97);  // 0 .. 96 px: every level
  prefilter_by_coc(in.data(), 3, coc.data(), w, h, 0.25f, out.data());
  for (size_t i = 0; i < in.size(); ++i) ASSERT_NEAR(out[i], in[i], 1e-6) << i;
}

// In training samples the filtered albedo is what the albedo input shows and
// what the radiance and the target are demodulated by, so remodulating the
// target's inverse still gives the reference.
TEST(AlbedoPrefilter, SampleUsesTheFilteredAlbedoEverywhere) {
  const int s = 32;
  const size_t n = size_t(s) * s;
  RawCrop raw;
  raw.frames = 1;
  raw.versions = 1;
  raw.size = s;
  raw.focal_distance = {2.0f};
  auto& a = raw.buffers["albedo_ref"];
  a.resize(3 * n);
  for (size_t i = 0; i < a.size(); ++i) a[i] = (i * 7919 % 101) / 100.0f;  // texture
  raw.buffers["reference"].assign(3 * n, 0.5f);
  raw.buffers["noisy"].assign(3 * n, 0.5f);
  raw.buffers["normal"].assign(3 * n, 0.0f);
  raw.buffers["depth"].assign(n, 2.0f);
  raw.buffers["roughness"].assign(n, 0.5f);
  auto& coc = raw.buffers["coc"];
  coc.resize(n);
  for (size_t p = 0; p < n; ++p) coc[p] = p % s < s / 2 ? 0.0f : 20.0f;  // right half blurred
  SequencePlan plan;
  plan.span = 1;
  plan.offset = {0};
  plan.version = {0};
  plan.stopped = {0};
  DataConfig data;
  data.albedo_prefilter = AlbedoPrefilter::kCoc;
  ModelConfig model;
  const Sample smp = build_sample(raw, plan, data, model);
  std::vector<float> want(3 * n);
  prefilter_by_coc(a.data(), 3, coc.data(), s, s, data.albedo_prefilter_scale, want.data());
  ASSERT_EQ(smp.albedo.size(), want.size());
  for (size_t i = 0; i < want.size(); ++i) ASSERT_EQ(smp.albedo[i], want[i]) << i;
  // The albedo input (channels 3..5 of the default inputs).
  for (size_t i = 0; i < 3 * n; ++i) ASSERT_EQ(smp.input[3 * n + i], want[i]) << i;
  for (size_t i = 0; i < 3 * n; ++i) {
    const float r =
        radiance_inverse(smp.target[i], radiance_space(model)) * (want[i] + data.demod_eps);
    ASSERT_NEAR(r, 0.5f, 1e-5) << i;
  }
  // Sharp pixels (left half) keep the stored albedo; the right half changed.
  EXPECT_EQ(want[5], a[5]);
  EXPECT_NE(want[s - 5], a[s - 5]);
}

}  // namespace
}  // namespace dofarm::trainer
