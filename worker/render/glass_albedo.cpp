#include "worker/render/glass_albedo.h"

#include <algorithm>
#include <cmath>

#include "common/math.h"
#include "worker/render/bsdf.h"
#include "worker/render/microfacet.h"
#include "worker/render/microfacet_albedo.h"

namespace dofarm::render::ggx {

double glass_albedo_by_quadrature(float eta, float alpha, float mu, int n) {
  const Vec3 wo(std::sqrt(std::max(0.0f, 1.0f - mu * mu)), 0.0f, mu);
  const float ro = smith_r(wo, alpha);
  // The visible-normal weight of a lobe, f cos / pdf, is F G2 / G1(wo) for
  // the reflection and (1 - F) G2 / G1(wo) (times 1 / eta^2, left out
  // here) for the refraction; G2 / G1 = G2 (mu + r_o) / (2 mu).
  const double inv_g1 = (mu + ro) / (2.0 * mu);
  double sum = 0;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const Vec2 u((i + 0.5f) / float(n), (j + 0.5f) / float(n));
      const Vec3 h = sample_vndf(wo, alpha, u);
      const float wo_h = dot(wo, h);
      const float f = fresnel_dielectric(wo_h, eta);
      const Vec3 wr = reflect(wo, h);
      if (wr.z > 0) sum += f * G2_from_r(mu, ro, wr.z, smith_r(wr, alpha)) * inv_g1;
      Vec3 wt;
      if (f < 1.0f && refract_through(wo, h, wo_h, eta, &wt) && wt.z < 0)
        sum += (1.0f - f) * G2_from_r(mu, ro, -wt.z, smith_r(wt, alpha)) * inv_g1;
    }
  return sum / (double(n) * n);
}

GlassAlbedoTable compute_glass_albedo_table(int n) {
  GlassAlbedoTable t{};
  constexpr int kI = GlassAlbedoTable::kIor, kR = GlassAlbedoTable::kRoughness,
                kM = GlassAlbedoTable::kMu;
  for (int side = 0; side < 2; ++side)
    for (int k = 0; k < kI; ++k) {
      const float ior = 1.0f + float(k) / 8.0f;
      const float eta = side == 0 ? ior : 1.0f / ior;
      for (int i = 0; i < kR; ++i) {
        const float alpha = node_alpha(i, kR);
        for (int j = 0; j < kM; ++j) {
          // Smooth glass (row 0) keeps everything; mu = 0 has no visible
          // normals, and a node just above it gives the limit.
          const float mu = node_mu(j, kM, 1e-4f);
          t.e[side][k][i][j] =
              i == 0 ? 1.0f : float(std::min(1.0, glass_albedo_by_quadrature(eta, alpha, mu, n)));
        }
      }
    }
  return t;
}

const GlassAlbedoTable& glass_albedo_table() {
  static const GlassAlbedoTable table = compute_glass_albedo_table(16);
  return table;
}

float glass_albedo(const GlassAlbedoTable& t, float ior, bool entering, float alpha, float mu) {
  auto axis = [](float x, int nodes, int* i, float* s) {
    if (!(x >= 0.0f)) x = 0.0f;
    x = std::min(x, float(nodes - 1));
    *i = std::min(int(x), nodes - 2);
    *s = x - float(*i);
  };
  int k, r, m;
  float sk, sr, sm;
  axis((ior - 1.0f) * 8.0f, GlassAlbedoTable::kIor, &k, &sk);
  axis(alpha_axis(alpha, GlassAlbedoTable::kRoughness), GlassAlbedoTable::kRoughness, &r, &sr);
  axis(mu_axis(mu, GlassAlbedoTable::kMu), GlassAlbedoTable::kMu, &m, &sm);
  const auto& e = t.e[entering ? 0 : 1];
  auto mix = [](float p, float q, float s) { return p + (q - p) * s; };
  auto plane = [&](int kk) {
    return mix(mix(e[kk][r][m], e[kk][r][m + 1], sm), mix(e[kk][r + 1][m], e[kk][r + 1][m + 1], sm),
               sr);
  };
  return mix(plane(k), plane(k + 1), sk);
}

}  // namespace dofarm::render::ggx
