#include "worker/render/microfacet.h"

#include <cmath>

#include "worker/render/trig.h"

namespace dofarm::render::ggx {

using detail::sin2;

float alpha_from_roughness(float roughness) {
  // clamp01 maps NaN to 0, so a broken texel becomes a mirror, not a NaN.
  float r = clamp01(roughness);
  return std::max(kMinAlpha, r * r);
}

// alpha_from_roughness never goes below kMinAlpha == kDeltaAlpha, so "<=" is
// what makes the mirror reachable from glTF roughness 0.
bool is_delta(float alpha) { return !(alpha > kDeltaAlpha); }

float lambda(Vec3 w, float alpha) {
  // Heitz 2014, GGX Lambda. It depends only on the slope of w, so it is defined through |z|; the
  // lower hemisphere mirrors the upper one. (r - z)/(2z) rationalised to
  // alpha^2 sin^2 / (2 z (r + z)), which has no cancellation for small slopes.
  float z = std::abs(w.z);
  float num = alpha * alpha * sin2(w);
  if (!(num > 0.0f)) return 0.0f;
  // Grazing: Lambda -> infinity. Cap it so callers get a huge finite value;
  // 1 / (1 + cap) is still 0 to float precision.
  constexpr float kMaxLambda = 1e30f;
  float den = 2.0f * z * (smith_r(w, alpha) + z);
  if (!(den > 0.0f)) return kMaxLambda;
  return std::min(num / den, kMaxLambda);
}

float G1(Vec3 w, float alpha) {
  if (!(w.z > 0.0f)) return 0.0f;
  // 1 / (1 + Lambda) = 2 z / (z + r): finite down to z = 0.
  return std::min(1.0f, 2.0f * w.z / (w.z + smith_r(w, alpha)));
}

Vec3 sample_vndf(Vec3 wo, float alpha, Vec2 u) {
  if (!(wo.z > 0.0f)) return Vec3(0, 0, 1);  // no visible normals; pdf_vndf is 0 here
  // Heitz 2018, listing 1. Stretch wo into the configuration where the
  // microsurface is a hemisphere of radius 1.
  Vec3 vh = normalize(Vec3(alpha * wo.x, alpha * wo.y, wo.z));
  // Orthonormal basis around vh; at normal incidence any tangent will do.
  float len2 = vh.x * vh.x + vh.y * vh.y;
  Vec3 t1 = len2 > 0.0f ? Vec3(-vh.y, vh.x, 0.0f) / std::sqrt(len2) : Vec3(1, 0, 0);
  Vec3 t2 = cross(vh, t1);
  // Uniform point on the unit disk, then squash its lower half onto the
  // projection of the visible part of the hemisphere (an ellipse of
  // half-height vh.z): that projection is what a ray along -vh sees.
  float r = std::sqrt(u.x);
  float phi = kTwoPi * u.y;
  float sin_phi, cos_phi;
  precise_sincos(phi, &sin_phi, &cos_phi);
  float p1 = r * cos_phi;
  float p2 = r * sin_phi;
  float s = 0.5f * (1.0f + vh.z);
  p2 = (1.0f - s) * safe_sqrt(1.0f - p1 * p1) + s * p2;
  // Lift the disk point onto the hemisphere, then unstretch the normal
  // (normals transform with the inverse transpose of the stretch).
  Vec3 nh = t1 * p1 + t2 * p2 + vh * safe_sqrt(1.0f - p1 * p1 - p2 * p2);
  return normalize(Vec3(alpha * nh.x, alpha * nh.y, std::max(0.0f, nh.z)));
}

}  // namespace dofarm::render::ggx
