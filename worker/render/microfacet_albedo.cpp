#include "worker/render/microfacet_albedo.h"

#include <cmath>

#include "worker/render/microfacet.h"

namespace dofarm::render::ggx {

namespace {

float schlick_weight(float cos_theta) {
  float m = 1.0f - clamp01(cos_theta);
  float m2 = m * m;
  return m2 * m2 * m;
}

// A and B at one (mu, alpha) by the estimator of the sampler itself: with
// visible normals drawn for wo (Heitz 2018), f cos / pdf = G2 / G1(wo), so
// A = E[G2 / G1 (1 - w)] and B = E[G2 / G1 w]. A midpoint grid in u makes it
// a deterministic quadrature. u.x near 1 is where the steep microfacets are
// (GGX's long tail), the ones that reflect below the horizon, so the grid is
// refined there: u.x = 1 - (1 - v)^3, dv uniform, weight 3 (1 - v)^2.
// (48 x 48 points agree with 192 x 192 to < 5e-4 on every node.)
AlbedoTable::Entry entry_by_vndf(float mu, float alpha, int n) {
  const Vec3 wo(safe_sqrt(1.0f - mu * mu), 0.0f, mu);
  const float g1 = G1(wo, alpha);
  double a = 0, b = 0, total = 0;
  for (int i = 0; i < n; ++i) {
    const double v = (i + 0.5) / n;
    total += 3.0 * (1.0 - v) * (1.0 - v) * n;
  }
  if (g1 > 0.0f) {
    for (int i = 0; i < n; ++i) {
      const double v = (i + 0.5) / n;
      const double jacobian = 3.0 * (1.0 - v) * (1.0 - v);
      const float ux = float(1.0 - (1.0 - v) * (1.0 - v) * (1.0 - v));
      for (int j = 0; j < n; ++j) {
        const Vec2 u(ux, (float(j) + 0.5f) / float(n));
        const Vec3 h = sample_vndf(wo, alpha, u);
        const Vec3 wi = reflect(wo, h);
        if (!(wi.z > 0.0f)) continue;
        const double weight = jacobian * G2(wo, wi, alpha) / g1;
        const double w = schlick_weight(dot(wo, h));
        a += weight * (1.0 - w);
        b += weight * w;
      }
    }
  }
  // Normalised by the weights' own sum, so that a constant integrates exactly.
  return {float(a / total), float(b / total)};
}

}  // namespace

AlbedoTable compute_albedo_table(int n) {
  AlbedoTable t{};
  constexpr int kMu = AlbedoTable::kMu, kR = AlbedoTable::kRoughness;
  for (int j = 0; j < kMu; ++j) {
    // Smooth limit: a mirror reflects F(mu), all of it (E = 1).
    const float x = float(j) / float(kMu - 1);
    const float w = schlick_weight(x * x);
    t.entry[0][j] = {1.0f - w, w};
  }
  for (int i = 1; i < kR; ++i) {
    const float alpha = node_alpha(i, kR);
    for (int j = 0; j < kMu; ++j) {
      // mu = 0 itself has no visible normals; the albedo's limit there is
      // finite (G2 / mu_o stays finite) and a node just above 0 gives it.
      t.entry[i][j] = entry_by_vndf(node_mu(j, kMu, 1e-6f), alpha, n);
    }
  }
  // Averages over the rows as albedo() returns them (linear in x = sqrt(mu)),
  // 2 ∫ X mu dmu = 4 ∫ X x^3 dx, by the midpoint rule on 16 steps per interval.
  constexpr int kSteps = 16;
  for (int i = 0; i < kR; ++i) {
    AlbedoRow row{t.entry[i], t.entry[i], 0.0f, i};
    double sa = 0, sb = 0, sak = 0, sbk = 0;
    const int steps = (kMu - 1) * kSteps;
    for (int s = 0; s < steps; ++s) {
      const double x = (s + 0.5) / steps;
      const Albedo e = albedo(row, float(x * x));
      const double k = e.k();
      const double wgt = 4.0 * x * x * x / steps;
      sa += wgt * e.a;
      sb += wgt * e.b;
      sak += wgt * e.a * k;
      sbk += wgt * e.b * k;
    }
    t.average[i] = {float(sa), float(sb), float(sak), float(sbk)};
  }
  return t;
}

const AlbedoTable& albedo_table() {
  static const AlbedoTable table = compute_albedo_table(48);
  return table;
}

}  // namespace dofarm::render::ggx
