// The full material (layered base + compensated GGX, worker/render/bsdf.h): sample()
// draws directions distributed as pdf() says (chi-square, missing mass
// included), sample().weight agrees with eval() / pdf(), the layered diffuse
// lobe is reciprocal, a white material reflects exactly what it receives
// (furnace) at every roughness, metallic and angle, outputs are finite for
// every input, and a perfect mirror is a delta lobe in the mirror direction.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <limits>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "common/math.h"
#include "tests/render/bsdf_chi2.h"
#include "tests/render/chi2.h"
#include "worker/render/bsdf.h"
#include "worker/render/microfacet.h"
#include "worker/render/sheen.h"

using dofarm::kInvPi;
using dofarm::kPi;
using dofarm::Vec2;
using dofarm::Vec3;
using dofarm::render::Bsdf;
using dofarm::render::BsdfSample;
using dofarm::test::Chi2Result;
using dofarm::test::SphereCells;

namespace {

const Vec3 kUp(0, 0, 1);
// A coat normal 23 degrees from kUp, in neither the x-z nor the y-z plane
// and tilted away from incident()'s azimuth, so that directions beyond 67
// degrees from kUp lie below it.
const Vec3 kCoatNormal = normalize(Vec3(-0.35f, -0.25f, 1.0f));

struct Material {
  const char* name;
  float metallic;
  float roughness;
  Vec3 base_color;
  dofarm::render::SpecularLayer specular = {};  // KHR_materials_specular
  dofarm::render::ClearcoatLayer coat = {};     // KHR_materials_clearcoat
  dofarm::render::SheenLayer sheen = {};        // KHR_materials_sheen
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
    // Where the multiple-scattering compensation and the layering matter
    // most: a coloured rough half-metal, a bright rough plastic whose coat
    // takes a sizeable share of the lobe choice at grazing angles.
    {"half_metal_r1", 0.5f, 1.0f, Vec3(0.7f, 0.2f, 0.9f)},
    {"plastic_r03", 0.0f, 0.3f, Vec3(0.95f, 0.9f, 0.2f)},
    // A smooth coat over a diffuse base: the mirror is a delta lobe, so only
    // the diffuse part has a pdf and every delta sample is missing mass.
    {"plastic_r0", 0.0f, 0.0f, Vec3(0.6f, 0.6f, 0.6f)},
    // KHR_materials_specular: a tinted, weakened coat (F0 per channel, the
    // base's share per channel), and Blender's Specular 0 (F0 = 0: a lobe
    // that only rises at grazing angles).
    {"plastic_spec_tint", 0.0f, 0.3f, Vec3(0.5f, 0.6f, 0.7f), {0.7f, Vec3(1.5f, 0.8f, 0.2f)}},
    {"plastic_spec0", 0.0f, 0.5f, Vec3(0.8f, 0.8f, 0.8f), {1.0f, Vec3(0.0f)}},
    // KHR_materials_clearcoat: a glossy coat over rough plastic, a rough
    // half coat over a metal, a mirror coat over a diffuse base (delta).
    {"coat_plastic", 0.0f, 0.6f, Vec3(0.8f, 0.2f, 0.1f), {}, {1.0f, 0.2f}},
    {"coat_metal", 1.0f, 0.4f, Vec3(0.9f, 0.6f, 0.3f), {}, {0.5f, 0.5f}},
    {"coat_mirror", 0.0f, 1.0f, Vec3(0.5f, 0.6f, 0.7f), {}, {1.0f, 0.0f}},
    // KHR_materials_sheen: a coloured sheen over rough plastic, a fine one
    // over a coated metal, a rough one under a mirror coat over glossy
    // plastic.
    {"sheen_plastic", 0.0f, 0.5f, Vec3(0.3f, 0.5f, 0.2f), {}, {}, {Vec3(0.9f, 0.6f, 0.4f), 0.3f}},
    {"sheen_coat_metal", 1.0f, 0.4f, Vec3(0.9f, 0.6f, 0.3f), {}, {0.5f, 0.3f}, {Vec3(0.8f), 0.1f}},
    {"sheen_mirror_coat",
     0.0f,
     0.2f,
     Vec3(0.2f, 0.3f, 0.8f),
     {},
     {1.0f, 0.0f},
     {Vec3(1.0f, 1.0f, 0.5f), 1.0f}},
    // clearcoatNormalTexture: a glossy coat and a mirror coat on a normal of
    // their own, 23 degrees from the base's (at 80 and 89 degrees wo lies
    // below it: the coat then takes the base's frame).
    {"coat_own_normal", 0.0f, 0.6f, Vec3(0.8f, 0.2f, 0.1f), {}, {1.0f, 0.2f, kCoatNormal}},
    {"mirror_coat_own_normal", 0.5f, 0.5f, Vec3(0.5f, 0.6f, 0.7f), {}, {1.0f, 0.0f, kCoatNormal}},
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
  return Bsdf(kUp, kUp, m.base_color, m.metallic, m.roughness, kIor, m.specular, {}, m.coat,
              m.sheen);
}

// GGX alpha as the material model defines it (glTF: roughness squared).
double lobe_width(const Material& m) {
  return 2.0 * dofarm::render::ggx::alpha_from_roughness(m.roughness);
}

using dofarm::test::bsdf_chi2;

}  // namespace

// ---------------------------------------------------------------------------
// Chi-square: sample() against pdf().

class BsdfChi2 : public ::testing::TestWithParam<std::tuple<int, double>> {
 protected:
  const Material& material() const { return kMaterials[std::get<0>(GetParam())]; }
  double angle() const { return std::get<1>(GetParam()); }
  void Report(const char* cells, const Chi2Result& r) {
    dofarm::test::expect_chi2_pass(r, kChi2Threshold, material().name, angle(), cells);
  }
};

// Cells that shrink towards the mirror direction resolve the GGX lobe even
// at roughness 0.1 (alpha 0.01).
TEST_P(BsdfChi2, DirectionsFollowPdfNearTheMirrorDirection) {
  const Bsdf bsdf = make_bsdf(material());
  const Vec3 wo = incident(angle());
  Report("mirror",
         bsdf_chi2(bsdf, bsdf, wo, SphereCells{mirror(wo), lobe_width(material()), 20, 40}));
}

// Equal-area cells around the normal (20 rings above the horizon, 20 below)
// resolve the diffuse lobe and the
// hemisphere's edge, where the narrow cells above are all in one ring.
TEST_P(BsdfChi2, DirectionsFollowPdfOverTheHemisphere) {
  const Bsdf bsdf = make_bsdf(material());
  const Vec3 wo = incident(angle());
  Report("normal", bsdf_chi2(bsdf, bsdf, wo, SphereCells{kUp, 0.0, 40, 40}));
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
      bsdf_chi2(make_bsdf(m), make_bsdf(wrong), wo, SphereCells{mirror(wo), lobe_width(m), 20, 40});
  EXPECT_LT(r.p_value, 1e-12) << r.summary();
}

TEST(BsdfChi2Control, RejectsPdfOfAnotherMetallic) {
  const Material m{"half_metal", 0.5f, 0.5f, Vec3(0.9f, 0.6f, 0.3f)};
  const Material wrong{"half_metal", 0.4f, 0.5f, Vec3(0.9f, 0.6f, 0.3f)};
  const Vec3 wo = incident(45);
  Chi2Result r = bsdf_chi2(make_bsdf(m), make_bsdf(wrong), wo, SphereCells{kUp, 0.0, 40, 40});
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

// The (1 - E_s(wo)) (1 - E_s(wi)) weighting of the diffuse base is symmetric,
// so f = eval / cos(wi) is too. Roughness 0 leaves only the base in eval().
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
// Energy: the white furnace. With base colour 1 every material reflects all
// the light it receives, at every roughness, metallic and angle: the
// multiple-scattering compensation gives back what the single-scattering
// lobe loses, and the diffuse base gets exactly what the specular layer lets
// through.

namespace {

const float kFurnaceRoughness[] = {0.0f, 0.05f, 0.3f, 0.6f, 1.0f};
const float kFurnaceMetallic[] = {0.0f, 0.5f, 1.0f};
// Incidence as mu = cos(theta), down to grazing (mu = 0.05, theta 87.1).
const float kFurnaceMu[] = {1.0f, 0.7f, 0.3f, 0.1f, 0.05f};

Vec3 incident_mu(float mu, double phi = 0.7) {
  const float s = std::sqrt(1.0f - mu * mu);
  return Vec3(s * float(std::cos(phi)), s * float(std::sin(phi)), mu);
}

// Directional albedo by quadrature of eval() over the sphere (cells that
// shrink towards the mirror direction resolve narrow lobes), plus the delta
// lobe's weight times its probability. Independent of sample().
// `channels` < 3 integrates only the first ones (the rest stay 0).
Vec3 albedo_by_quadrature(const Bsdf& bsdf, Vec3 wo, float roughness, int channels = 3) {
  const double width = 2.0 * dofarm::render::ggx::alpha_from_roughness(roughness);
  const SphereCells cells{mirror(wo), width, 20, 40};
  Vec3 sum;
  for (int c = 0; c < channels; ++c)
    sum[c] = float(dofarm::test::integrate_sphere(
        [&](Vec3 wi) { return double(bsdf.eval(wo, wi)[c]); }, cells, 1e-6));
  const Bsdf::Outgoing o = bsdf.outgoing(wo);
  const BsdfSample s = bsdf.sample(o, 0.0f, Vec2(0.5f, 0.5f));
  if (s.valid && s.is_delta) sum += s.weight * o.specular_prob;
  return sum;
}

struct MeanWeight {
  double mean = 0, std_error = 0;
};

// Directional albedo as the mean of sample().weight (channel 0), which is
// what the path tracer's continuation sees; u on a stratified grid.
MeanWeight albedo_by_sampling(const Bsdf& bsdf, Vec3 wo, uint64_t seed, int n = 200) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> uni(0.0f, 0.999999f);
  double sum = 0, sum2 = 0;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      const Vec2 u((i + uni(rng)) / n, (j + uni(rng)) / n);
      const BsdfSample s = bsdf.sample(wo, uni(rng), u);
      if (!s.valid) continue;
      EXPECT_TRUE(dofarm::is_finite(s.weight));
      sum += s.weight.x;
      sum2 += double(s.weight.x) * s.weight.x;
    }
  }
  const double count = double(n) * n;
  MeanWeight m;
  m.mean = sum / count;
  m.std_error = std::sqrt(std::max(0.0, sum2 / count - m.mean * m.mean) / (count - 1));
  return m;
}

}  // namespace

TEST(BsdfFurnace, WhiteMaterialReflectsOneAtEveryRoughnessMetallicAndAngle) {
  std::printf("  white furnace: quadrature of eval (+ delta) | mean sample weight\n");
  std::printf("  rough metal |   mu=1.00   0.70   0.30   0.10   0.05\n");
  uint64_t seed = 41;
  for (float roughness : kFurnaceRoughness) {
    for (float metallic : kFurnaceMetallic) {
      const Bsdf bsdf(kUp, kUp, Vec3(1.0f), metallic, roughness, kIor);
      std::string quadrature, sampled;
      for (float mu : kFurnaceMu) {
        const Vec3 wo = incident_mu(mu);
        // White in, white out (every channel is the same; the sampled test
        // below checks that): channel 0 stands for all.
        const Vec3 q = albedo_by_quadrature(bsdf, wo, roughness, 1);
        const MeanWeight s = albedo_by_sampling(bsdf, wo, ++seed);
        const std::string where = "roughness " + std::to_string(roughness) + " metallic " +
                                  std::to_string(metallic) + " mu " + std::to_string(mu);
        // The quadrature has no noise: what is left is the table's error
        // (quadrature of its nodes, interpolation), measured at < 6e-4.
        EXPECT_GE(q.x, 0.998f) << where;
        EXPECT_LE(q.x, 1.002f) << where;
        EXPECT_GE(s.mean, 0.99) << where << " +- " << s.std_error;
        EXPECT_LE(s.mean, 1.01) << where << " +- " << s.std_error;
        char buf[32];
        std::snprintf(buf, sizeof buf, " %.4f", q.x);
        quadrature += buf;
        std::snprintf(buf, sizeof buf, " %.4f", s.mean);
        sampled += buf;
      }
      std::printf("  %4.2f  %4.2f  |%s |%s\n", roughness, metallic, quadrature.c_str(),
                  sampled.c_str());
    }
  }
}

// KHR_materials_clearcoat: a coat of any strength and roughness over any
// white material still returns 1: the coat reflects E_c(mu_o) and the rest
// receives 1 - E_c(mu_o). Mean sample weight (the coat may be a delta lobe).
TEST(BsdfFurnace, WhiteMaterialUnderAClearcoatReflectsOne) {
  const dofarm::render::ClearcoatLayer coats[] = {{1.0f, 0.0f}, {1.0f, 0.2f}, {0.5f, 0.7f}};
  uint64_t seed = 97;
  for (const auto& coat : coats)
    for (float metallic : {0.0f, 1.0f})
      for (float roughness : {0.0f, 0.3f, 1.0f}) {
        const Bsdf bsdf(kUp, kUp, Vec3(1.0f), metallic, roughness, kIor, {}, {}, coat);
        for (float mu : {1.0f, 0.3f, 0.05f}) {
          const MeanWeight s = albedo_by_sampling(bsdf, incident_mu(mu), ++seed, 120);
          EXPECT_NEAR(s.mean, 1.0, 3.0 * s.std_error + 0.01)
              << "coat " << coat.factor << "/" << coat.roughness << " metallic " << metallic
              << " roughness " << roughness << " mu " << mu;
        }
      }
  // A coat on a normal of its own (clearcoatNormalTexture), 23 degrees from
  // the base's: the coat's albedo and what it lets through are both taken
  // in the coat's frame, so the sum stays 1 wherever the coat's lobe stays
  // above the surface (here wo within 20 degrees of the base's normal).
  for (const dofarm::render::ClearcoatLayer coat :
       {dofarm::render::ClearcoatLayer{1.0f, 0.0f, kCoatNormal},
        dofarm::render::ClearcoatLayer{1.0f, 0.2f, kCoatNormal}})
    for (float metallic : {0.0f, 1.0f}) {
      const Bsdf bsdf(kUp, kUp, Vec3(1.0f), metallic, 0.5f, kIor, {}, {}, coat);
      for (float mu : {1.0f, 0.95f}) {
        const MeanWeight s = albedo_by_sampling(bsdf, incident_mu(mu), ++seed, 120);
        EXPECT_NEAR(s.mean, 1.0, 3.0 * s.std_error + 0.01)
            << "tilted coat " << coat.roughness << " metallic " << metallic << " mu " << mu;
      }
    }
  // A coat over black (and no interface of its own: IOR 1) reflects what
  // the coat alone reflects: F0 0.04 at normal incidence.
  const Bsdf black(kUp, kUp, Vec3(0.0f), 0.0f, 1.0f, 1.0f, {}, {}, {1.0f, 0.0f});
  const MeanWeight b = albedo_by_sampling(black, incident_mu(1.0f), 5, 120);
  EXPECT_NEAR(b.mean, 0.04, 3.0 * b.std_error + 1e-5);
  EXPECT_LT(b.std_error, 2e-3);
}

// KHR_materials_sheen: a white sheen of any roughness over any white
// material, with and without a coat over it, still returns 1: the sheen
// reflects E_sheen(mu_o) and the rest receives 1 - E_sheen(mu_o). Over black
// (IOR 1: no interface) the material reflects the sheen's albedo alone, the
// table's value, times its colour's channels.
TEST(BsdfFurnace, WhiteMaterialUnderASheenReflectsOne) {
  uint64_t seed = 131;
  for (float sheen_roughness : {0.0f, 0.3f, 1.0f})
    for (float metallic : {0.0f, 1.0f})
      for (float roughness : {0.0f, 0.3f, 1.0f})
        for (float coat : {0.0f, 1.0f}) {
          const Bsdf bsdf(kUp, kUp, Vec3(1.0f), metallic, roughness, kIor, {}, {}, {coat, 0.3f},
                          {Vec3(1.0f), sheen_roughness});
          for (float mu : {1.0f, 0.3f, 0.05f}) {
            const MeanWeight s = albedo_by_sampling(bsdf, incident_mu(mu), ++seed, 120);
            EXPECT_NEAR(s.mean, 1.0, 3.0 * s.std_error + 0.01)
                << "sheen roughness " << sheen_roughness << " metallic " << metallic
                << " roughness " << roughness << " coat " << coat << " mu " << mu;
          }
        }
  for (float sheen_roughness : {0.1f, 0.5f, 1.0f})
    for (float mu : {1.0f, 0.5f, 0.1f, 0.02f}) {
      const Bsdf black(kUp, kUp, Vec3(0.0f), 0.0f, 1.0f, 1.0f, {}, {}, {},
                       {Vec3(1.0f, 0.5f, 0.25f), sheen_roughness});
      const Vec3 wo = incident_mu(mu);
      const MeanWeight s = albedo_by_sampling(black, wo, ++seed, 120);
      const double e =
          dofarm::render::sheen::albedo(dofarm::render::sheen::albedo_table(), sheen_roughness, mu);
      EXPECT_GT(e, 0.0);
      EXPECT_NEAR(s.mean, std::min(e, 1.0), 3.0 * s.std_error + 0.003)
          << "sheen roughness " << sheen_roughness << " mu " << mu;
    }
}

// The sheen's albedo table against a quadrature three times as fine: every
// node within 0.002 (the furnace above needs the table to match what
// evaluation integrates); and the distribution is normalised.
TEST(Sheen, AlbedoTableMatchesAFinerQuadrature) {
  namespace sh = dofarm::render::sheen;
  const sh::AlbedoTable& t = sh::albedo_table();
  const sh::AlbedoTable fine = sh::compute_albedo_table(384);
  double worst = 0, largest = 0;
  for (int i = 0; i < sh::AlbedoTable::kRoughness; ++i)
    for (int j = 0; j < sh::AlbedoTable::kMu; ++j) {
      worst = std::max(worst, double(std::abs(t.e[i][j] - fine.e[i][j])));
      largest = std::max(largest, double(fine.e[i][j]));
    }
  EXPECT_LT(worst, 2e-3);
  // The lobe reflects, and near the horizon at low roughness more than it
  // receives (which Bsdf scales back to 1; the furnace above).
  EXPECT_GT(largest, 1.5);
  // The Charlie distribution is normalised: ∫ D(h) cos(theta_h) dh = 1.
  for (float alpha : {0.01f, 0.1f, 0.5f, 1.0f}) {
    double sum = 0;
    const int n = 20000;
    for (int k = 0; k < n; ++k) {
      const double c = (k + 0.5) / n;  // cos theta_h
      sum += sh::D(float(c), alpha) * c * 2.0 * kPi / n;
    }
    EXPECT_NEAR(sum, 1.0, 2e-3) << "alpha " << alpha;
  }
}

// Any IOR: the coat's F0 runs from 0 (IOR 1: no interface, a pure Lambert
// base) to 0.67 (IOR 10), which weighs the quadratic terms of E_s,avg.
TEST(BsdfFurnace, WhiteMaterialReflectsOneForAnyIor) {
  for (float ior : {1.0f, 1.33f, 2.5f, 10.0f}) {
    for (float metallic : {0.0f, 0.5f}) {
      for (float roughness : {0.0f, 0.6f}) {
        const Bsdf bsdf(kUp, kUp, Vec3(1.0f), metallic, roughness, ior);
        for (float mu : {1.0f, 0.2f, 0.05f}) {
          const float q = albedo_by_quadrature(bsdf, incident_mu(mu), roughness, 1).x;
          EXPECT_NEAR(q, 1.0f, 2e-3f) << "ior " << ior << " metallic " << metallic << " roughness "
                                      << roughness << " mu " << mu;
        }
      }
    }
  }
}

// KHR_materials_specular: with any strength s and colour c of the
// dielectric's coat, a white base still reflects exactly 1, in every channel
// (the coat's albedo and what the base receives are per channel), smooth and
// rough, at every angle; s = 0 leaves the base alone, a Lambert lobe exactly.
TEST(BsdfFurnace, WhiteMaterialReflectsOneForAnySpecularLayer) {
  const dofarm::render::SpecularLayer layers[] = {
      {0.0f, Vec3(1.0f)},
      {0.5f, Vec3(1.0f)},
      {1.0f, Vec3(0.0f)},
      {1.0f, Vec3(1.0f, 0.5f, 0.0f)},
      {0.3f, Vec3(2.0f, 0.7f, 0.1f)},
      {1.0f, Vec3(100.0f)}};  // the last: F0 clamped to 1
  for (const auto& layer : layers) {
    for (float metallic : {0.0f, 0.5f}) {
      for (float roughness : {0.0f, 0.3f, 1.0f}) {
        const Bsdf bsdf(kUp, kUp, Vec3(1.0f), metallic, roughness, kIor, layer);
        for (float mu : {1.0f, 0.1f}) {
          const Vec3 q = albedo_by_quadrature(bsdf, incident_mu(mu), roughness);
          for (int c = 0; c < 3; ++c)
            EXPECT_NEAR(q[c], 1.0f, 2e-3f)
                << "s " << layer.factor << " colour " << layer.color[c] << " metallic " << metallic
                << " roughness " << roughness << " mu " << mu << " channel " << c;
        }
      }
    }
  }
  const Vec3 base(0.2f, 0.5f, 0.9f);
  const Bsdf bare(kUp, kUp, base, 0.0f, 0.4f, kIor, {0.0f, Vec3(1.0f)});
  for (float mu_o : {1.0f, 0.3f})
    for (float mu_i : {0.9f, 0.2f}) {
      const Vec3 f = bare.eval(incident_mu(mu_o, 0.3), incident_mu(mu_i, 2.0));
      for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(f[c], base[c] * kInvPi * mu_i);
    }
}

// The coat's albedo is the albedo of the material over a black base, per
// channel; a coloured F0 tints what the coat reflects and, with it, what the
// base receives: a white base under a coat with F0 red > blue reflects the
// same 1, but a grey base reflects more red than blue (more of the red is
// the coat's, which the base's grey does not dim).
TEST(BsdfFurnace, ColouredCoatTintsTheReflectionPerChannel) {
  const dofarm::render::SpecularLayer red{1.0f, Vec3(4.0f, 1.0f, 0.0f)};
  const float c = 0.5f;
  const Bsdf grey(kUp, kUp, Vec3(c), 0.0f, 0.6f, kIor, red);
  const Bsdf black(kUp, kUp, Vec3(0.0f), 0.0f, 0.6f, kIor, red);
  for (float mu : {1.0f, 0.4f, 0.1f}) {
    const Vec3 a = albedo_by_quadrature(grey, incident_mu(mu), 0.6f);
    const Vec3 s = albedo_by_quadrature(black, incident_mu(mu), 0.6f);
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(a[k], s[k] + c * (1.0f - s[k]), 2e-3f) << mu << " " << k;
    EXPECT_GT(s.x, s.y) << mu;
    EXPECT_GT(s.y, s.z) << mu;
    EXPECT_GT(a.x, a.z + 1e-3f) << mu;
  }
}

// The layering is linear in the base colour: albedo(c) = S + c (1 - S), S
// the specular layer's albedo (the albedo of a black base). A grey rough
// dielectric therefore reflects a little more than its base colour alone
// (Lambert: 0.73), where the former model, which weighted Lambert by
// (1 - F(n.wo)) (1 - F(n.wi)) next to an uncompensated GGX lobe, reflected 0.632.
TEST(BsdfFurnace, GreyRoughDielectricIsItsBaseColourPlusTheCoat) {
  const float c = 0.73f;
  const Bsdf grey(kUp, kUp, Vec3(c), 0.0f, 1.0f, kIor);
  const Bsdf black(kUp, kUp, Vec3(0.0f), 0.0f, 1.0f, kIor);
  // Cosine-weighted average over incidence, 2 ∫ albedo(mu) mu dmu, by the
  // midpoint rule in mu^2 (uniform in projected solid angle).
  const int kSteps = 16;
  double average = 0;
  std::printf("  base 0.73, roughness 1, dielectric (ior 1.5):\n");
  for (int i = 0; i < kSteps; ++i) {
    const float mu = float(std::sqrt((i + 0.5) / kSteps));
    const Vec3 wo = incident_mu(mu);
    const float a = albedo_by_quadrature(grey, wo, 1.0f).x;
    const float s = albedo_by_quadrature(black, wo, 1.0f).x;
    EXPECT_NEAR(a, s + c * (1.0f - s), 2e-3f) << "mu " << mu;
    EXPECT_GT(a, c - 2e-3f) << "mu " << mu;
    std::printf("    mu %.3f: albedo %.4f (coat alone %.4f)\n", mu, a, s);
    average += a / kSteps;
  }
  std::printf("  hemispherical average albedo %.4f (Lambert %.2f)\n", average, c);
  EXPECT_GT(average, 0.725);
  EXPECT_LT(average, 0.76);
}

// The mean of sample().weight for white is 1 (never more, hardly less) over a
// finer grid of roughness and angles than above, down to 89 degrees, with
// every weight finite, non-negative and grey.
TEST(Bsdf, SampledAlbedoOfWhiteIsOneOnAFinerGrid) {
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
        EXPECT_LE(mean, 1.0 + 4.0 * std_error + 2e-3)
            << "metallic " << metallic << " roughness " << roughness << " theta " << angle
            << ": albedo " << mean << " +- " << std_error;
        // Nor lose any: the compensated model keeps everything (to the table error).
        EXPECT_GE(mean, 1.0 - 4.0 * std_error - 2e-3)
            << "metallic " << metallic << " roughness " << roughness << " theta " << angle;
      }
    }
  }
}

// No input makes a weight, eval or pdf NaN or infinite: alpha at its
// minimum, grazing directions on either side, extreme IORs.
TEST(Bsdf, EveryOutputIsFiniteOnTheEdgesOfItsDomain) {
  std::vector<Vec3> directions;
  for (float z : {1.0f, 0.5f, 1e-2f, 1e-4f, 1e-6f, 1e-7f, 0.0f, -1e-6f, -0.5f})
    for (float phi : {0.0f, 1.3f, -2.0f}) {
      const float s = std::sqrt(1.0f - z * z);
      directions.push_back(Vec3(s * std::cos(phi), s * std::sin(phi), z));
    }
  const float us[] = {0.0f, 1e-7f, 0.5f, 0x1.fffffep-1f};
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (float roughness : {0.0f, 0.0316f, 0.032f, 0.05f, 1e-3f, 0.5f, 1.0f, nan}) {
    for (float metallic : {0.0f, 0.5f, 1.0f}) {
      for (float ior : {1.0f, 1.0001f, 1.5f, 1e30f, 0.5f, 0.0f, nan}) {
        for (Vec3 base : {Vec3(0.0f), Vec3(1.0f), Vec3(1.0f, 0.0f, 0.5f)}) {
          // KHR_materials_transmission: none, glass seen from outside and
          // inside, half glass, a factor that is not a number.
          for (dofarm::render::TransmissionLayer glass :
               {dofarm::render::TransmissionLayer{0.0f, true},
                {1.0f, true},
                {1.0f, false},
                {0.5f, false},
                {nan, true}}) {
            // KHR_materials_clearcoat alongside: none, a rough coat on the
            // glass-less materials, a mirror coat on the rest.
            const dofarm::render::ClearcoatLayer coat =
                glass.factor > 0
                    ? dofarm::render::ClearcoatLayer{1.0f, 0.0f}
                    : dofarm::render::ClearcoatLayer{roughness > 0.4f ? 1.0f : 0.0f, 0.5f};
            const Bsdf bsdf(kUp, kUp, base, metallic, roughness, ior, {}, glass, coat);
            for (Vec3 wo : directions) {
              const Bsdf::Outgoing o = bsdf.outgoing(wo);
              for (Vec3 wi : directions) {
                float p = -1;
                const Vec3 f = bsdf.evaluate(o, wi, &p);
                ASSERT_TRUE(dofarm::is_finite(f) && std::isfinite(p))
                    << roughness << " " << metallic << " " << ior << " " << glass.factor << " "
                    << wo.z << " " << wi.z;
                ASSERT_GE(std::min({f.x, f.y, f.z}), 0.0f);
                ASSERT_GE(p, 0.0f);
              }
              for (float ul : us)
                for (float u1 : us)
                  for (float u2 : us) {
                    const BsdfSample s = bsdf.sample(o, ul, Vec2(u1, u2));
                    if (!s.valid) continue;
                    ASSERT_TRUE(dofarm::is_finite(s.weight) && std::isfinite(s.pdf))
                        << roughness << " " << metallic << " " << ior << " " << wo.z;
                    ASSERT_GE(std::min({s.weight.x, s.weight.y, s.weight.z}), 0.0f);
                  }
            }
          }
        }
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
