// The reference's half-sample estimate (`reference_half`, render_job.cpp):
// the mean of the first half of the reference's samples, so that it and the
// second half (2 * reference - reference_half) are two disjoint estimates of
// the pixel that the trainer compares to measure the reference ceiling.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <map>
#include <set>

#include "tests/render/render_fixtures.h"

namespace dofarm::render {
namespace {

using testing::make_scene;
using testing::make_spec;

JobSpec room_spec(int w = 12, int h = 12) {
  JobSpec spec = make_spec(w, h, Vec3(0, 1, 3.2f), Vec3(0, 0.9f, 0), 45.0f);
  spec.versions = 1;
  spec.albedo_ref_spp = 1;
  return spec;
}

bool same_floats(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

double luminance_at(const std::vector<float>& img, size_t plane, size_t i) {
  return 0.2126 * img[i] + 0.7152 * img[plane + i] + 0.0722 * img[2 * plane + i];
}

// The first N samples of a 2N-sample reference are the samples of an N-sample
// reference (every sample is a function of its index), summed in the same
// order: the half must be that reference, bit for bit.
TEST(ReferenceHalf, IsTheReferenceOfHalfTheSamplesBitForBit) {
  auto scene = make_scene(testing::small_room());
  for (int n : {1, 8, 24}) {
    JobSpec half = room_spec(), full = room_spec();
    half.reference_spp = n;
    full.reference_spp = 2 * n;
    FrameBuffers a = render_frame(*scene, half, 0);
    FrameBuffers b = render_frame(*scene, full, 0);
    EXPECT_TRUE(same_floats(b.reference_half, a.reference)) << "spp " << 2 * n;
    EXPECT_FALSE(same_floats(b.reference, a.reference)) << "spp " << 2 * n;
  }
}

// An odd count gives the first ceil(n/2) samples; one sample is its own half.
TEST(ReferenceHalf, OddCountsTakeTheLargerHalf) {
  auto scene = make_scene(testing::small_room());
  JobSpec three = room_spec(), two = room_spec(), one = room_spec();
  three.reference_spp = 3;
  two.reference_spp = 2;
  one.reference_spp = 1;
  FrameBuffers f3 = render_frame(*scene, three, 0), f2 = render_frame(*scene, two, 0),
               f1 = render_frame(*scene, one, 0);
  EXPECT_TRUE(same_floats(f3.reference_half, f2.reference));
  EXPECT_TRUE(same_floats(f1.reference_half, f1.reference));
}

// With an error target, a pixel stops after 64k samples; its half is the
// first 32k. A target no pixel can meet runs every pixel to the cap (the half
// of the cap); one every pixel meets stops them all after the first batch.
TEST(ReferenceHalf, FollowsTheAdaptiveStoppingPoint) {
  auto scene = make_scene(testing::small_room());
  JobSpec fixed32 = room_spec(), fixed96 = room_spec();
  fixed32.reference_spp = 32;
  fixed96.reference_spp = 96;
  const FrameBuffers r32 = render_frame(*scene, fixed32, 0);
  const FrameBuffers r96 = render_frame(*scene, fixed96, 0);

  JobSpec loose = room_spec();
  loose.reference_error = 0.999f;  // met by every pixel after 64 samples
  loose.reference_max_spp = 4096;
  EXPECT_TRUE(same_floats(render_frame(*scene, loose, 0).reference_half, r32.reference));

  JobSpec tight = room_spec();
  tight.reference_error = 1e-6f;  // met by no pixel: all run to the cap
  tight.reference_max_spp = 192;
  EXPECT_TRUE(same_floats(render_frame(*scene, tight, 0).reference_half, r96.reference));
}

// Between the extremes pixels stop at different counts; each pixel's half
// must be that pixel's own first half, so (A + B) / 2 = R and B's samples
// start where A's end: checked through a pixel whose count is known from a
// fixed render with the same samples.
TEST(ReferenceHalf, EachPixelHalvesItsOwnCount) {
  auto scene = make_scene(testing::small_room());
  JobSpec adaptive = room_spec();
  adaptive.reference_error = 0.05f;
  adaptive.reference_max_spp = 1024;
  const FrameBuffers fa = render_frame(*scene, adaptive, 0);
  // Every pixel's reference equals one fixed-count reference (n = 64k); its
  // half must equal the reference at n/2 for the same pixel.
  std::map<int, FrameBuffers> fixed;
  auto at = [&](int spp) -> const FrameBuffers& {
    if (!fixed.count(spp)) {
      JobSpec s = room_spec();
      s.reference_spp = spp;
      fixed.emplace(spp, render_frame(*scene, s, 0));
    }
    return fixed.at(spp);
  };
  const size_t plane = fa.plane();
  int matched = 0;
  std::set<int> counts;
  for (size_t i = 0; i < plane; ++i) {
    for (int n = 64; n <= 1024; n += 64) {
      const FrameBuffers& f = at(n);
      bool same = true;
      for (int c = 0; c < 3; ++c) same &= f.reference[c * plane + i] == fa.reference[c * plane + i];
      if (!same) continue;
      const FrameBuffers& h = at(n / 2);
      for (int c = 0; c < 3; ++c)
        EXPECT_EQ(fa.reference_half[c * plane + i], h.reference[c * plane + i])
            << "pixel " << i << " channel " << c << " stopped at " << n;
      counts.insert(n);
      ++matched;
      break;
    }
  }
  EXPECT_EQ(matched, int(plane));
  EXPECT_GE(counts.size(), 2u) << "the error target should stop pixels at different counts";
}

// sRGB's slope (IEC 61966-2-1) by a central difference of the curve itself,
// at the luminance clamped to 1 as the display rule takes it.
double srgb_slope_numeric(double l) {
  auto encode = [](double v) {
    return v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055;
  };
  l = std::min(l, 1.0);
  const double h = 1e-7;
  if (l <= 0.0031308 - h) return 12.92;
  return (encode(l + h) - encode(l - h)) / (2 * h);
}

// The small room in grey, lit by a lamp of colour k: every path's radiance
// is k times a scalar, so each channel's variance is k_c^2 / (w . k)^2 times
// the luminance's, which the renderer reports (reference_var).
SceneData tinted_room(Vec3 k) {
  SceneData d;
  const Material grey = testing::diffuse(Vec3(0.6f));
  add_quad(d, Vec3(0, 0, 0), Vec3(0, 0, 1), Vec3(1, 0, 0), grey);
  add_quad(d, Vec3(0, 2, 0), Vec3(1, 0, 0), Vec3(0, 0, 1), grey);
  add_quad(d, Vec3(0, 1, -1), Vec3(1, 0, 0), Vec3(0, 1, 0), grey);
  add_quad(d, Vec3(-1, 1, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), testing::diffuse(Vec3(0.3f)));
  add_quad(d, Vec3(1, 1, 0), Vec3(0, 0, 1), Vec3(0, 1, 0), testing::diffuse(Vec3(0.9f)));
  add_quad(d, Vec3(0, 1.98f, 0), Vec3(0.3f, 0, 0), Vec3(0, 0, 0.3f), testing::emitter(k * 12.0f));
  add_box(d, Vec3(0.1f, 0, -0.3f), Vec3(0.7f, 0.8f, 0.3f), testing::diffuse(Vec3(0.2f)));
  return d;
}

// The display-space rule (buffers.reference_display_error): each pixel stops
// at the first batch boundary, from 1024 samples on, where its relative error
// meets reference_error or the largest of its channels' display-space errors
// (standard error times sRGB's slope at the channel's mean) meets
// reference_display_error; else at the cap. Recomputed here from fixed-count
// renders of the same samples (each reports its mean and the variance of
// that mean), the adaptive pixel must equal the fixed render at exactly that
// count. A grey lamp and a red one: with the red one a channel carries all
// the noise that the luminance shows at a fifth of its size.
TEST(ReferenceHalf, DisplayRuleStopsWhereEitherErrorIsFirstMet) {
  const double w[3] = {0.2126, 0.7152, 0.0722};
  for (Vec3 k : {Vec3(1, 1, 1), Vec3(1, 0, 0)}) {
    SCOPED_TRACE(k.y == 0 ? "red lamp" : "white lamp");
    auto scene = make_scene(tinted_room(k));
    const int kMin = 1024, kCap = 1536;
    JobSpec adaptive = room_spec(6, 6);
    adaptive.reference_error = 0.01f;
    adaptive.reference_max_spp = kCap;
    adaptive.reference_display_error = 0.004f;
    const FrameBuffers fa = render_frame(*scene, adaptive, 0);
    std::map<int, FrameBuffers> fixed;
    for (int n = 64; n <= kCap; n += 64) {
      JobSpec s = room_spec(6, 6);
      s.reference_spp = n;
      fixed.emplace(n, render_frame(*scene, s, 0));
    }
    const double wk = w[0] * k.x + w[1] * k.y + w[2] * k.z;
    const size_t plane = fa.plane();
    int by_display = 0, by_relative = 0, at_cap = 0;
    for (size_t i = 0; i < plane; ++i) {
      int expected = kCap;
      bool display_stop = false;
      for (int n = 64; n <= kCap; n += 64) {
        const FrameBuffers& f = fixed.at(n);
        const double lum = luminance_at(f.reference, plane, i);
        const double se = std::sqrt(double(f.reference_var[i]));
        const bool relative_met = se / std::max(std::fabs(lum), 1e-3) <= adaptive.reference_error;
        double display = 0;
        for (float kc : {k.x, k.y, k.z})
          display = std::max(display, se / wk * kc * srgb_slope_numeric(lum / wk * kc));
        const bool display_met = n >= kMin && display <= adaptive.reference_display_error;
        if (relative_met || display_met) {
          expected = n;
          display_stop = !relative_met;
          break;
        }
      }
      for (int c = 0; c < 3; ++c)
        EXPECT_EQ(fa.reference[c * plane + i], fixed.at(expected).reference[c * plane + i])
            << "pixel " << i << " should stop at " << expected;
      if (display_stop)
        ++by_display;
      else if (expected == kCap)
        ++at_cap;
      else
        ++by_relative;
    }
    // The scene has to exercise the rule: some pixels stop by it, before the cap.
    EXPECT_GT(by_display, 0) << "relative " << by_relative << ", cap " << at_cap;
  }
}

// With independent random numbers the two halves are independent, each with
// twice the variance of the full mean, so E[(A - B)^2] = 4 Var(R), and
// reference_var estimates Var(R): their ratio, averaged over pixels, is 1.
// Positively correlated halves (e.g. overlapping samples) give less, halves
// of different sizes more. Both halves are unbiased: their image means agree
// with each other within the noise.
TEST(ReferenceHalf, HalvesAreIndependentUnbiasedEstimates) {
  auto scene = make_scene(testing::small_room());
  JobSpec spec = room_spec(24, 24);
  spec.sampler = SamplerKind::kIndependent;
  spec.reference_spp = 64;
  const FrameBuffers fb = render_frame(*scene, spec, 0);
  const size_t plane = fb.plane();
  double ratio_sum = 0, diff_sum = 0, diff_sq = 0;
  int used = 0;
  for (size_t i = 0; i < plane; ++i) {
    const double r = luminance_at(fb.reference, plane, i);
    const double a = luminance_at(fb.reference_half, plane, i);
    const double b = 2 * r - a;
    diff_sum += a - b;
    diff_sq += (a - b) * (a - b);
    if (fb.reference_var[i] <= 0) continue;
    ratio_sum += (a - b) * (a - b) / (4.0 * fb.reference_var[i]);
    ++used;
  }
  ASSERT_GT(used, int(plane) / 2);
  // A mean of `used` ratios of roughly chi-square(1) variables: std ~ sqrt(2/used).
  EXPECT_NEAR(ratio_sum / used, 1.0, 4.0 * std::sqrt(2.0 / used));
  const double mean_diff = diff_sum / plane;
  const double se = std::sqrt(diff_sq / plane / plane);
  EXPECT_LT(std::fabs(mean_diff), 4.0 * se) << "mean of A - B " << mean_diff << " se " << se;
}

// White furnace (test_integrator.cpp): a Lambertian sphere of albedo 1 in a
// uniform environment of radiance 1 is exactly 1 in expectation, so each half
// on its own, and the second half too, must average to 1 within its noise.
TEST(ReferenceHalf, BothHalvesAreOneInTheWhiteFurnace) {
  SceneData d;
  add_icosphere(d, Vec3(0), 1.0f, 3, testing::diffuse(Vec3(1), /*ior=*/1.0f), /*smooth=*/false);
  auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
  JobSpec spec = make_spec(24, 24, Vec3(0, 0, 4), Vec3(0, 0, 0), 20.0f);
  spec.versions = 1;
  spec.albedo_ref_spp = 1;
  spec.reference_spp = 32;
  const FrameBuffers fb = render_frame(*scene, spec, 0);
  const size_t plane = fb.plane();
  double sa = 0, sb = 0, sa2 = 0, sb2 = 0;
  int n = 0;
  for (size_t i = 0; i < plane; ++i) {
    if (fb.depth[i] <= 0) continue;  // the background is 1 exactly, not a test
    const double r = luminance_at(fb.reference, plane, i);
    const double a = luminance_at(fb.reference_half, plane, i);
    const double b = 2 * r - a;
    sa += a, sb += b, sa2 += a * a, sb2 += b * b;
    ++n;
  }
  ASSERT_GT(n, 100);
  const double ma = sa / n, mb = sb / n;
  const double se_a = std::sqrt(std::max(0.0, sa2 / n - ma * ma) / n);
  const double se_b = std::sqrt(std::max(0.0, sb2 / n - mb * mb) / n);
  EXPECT_NEAR(ma, 1.0, 4.0 * se_a + 1e-6);
  EXPECT_NEAR(mb, 1.0, 4.0 * se_b + 1e-6);
  EXPECT_GT(se_a, 0.0) << "the halves should carry noise; the test would be empty";
}

}  // namespace
}  // namespace dofarm::render
