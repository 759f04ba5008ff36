#include "trainer/augment.h"

#include <gtest/gtest.h>

#include <cmath>

namespace dofarm::trainer {
namespace {

DataConfig small_config(int crop = 32) {
  DataConfig d;
  d.crop = crop;
  return d;
}

// Source values encode where they came from: reference = 1 + x + S*y (crop
// coordinates), noisy = reference + 2000*version, depth = frame + 1.
RawCrop coded_crop(int frames, int versions, int s) {
  RawCrop r;
  r.frames = frames;
  r.versions = versions;
  r.size = s;
  const size_t n = size_t(s) * s;
  r.noisy.resize(size_t(frames) * versions * 3 * n);
  r.albedo.assign(r.noisy.size(), 1.0f);
  r.albedo_ref.assign(size_t(frames) * 3 * n, 1.0f);
  r.reference.resize(r.albedo_ref.size());
  r.normal.resize(r.albedo_ref.size());
  r.depth.resize(size_t(frames) * n);
  r.roughness.assign(r.depth.size(), 0.5f);
  r.coc.assign(r.depth.size(), 2.0f);
  r.focal_distance.assign(frames, 1.0f);
  for (int f = 0; f < frames; ++f)
    for (size_t p = 0; p < n; ++p) {
      float code = 1.0f + float(p);
      for (int c = 0; c < 3; ++c) {
        r.reference[(size_t(f) * 3 + c) * n + p] = code;
        for (int v = 0; v < versions; ++v)
          r.noisy[((size_t(f) * versions + v) * 3 + c) * n + p] = code + 2000.0f * v;
      }
      r.normal[(size_t(f) * 3 + 0) * n + p] = 1.0f;  // pointing right
      r.normal[(size_t(f) * 3 + 1) * n + p] = 0.0f;
      r.normal[(size_t(f) * 3 + 2) * n + p] = 0.0f;
      r.depth[size_t(f) * n + p] = float(f + 1);
    }
  return r;
}

float decode(float transformed, float eps) { return radiance_inverse(transformed) * (1.0f + eps); }

TEST(Augment, SameCropRotationAndOrderForEveryFrameAndTheTarget) {
  const int s = 32, frames = 12, versions = 4;
  DataConfig data = small_config(s);
  std::mt19937_64 rng(5);
  RawCrop raw = coded_crop(frames, versions, s);
  const size_t n = size_t(s) * s;
  int seen_turns[4] = {0, 0, 0, 0};
  for (int trial = 0; trial < 40; ++trial) {
    SequencePlan plan = draw_plan(rng, data, 0, frames, versions, 64, 64);
    plan.first_frame = 0;  // `raw` starts at the plan's first frame
    seen_turns[plan.quarter_turns]++;
    Sample smp = build_sample(raw, plan, data, /*dof=*/true);
    ASSERT_EQ(smp.frames, 7);
    ASSERT_EQ(smp.channels, 12);
    // Where source pixel (0, 0) (the top-left) lands after the rotation.
    const int corner[4][2] = {{0, 0}, {0, s - 1}, {s - 1, s - 1}, {s - 1, 0}};  // x, y
    const int cx = corner[plan.quarter_turns][0], cy = corner[plan.quarter_turns][1];
    for (int t = 0; t < 7; ++t) {
      const float* in = &smp.input[size_t(t) * 12 * n];
      const float* tg = &smp.target[size_t(t) * 3 * n];
      for (size_t p = 0; p < n; ++p) {
        float target_code = std::round(decode(tg[p], data.demod_eps));
        float input_code = std::round(decode(in[p], data.demod_eps));
        // Same pixel of the same crop in input and target, the version's offset apart.
        ASSERT_EQ(input_code - target_code, 2000.0f * plan.version[t]) << "t=" << t;
      }
      EXPECT_EQ(std::round(decode(tg[size_t(cy) * s + cx], data.demod_eps)), 1.0f);
      // Frame order: depth channel is frame / (frame + focal) with frame = offset + 1.
      float z = float(plan.offset[t] + 1);
      EXPECT_NEAR(in[9 * n], z / (z + 1.0f), 1e-6);
      // The normal turned with the image: (1, 0) after k quarter turns.
      float ang = float(plan.quarter_turns) * float(M_PI) / 2;
      EXPECT_NEAR(in[6 * n], std::cos(ang), 1e-6);
      EXPECT_NEAR(in[7 * n], std::sin(ang), 1e-6);
    }
  }
  for (int k = 0; k < 4; ++k) EXPECT_GT(seen_turns[k], 0) << k;
}

TEST(Augment, StopAndReversalRatesWithinStatisticalBounds) {
  DataConfig data = small_config(64);
  std::mt19937_64 rng(11);
  const int trials = 4000;
  int stops = 0, reversals = 0;
  for (int i = 0; i < trials; ++i) {
    SequencePlan p = draw_plan(rng, data, 0, 20, 10, 128, 96);
    reversals += p.reversed;
    for (int t = 1; t < 7; ++t) {
      stops += p.stopped[t];
      int step = p.offset[t] - p.offset[t - 1];
      if (p.stopped[t]) {
        EXPECT_EQ(step, 0);
        EXPECT_NE(p.version[t], p.version[t - 1]) << "a stop shows another noisy version";
      } else {
        EXPECT_EQ(step, p.reversed ? -1 : 1);
      }
    }
    EXPECT_GE(p.first_frame, 0);
    EXPECT_LE(p.first_frame + p.span, 20);
    EXPECT_LE(p.crop_x, 128 - 64);
    EXPECT_LE(p.crop_y, 96 - 64);
  }
  // Binomial: 4 standard deviations.
  const double n_steps = trials * 6.0;
  EXPECT_NEAR(stops / n_steps, 0.25, 4 * std::sqrt(0.25 * 0.75 / n_steps));
  EXPECT_NEAR(reversals / double(trials), 0.5, 4 * std::sqrt(0.25 / trials));
}

TEST(Augment, SameSeedSamePlan) {
  DataConfig data = small_config(64);
  std::mt19937_64 a(3), b(3);
  SequencePlan p = draw_plan(a, data, 0, 16, 10, 256, 256);
  SequencePlan q = draw_plan(b, data, 0, 16, 10, 256, 256);
  EXPECT_EQ(p.offset, q.offset);
  EXPECT_EQ(p.version, q.version);
  EXPECT_EQ(p.crop_x, q.crop_x);
  EXPECT_EQ(p.quarter_turns, q.quarter_turns);
}

TEST(Augment, DemodulateRemodulateIsIdentity) {
  const float eps = DataConfig{}.demod_eps;
  for (float albedo : {0.0f, 1e-4f, 2e-3f, 0.05f, 0.5f, 1.0f})
    for (float radiance : {0.0f, 1e-3f, 0.7f, 3.0f, 250.0f, 1e5f}) {
      float back = remodulate(demodulate(radiance, albedo, eps), albedo, eps);
      EXPECT_NEAR(back, radiance, 1e-6f * radiance) << albedo << " " << radiance;
      float through = remodulate(
          radiance_inverse(radiance_forward(demodulate(radiance, albedo, eps))), albedo, eps);
      EXPECT_NEAR(through, radiance, 2e-5f * radiance + 1e-6f) << albedo << " " << radiance;
    }
}

TEST(Augment, FourQuarterTurnsAreIdentity) {
  const int s = 8;
  std::vector<float> img(2 * s * s), orig;
  for (size_t i = 0; i < img.size(); ++i) img[i] = float(i);
  orig = img;
  rotate_planes(img.data(), 2, s, 1);
  EXPECT_NE(img, orig);
  EXPECT_EQ(img[0], orig[s - 1]);  // the top-right corner moved to the top-left
  rotate_planes(img.data(), 2, s, 3);
  EXPECT_EQ(img, orig);
}

TEST(Augment, EscapedRaysAreFarAndCocIsLogScaled) {
  DataConfig data;
  float noisy[3] = {1, 1, 1}, albedo[3] = {0.5f, 0.5f, 0.5f}, normal[3] = {0, 0, 1};
  float depth = 0, rough = 0.3f, coc = 32.0f;
  FrameView v{noisy, albedo, normal, &depth, &rough, &coc, 2.0f, 1};
  float out[12];
  make_input(v, data, true, out);
  EXPECT_EQ(out[9], 1.0f);
  EXPECT_NEAR(out[11], 1.0f, 1e-4f);
  EXPECT_NEAR(out[0], std::log1p(1.0f / (0.5f + data.demod_eps)), 1e-6f);
  depth = 2.0f;
  make_input(v, data, false, out);
  EXPECT_NEAR(out[9], 0.5f, 1e-6f);  // on the focal plane
}

}  // namespace
}  // namespace dofarm::trainer
