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

// r = sqrt(z^2 + alpha^2 (x^2 + y^2)). The GGX Smith Lambda
// (-1 + sqrt(1 + alpha^2 tan^2)) / 2 equals (r - z) / (2 z), so Lambda, G1,
// G2 and the VNDF can all be written as ratios of z and r that stay finite
// at z = 0; callers that need several of them for one direction compute r
// once (the BSDF does, per outgoing direction).
float smith_r(Vec3 w, float alpha);
// G2 from both directions' smith_r.
float G2_from_r(float zo, float ro, float zi, float ri);

// ---------------------------------------------------------------------------
// Inline: these run several times per path vertex.

namespace detail {
// sin^2 of the polar angle, from x and y rather than 1 - z^2: near the pole
// 1 - z^2 cancels catastrophically in float, and small alphas live there.
inline float sin2(Vec3 w) { return w.x * w.x + w.y * w.y; }
}  // namespace detail

inline float smith_r(Vec3 w, float alpha) {
  return std::sqrt(w.z * w.z + alpha * alpha * detail::sin2(w));
}

inline float D(Vec3 h, float alpha) {
  if (!(h.z > 0.0f)) return 0.0f;
  // Walter 2007, eq. 33, rewritten with cos^4 (1 + tan^2/alpha^2)^2 =
  // (sin^2/alpha^2 + cos^2)^2, which has no tan and so no pole at the horizon.
  float a2 = alpha * alpha;
  float t = detail::sin2(h) / a2 + h.z * h.z;
  float d = 1.0f / (kPi * a2 * t * t);
  return std::isfinite(d) ? d : 0.0f;
}

inline float G2_from_r(float zo, float ro, float zi, float ri) {
  if (!(zo > 0.0f) || !(zi > 0.0f)) return 0.0f;
  // Heitz 2014, eq. 99: 1 / (1 + Lambda(wo) + Lambda(wi)), multiplied through
  // by 2 zo zi so that neither Lambda is ever formed (both blow up at grazing).
  float den = zi * ro + zo * ri;
  if (!(den > 0.0f)) return 0.0f;
  return std::min(1.0f, 2.0f * zo * zi / den);
}

inline float G2(Vec3 wo, Vec3 wi, float alpha) {
  return G2_from_r(wo.z, smith_r(wo, alpha), wi.z, smith_r(wi, alpha));
}

inline float pdf_vndf(Vec3 wo, Vec3 h, float alpha) {
  if (!(wo.z > 0.0f)) return 0.0f;
  float cos_oh = dot(wo, h);
  if (!(cos_oh > 0.0f)) return 0.0f;
  // Heitz 2018, the VNDF: G1(wo) (wo.h) D(h) / wo.z, with G1 / wo.z = 2 / (z + r)
  // so grazing wo does not divide a tiny G1 by a tiny z.
  float pdf = 2.0f * cos_oh * D(h, alpha) / (wo.z + smith_r(wo, alpha));
  return std::isfinite(pdf) ? pdf : 0.0f;
}

inline Vec3 fresnel_schlick(Vec3 f0, float cos_theta) {
  float m = 1.0f - clamp01(cos_theta);
  float m2 = m * m;
  float w = m2 * m2 * m;  // Schlick 1994
  return f0 + (Vec3(1.0f) - f0) * w;
}

}  // namespace dofarm::render::ggx
