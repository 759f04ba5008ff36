// The glass lobe of KHR_materials_transmission (worker/render/bsdf.h): the
// exact dielectric Fresnel against hand-computed values, sample() against
// pdf() over the whole sphere (chi-square, refraction included, entering and
// leaving the material), sample().weight against eval() / pdf(), the
// generalised reciprocity of the rough BTDF, the energy of smooth and
// rough glass and the table that compensates the rough one.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <iterator>
#include <random>
#include <string>
#include <tuple>

#include "common/math.h"
#include "tests/render/bsdf_chi2.h"
#include "tests/render/chi2.h"
#include "worker/render/bsdf.h"
#include "worker/render/glass_albedo.h"
#include "worker/render/microfacet.h"

using dofarm::kPi;
using dofarm::Vec2;
using dofarm::Vec3;
using dofarm::render::Bsdf;
using dofarm::render::BsdfSample;
using dofarm::render::fresnel_dielectric;
using dofarm::render::TransmissionLayer;
using dofarm::test::Chi2Result;
using dofarm::test::SphereCells;

namespace {

const Vec3 kUp(0, 0, 1);
constexpr float kIor = 1.5f;

struct Glass {
  const char* name;
  float metallic, roughness, transmission;
  bool entering;
  Vec3 base_color;
  float coat = 0;  // KHR_materials_clearcoat at roughness 0.3
};

// Rough glass seen from outside and from inside (where total internal
// reflection starts at 41.8 degrees), glass mixed with the layered
// dielectric, and with a metal.
const Glass kGlasses[] = {
    {"glass_r03_in", 0.0f, 0.3f, 1.0f, true, Vec3(1.0f)},
    {"glass_r06_in", 0.0f, 0.6f, 1.0f, true, Vec3(0.9f, 0.7f, 0.5f)},
    {"glass_r1_in", 0.0f, 1.0f, 1.0f, true, Vec3(1.0f)},
    {"glass_r03_out", 0.0f, 0.3f, 1.0f, false, Vec3(1.0f)},
    {"glass_r06_out", 0.0f, 0.6f, 1.0f, false, Vec3(0.6f, 0.8f, 1.0f)},
    {"half_glass_r05", 0.0f, 0.5f, 0.5f, true, Vec3(0.8f, 0.5f, 0.3f)},
    {"glass_metal_r04", 0.5f, 0.4f, 1.0f, false, Vec3(0.9f, 0.9f, 0.6f)},
    {"coated_glass_r05", 0.0f, 0.5f, 1.0f, true, Vec3(0.8f, 0.9f, 1.0f), 1.0f},
};
const double kAngles[] = {0, 30, 60, 85};

constexpr int kChi2Tests = 2 * std::size(kGlasses) * std::size(kAngles);
constexpr double kChi2Threshold = 0.01 / kChi2Tests;

Vec3 incident(double theta_deg, double phi = 0.7) {
  double t = theta_deg * kPi / 180.0;
  return Vec3(float(std::sin(t) * std::cos(phi)), float(std::sin(t) * std::sin(phi)),
              float(std::cos(t)));
}

Bsdf make_bsdf(const Glass& g) {
  return Bsdf(kUp, kUp, g.base_color, g.metallic, g.roughness, kIor, {},
              TransmissionLayer{g.transmission, g.entering}, {g.coat, 0.3f});
}

float eta_of(const Glass& g) { return g.entering ? kIor : 1.0f / kIor; }

// wo refracted through the macro surface (Snell), or mirrored under total
// internal reflection: where the lobe that matters lies.
Vec3 lobe_centre(Vec3 wo, float eta) {
  const double sin2_t = (1.0 - double(wo.z) * wo.z) / (double(eta) * eta);
  if (sin2_t >= 1.0) return Vec3(-wo.x, -wo.y, wo.z);
  const double cos_t = std::sqrt(1.0 - sin2_t);
  return dofarm::normalize(Vec3(float(-wo.x / eta), float(-wo.y / eta), float(-cos_t)));
}

Chi2Result run_chi2(const Bsdf& bsdf, Vec3 wo, const SphereCells& cells) {
  return dofarm::test::bsdf_chi2(bsdf, bsdf, wo, cells);
}

}  // namespace

// Hand-computed: normal incidence ((n - 1) / (n + 1))^2; Brewster's angle
// (tan = n: the p-polarised part vanishes, F = rs^2 / 2 with cos_i =
// 1/sqrt(1 + n^2), cos_t = n/sqrt(1 + n^2): rs = (1 - n^2) / (1 + n^2));
// total internal reflection beyond the critical angle from inside; grazing
// incidence reflects everything; IOR 1 reflects nothing.
TEST(Fresnel, DielectricMatchesHandComputedValues) {
  EXPECT_NEAR(fresnel_dielectric(1.0f, 1.5f), 0.04f, 1e-6f);
  EXPECT_NEAR(fresnel_dielectric(1.0f, 1.0f / 1.5f), 0.04f, 1e-6f);  // the same from inside
  const double n = 1.5, cos_b = 1.0 / std::sqrt(1.0 + n * n);
  const double rs = (1.0 - n * n) / (1.0 + n * n);
  EXPECT_NEAR(fresnel_dielectric(float(cos_b), 1.5f), 0.5 * rs * rs, 1e-6);  // 0.0739645
  EXPECT_NEAR(0.5 * rs * rs, 0.0739645, 1e-7);
  // Critical angle from inside: sin = 1 / 1.5 (41.81 degrees).
  const double cos_c = std::sqrt(1.0 - 1.0 / (n * n));
  EXPECT_EQ(fresnel_dielectric(float(cos_c) - 1e-4f, 1.0f / 1.5f), 1.0f);
  EXPECT_LT(fresnel_dielectric(float(cos_c) + 1e-3f, 1.0f / 1.5f), 1.0f);
  EXPECT_NEAR(fresnel_dielectric(0.0f, 1.5f), 1.0f, 1e-6f);
  EXPECT_LT(fresnel_dielectric(0.3f, 1.0f), 1e-12f);
}

class GlassChi2 : public ::testing::TestWithParam<std::tuple<int, double>> {
 protected:
  const Glass& glass() const { return kGlasses[std::get<0>(GetParam())]; }
  double angle() const { return std::get<1>(GetParam()); }
  void Report(const char* cells, const Chi2Result& r) {
    dofarm::test::expect_chi2_pass(r, kChi2Threshold, glass().name, angle(), cells);
  }
};

// Cells that shrink towards the refracted (or totally reflected) direction.
TEST_P(GlassChi2, DirectionsFollowPdfAroundTheRefractedDirection) {
  const Bsdf bsdf = make_bsdf(glass());
  const Vec3 wo = incident(angle());
  const double width = 2.0 * dofarm::render::ggx::alpha_from_roughness(glass().roughness);
  Report("refracted",
         run_chi2(bsdf, wo, SphereCells{lobe_centre(wo, eta_of(glass())), width, 20, 40}));
}

// Equal-area cells around the normal over the whole sphere.
TEST_P(GlassChi2, DirectionsFollowPdfOverTheSphere) {
  const Bsdf bsdf = make_bsdf(glass());
  Report("normal", run_chi2(bsdf, incident(angle()), SphereCells{kUp, 0.0, 40, 40}));
}

INSTANTIATE_TEST_SUITE_P(GlassesAndAngles, GlassChi2,
                         ::testing::Combine(::testing::Range(0, int(std::size(kGlasses))),
                                            ::testing::ValuesIn(kAngles)),
                         [](const ::testing::TestParamInfo<GlassChi2::ParamType>& info) {
                           return std::string(kGlasses[std::get<0>(info.param)].name) + "_theta" +
                                  std::to_string(int(std::get<1>(info.param)));
                         });

// Negative control: the test must reject the pdf of glass with another IOR
// (a refracted lobe in the wrong place).
TEST(GlassChi2Control, RejectsPdfOfAnotherIor) {
  const Bsdf bsdf = make_bsdf(kGlasses[0]);
  const Bsdf wrong(kUp, kUp, Vec3(1.0f), 0.0f, 0.3f, 1.6f, {}, TransmissionLayer{1.0f, true});
  const Chi2Result r =
      dofarm::test::bsdf_chi2(bsdf, wrong, incident(30), SphereCells{kUp, 0.0, 40, 40});
  EXPECT_LT(r.p_value, 1e-12) << r.summary();
}

TEST(Glass, SampleWeightEqualsEvalOverPdf) {
  std::mt19937_64 rng(29);
  std::uniform_real_distribution<float> uni(0.0f, 0.999999f);
  int refracted = 0, reflected = 0;
  for (const Glass& g : kGlasses) {
    const Bsdf bsdf = make_bsdf(g);
    for (double angle : kAngles) {
      const Vec3 wo = incident(angle);
      for (int i = 0; i < 2000; ++i) {
        BsdfSample s = bsdf.sample(wo, uni(rng), Vec2(uni(rng), uni(rng)));
        if (!s.valid) continue;
        ASSERT_FALSE(s.is_delta) << g.name;
        (s.wi.z < 0 ? refracted : reflected) += 1;
        const float pdf = bsdf.pdf(wo, s.wi);
        const Vec3 f = bsdf.eval(wo, s.wi);
        ASSERT_GT(pdf, 0.0f) << g.name << " theta " << angle;
        EXPECT_NEAR(s.pdf, pdf, 1e-5f * pdf) << g.name << " theta " << angle;
        for (int c = 0; c < 3; ++c) {
          const float expected = f[c] / pdf;
          EXPECT_NEAR(s.weight[c], expected, 1e-4f * std::max(1.0f, expected))
              << g.name << " theta " << angle << " channel " << c;
        }
      }
    }
  }
  EXPECT_GT(refracted, 10000);
  EXPECT_GT(reflected, 5000);
}

// Veach 1997, eq. 5.14 in radiance form: f(wo -> wi) / n_o^2 = f(wi -> wo) /
// n_i^2 for the refracted part. Outside (n = 1) looking in, against inside
// (n = 1.5) looking out through the same surface (the frame turned over).
// The compensation 1 / E(mu_o) (glass_albedo.h) depends on wo alone, so it
// is divided out: the single-scattering lobe is what must be reciprocal.
TEST(Glass, RoughRefractionIsReciprocalUpToEtaSquared) {
  std::mt19937_64 rng(31);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  const Vec3 down(0, 0, -1);
  for (float roughness : {0.2f, 0.5f, 1.0f}) {
    const Bsdf outside(kUp, kUp, Vec3(1.0f), 0.0f, roughness, kIor, {}, {1.0f, true});
    const Bsdf inside(down, down, Vec3(1.0f), 0.0f, roughness, kIor, {}, {1.0f, false});
    int checked = 0;
    for (int i = 0; i < 4000; ++i) {
      const Vec3 wo = incident(89.0 * uni(rng), 2 * kPi * uni(rng));
      Vec3 wi = incident(89.0 * uni(rng), 2 * kPi * uni(rng));
      wi.z = -wi.z;
      const float alpha = dofarm::render::ggx::alpha_from_roughness(roughness);
      const auto& table = dofarm::render::ggx::glass_albedo_table();
      const float f_in = outside.eval(wo, wi).x / std::abs(wi.z) *
                         dofarm::render::ggx::glass_albedo(table, kIor, true, alpha, wo.z);
      const float f_out = inside.eval(wi, wo).x / std::abs(wo.z) *
                          dofarm::render::ggx::glass_albedo(table, kIor, false, alpha, -wi.z);
      if (!(f_in > 1e-4f)) continue;
      ++checked;
      // Float rounding of the half vector: up to 1e-3 relative near grazing.
      EXPECT_NEAR(f_in, f_out / (kIor * kIor), 3e-3f * f_in) << "roughness " << roughness;
    }
    EXPECT_GT(checked, 1000) << "roughness " << roughness;
  }
}

// Energy in importance form (the radiance scaling 1 / eta^2 of refracted
// light undone: what a closed object returns, entering and leaving). Smooth
// glass keeps exactly all of it (F + (1 - F)).
TEST(Glass, SmoothGlassConservesEnergyExactly) {
  for (bool entering : {true, false}) {
    const Bsdf bsdf(kUp, kUp, Vec3(1.0f), 0.0f, 0.0f, kIor, {}, {1.0f, entering});
    const float eta = entering ? kIor : 1.0f / kIor;
    for (double angle : {0.0, 30.0, 41.0, 43.0, 70.0, 89.0}) {
      const Vec3 wo = incident(angle);
      double sum = 0, f_reflect = 0;
      const int n = 10000;
      for (int i = 0; i < n; ++i) {
        const BsdfSample s = bsdf.sample(wo, (i + 0.5f) / n, Vec2(0.5f, 0.5f));
        ASSERT_TRUE(s.valid && s.is_delta);
        if (s.wi.z > 0) {
          EXPECT_NEAR(s.wi.x, -wo.x, 1e-6f);
          f_reflect += 1.0 / n;
          sum += s.weight.x;
        } else {
          // Snell: the tangential component shrinks by 1 / eta.
          EXPECT_NEAR(s.wi.x, -wo.x / eta, 1e-5f);
          EXPECT_NEAR(s.wi.y, -wo.y / eta, 1e-5f);
          sum += s.weight.x * eta * eta;
        }
      }
      EXPECT_NEAR(sum / n, 1.0, 1e-5) << "theta " << angle;
      EXPECT_NEAR(f_reflect, fresnel_dielectric(wo.z, eta), 2.0 / n) << "theta " << angle;
    }
  }
}

// Rough glass: the single-scattering lobe loses what multiple scattering
// between the microfacets would return, little when smooth, much at high
// roughness from inside, where many microfacets reflect totally into the
// material (quadrature: entering 1.00 / 0.95-1.00 / 0.88-0.98 /
// 0.71-0.89 at roughness 0.05 / 0.3 / 0.6 / 1, leaving 1.00 / 0.89-0.99 /
// 0.74-0.86 / 0.42-0.50). With the compensation 1 / E(mu_o) the lobe
// returns what it receives within the table's error (printed;
// docs/renderer.md).
TEST(Glass, SingleScatteringLosesWhatTheCompensationReturns) {
  using dofarm::render::ggx::glass_albedo_by_quadrature;
  EXPECT_LT(glass_albedo_by_quadrature(1.0f / kIor, 1.0f, 1.0f, 64), 0.6);
  EXPECT_LT(glass_albedo_by_quadrature(kIor, 1.0f, 0.2f, 64), 0.8);
  EXPECT_GT(glass_albedo_by_quadrature(kIor, 0.0025f, 0.7f, 64), 0.999);
}

// The table against quadrature at 96 x 96 visible normals, between its
// nodes in every axis (IORs 1.33, 1.5, 2.05; both sides).
TEST(Glass, AlbedoTableMatchesQuadratureBetweenItsNodes) {
  using namespace dofarm::render::ggx;
  const GlassAlbedoTable& table = glass_albedo_table();
  double worst = 0;
  for (float ior : {1.33f, 1.5f, 2.05f})
    for (bool entering : {true, false})
      for (float roughness : {0.2f, 0.37f, 0.6f, 0.83f, 1.0f})
        for (float mu : {0.05f, 0.23f, 0.5f, 0.77f, 1.0f}) {
          const float alpha = roughness * roughness;
          const double q = glass_albedo_by_quadrature(entering ? ior : 1.0f / ior, alpha, mu, 96);
          const double e = glass_albedo(table, ior, entering, alpha, mu);
          worst = std::max(worst, std::abs(e - q));
          EXPECT_NEAR(e, q, 0.025) << ior << " " << entering << " " << roughness << " " << mu;
        }
  std::printf("  glass albedo table: worst |table - quadrature| %.4f\n", worst);
}

TEST(Glass, RoughGlassReturnsWhatItReceives) {
  std::mt19937_64 rng(37);
  std::uniform_real_distribution<float> uni(0.0f, 0.999999f);
  for (bool entering : {true, false}) {
    const float eta = entering ? kIor : 1.0f / kIor;
    for (float roughness : {0.05f, 0.3f, 0.6f, 1.0f}) {
      const Bsdf bsdf(kUp, kUp, Vec3(1.0f), 0.0f, roughness, kIor, {}, {1.0f, entering});
      for (double angle : {0.0, 45.0, 80.0}) {
        const Vec3 wo = incident(angle);
        const int n = 200;
        double sum = 0;
        for (int i = 0; i < n; ++i)
          for (int j = 0; j < n; ++j) {
            const BsdfSample s =
                bsdf.sample(wo, uni(rng), Vec2((i + uni(rng)) / n, (j + uni(rng)) / n));
            if (!s.valid) continue;
            ASSERT_TRUE(dofarm::is_finite(s.weight));
            sum += s.weight.x * (s.wi.z < 0 ? eta * eta : 1.0f);
          }
        const double albedo = sum / (double(n) * n);
        std::printf("  rough glass %s, roughness %.2f, theta %2.0f: albedo %.4f\n",
                    entering ? "entering" : "leaving ", roughness, angle, albedo);
        const double tolerance = roughness <= 0.05f ? 0.002 : 0.03;
        EXPECT_NEAR(albedo, 1.0, tolerance) << "roughness " << roughness << " theta " << angle;
      }
    }
  }
}

// IOR 1 is no interface: light passes unbent, tinted by the base colour,
// whatever the roughness.
TEST(Glass, IorOneLetsLightThroughUnbent) {
  const Bsdf bsdf(kUp, kUp, Vec3(0.5f, 0.25f, 1.0f), 0.0f, 0.7f, 1.0f, {}, {1.0f, true});
  EXPECT_FALSE(bsdf.has_non_delta());
  const Vec3 wo = incident(50);
  const BsdfSample s = bsdf.sample(wo, 0.3f, Vec2(0.2f, 0.9f));
  ASSERT_TRUE(s.valid && s.is_delta);
  EXPECT_NEAR(s.wi.x, -wo.x, 1e-6f);
  EXPECT_NEAR(s.wi.z, -wo.z, 1e-6f);
  EXPECT_NEAR(s.weight.x, 0.5f, 1e-6f);
  EXPECT_NEAR(s.weight.y, 0.25f, 1e-6f);
}

// Transmission 0 is the opaque material: the same directions, weights and
// pdfs, bit for bit.
TEST(Glass, TransmissionZeroIsTheOpaqueMaterialBitForBit) {
  std::mt19937_64 rng(41);
  std::uniform_real_distribution<float> uni(0.0f, 0.999999f);
  const Bsdf opaque(kUp, kUp, Vec3(0.8f, 0.4f, 0.2f), 0.3f, 0.4f, kIor);
  const Bsdf zero(kUp, kUp, Vec3(0.8f, 0.4f, 0.2f), 0.3f, 0.4f, kIor, {}, {0.0f, true});
  for (int i = 0; i < 1000; ++i) {
    const Vec3 wo = incident(85.0 * uni(rng), 6.0 * uni(rng));
    const float ul = uni(rng);
    const Vec2 u(uni(rng), uni(rng));
    const BsdfSample a = opaque.sample(wo, ul, u), b = zero.sample(wo, ul, u);
    ASSERT_EQ(a.valid, b.valid);
    if (!a.valid) continue;
    EXPECT_EQ(a.wi.x, b.wi.x);
    EXPECT_EQ(a.weight.x, b.weight.x);
    EXPECT_EQ(a.pdf, b.pdf);
  }
}
