#include "worker/render/sheen.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "worker/render/microfacet_albedo.h"

namespace dofarm::render::sheen {

float D(float cos_h, float alpha) {
  const float inv = 1.0f / alpha;
  const float sin2 = std::max(0.0f, 1.0f - cos_h * cos_h);
  // sin^(1/alpha) = (sin^2)^(1/(2 alpha)).
  return (2.0f + inv) * std::pow(sin2, 0.5f * inv) * (0.5f * kInvPi);
}

namespace {

// Estevez and Kulla 2017's fit of the Charlie lobe's shadowing: L(x) =
// a / (1 + b x^c) + d x + e, the coefficients linear in (1 - alpha)^2
// between the paper's two published sets (their table 1).
float fit_l(float x, float alpha) {
  const float t = (1.0f - alpha) * (1.0f - alpha);
  auto mix = [t](float p, float q) { return p + (q - p) * t; };
  const float a = mix(21.5473f, 25.3245f), b = mix(3.82987f, 3.32435f), c = mix(0.19823f, 0.16801f),
              d = mix(-1.97760f, -1.27393f), e = mix(-4.32054f, -4.85967f);
  return a / (1.0f + b * std::pow(x, c)) + d * x + e;
}

}  // namespace

// Lambda(mu): exp(L(mu)) below mu = 0.5, mirrored above it so that it
// falls smoothly to 0 at normal incidence (the paper's eq. 3).
float lambda(float mu, float alpha) {
  if (mu < 0.5f) return std::exp(fit_l(mu, alpha));
  return std::exp(2.0f * fit_l(0.5f, alpha) - fit_l(1.0f - mu, alpha));
}

float eval_cos(Vec3 wo, Vec3 wi, float alpha, float lambda_o) {
  Vec3 h = wo + wi;
  const float len2 = dot(h, h);
  if (!(len2 > 0) || wo.z <= 0 || wi.z <= 0) return 0.0f;
  const float cos_h = h.z / std::sqrt(len2);
  // The height-correlated masking-shadowing 1 / (1 + Lambda_o + Lambda_i)
  // over the microfacet BRDF's 4 mu_o mu_i; mu_i cancels.
  const float g = 1.0f / (1.0f + lambda_o + lambda(wi.z, alpha));
  return D(cos_h, alpha) * g / (4.0f * wo.z);
}

namespace {

float node_roughness(int i) {
  return kMinRoughness + (1.0f - kMinRoughness) * float(i) / float(AlbedoTable::kRoughness - 1);
}

}  // namespace

AlbedoTable compute_albedo_table(int n) {
  AlbedoTable t{};
  // Midpoint rule in (x, phi), mu_i = x^2 (dmu_i = 2 x dx crowds the points
  // towards the horizon, where the lobe peaks); the integrand is even in
  // phi, so phi covers [0, pi], doubled. What depends on mu_i alone is
  // computed once per row.
  std::vector<float> cos_phi(n), sin_phi(n), mu_i(n), sin_i(n), lambda_i(n);
  for (int b = 0; b < n; ++b) {
    const double phi = kPi * (b + 0.5) / n;
    cos_phi[b] = float(std::cos(phi));
    sin_phi[b] = float(std::sin(phi));
  }
  for (int a = 0; a < n; ++a) {
    const double x = (a + 0.5) / n;
    mu_i[a] = float(x * x);
    sin_i[a] = std::sqrt(std::max(0.0f, 1.0f - mu_i[a] * mu_i[a]));
  }
  for (int i = 0; i < AlbedoTable::kRoughness; ++i) {
    const float r = node_roughness(i);
    const float alpha = r * r;
    for (int a = 0; a < n; ++a) lambda_i[a] = lambda(mu_i[a], alpha);
    for (int j = 0; j < AlbedoTable::kMu; ++j) {
      const float mu_o = ggx::node_mu(j, AlbedoTable::kMu, 1e-4f);
      const float sin_o = std::sqrt(1.0f - mu_o * mu_o);
      const float lambda_o = lambda(mu_o, alpha);
      double sum = 0;
      for (int a = 0; a < n; ++a) {
        double row = 0;
        for (int b = 0; b < n; ++b) {
          // h = wo + wi, wo = (sin_o, 0, mu_o), wi at azimuth phi_b.
          const float hx = sin_o + sin_i[a] * cos_phi[b], hy = sin_i[a] * sin_phi[b];
          const float hz = mu_o + mu_i[a];
          row += D(hz / std::sqrt(hx * hx + hy * hy + hz * hz), alpha);
        }
        sum += row * 2.0 * ((a + 0.5) / n) / (1.0 + lambda_o + lambda_i[a]);
      }
      // f cos = D G / (4 mu_o); dw = dmu dphi; 2 for the other half of phi;
      // steps 1/n and pi/n.
      t.e[i][j] = float(sum / (4.0 * mu_o) * 2.0 * (1.0 / n) * (kPi / n));
    }
  }
  return t;
}

const AlbedoTable& albedo_table() {
  static const AlbedoTable table = compute_albedo_table(128);
  return table;
}

float albedo(const AlbedoTable& table, float roughness, float mu) {
  constexpr int kR = AlbedoTable::kRoughness, kMu = AlbedoTable::kMu;
  float x = (roughness - kMinRoughness) / (1.0f - kMinRoughness) * float(kR - 1);
  if (!(x >= 0.0f)) x = 0.0f;  // NaN too
  x = std::min(x, float(kR - 1));
  const int i = std::min(int(x), kR - 2);
  const float t = x - float(i);
  const float y = ggx::mu_axis(mu, kMu);
  const int j = std::min(int(y), kMu - 2);
  const float s = y - float(j);
  auto mix = [](float p, float q, float w) { return p + (q - p) * w; };
  return mix(mix(table.e[i][j], table.e[i][j + 1], s),
             mix(table.e[i + 1][j], table.e[i + 1][j + 1], s), t);
}

}  // namespace dofarm::render::sheen
