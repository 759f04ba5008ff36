// The full material (Lambert + GGX mixture, worker/render/bsdf.h): sample()
// draws directions distributed as pdf() says (chi-square, missing mass
// included), sample().weight agrees with eval() / pdf(), the Fresnel-weighted
// diffuse lobe is reciprocal, no material reflects more than it receives, and
// a perfect mirror is a delta lobe in the mirror direction.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <optional>
#include <random>
#include <string>
#include <tuple>

#include "common/math.h"
#include "tests/render/chi2.h"
#include "worker/render/bsdf.h"
#include "worker/render/microfacet.h"

using dofarm::kPi;
using dofarm::Vec2;
using dofarm::Vec3;
using dofarm::render::Bsdf;
using dofarm::render::BsdfSample;
using dofarm::test::Chi2Options;
using dofarm::test::Chi2Result;
using dofarm::test::SphereCells;

namespace {

const Vec3 kUp(0, 0, 1);

struct Material {
  const char* name;
  float metallic;
  float roughness;
  Vec3 base_color;
};

// Roughness 0.1 / 0.5 / 1 and metallic 0 / 0.5 / 1, coloured so that the
// lobe-selection probability (a luminance) differs from every channel.
const Material kMaterials[] = {
    {"plastic_r1", 0.0f, 1.0f, Vec3(0.8f, 0.8f, 0.8f)},
    {"plastic_r05", 0.0f, 0.5f, Vec3(0.2f, 0.5f, 0.8f)},
    {"plastic_r01", 0.0f, 0.1f, Vec3(0.9f, 0.3f, 0.1f)},
    {"half_metal_r05", 0.5f, 0.5f, Vec3(0.9f, 0.6f, 0.3f)},
    {"half_metal_r01", 0.5f, 0.1f, Vec3(0.3f, 0.9f, 0.4f)},
    {"metal_r01", 1.0f, 0.1f, Vec3(0.95f, 0.64f, 0.54f)},
    {"metal_r05", 1.0f, 0.5f, Vec3(0.91f, 0.92f, 0.92f)},
    {"metal_r1", 1.0f, 1.0f, Vec3(0.5f, 0.5f, 0.5f)},
    // A smooth coat over a diffuse base: the mirror is a delta lobe, so only
    // the diffuse part has a pdf and every delta sample is missing mass.
    {"plastic_r0", 0.0f, 0.0f, Vec3(0.6f, 0.6f, 0.6f)},
};
const double kAngles[] = {0, 45, 80, 89};

constexpr float kIor = 1.5f;

// Two chi-square tests (around the mirror direction, around the normal) per
// (material, angle); Bonferroni, so the whole family passes at 0.01.
constexpr int kChi2Tests = 2 * std::size(kMaterials) * std::size(kAngles);
constexpr double kChi2Threshold = 0.01 / kChi2Tests;

// Incident direction at polar angle theta; the azimuth is not 0 so that a
// sampler that only works in the x-z plane is caught.
Vec3 incident(double theta_deg, double phi = 0.7) {
  double t = theta_deg * kPi / 180.0;
  return Vec3(float(std::sin(t) * std::cos(phi)), float(std::sin(t) * std::sin(phi)),
              float(std::cos(t)));
}

Vec3 mirror(Vec3 wo) { return Vec3(-wo.x, -wo.y, wo.z); }

Bsdf make_bsdf(const Material& m) {
  return Bsdf(kUp, kUp, m.base_color, m.metallic, m.roughness, kIor);
}

// GGX alpha as the material model defines it (glTF: roughness squared).
double lobe_width(const Material& m) {
  return 2.0 * dofarm::render::ggx::alpha_from_roughness(m.roughness);
}

// The directions the sampler produces for the non-delta part; rejected and
// delta samples are missing mass, which pdf() must account for.
std::optional<Vec3> sampled_direction(const Bsdf& bsdf, Vec3 wo, Vec2 u, float u_lobe) {
  BsdfSample s = bsdf.sample(wo, u_lobe, u);
  if (!s.valid || s.is_delta) return std::nullopt;
  return s.wi;
}

Chi2Result run_chi2(const Bsdf& sampler, const Bsdf& density, Vec3 wo, const SphereCells& cells,
                    int64_t samples = 100000) {
  Chi2Options options;
  options.cells = cells;
  options.samples = samples;
  // An error of 0.02 expected samples per cell is far below the Poisson noise
  // of cells that hold >= 5, and keeps the integration of cells cut by the
  // horizon (grazing incidence, narrow lobes) from running to full depth.
  options.count_tolerance = 2e-2;
  return dofarm::test::chi2_test(
      [&](Vec2 u, float u_lobe) { return sampled_direction(sampler, wo, u, u_lobe); },
      [&](Vec3 wi) { return density.pdf(wo, wi); }, options);
}

}  // namespace

// ---------------------------------------------------------------------------
// Chi-square: sample() against pdf().

class BsdfChi2 : public ::testing::TestWithParam<std::tuple<int, double>> {
 protected:
  const Material& material() const { return kMaterials[std::get<0>(GetParam())]; }
  double angle() const { return std::get<1>(GetParam()); }
  void Report(const char* cells, const Chi2Result& r) {
    EXPECT_EQ(r.malformed, 0) << r.summary();
    EXPECT_LE(r.pdf_integral, 1.0 + 1e-3) << r.summary();
    EXPECT_EQ(r.outside_support, 0) << r.summary();
    EXPECT_GT(r.p_value, kChi2Threshold) << r.summary();
    std::printf("  %-15s theta %2.0f, %s cells: %s\n", material().name, angle(), cells,
                r.summary().c_str());
  }
};

// Cells that shrink towards the mirror direction resolve the GGX lobe even
// at roughness 0.1 (alpha 0.01).
TEST_P(BsdfChi2, DirectionsFollowPdfNearTheMirrorDirection) {
  const Bsdf bsdf = make_bsdf(material());
  const Vec3 wo = incident(angle());
  Report("mirror",
         run_chi2(bsdf, bsdf, wo, SphereCells{mirror(wo), lobe_width(material()), 20, 40}));
}

// Equal-area cells around the normal (20 rings above the horizon, 20 below)
// resolve the diffuse lobe and the
// hemisphere's edge, where the narrow cells above are all in one ring.
TEST_P(BsdfChi2, DirectionsFollowPdfOverTheHemisphere) {
  const Bsdf bsdf = make_bsdf(material());
  const Vec3 wo = incident(angle());
  Report("normal", run_chi2(bsdf, bsdf, wo, SphereCells{kUp, 0.0, 40, 40}));
}

INSTANTIATE_TEST_SUITE_P(MaterialsAndAngles, BsdfChi2,
                         ::testing::Combine(::testing::Range(0, int(std::size(kMaterials))),
                                            ::testing::ValuesIn(kAngles)),
                         [](const ::testing::TestParamInfo<BsdfChi2::ParamType>& info) {
                           return std::string(kMaterials[std::get<0>(info.param)].name) + "_theta" +
                                  std::to_string(int(std::get<1>(info.param)));
                         });

// Negative controls: the same test must reject the pdf of a slightly
// different material (the lobe's width, the lobe-selection probability).
TEST(BsdfChi2Control, RejectsPdfOfAnotherRoughness) {
  const Material m{"half_metal", 0.5f, 0.5f, Vec3(0.9f, 0.6f, 0.3f)};
  const Material wrong{"half_metal", 0.5f, 0.55f, Vec3(0.9f, 0.6f, 0.3f)};
  const Vec3 wo = incident(45);
  Chi2Result r =
      run_chi2(make_bsdf(m), make_bsdf(wrong), wo, SphereCells{mirror(wo), lobe_width(m), 20, 40});
  EXPECT_LT(r.p_value, 1e-12) << r.summary();
}

TEST(BsdfChi2Control, RejectsPdfOfAnotherMetallic) {
  const Material m{"half_metal", 0.5f, 0.5f, Vec3(0.9f, 0.6f, 0.3f)};
  const Material wrong{"half_metal", 0.4f, 0.5f, Vec3(0.9f, 0.6f, 0.3f)};
  const Vec3 wo = incident(45);
  Chi2Result r = run_chi2(make_bsdf(m), make_bsdf(wrong), wo, SphereCells{kUp, 0.0, 40, 40});
  EXPECT_LT(r.p_value, 1e-12) << r.summary();
}

// ---------------------------------------------------------------------------
// Consistency of sample(), eval() and pdf().

// The integrator divides eval() by pdf() for NEE-MIS and multiplies by
// sample().weight for the continuation: both must be the same estimator.
TEST(Bsdf, SampleWeightEqualsEvalOverPdf) {
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<float> uni(0.0f, 0.999999f);
  int checked = 0;
  for (const Material& m : kMaterials) {
    const Bsdf bsdf = make_bsdf(m);
    for (double angle : kAngles) {
      const Vec3 wo = incident(angle);
      for (int i = 0; i < 2000; ++i) {
        BsdfSample s = bsdf.sample(wo, uni(rng), Vec2(uni(rng), uni(rng)));
        if (!s.valid || s.is_delta) continue;
        ++checked;
        const float pdf = bsdf.pdf(wo, s.wi);
        const Vec3 f = bsdf.eval(wo, s.wi);
        ASSERT_GT(pdf, 0.0f) << m.name << " theta " << angle;
        EXPECT_NEAR(s.pdf, pdf, 1e-5f * pdf) << m.name << " theta " << angle;
        for (int c = 0; c < 3; ++c) {
          const float expected = f[c] / pdf;
          EXPECT_NEAR(s.weight[c], expected, 1e-4f * std::max(1.0f, expected))
              << m.name << " theta " << angle << " channel " << c;
        }
      }
    }
  }
  EXPECT_GT(checked, 50000);
}

// The (1 - F(wo)) (1 - F(wi)) weighting of the diffuse lobe is symmetric, so
// f = eval / cos(wi) is too. Roughness 0 leaves only the diffuse lobe in eval().
TEST(Bsdf, DiffuseLobeIsReciprocal) {
  std::mt19937_64 rng(23);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (float metallic : {0.0f, 0.5f}) {
    const Bsdf bsdf(kUp, kUp, Vec3(0.8f, 0.5f, 0.2f), metallic, 0.0f, kIor);
    for (int i = 0; i < 2000; ++i) {
      const Vec3 a = incident(89.5 * uni(rng), 2 * kPi * uni(rng));
      const Vec3 b = incident(89.5 * uni(rng), 2 * kPi * uni(rng));
      const Vec3 f_ab = bsdf.eval(a, b) / b.z, f_ba = bsdf.eval(b, a) / a.z;
      ASSERT_GT(f_ab.x, 0.0f);
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(f_ab[c], f_ba[c], 1e-5f * f_ab[c] + 1e-7f);
    }
    // Fresnel makes the weighting matter: grazing light is mostly reflected
    // by the coat, so the diffuse part is darker there.
    const Vec3 f_normal = bsdf.eval(incident(0), incident(0)) / 1.0f;
    const Vec3 f_grazing = bsdf.eval(incident(0), incident(89)) / incident(89).z;
    EXPECT_LT(f_grazing.x, 0.9f * f_normal.x);
  }
}

// ---------------------------------------------------------------------------
// Energy: directional albedo, the mean of sample().weight, never exceeds 1
// for a white base colour.

TEST(Bsdf, DirectionalAlbedoOfWhiteIsAtMostOne) {
  const int kSamples = 40000;
  std::mt19937_64 rng(29);
  std::uniform_real_distribution<float> uni(0.0f, 0.999999f);
  for (float metallic : {0.0f, 0.5f, 1.0f}) {
    for (float roughness : {0.0f, 0.05f, 0.1f, 0.3f, 0.5f, 0.75f, 1.0f}) {
      const Bsdf bsdf(kUp, kUp, Vec3(1.0f), metallic, roughness, kIor);
      for (double angle : {0.0, 30.0, 60.0, 80.0, 89.0}) {
        const Vec3 wo = incident(angle);
        double sum = 0, sum2 = 0;
        for (int i = 0; i < kSamples; ++i) {
          BsdfSample s = bsdf.sample(wo, uni(rng), Vec2(uni(rng), uni(rng)));
          if (!s.valid) continue;
          ASSERT_TRUE(dofarm::is_finite(s.weight));
          ASSERT_GE(std::min({s.weight.x, s.weight.y, s.weight.z}), 0.0f);
          // White base colour: every channel is the same.
          ASSERT_EQ(s.weight.x, s.weight.y);
          ASSERT_EQ(s.weight.x, s.weight.z);
          sum += s.weight.x;
          sum2 += double(s.weight.x) * s.weight.x;
        }
        const double mean = sum / kSamples;
        const double std_error =
            std::sqrt(std::max(0.0, sum2 / kSamples - mean * mean) / (kSamples - 1));
        EXPECT_LE(mean, 1.0 + 4.0 * std_error + 1e-4)
            << "metallic " << metallic << " roughness " << roughness << " theta " << angle
            << ": albedo " << mean << " +- " << std_error;
        // Not vacuous: single-scattering GGX loses energy at high roughness
        // (a white rough metal keeps ~0.3 at normal incidence), but a white
        // material never goes dark.
        EXPECT_GT(mean, 0.1) << "metallic " << metallic << " roughness " << roughness << " theta "
                             << angle;
      }
    }
  }
}

// ---------------------------------------------------------------------------
// The perfect mirror.

TEST(Bsdf, SmoothMetalIsADeltaMirror) {
  const Vec3 color(0.9f, 0.7f, 0.5f);
  const Bsdf bsdf(kUp, kUp, color, 1.0f, 0.0f, kIor);
  EXPECT_FALSE(bsdf.has_non_delta());
  std::mt19937_64 rng(31);
  std::uniform_real_distribution<float> uni(0.0f, 0.999999f);
  for (double angle : kAngles) {
    const Vec3 wo = incident(angle);
    for (int i = 0; i < 100; ++i) {
      BsdfSample s = bsdf.sample(wo, uni(rng), Vec2(uni(rng), uni(rng)));
      ASSERT_TRUE(s.valid) << "theta " << angle;
      EXPECT_TRUE(s.is_delta);
      EXPECT_EQ(s.pdf, 0.0f);
      const Vec3 m = mirror(wo);
      EXPECT_NEAR(s.wi.x, m.x, 1e-6f);
      EXPECT_NEAR(s.wi.y, m.y, 1e-6f);
      EXPECT_NEAR(s.wi.z, m.z, 1e-6f);
      // A metal's Fresnel starts at its base colour and rises towards 1.
      for (int c = 0; c < 3; ++c) {
        EXPECT_GE(s.weight[c], color[c] - 1e-5f);
        EXPECT_LE(s.weight[c], 1.0f + 1e-5f);
      }
      // No non-delta part: nothing to evaluate, no density anywhere.
      EXPECT_EQ(bsdf.pdf(wo, s.wi), 0.0f);
      EXPECT_EQ(bsdf.eval(wo, s.wi).x, 0.0f);
    }
  }
  // At normal incidence the weight is exactly F0 = the base colour.
  BsdfSample s = bsdf.sample(incident(0), 0.5f, Vec2(0.5f, 0.5f));
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(s.weight[c], color[c], 1e-5f);
}

// A direction below the surface on either side is never sampled or evaluated.
TEST(Bsdf, NothingBelowTheSurface) {
  const Bsdf bsdf(kUp, kUp, Vec3(0.5f), 0.5f, 0.5f, kIor);
  const Vec3 below(0.3f, 0.1f, -0.9f);
  EXPECT_FALSE(bsdf.sample(dofarm::normalize(below), 0.5f, Vec2(0.3f, 0.3f)).valid);
  EXPECT_EQ(bsdf.pdf(incident(45), dofarm::normalize(below)), 0.0f);
  EXPECT_EQ(bsdf.eval(incident(45), dofarm::normalize(below)).x, 0.0f);
  EXPECT_EQ(bsdf.pdf(dofarm::normalize(below), incident(45)), 0.0f);
}
