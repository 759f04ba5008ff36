// The sheen lobe of glTF KHR_materials_sheen: the "Charlie" microfibre
// distribution of Estevez and Kulla 2017 ("Production Friendly Microfacet
// Sheen BRDF"),
//   D(h) = (2 + 1/alpha) sin(theta_h)^(1/alpha) / (2 pi),   alpha = r^2,
// with the paper's height-correlated shadowing G = 1 / (1 + Lambda(mu_o) +
// Lambda(mu_i)) (its fitted Lambda), f = C D G / (4 mu_o mu_i). The lobe
// reflects without Fresnel; what it reflects is its directional albedo
// C E(mu_o, r), tabulated here, and the material beneath it receives
// 1 - max(C) E(mu_o) (the extension's albedo scaling, taken at wo as the
// clearcoat's is: bsdf.h), so that a white material under a white sheen
// returns exactly 1.
#pragma once

#include "common/math.h"

namespace dofarm::render::sheen {

// Roughness below this is clamped: sin^(1/alpha) with 1/alpha above about
// 200 is a lobe narrower than the table resolves (a sheen that fine is
// invisible anyway).
inline constexpr float kMinRoughness = 0.07f;

// The Charlie distribution at cos(theta_h) = cos_h, alpha = r^2.
float D(float cos_h, float alpha);
// The paper's fitted Lambda(mu) of the lobe's shadowing.
float lambda(float mu, float alpha);
// f cos(wi) of the lobe with colour 1, local directions above the surface;
// lambda_o = lambda(wo.z, alpha), which depends on wo alone (Bsdf keeps it
// per path vertex).
float eval_cos(Vec3 wo, Vec3 wi, float alpha, float lambda_o);

struct AlbedoTable {
  static constexpr int kMu = 32;         // nodes sqrt(mu)_j = j / (kMu - 1)
  static constexpr int kRoughness = 32;  // nodes r_i from kMinRoughness to 1, even steps
  float e[kRoughness][kMu];
};
// E(mu, r) = ∫ D V mu_i dw_i by deterministic quadrature with n x n points
// per entry (albedo_table() uses n = 128); for tests.
AlbedoTable compute_albedo_table(int n);
// Thread-safe; built on first use (only scenes with sheen pay for it).
const AlbedoTable& albedo_table();
// Bilinear lookup; r and mu clamped to their ranges.
float albedo(const AlbedoTable& table, float roughness, float mu);

}  // namespace dofarm::render::sheen
