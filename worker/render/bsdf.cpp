#include "worker/render/bsdf.h"

#include <cmath>

#include "worker/render/microfacet.h"

namespace dofarm::render {

Bsdf::Bsdf(Vec3 ns, Vec3 ng, Vec3 base_color, float metallic, float roughness, float ior)
    : frame_(ns), ng_(ng) {
  metallic = clamp01(metallic);
  roughness = clamp01(roughness);
  float f = (ior - 1.0f) / (ior + 1.0f);
  Vec3 dielectric_f0(std::isfinite(f) ? f * f : 0.04f);
  f0_ = lerp(dielectric_f0, base_color, metallic);
  diffuse_color_ = base_color * (1.0f - metallic);
  diffuse_weight_ = max_component(diffuse_color_);
  diffuse_luminance_ = luminance(diffuse_color_);
  alpha_ = ggx::alpha_from_roughness(roughness);
  delta_specular_ = roughness * roughness < ggx::kDeltaAlpha;
  // IOR 1 (F0 = 0) is no interface at all: Schlick's curve would still rise
  // to 1 at grazing angles, so the specular lobe is switched off instead.
  has_specular_ = max_component(f0_) > 0;
}

Bsdf::Outgoing Bsdf::outgoing(Vec3 wo_w) const {
  Outgoing o;
  o.wo = frame_.to_local(wo_w);
  o.valid = o.wo.z > 0 && dot(wo_w, ng_) > 0;
  if (!o.valid) return o;
  if (has_specular_) {
    const Vec3 f = ggx::fresnel_schlick(f0_, o.wo.z);
    o.fresnel = f;
    if (diffuse_weight_ <= 0) {
      o.specular_prob = 1.0f;
    } else {
      // The lobes' shares of the reflected energy at this wo, bounded away
      // from 0 and 1 so that neither lobe is ever starved.
      const float fs = luminance(f);
      const float fd = diffuse_luminance_ * (1.0f - fs);
      o.specular_prob = std::clamp(fs / (fs + fd), 0.05f, 0.95f);
    }
    if (!delta_specular_) {
      o.smith_r = ggx::smith_r(o.wo, alpha_);
      o.inv_4_cos_o = 1.0f / (4.0f * o.wo.z);
      // VNDF pdf of h (Heitz 2018: 2 (wo.h) D / (wo.z + r)) times the
      // reflection Jacobian 1 / (4 wo.h): wo.h cancels, D remains.
      o.specular_pdf_scale = o.specular_prob / (2.0f * (o.wo.z + o.smith_r));
    }
  }
  return o;
}

Vec3 Bsdf::evaluate_local(const Outgoing& o, Vec3 wi, float* pdf_out) const {
  const Vec3 wo = o.wo;
  const float ps = o.specular_prob;
  Vec3 f(0);
  float p = (1.0f - ps) * wi.z * kInvPi;
  if (diffuse_weight_ > 0) {
    Vec3 t(1);
    if (has_specular_) t = (Vec3(1) - o.fresnel) * (Vec3(1) - ggx::fresnel_schlick(f0_, wi.z));
    f += diffuse_color_ * t * (kInvPi * wi.z);
  }
  if (has_specular_ && !delta_specular_) {
    // Both directions are above the surface, so wo + wi is never zero.
    const Vec3 sum = wo + wi;
    const Vec3 h = sum * (1.0f / std::sqrt(dot(sum, sum)));
    const float d = ggx::D(h, alpha_);
    const float g = ggx::G2_from_r(wo.z, o.smith_r, wi.z, ggx::smith_r(wi, alpha_));
    const float wo_h = dot(wo, h);
    const Vec3 fr = ggx::fresnel_schlick(f0_, wo_h);
    f += fr * (d * g * o.inv_4_cos_o);  // times cos(wi) / cos(wi) cancels
    if (wo_h > 0) p += d * o.specular_pdf_scale;
  }
  *pdf_out = p;
  return f;
}

Vec3 Bsdf::evaluate(const Outgoing& o, Vec3 wi_w, float* pdf_out) const {
  *pdf_out = 0;
  // Reflection only: both directions above the geometric surface, so light
  // never leaks through a surface because of a bent shading normal.
  if (!o.valid || dot(wi_w, ng_) <= 0) return Vec3(0);
  const Vec3 wi = frame_.to_local(wi_w);
  if (wi.z <= 0) return Vec3(0);
  return evaluate_local(o, wi, pdf_out);
}

Vec3 Bsdf::evaluate(Vec3 wo_w, Vec3 wi_w, float* pdf_out) const {
  return evaluate(outgoing(wo_w), wi_w, pdf_out);
}

Vec3 Bsdf::eval(Vec3 wo, Vec3 wi) const {
  float unused;
  return evaluate(wo, wi, &unused);
}

float Bsdf::pdf(Vec3 wo, Vec3 wi) const {
  float p;
  evaluate(wo, wi, &p);
  return p;
}

BsdfSample Bsdf::sample(Vec3 wo_w, float u_lobe, Vec2 u) const {
  return sample(outgoing(wo_w), u_lobe, u);
}

BsdfSample Bsdf::sample(const Outgoing& o, float u_lobe, Vec2 u) const {
  BsdfSample s;
  if (!o.valid) return s;
  const Vec3 wo = o.wo;
  const float ps = o.specular_prob;
  Vec3 wi;
  if (u_lobe < ps) {
    if (delta_specular_) {
      wi = Vec3(-wo.x, -wo.y, wo.z);
      s.wi = frame_.to_world(wi);
      if (dot(s.wi, ng_) <= 0) return s;
      s.weight = o.fresnel / ps;
      s.is_delta = true;
      s.valid = true;
      return s;
    }
    Vec3 h = ggx::sample_vndf(wo, alpha_, u);
    wi = reflect(wo, h);
  } else {
    // Cosine-weighted hemisphere (Malley's method).
    float r = std::sqrt(u.x), phi = kTwoPi * u.y;
    wi = Vec3(r * std::cos(phi), r * std::sin(phi), safe_sqrt(1.0f - u.x));
  }
  if (wi.z <= 0) return s;
  s.wi = frame_.to_world(wi);
  if (dot(s.wi, ng_) <= 0) return s;
  Vec3 f = evaluate_local(o, wi, &s.pdf);
  if (!(s.pdf > 0)) return s;
  s.weight = f / s.pdf;
  s.valid = is_finite(s.weight);
  return s;
}

}  // namespace dofarm::render
