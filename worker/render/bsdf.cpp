#include "worker/render/bsdf.h"

#include <cmath>

#include "worker/render/microfacet.h"
#include "worker/render/trig.h"

namespace dofarm::render {

namespace {

float schlick_weight(float cos_theta) {
  float m = 1.0f - clamp01(cos_theta);
  float m2 = m * m;
  return m2 * m2 * m;
}

// 2 ∫_0^1 (1 - mu)^5 mu dmu: the cosine-weighted average of Schlick's weight.
constexpr float kSchlickWeightAverage = 1.0f / 21.0f;

}  // namespace

Bsdf::Bsdf(Vec3 ns, Vec3 ng, Vec3 base_color, float metallic, float roughness, float ior,
           const SpecularLayer& specular)
    : frame_(ns), ng_(ng) {
  metallic = clamp01(metallic);
  roughness = clamp01(roughness);
  float f = (ior - 1.0f) / (ior + 1.0f);
  const float f0_ior = std::isfinite(f) ? std::min(f * f, 1.0f) : 0.04f;
  // KHR_materials_specular: F0' = min(F0_ior c, 1) per channel, the lobe
  // scaled by s. Without the extension (c = 1) F0' is F0_ior exactly.
  const float s = std::isfinite(specular.factor) ? std::max(specular.factor, 0.0f) : 1.0f;
  const Vec3 c = specular.color;
  if (c.x == 1.0f && c.y == 1.0f && c.z == 1.0f) {  // no colour: the common case, cheaply
    dielectric_f0_ = Vec3(f0_ior);
    grey_f0_ = true;
  } else {
    auto f0_of = [&](float k) {
      return std::isfinite(k) ? std::min(f0_ior * std::max(k, 0.0f), 1.0f) : f0_ior;
    };
    dielectric_f0_ = Vec3(f0_of(c.x), f0_of(c.y), f0_of(c.z));
    grey_f0_ = dielectric_f0_.x == dielectric_f0_.y && dielectric_f0_.y == dielectric_f0_.z;
  }
  metal_f0_ = base_color;
  metal_weight_ = max_component(base_color) > 0 ? metallic : 0.0f;
  // IOR 1 is no interface whatever the extension says; otherwise the layer
  // is there unless s = 0 (a channel of F0' = 0 still rises at grazing
  // angles, F90 = s, as the extension defines).
  specular_factor_ = f0_ior > 0 ? s : 0.0f;
  dielectric_weight_ = specular_factor_ > 0 ? (1.0f - metallic) * specular_factor_ : 0.0f;
  diffuse_color_ = base_color * (1.0f - metallic);
  diffuse_weight_ = max_component(diffuse_color_);
  alpha_ = ggx::alpha_from_roughness(roughness);
  delta_specular_ = roughness * roughness < ggx::kDeltaAlpha;
  has_specular_ = metal_weight_ > 0 || dielectric_weight_ > 0;
  // The base's normalisation; a mirror's albedo s F(mu) has the closed-form
  // average s (f0 + (1 - f0) / 21).
  diffuse_norm_ = Vec3(kInvPi);
  // One channel's normalisation, copied to all when F0 is grey.
  auto per_channel = [&](auto norm_of) {
    diffuse_norm_ = Vec3(norm_of(dielectric_f0_.x));
    if (!grey_f0_) {
      diffuse_norm_.y = norm_of(dielectric_f0_.y);
      diffuse_norm_.z = norm_of(dielectric_f0_.z);
    }
  };
  if (has_specular_ && delta_specular_ && dielectric_weight_ > 0) {
    per_channel([&](float f0) {
      return kInvPi /
             std::max(1.0f - specular_factor_ * (f0 + (1.0f - f0) * kSchlickWeightAverage), 1e-6f);
    });
  }
  if (!has_specular_ || delta_specular_) return;  // no table needed
  const ggx::AlbedoTable& table = ggx::albedo_table();
  row_ = ggx::albedo_row(table, alpha_);

  // The base's normalisation 1 / (pi (1 - E_s_avg)) (Kulla & Conty 2017), with
  // E_s(mu) = s (f0 A + B)(1 + f0 k) the dielectric's compensated specular
  // albedo, k = (1 - E) / E; its cosine-weighted average is therefore
  // s (f0 avg(A) + avg(B) + f0^2 avg(A k) + f0 avg(B k)).
  if (diffuse_weight_ > 0 && dielectric_weight_ > 0) {
    const ggx::AlbedoTable::Averages avg = ggx::albedo_averages(table, row_);
    per_channel([&](float f0) {
      const float e_avg = specular_factor_ * (f0 * avg.a + avg.b + f0 * f0 * avg.ak + f0 * avg.bk);
      return kInvPi / std::max(1.0f - e_avg, 1e-6f);
    });
  }
}

ggx::Albedo Bsdf::specular_albedo(float mu) const {
  if (delta_specular_) {
    // A mirror reflects F(mu) exactly: no table, no interpolation error.
    const float w = schlick_weight(mu);
    return {1.0f - w, w};
  }
  return ggx::albedo(row_, mu);
}

[[gnu::always_inline]] inline Vec3 Bsdf::base_transmission(const ggx::Albedo& e) const {
  if (!(dielectric_weight_ > 0)) return Vec3(1.0f);
  const float k = delta_specular_ ? 0.0f : e.k();
  auto channel = [&](float f0) {
    return std::max(0.0f, 1.0f - specular_factor_ * ((f0 * e.a + e.b) * (1.0f + f0 * k)));
  };
  if (grey_f0_) return Vec3(channel(dielectric_f0_.x));
  return Vec3(channel(dielectric_f0_.x), channel(dielectric_f0_.y), channel(dielectric_f0_.z));
}

Bsdf::Outgoing Bsdf::outgoing(Vec3 wo_w) const {
  Outgoing o;
  o.wo = frame_.to_local(wo_w);
  o.valid = o.wo.z > 0 && dot(wo_w, ng_) > 0;
  if (!o.valid) return o;
  const float mu = o.wo.z;
  Vec3 specular_albedo_o(0);
  ggx::Albedo e;
  if (has_specular_) {
    e = specular_albedo(mu);
    // Turquin 2019: each part's single-scattering lobe times
    // 1 + F0 (1 - E(mu_o)) / E(mu_o); a mirror loses nothing (k = 0).
    // Schlick's F = F0 + (1 - F0) w is affine in w, and so is the sum of the
    // two parts: c0 + c1 w.
    const float k = delta_specular_ ? 0.0f : e.k();
    const Vec3 one(1.0f);
    const Vec3 metal = (one + metal_f0_ * k) * metal_weight_;
    const Vec3 dielectric = (one + dielectric_f0_ * k) * dielectric_weight_;
    o.fresnel_c0 = metal * metal_f0_ + dielectric * dielectric_f0_;
    o.fresnel_c1 = metal * (one - metal_f0_) + dielectric * (one - dielectric_f0_);
    // The lobe's albedo: c0 E + c1 B (microfacet_albedo.h).
    specular_albedo_o = o.fresnel_c0 * e.e() + o.fresnel_c1 * e.b;
  }
  if (diffuse_weight_ > 0) {
    const Vec3 t = base_transmission(e);
    o.diffuse = diffuse_color_ * (t * diffuse_norm_);
    if (!has_specular_) {
      o.specular_prob = 0.0f;
    } else {
      // The lobes' albedos at this wo (the base's is diffuse_color (1 - E_s(mu_o))),
      // bounded away from 0 and 1 so that neither lobe is ever starved.
      const float fs = luminance(specular_albedo_o);
      const float fd = grey_f0_ ? luminance(diffuse_color_) * t.x : luminance(diffuse_color_ * t);
      const float sum = fs + fd;
      o.specular_prob = sum > 0 ? std::clamp(fs / sum, 0.05f, 0.95f) : 0.5f;
    }
  } else {
    o.specular_prob = has_specular_ ? 1.0f : 0.0f;
  }
  if (has_specular_ && !delta_specular_) {
    o.smith_r = ggx::smith_r(o.wo, alpha_);
    o.inv_4_cos_o = 1.0f / (4.0f * o.wo.z);
    // VNDF pdf of h (Heitz 2018: 2 (wo.h) D / (wo.z + r)) times the
    // reflection Jacobian 1 / (4 wo.h): wo.h cancels, D remains.
    o.specular_pdf_scale = o.specular_prob / (2.0f * (o.wo.z + o.smith_r));
  }
  return o;
}

Vec3 Bsdf::evaluate_local(const Outgoing& o, Vec3 wi, float* pdf_out) const {
  const Vec3 wo = o.wo;
  const float ps = o.specular_prob;
  Vec3 f(0);
  float p = (1.0f - ps) * wi.z * kInvPi;
  if (diffuse_weight_ > 0) {
    if (dielectric_weight_ > 0) {
      f += o.diffuse * (base_transmission(specular_albedo(wi.z)) * wi.z);
    } else {
      f += o.diffuse * wi.z;
    }
  }
  if (has_specular_ && !delta_specular_) {
    // Both directions are above the surface, so wo + wi is never zero.
    const Vec3 sum = wo + wi;
    const Vec3 h = sum * (1.0f / std::sqrt(dot(sum, sum)));
    const float d = ggx::D(h, alpha_);
    const float g = ggx::G2_from_r(wo.z, o.smith_r, wi.z, ggx::smith_r(wi, alpha_));
    const float wo_h = dot(wo, h);
    const Vec3 fr = o.fresnel_c0 + o.fresnel_c1 * schlick_weight(wo_h);
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
      // h = n, so wo.h = mu_o.
      s.weight = (o.fresnel_c0 + o.fresnel_c1 * schlick_weight(wo.z)) / ps;
      s.is_delta = true;
      s.valid = is_finite(s.weight);
      return s;
    }
    // The compensated lobe is the single-scattering lobe scaled by a factor
    // of wo alone, so visible normals sample it as well as before.
    Vec3 h = ggx::sample_vndf(wo, alpha_, u);
    wi = reflect(wo, h);
  } else {
    // Cosine-weighted hemisphere (Malley's method).
    float r = std::sqrt(u.x), sin_phi, cos_phi;
    precise_sincos(kTwoPi * u.y, &sin_phi, &cos_phi);
    wi = Vec3(r * cos_phi, r * sin_phi, safe_sqrt(1.0f - u.x));
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
