// Isotropic GGX (Trowbridge-Reitz) microfacet distribution in the local
// shading frame (n = +z). Walter et al. 2007 for D and Smith G; Heitz 2014
// ("Understanding the Masking-Shadowing Function") for the height-correlated
// G2; Heitz 2018 ("Sampling the GGX Distribution of Visible Normals") for VNDF
// sampling. All functions return finite values for every input, including
// grazing directions and alpha at its minimum.
#pragma once

#include "common/math.h"

namespace dofarm::render::ggx {

// Below this alpha a surface is treated as a perfect mirror (delta lobe).
inline constexpr float kDeltaAlpha = 1e-3f;
// Rough lobes never use a smaller alpha than this (keeps D finite in float).
inline constexpr float kMinAlpha = 1e-3f;

// glTF: alpha = roughness^2, clamped to [kMinAlpha, 1].
float alpha_from_roughness(float roughness);
bool is_delta(float alpha);

float D(Vec3 h, float alpha);               // normal distribution, h in the upper hemisphere
float lambda(Vec3 w, float alpha);          // Smith Lambda
float G1(Vec3 w, float alpha);              // Smith masking, 1 / (1 + Lambda)
float G2(Vec3 wo, Vec3 wi, float alpha);    // height-correlated masking-shadowing
// Visible normal for direction wo (wo.z > 0), u in [0,1)^2. Heitz 2018.
Vec3 sample_vndf(Vec3 wo, float alpha, Vec2 u);
// pdf of sample_vndf over half-vectors: G1(wo) max(0, wo.h) D(h) / wo.z.
float pdf_vndf(Vec3 wo, Vec3 h, float alpha);
// Schlick's Fresnel, per channel.
Vec3 fresnel_schlick(Vec3 f0, float cos_theta);

}  // namespace dofarm::render::ggx
