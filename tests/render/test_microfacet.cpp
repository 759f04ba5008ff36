// GGX microfacet distribution: normalisation, known values, finiteness at
// the edges of the domain, energy conservation, and chi-square tests of the
// visible-normal sampler against its pdf; the directional-albedo table
// against an independent quadrature.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

#include "common/math.h"
#include "tests/render/chi2.h"
#include "worker/render/microfacet.h"
#include "worker/render/microfacet_albedo.h"

namespace ggx = dofarm::render::ggx;
using dofarm::kPi;
using dofarm::Vec2;
using dofarm::Vec3;
using dofarm::test::Chi2Options;
using dofarm::test::Chi2Result;
using dofarm::test::SphereCells;

namespace {

// Incident direction at polar angle theta; the azimuth is deliberately not 0
// so that a sampler that only works in the x-z plane is caught.
Vec3 incident(double theta_deg) {
  double t = theta_deg * kPi / 180.0, p = 0.7;
  return Vec3(float(std::sin(t) * std::cos(p)), float(std::sin(t) * std::sin(p)),
              float(std::cos(t)));
}

Vec3 mirror(Vec3 wo) { return Vec3(-wo.x, -wo.y, wo.z); }

// pdf over reflected directions wi = reflect(wo, h), h ~ VNDF: the pdf over h
// times the Jacobian dh/dwi = 1 / (4 |wo.h|) (Walter 2007, eq. 14).
float reflected_pdf(Vec3 wo, Vec3 wi, float alpha) {
  if (!(wi.z > 0.0f)) return 0.0f;
  Vec3 h = dofarm::normalize(wo + wi);
  float cos_oh = dot(wo, h);
  if (!(cos_oh > 0.0f)) return 0.0f;
  return ggx::pdf_vndf(wo, h, alpha) / (4.0f * cos_oh);
}

std::optional<Vec3> sample_reflected(Vec3 wo, float alpha, Vec2 u) {
  Vec3 wi = dofarm::reflect(wo, ggx::sample_vndf(wo, alpha, u));
  if (!(wi.z > 0.0f)) return std::nullopt;  // below the surface: absorbed
  return wi;
}

const float kTestAlphas[] = {0.05f, 0.2f, 0.5f, 1.0f};
// Polar angles of wo in degrees; the last one has cos(theta) = 1e-6.
const double kTestAngles[] = {0, 30, 60, 80, 89, 89.99994270422};
// Two chi-square tests (half-vectors, reflected directions) per (alpha, angle).
constexpr int kChi2Tests = 2 * std::size(kTestAlphas) * std::size(kTestAngles);
// Bonferroni: the whole family passes at significance 0.01.
constexpr double kChi2Threshold = 0.01 / kChi2Tests;

}  // namespace

// ---------------------------------------------------------------------------
// The chi-square helper itself.

TEST(Chi2, PValueMatchesTables) {
  // Critical values from standard chi-square tables.
  EXPECT_NEAR(dofarm::test::chi2_p_value(3.841459, 1), 0.05, 1e-6);
  EXPECT_NEAR(dofarm::test::chi2_p_value(18.307038, 10), 0.05, 1e-6);
  EXPECT_NEAR(dofarm::test::chi2_p_value(124.342113, 100), 0.05, 1e-6);
  EXPECT_NEAR(dofarm::test::chi2_p_value(6.634897, 1), 0.01, 1e-6);
  // dof = 2 is an exponential: Q = exp(-x/2) exactly. Covers both branches.
  for (double x : {0.5, 2.0, 5.0, 40.0})
    EXPECT_NEAR(dofarm::test::chi2_p_value(x, 2), std::exp(-0.5 * x), 1e-12) << x;
  EXPECT_EQ(dofarm::test::chi2_p_value(0.0, 5), 1.0);
}

TEST(Chi2, CellsRoundTripThroughTheirEdges) {
  SphereCells cells{Vec3(0.3f, -0.2f, 0.93f), 0.05, 20, 40};
  EXPECT_DOUBLE_EQ(cells.ring_edge(0), 0.0);
  EXPECT_DOUBLE_EQ(cells.ring_edge(cells.rings), 2.0);
  for (int i = 0; i < cells.rings; ++i) {
    double mid = 0.5 * (cells.ring_edge(i) + cells.ring_edge(i + 1));
    EXPECT_EQ(int(cells.warp(mid) * cells.rings), i);
  }
  // The cells tile the sphere: a constant integrates to 4 pi.
  double area = dofarm::test::integrate_sphere([](Vec3) { return 1.0; }, cells, 1e-10);
  EXPECT_NEAR(area, 4.0 * kPi, 1e-6);
}

// Cosine-weighted hemisphere sampling (Malley's method) is an independent
// sampler with a textbook pdf: the test must accept it with its own pdf and
// reject it with the uniform-hemisphere pdf.
TEST(Chi2, AcceptsTheRightPdfAndRejectsAWrongOne) {
  auto cosine = [](Vec2 u) -> std::optional<Vec3> {
    float r = std::sqrt(u.x), phi = 2.0f * kPi * u.y;
    return Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1.0f - u.x)));
  };
  Chi2Options options;
  options.samples = 100000;
  Chi2Result right = dofarm::test::chi2_test(
      cosine, [](Vec3 w) { return std::max(0.0f, w.z) / kPi; }, options);
  EXPECT_GT(right.p_value, 0.01) << right.summary();
  EXPECT_NEAR(right.pdf_integral, 1.0, 1e-6);
  Chi2Result wrong = dofarm::test::chi2_test(
      cosine, [](Vec3 w) { return w.z > 0 ? 0.5f / kPi : 0.0f; }, options);
  EXPECT_LT(wrong.p_value, 1e-12) << wrong.summary();
}

// ---------------------------------------------------------------------------
// Known values.

TEST(Ggx, RoughnessMapsToAlphaAsInGltf) {
  EXPECT_FLOAT_EQ(ggx::alpha_from_roughness(0.5f), 0.25f);
  EXPECT_FLOAT_EQ(ggx::alpha_from_roughness(1.0f), 1.0f);
  EXPECT_FLOAT_EQ(ggx::alpha_from_roughness(3.0f), 1.0f);
  EXPECT_FLOAT_EQ(ggx::alpha_from_roughness(0.0f), ggx::kMinAlpha);
  EXPECT_FLOAT_EQ(ggx::alpha_from_roughness(-1.0f), ggx::kMinAlpha);
  EXPECT_FLOAT_EQ(ggx::alpha_from_roughness(NAN), ggx::kMinAlpha);
  EXPECT_TRUE(ggx::is_delta(ggx::alpha_from_roughness(0.0f)));
  EXPECT_FALSE(ggx::is_delta(ggx::alpha_from_roughness(0.1f)));
}

TEST(Ggx, DistributionMatchesClosedForm) {
  for (float alpha : {ggx::kMinAlpha, 0.1f, 0.5f, 1.0f})
    EXPECT_FLOAT_EQ(ggx::D(Vec3(0, 0, 1), alpha), 1.0f / (kPi * alpha * alpha)) << alpha;
  // alpha = 1: D is 1/pi on the whole upper hemisphere.
  EXPECT_FLOAT_EQ(ggx::D(incident(70), 1.0f), 1.0f / kPi);
  // alpha = 0.5, theta = 45 deg: alpha^2 / (pi cos^4 (alpha^2 + tan^2)^2).
  EXPECT_NEAR(ggx::D(incident(45), 0.5f), 0.25 / (kPi * 0.25 * 1.25 * 1.25), 1e-5);
  EXPECT_EQ(ggx::D(Vec3(0, 0.6f, -0.8f), 0.5f), 0.0f);
}

TEST(Ggx, LambdaAndMaskingMatchClosedForm) {
  // alpha = 0.5, theta = 60 deg: Lambda = (-1 + sqrt(1 + 0.25 * 3)) / 2.
  double expected = 0.5 * (std::sqrt(1.75) - 1.0);
  EXPECT_NEAR(ggx::lambda(incident(60), 0.5f), expected, 1e-6);
  EXPECT_NEAR(ggx::G1(incident(60), 0.5f), 1.0 / (1.0 + expected), 1e-6);
  // Height-correlated G2 with both directions at 60 deg.
  EXPECT_NEAR(ggx::G2(incident(60), mirror(incident(60)), 0.5f), 1.0 / (1.0 + 2.0 * expected),
              1e-6);
  EXPECT_EQ(ggx::lambda(Vec3(0, 0, 1), 0.5f), 0.0f);
  EXPECT_EQ(ggx::G1(Vec3(0, 0, 1), 0.5f), 1.0f);
}

TEST(Ggx, SchlickFresnel) {
  Vec3 f0(0.04f, 0.5f, 1.0f);
  Vec3 at_normal = ggx::fresnel_schlick(f0, 1.0f);
  EXPECT_FLOAT_EQ(at_normal.x, 0.04f);
  EXPECT_FLOAT_EQ(at_normal.y, 0.5f);
  Vec3 grazing = ggx::fresnel_schlick(f0, 0.0f);
  EXPECT_FLOAT_EQ(grazing.x, 1.0f);
  EXPECT_FLOAT_EQ(ggx::fresnel_schlick(f0, 0.5f).x, 0.04f + 0.96f / 32.0f);
  EXPECT_FLOAT_EQ(ggx::fresnel_schlick(f0, -0.3f).x, 1.0f);
  EXPECT_FLOAT_EQ(ggx::fresnel_schlick(f0, 1.7f).z, 1.0f);
}

// ---------------------------------------------------------------------------
// Normalisation by quadrature.

// Projected-area normalisation, Walter 2007 eq. 4: ∫ D(h) cos(theta_h) dω = 1.
// Rings shrink with alpha, so even kMinAlpha (a lobe 0.06 degrees wide) is
// resolved.
TEST(Ggx, DistributionIsNormalized) {
  for (float alpha : {ggx::kMinAlpha, 0.01f, 0.05f, 0.1f, 0.3f, 0.6f, 1.0f}) {
    SphereCells cells{Vec3(0, 0, 1), alpha, 20, 8};
    double integral = dofarm::test::integrate_sphere(
        [&](Vec3 h) { return double(ggx::D(h, alpha)) * std::max(0.0f, h.z); }, cells, 1e-9);
    EXPECT_NEAR(integral, 1.0, 1e-4) << "alpha = " << alpha;
  }
}

// ∫ pdf_vndf(wo, h) dh = 1 holds only if G1 is the Smith masking that belongs
// to D (∫ D (wo.h)+ dh = wo.z (1 + Lambda(wo))), so this checks Lambda as well.
TEST(Ggx, VisibleNormalPdfIsNormalized) {
  std::vector<Vec3> directions;
  for (double theta : kTestAngles) directions.push_back(incident(theta));
  for (float alpha : {0.01f, 0.05f, 0.2f, 0.5f, 1.0f}) {
    for (Vec3 wo : directions) {
      SphereCells cells{Vec3(0, 0, 1), alpha, 20, 40};
      double integral = dofarm::test::integrate_sphere(
          [&](Vec3 h) { return ggx::pdf_vndf(wo, h, alpha); }, cells, 1e-9);
      EXPECT_NEAR(integral, 1.0, 2e-4) << "alpha = " << alpha << ", wo.z = " << wo.z;
    }
  }
}

// ---------------------------------------------------------------------------
// Chi-square tests of the sampler.

class VndfChi2 : public ::testing::TestWithParam<std::tuple<float, double>> {
 protected:
  float alpha() const { return std::get<0>(GetParam()); }
  Vec3 wo() const { return incident(std::get<1>(GetParam())); }
  void Report(const Chi2Result& r) {
    RecordProperty("p_value", std::to_string(r.p_value));
    EXPECT_EQ(r.malformed, 0) << r.summary();
    EXPECT_GT(r.p_value, kChi2Threshold) << r.summary();
    std::printf("  alpha %.2f, theta %2.0f deg: %s\n", alpha(), std::get<1>(GetParam()),
                r.summary().c_str());
  }
};

TEST_P(VndfChi2, HalfVectorsFollowPdfVndf) {
  const float alpha = this->alpha();
  const Vec3 wo = this->wo();
  Chi2Options options;
  options.cells = SphereCells{Vec3(0, 0, 1), alpha, 20, 40};
  Chi2Result r = dofarm::test::chi2_test(
      [&](Vec2 u) -> std::optional<Vec3> { return ggx::sample_vndf(wo, alpha, u); },
      [&](Vec3 h) { return ggx::pdf_vndf(wo, h, alpha); }, options);
  EXPECT_EQ(r.invalid, 0);
  EXPECT_NEAR(r.pdf_integral, 1.0, 1e-3);
  Report(r);
}

// The density a path tracer divides by: reflected directions, with the rays
// that end up below the horizon counted as missing mass.
TEST_P(VndfChi2, ReflectedDirectionsFollowReflectedPdf) {
  const float alpha = this->alpha();
  const Vec3 wo = this->wo();
  Chi2Options options;
  // Reflection doubles angular distances, so the lobe around the mirror
  // direction is about 2 alpha wide.
  options.cells = SphereCells{mirror(wo), 2.0 * alpha, 20, 40};
  Chi2Result r =
      dofarm::test::chi2_test([&](Vec2 u) { return sample_reflected(wo, alpha, u); },
                              [&](Vec3 wi) { return reflected_pdf(wo, wi, alpha); }, options);
  EXPECT_LE(r.pdf_integral, 1.0 + 1e-4);
  Report(r);
}

INSTANTIATE_TEST_SUITE_P(AlphasAndAngles, VndfChi2,
                         ::testing::Combine(::testing::ValuesIn(kTestAlphas),
                                            ::testing::ValuesIn(kTestAngles)));

// Negative controls: the same machinery must reject a pdf that is a perfectly
// valid distribution but the wrong one (alpha off by 20%), and a reflected
// pdf that forgets the half-vector Jacobian.
TEST(VndfChi2Control, RejectsPdfWithWrongAlpha) {
  const float alpha = 0.2f;
  const Vec3 wo = incident(30);
  Chi2Options options;
  options.cells = SphereCells{Vec3(0, 0, 1), alpha, 20, 40};
  Chi2Result r = dofarm::test::chi2_test(
      [&](Vec2 u) -> std::optional<Vec3> { return ggx::sample_vndf(wo, alpha, u); },
      [&](Vec3 h) { return ggx::pdf_vndf(wo, h, 1.2f * alpha); }, options);
  EXPECT_NEAR(r.pdf_integral, 1.0, 1e-3);  // a valid pdf: only its shape is wrong
  EXPECT_LT(r.p_value, 1e-12) << r.summary();
}

TEST(VndfChi2Control, RejectsReflectedPdfWithWrongAlpha) {
  const float alpha = 0.5f;
  const Vec3 wo = incident(60);
  Chi2Options options;
  options.cells = SphereCells{mirror(wo), 2.0 * alpha, 20, 40};
  Chi2Result r = dofarm::test::chi2_test(
      [&](Vec2 u) { return sample_reflected(wo, alpha, u); },
      [&](Vec3 wi) { return reflected_pdf(wo, wi, 1.2f * alpha); }, options);
  EXPECT_LT(r.p_value, 1e-12) << r.summary();
}

TEST(VndfChi2Control, RejectsReflectedPdfWithoutJacobian) {
  const float alpha = 0.5f;
  const Vec3 wo = incident(30);
  Chi2Options options;
  options.cells = SphereCells{mirror(wo), 2.0 * alpha, 20, 40};
  Chi2Result r = dofarm::test::chi2_test([&](Vec2 u) { return sample_reflected(wo, alpha, u); },
                                         [&](Vec3 wi) {
                                           Vec3 h = dofarm::normalize(wo + wi);
                                           return wi.z > 0 ? ggx::pdf_vndf(wo, h, alpha) : 0.0f;
                                         },
                                         options);
  EXPECT_LT(r.p_value, 1e-12) << r.summary();
}

// ---------------------------------------------------------------------------
// Properties and edge cases.

TEST(Ggx, MaskingIsBoundedAndConsistent) {
  for (float alpha : {ggx::kMinAlpha, 0.05f, 0.3f, 1.0f}) {
    for (double to = 0; to < 90; to += 7.5) {
      Vec3 wo = incident(to);
      float g1o = ggx::G1(wo, alpha);
      EXPECT_GE(g1o, 0.0f);
      EXPECT_LE(g1o, 1.0f);
      for (double ti = 0; ti < 90; ti += 7.5) {
        Vec3 wi = Vec3(-0.3f, 0.9f, 0.0f) * float(std::sin(ti * kPi / 180)) +
                  Vec3(0, 0, float(std::cos(ti * kPi / 180)));
        wi = dofarm::normalize(wi);
        float g2 = ggx::G2(wo, wi, alpha);
        EXPECT_GE(g2, 0.0f);
        EXPECT_LE(g2, std::min(g1o, ggx::G1(wi, alpha)) * (1.0f + 1e-6f))
            << "alpha " << alpha << ", theta_o " << to << ", theta_i " << ti;
        EXPECT_FLOAT_EQ(g2, ggx::G2(wi, wo, alpha));  // reciprocity
      }
    }
    // Masking vanishes towards normal incidence and is total at the horizon.
    EXPECT_GT(ggx::G1(incident(0.01), alpha), 1.0f - 1e-6f);
    EXPECT_LT(ggx::G1(dofarm::normalize(Vec3(1, 0, 1e-7f)), alpha), 1e-3f);
  }
  // G1 decreases monotonically with the angle.
  float previous = 1.0f;
  for (double t = 0; t < 90; t += 1) {
    float g = ggx::G1(incident(t), 0.4f);
    EXPECT_LE(g, previous) << t;
    previous = g;
  }
}

namespace {

// Directional albedo of the microfacet BRDF with F = 1:
// ∫ D(h) G2(wo, wi) / (4 wo.z wi.z) wi.z dωi, by quadrature around the mirror
// direction (independent of the sampler). Only for alpha >= ~0.05: h comes
// from a float sum, and D's relative rounding noise (~1e-7 / alpha^2) would
// otherwise keep the adaptive quadrature subdividing.
double albedo_by_quadrature(Vec3 wo, float alpha) {
  SphereCells cells{mirror(wo), 2.0 * alpha, 20, 40};
  return dofarm::test::integrate_sphere(
      [&](Vec3 wi) {
        if (!(wi.z > 0.0f)) return 0.0;
        Vec3 h = dofarm::normalize(wo + wi);
        return double(ggx::D(h, alpha)) * ggx::G2(wo, wi, alpha) / (4.0 * wo.z);
      },
      cells, 1e-8);
}

// The same albedo estimated through the sampler: E[G2 / G1(wo)] over visible
// normals, on a stratified grid of u.
double albedo_by_vndf(Vec3 wo, float alpha) {
  const int n = 256;
  double sum = 0;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      Vec2 u((i + 0.5f) / n, (j + 0.5f) / n);
      Vec3 wi = dofarm::reflect(wo, ggx::sample_vndf(wo, alpha, u));
      if (wi.z > 0.0f) sum += ggx::G2(wo, wi, alpha) / ggx::G1(wo, alpha);
    }
  }
  return sum / (n * n);
}

}  // namespace

// White furnace: with F = 1 a single-scattering microfacet surface reflects
// at most what arrives (the rest is lost to multiple scattering, so less than
// 1 at high roughness), and almost everything when it is smooth.
TEST(Ggx, WhiteFurnaceNeverCreatesEnergy) {
  for (float alpha : kTestAlphas) {
    for (double theta : kTestAngles) {
      Vec3 wo = incident(theta);
      double albedo = albedo_by_quadrature(wo, alpha);
      EXPECT_LE(albedo, 1.0 + 1e-4) << "alpha " << alpha << ", theta " << theta;
      EXPECT_GT(albedo, 0.0);
      EXPECT_NEAR(albedo, albedo_by_vndf(wo, alpha), 2e-3)
          << "alpha " << alpha << ", theta " << theta;
      if (alpha <= 0.05f && theta <= 30) {
        EXPECT_GT(albedo, 0.995) << "alpha " << alpha << ", theta " << theta;
      }
    }
  }
  // Known answer at alpha = 1 and normal incidence: D = 1/pi, theta_i =
  // 2 theta_h and G2 = cos(2 theta_h) / cos^2(theta_h), so the albedo is
  // 2 ∫_0^{pi/4} cos(2t) tan(t) dt = 1 - ln 2.
  EXPECT_NEAR(albedo_by_quadrature(Vec3(0, 0, 1), 1.0f), 1.0 - std::log(2.0), 1e-5);
}

// ---------------------------------------------------------------------------
// The directional-albedo table (microfacet_albedo.h) against an independent
// computation: adaptive quadrature of D G2 / (4 mu_o) over the sphere with
// Schlick's weight w = (1 - wo.h)^5 split off, A = ∫ f (1 - w), B = ∫ f w.

namespace {

struct FresnelTerms {
  double a, b;
};

FresnelTerms fresnel_terms_by_quadrature(Vec3 wo, float alpha) {
  SphereCells cells{mirror(wo), 2.0 * alpha, 20, 40};
  auto term = [&](bool weighted) {
    return dofarm::test::integrate_sphere(
        [&](Vec3 wi) {
          if (!(wi.z > 0.0f)) return 0.0;
          Vec3 h = dofarm::normalize(wo + wi);
          double m = 1.0 - std::clamp(double(dot(wo, h)), 0.0, 1.0);
          double w = m * m * m * m * m;
          double f = double(ggx::D(h, alpha)) * ggx::G2(wo, wi, alpha) / (4.0 * wo.z);
          return f * (weighted ? w : 1.0 - w);
        },
        cells, 1e-8);
  };
  return {term(false), term(true)};
}

float node_alpha(int i) {
  float x = float(i) / float(ggx::AlbedoTable::kRoughness - 1);
  return std::max(ggx::kMinAlpha, x * x * x * x);
}
float node_mu(int j) {
  float x = float(j) / float(ggx::AlbedoTable::kMu - 1);
  return x * x;
}

}  // namespace

TEST(GgxAlbedoTable, NodesMatchQuadrature) {
  const ggx::AlbedoTable& table = ggx::albedo_table();
  // Rows from alpha 0.055 to 1 (quadrature needs alpha >= ~0.05, see
  // albedo_by_quadrature), columns from mu 0.026 to 1.
  for (int i : {15, 20, 25, 31}) {
    for (int j : {5, 12, 20, 31}) {
      const float mu = node_mu(j);
      const Vec3 wo(std::sqrt(1.0f - mu * mu), 0.0f, mu);
      const FresnelTerms q = fresnel_terms_by_quadrature(wo, node_alpha(i));
      const ggx::AlbedoTable::Entry e = table.entry[i][j];
      EXPECT_NEAR(e.a, q.a, 1e-3) << "alpha " << node_alpha(i) << " mu " << mu;
      EXPECT_NEAR(e.b, q.b, 1e-3) << "alpha " << node_alpha(i) << " mu " << mu;
    }
  }
  // Known answer: alpha = 1, normal incidence, E = 1 - ln 2.
  const ggx::AlbedoTable::Entry e = table.entry[ggx::AlbedoTable::kRoughness - 1][31];
  EXPECT_NEAR(e.a + e.b, 1.0 - std::log(2.0), 1e-3);
  // The smooth limit: all of F reflected.
  for (int j = 0; j < ggx::AlbedoTable::kMu; ++j) {
    const float w = std::pow(1.0f - node_mu(j), 5.0f);
    EXPECT_NEAR(table.entry[0][j].a, 1.0f - w, 1e-6f);
    EXPECT_NEAR(table.entry[0][j].b, w, 1e-6f);
  }
}

// Lookups return the nodes at the nodes and stay between neighbours in
// between; every entry is a valid albedo.
TEST(GgxAlbedoTable, LookupInterpolatesBetweenNodes) {
  const ggx::AlbedoTable& table = ggx::albedo_table();
  for (int i = 0; i < ggx::AlbedoTable::kRoughness; ++i) {
    const ggx::AlbedoRow row = ggx::albedo_row(table, i == 0 ? 0.0f : node_alpha(i));
    for (int j = 0; j < ggx::AlbedoTable::kMu; ++j) {
      const ggx::AlbedoTable::Entry e = table.entry[i][j];
      ASSERT_GE(e.a, 0.0f);
      ASSERT_GE(e.b, 0.0f);
      ASSERT_GE(e.a + e.b, 0.3f);  // 1 - ln 2 at alpha 1 is the least
      ASSERT_LE(e.a + e.b, 1.0f + 1e-4f);
      // Nodes 1 to 5 lie below kMinAlpha, which their alpha is clamped to
      // (no material reads them: the smallest rough alpha falls at 5.5).
      if (i >= 1 && i <= 5) continue;
      const ggx::Albedo l = ggx::albedo(row, node_mu(j));
      EXPECT_NEAR(l.a, e.a, 1e-4f) << i << " " << j;
      EXPECT_NEAR(l.b, e.b, 1e-4f) << i << " " << j;
    }
  }
  const ggx::AlbedoRow row = ggx::albedo_row(table, 0.3f);
  for (float mu : {0.0f, 0.01f, 0.2f, 0.77f, 1.0f}) {
    const float e = ggx::albedo(row, mu).e();
    float lo = 2, hi = -1;
    for (int i : {row.index, row.index + 1})
      for (int j = 0; j < ggx::AlbedoTable::kMu; ++j)
        if (std::abs(node_mu(j) - mu) <= 1.0f / 15.0f) {
          lo = std::min(lo, table.entry[i][j].a + table.entry[i][j].b);
          hi = std::max(hi, table.entry[i][j].a + table.entry[i][j].b);
        }
    EXPECT_GE(e, lo - 1e-6f) << mu;
    EXPECT_LE(e, hi + 1e-6f) << mu;
  }
  // Out-of-range inputs are clamped, not read out of bounds.
  EXPECT_TRUE(std::isfinite(ggx::albedo(ggx::albedo_row(table, 7.0f), 2.0f).e()));
  EXPECT_TRUE(std::isfinite(ggx::albedo(ggx::albedo_row(table, -1.0f), -1.0f).e()));
}

// The cosine-weighted averages against a trapezoid rule in mu over the
// nodes (a different rule from the table's own).
TEST(GgxAlbedoTable, AveragesMatchAnIndependentRule) {
  const ggx::AlbedoTable& table = ggx::albedo_table();
  for (int i = 0; i < ggx::AlbedoTable::kRoughness; i += 5) {
    const ggx::AlbedoRow row = ggx::albedo_row(table, i == 0 ? 0.0f : node_alpha(i));
    const int steps = 4000;
    double a = 0, b = 0, ak = 0;
    for (int s = 0; s <= steps; ++s) {
      const double mu = double(s) / steps;
      const double wgt = (s == 0 || s == steps ? 0.5 : 1.0) * 2.0 * mu / steps;
      const ggx::Albedo e = ggx::albedo(row, float(mu));
      a += wgt * e.a;
      b += wgt * e.b;
      ak += wgt * e.a * e.k();
    }
    const ggx::AlbedoTable::Averages avg = ggx::albedo_averages(table, row);
    EXPECT_NEAR(avg.a, a, 1e-4) << "row " << i;
    EXPECT_NEAR(avg.b, b, 1e-4) << "row " << i;
    EXPECT_NEAR(avg.ak, ak, 1e-4) << "row " << i;
  }
  // The smooth limit in closed form: avg(B) = 2 ∫ (1 - mu)^5 mu dmu = 1/21.
  const ggx::AlbedoTable::Averages smooth =
      ggx::albedo_averages(table, ggx::albedo_row(table, 0.0f));
  EXPECT_NEAR(smooth.b, 1.0 / 21.0, 2e-4);
  EXPECT_NEAR(smooth.a + smooth.b, 1.0, 1e-4);
  EXPECT_NEAR(smooth.ak, 0.0, 1e-6);
}

TEST(Ggx, EveryFunctionIsFiniteOnTheEdgesOfItsDomain) {
  std::vector<Vec3> directions = {Vec3(0, 0, 1), Vec3(0, 0, -1), Vec3(0, 0, 0)};
  for (float z : {1.0f, 0.5f, 1e-3f, 1e-6f, 1e-7f, 0.0f, -1e-7f, -0.1f, -0.9f})
    for (float phi : {0.0f, 1.3f, 3.0f, -2.0f})
      directions.push_back(dofarm::normalize(
          Vec3(std::cos(phi) * std::sqrt(1 - z * z), std::sin(phi) * std::sqrt(1 - z * z), z)));
  const float us[] = {0.0f, 1e-7f, 0.25f, 0.5f, 0.999f, 0x1.fffffep-1f};
  for (float alpha : {ggx::kMinAlpha, 0.01f, 0.3f, 1.0f}) {
    for (Vec3 a : directions) {
      ASSERT_TRUE(std::isfinite(ggx::D(a, alpha)));
      ASSERT_GE(ggx::D(a, alpha), 0.0f);
      ASSERT_TRUE(std::isfinite(ggx::lambda(a, alpha)));
      ASSERT_GE(ggx::lambda(a, alpha), 0.0f);
      float g1 = ggx::G1(a, alpha);
      ASSERT_TRUE(g1 >= 0.0f && g1 <= 1.0f);
      for (Vec3 b : directions) {
        float g2 = ggx::G2(a, b, alpha);
        ASSERT_TRUE(g2 >= 0.0f && g2 <= 1.0f);
        float pdf = ggx::pdf_vndf(a, b, alpha);
        ASSERT_TRUE(std::isfinite(pdf) && pdf >= 0.0f);
        if (a.z <= 0.0f) {
          ASSERT_EQ(pdf, 0.0f);
        }
      }
      for (float u1 : us) {
        for (float u2 : us) {
          Vec3 h = ggx::sample_vndf(a, alpha, Vec2(u1, u2));
          ASSERT_TRUE(dofarm::is_finite(h)) << a.x << " " << a.y << " " << a.z;
          ASSERT_NEAR(dofarm::length(h), 1.0f, 1e-5f);
          ASSERT_GE(h.z, 0.0f);
          if (a.z > 0.0f) {
            // A visible normal faces wo (up to rounding at the silhouette).
            ASSERT_GE(dot(a, h), -1e-6f) << a.z << " " << alpha;
            ASSERT_TRUE(std::isfinite(ggx::pdf_vndf(a, h, alpha)));
          }
        }
      }
    }
  }
}
