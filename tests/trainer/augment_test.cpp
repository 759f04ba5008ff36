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
  auto& noisy = r.buffers["noisy"];
  noisy.resize(size_t(frames) * versions * 3 * n);
  r.buffers["albedo"].assign(noisy.size(), 1.0f);
  r.buffers["albedo_ref"].assign(size_t(frames) * 3 * n, 1.0f);
  auto& reference = r.buffers["reference"];
  auto& normal = r.buffers["normal"];
  auto& depth = r.buffers["depth"];
  reference.resize(size_t(frames) * 3 * n);
  normal.resize(reference.size());
  depth.resize(size_t(frames) * n);
  r.buffers["roughness"].assign(depth.size(), 0.5f);
  r.buffers["coc"].assign(depth.size(), 2.0f);
  r.focal_distance.assign(frames, 1.0f);
  for (int f = 0; f < frames; ++f)
    for (size_t p = 0; p < n; ++p) {
      float code = 1.0f + float(p);
      for (int c = 0; c < 3; ++c) {
        reference[(size_t(f) * 3 + c) * n + p] = code;
        for (int v = 0; v < versions; ++v)
          noisy[((size_t(f) * versions + v) * 3 + c) * n + p] = code + 2000.0f * v;
      }
      normal[(size_t(f) * 3 + 0) * n + p] = 1.0f;  // pointing right
      normal[(size_t(f) * 3 + 1) * n + p] = 0.0f;
      normal[(size_t(f) * 3 + 2) * n + p] = 0.0f;
      depth[size_t(f) * n + p] = float(f + 1);
    }
  return r;
}

float decode(float transformed, float eps) {
  return radiance_inverse(transformed, RadianceSpace::kLog1p) * (1.0f + eps);
}

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
    Sample smp = build_sample(raw, plan, data, ModelConfig{});
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
      for (RadianceSpace space : {RadianceSpace::kLog1p, RadianceSpace::kLinear}) {
        float through = remodulate(
            radiance_inverse(radiance_forward(demodulate(radiance, albedo, eps), space), space),
            albedo, eps);
        EXPECT_NEAR(through, radiance, 2e-5f * radiance + 1e-6f) << albedo << " " << radiance;
      }
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

FrameView one_pixel(float* noisy, float* albedo, float* normal, float* depth, float* rough,
                    float* coc, float focal) {
  FrameView v;
  v.buffers = {{"noisy", noisy}, {"albedo_ref", albedo}, {"normal", normal},
               {"depth", depth}, {"roughness", rough},   {"coc", coc}};
  v.albedo = albedo;
  v.focal_distance = focal;
  v.pixels = 1;
  return v;
}

TEST(Augment, EscapedRaysAreFarAndCocIsLogScaled) {
  DataConfig data;
  ModelConfig model;
  float noisy[3] = {1, 1, 1}, albedo[3] = {0.5f, 0.5f, 0.5f}, normal[3] = {0, 0, 1};
  float depth = 0, rough = 0.3f, coc = 32.0f;
  FrameView v = one_pixel(noisy, albedo, normal, &depth, &rough, &coc, 2.0f);
  float out[12];
  make_input(v, data, resolve_inputs(model, data), out);
  EXPECT_EQ(out[9], 1.0f);
  EXPECT_NEAR(out[11], 1.0f, 1e-4f);
  EXPECT_NEAR(out[0], std::log1p(1.0f / (0.5f + data.demod_eps)), 1e-6f);
  depth = 2.0f;
  std::erase(model.inputs, std::string("coc:log"));
  ASSERT_EQ(model.input_channels(), 11);
  make_input(v, data, resolve_inputs(model, data), out);
  EXPECT_NEAR(out[9], 0.5f, 1e-6f);  // on the focal plane
}

// Thesis 4.2.4 by hand: listing 1 (normal), depth / scene depth, listing 2
// (CoC, here in pixels), and linear demodulated radiance (4.3.2).
TEST(Augment, ThesisEncodingsMatchSection424ByHand) {
  TrainConfig cfg = apply_preset("thesis");
  const DataConfig& data = cfg.data;
  ASSERT_EQ(cfg.model.input_channels(), 12);
  float noisy[3] = {0.3f, 2.0f, 0.0f}, albedo[3] = {0.5f, 0.25f, 1.0f};
  float normal[3] = {0.6f, -0.8f, 0.0f}, depth = 2.5f, rough = 0.3f, coc = 0.8f;
  FrameView v = one_pixel(noisy, albedo, normal, &depth, &rough, &coc, 4.0f);
  float out[12];
  make_input(v, data, resolve_inputs(cfg.model, data), out);
  const float eps = data.demod_eps;
  EXPECT_FLOAT_EQ(out[0], 0.3f / (0.5f + eps));
  EXPECT_FLOAT_EQ(out[1], 2.0f / (0.25f + eps));
  EXPECT_FLOAT_EQ(out[2], 0.0f);
  EXPECT_FLOAT_EQ(out[3], 0.5f);                     // albedo as stored
  EXPECT_FLOAT_EQ(out[6], 0.8f);                     // (0.6 + 1) / 2
  EXPECT_FLOAT_EQ(out[7], 0.1f);                     // (-0.8 + 1) / 2
  EXPECT_FLOAT_EQ(out[8], 0.5f);                     // (1 - 0) / 2
  EXPECT_FLOAT_EQ(out[9], 2.5f / data.depth_scale);  // depth / scene depth
  EXPECT_FLOAT_EQ(out[10], 0.3f);                    // roughness
  EXPECT_FLOAT_EQ(out[11], 1.0f);                    // 0.8 px: acceptably sharp
  coc = 8.0f;                                        // (32 - 8) / 32
  make_input(v, data, resolve_inputs(cfg.model, data), out);
  EXPECT_FLOAT_EQ(out[11], 0.75f);
  EXPECT_FLOAT_EQ(coc_thesis(1.0f, 1.0f, 32.0f), 1.0f);   // the limit itself is sharp
  EXPECT_FLOAT_EQ(coc_thesis(32.0f, 1.0f, 32.0f), 0.0f);  // the scene maximum
}

// The normal's remap is not odd in the sign: the augmentation must turn the
// vector before encoding. A normal pointing right, turned a quarter turn
// counter-clockwise, points up: remapped (0.5, 1, 0.5).
TEST(Augment, RemappedNormalsTurnWithTheImage) {
  const int s = 32;
  TrainConfig cfg = apply_preset("thesis");
  cfg.data.crop = s;
  RawCrop raw = coded_crop(8, 2, s);
  std::mt19937_64 rng(1);
  SequencePlan plan = draw_plan(rng, cfg.data, 0, 8, 2, s, s);
  plan.first_frame = 0;
  plan.quarter_turns = 1;
  Sample smp = build_sample(raw, plan, cfg.data, cfg.model);
  const size_t n = size_t(s) * s;
  for (size_t p : {size_t(0), n / 2 + 3, n - 1}) {
    EXPECT_FLOAT_EQ(smp.input[6 * n + p], 0.5f);
    EXPECT_FLOAT_EQ(smp.input[7 * n + p], 1.0f);
    EXPECT_FLOAT_EQ(smp.input[8 * n + p], 0.5f);
  }
}

}  // namespace
}  // namespace dofarm::trainer
