#include "worker/render/bsdf.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>

#include "worker/render/glass_albedo.h"
#include "worker/render/microfacet.h"
#include "worker/render/sheen.h"
#include "worker/render/simd.h"
#include "worker/render/trig.h"
#include "worker/render/trig8.h"

namespace dofarm::render {

namespace {

float schlick_weight(float cos_theta) {
  float m = 1.0f - clamp01(cos_theta);
  float m2 = m * m;
  return m2 * m2 * m;
}

// 2 ∫_0^1 (1 - mu)^5 mu dmu: the cosine-weighted average of Schlick's weight.
constexpr float kSchlickWeightAverage = 1.0f / 21.0f;

// What a GGX reflection lobe of roughness alpha needs at (wo, wi), both
// above the surface (so wo + wi is never zero): wo.h of their half vector
// h, D(h) and the height-correlated G2 (smith_r_o: wo's smith_r).
struct ReflectionTerms {
  float wo_h, d, g;
};
[[gnu::always_inline]] inline ReflectionTerms reflection_terms(Vec3 wo, Vec3 wi, float alpha,
                                                               float smith_r_o) {
  const Vec3 sum = wo + wi;
  const Vec3 h = sum * (1.0f / std::sqrt(dot(sum, sum)));
  return {dot(wo, h), ggx::D(h, alpha),
          ggx::G2_from_r(wo.z, smith_r_o, wi.z, ggx::smith_r(wi, alpha))};
}

// A lobe-choice number u >= p, mapped back onto [0, 1) for the lobes after
// the one chosen below p.
float rest_of(float u, float p) { return std::min((u - p) / (1.0f - p), 0.99999994f); }

// A cosine-weighted direction on the local hemisphere (Malley's method).
Vec3 cosine_hemisphere(Vec2 u) {
  float r = std::sqrt(u.x), sin_phi, cos_phi;
  precise_sincos(kTwoPi * u.y, &sin_phi, &cos_phi);
  return Vec3(r * cos_phi, r * sin_phi, safe_sqrt(1.0f - u.x));
}

}  // namespace

bool refract_through(Vec3 wo, Vec3 h, float cos_oh, float eta, Vec3* wi) {
  const float inv_eta = 1.0f / eta;
  const float sin2_t = (1.0f - cos_oh * cos_oh) * inv_eta * inv_eta;
  if (!(sin2_t < 1.0f)) return false;
  const float cos_t = std::sqrt(1.0f - sin2_t);
  *wi = h * (cos_oh * inv_eta - cos_t) - wo * inv_eta;
  return true;
}

float fresnel_dielectric(float cos_i, float eta) {
  cos_i = clamp01(cos_i);
  const float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
  if (!(sin2_t < 1.0f)) return 1.0f;
  const float cos_t = std::sqrt(1.0f - sin2_t);
  // The s- and p-polarised amplitudes (Born & Wolf; pbrt-v3 eq. 8.2).
  const float rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
  const float rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
  const float f = 0.5f * (rs * rs + rp * rp);
  return std::isfinite(f) ? std::min(f, 1.0f) : 1.0f;
}

namespace {
// The clearcoat's F0: IOR 1.5 (glTF KHR_materials_clearcoat), and its
// Schlick Fresnel.
constexpr float kCoatF0 = 0.04f;
float coat_schlick(float cos_theta) {
  return kCoatF0 + (1.0f - kCoatF0) * schlick_weight(cos_theta);
}
}  // namespace

BsdfConstants::BsdfConstants(float metallic, float roughness, float ior,
                             const SpecularLayer& specular, float transmission,
                             const ClearcoatLayer& clearcoat, const SheenLayer& sheen) {
  if (sheen.color.x > 0 || sheen.color.y > 0 || sheen.color.z > 0) [[unlikely]] {
    auto channel = [](float c) { return std::isfinite(c) ? clamp01(c) : 0.0f; };
    sheen_color_ = Vec3(channel(sheen.color.x), channel(sheen.color.y), channel(sheen.color.z));
    sheen_weight_ = max_component(sheen_color_);
    sheen_roughness_ = std::isfinite(sheen.roughness)
                           ? std::clamp(sheen.roughness, sheen::kMinRoughness, 1.0f)
                           : 1.0f;
    sheen_alpha_ = sheen_roughness_ * sheen_roughness_;
  }
  if (clearcoat.factor > 0) [[unlikely]] {  // false for NaN too
    coat_weight_ = std::min(clearcoat.factor, 1.0f);
    const float r = std::isfinite(clearcoat.roughness) ? clamp01(clearcoat.roughness) : 0.0f;
    coat_alpha_ = ggx::alpha_from_roughness(r);
    coat_delta_ = r * r < ggx::kDeltaAlpha;
    if (!coat_delta_) coat_row_ = ggx::albedo_row(ggx::albedo_table(), coat_alpha_);
  }
  metallic = clamp01(metallic);
  metallic_ = metallic;
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
  // IOR 1 is no interface whatever the extension says; otherwise the layer
  // is there unless s = 0 (a channel of F0' = 0 still rises at grazing
  // angles, F90 = s, as the extension defines).
  specular_factor_ = f0_ior > 0 ? s : 0.0f;
  // KHR_materials_transmission: the share t of the dielectric that is glass;
  // the layered (opaque) dielectric keeps 1 - t (exactly 1 without it).
  const float t = std::isfinite(transmission) ? clamp01(transmission) : 0.0f;
  const float opaque = 1.0f - t;
  dielectric_weight_ = specular_factor_ > 0 ? (1.0f - metallic) * opaque * specular_factor_ : 0.0f;
  diffuse_scale_ = (1.0f - metallic) * opaque;
  alpha_ = ggx::alpha_from_roughness(roughness);
  delta_specular_ = roughness * roughness < ggx::kDeltaAlpha;
  if (t > 0 && metallic < 1.0f) {
    glass_weight_ = (1.0f - metallic) * t;
    glass_ior_ = std::isfinite(ior) && ior >= 1.0f ? std::min(ior, 1e4f) : 1.5f;
    // IOR 1 is no interface: light passes unbent whatever the roughness.
    glass_delta_ = delta_specular_ || glass_ior_ == 1.0f;
  }
  // Evaluated in lanes (evaluate_lanes) where no lobe needs more than
  // evaluate_local()'s opaque lobes and a grey F0.
  in_lanes_ = !(glass_weight_ > 0) && !(coat_weight_ > 0) && !(sheen_weight_ > 0) && grey_f0_;
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
  if (delta_specular_ && dielectric_weight_ > 0) {
    per_channel([&](float f0) {
      return kInvPi /
             std::max(1.0f - specular_factor_ * (f0 + (1.0f - f0) * kSchlickWeightAverage), 1e-6f);
    });
  }
  if (delta_specular_) return;  // no table needed
  const ggx::AlbedoTable& table = ggx::albedo_table();
  row_ = ggx::albedo_row(table, alpha_);

  // The base's normalisation 1 / (pi (1 - E_s_avg)) (Kulla & Conty 2017), with
  // E_s(mu) = s (f0 A + B)(1 + f0 k) the dielectric's compensated specular
  // albedo, k = (1 - E) / E; its cosine-weighted average is therefore
  // s (f0 avg(A) + avg(B) + f0^2 avg(A k) + f0 avg(B k)).
  if (dielectric_weight_ > 0) {
    const ggx::AlbedoTable::Averages avg = ggx::albedo_averages(table, row_);
    per_channel([&](float f0) {
      const float e_avg = specular_factor_ * (f0 * avg.a + avg.b + f0 * f0 * avg.ak + f0 * avg.bk);
      return kInvPi / std::max(1.0f - e_avg, 1e-6f);
    });
  }
}

Bsdf::Bsdf(const BsdfConstants& k, Vec3 ns, Vec3 ng, Vec3 base_color, bool entering,
           Vec3 coat_normal)
    : BsdfConstants(k), frame_(ns), ng_(ng) {
  metal_f0_ = base_color;
  metal_weight_ = max_component(base_color) > 0 ? metallic_ : 0.0f;
  has_specular_ = metal_weight_ > 0 || dielectric_weight_ > 0;
  diffuse_color_ = base_color * diffuse_scale_;
  diffuse_weight_ = max_component(diffuse_color_);
  if (glass_weight_ > 0) [[unlikely]] {
    glass_tint_ = base_color;
    eta_ = entering ? glass_ior_ : 1.0f / glass_ior_;
    glass_entering_ = entering;
  }
  if (coat_weight_ > 0 && is_finite(coat_normal) && dot(coat_normal, coat_normal) > 0.5f)
      [[unlikely]] {
    coat_normal_ = true;
    coat_frame_ = Frame(coat_normal);
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
  if (glass_weight_ > 0 || coat_weight_ > 0 || sheen_weight_ > 0) [[unlikely]]
    o.set_layer_defaults();
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
    // A part of weight 0 adds (+0, +0, +0) to the other's terms (whose
    // factors are all >= 0): only the present part is computed, and the
    // +0 keeps the sum's bits (a -0 term becomes +0 as it did).
    if (metal_weight_ > 0 && dielectric_weight_ > 0) [[unlikely]] {
      const Vec3 metal = (one + metal_f0_ * k) * metal_weight_;
      const Vec3 dielectric = (one + dielectric_f0_ * k) * dielectric_weight_;
      o.fresnel_c0 = metal * metal_f0_ + dielectric * dielectric_f0_;
      o.fresnel_c1 = metal * (one - metal_f0_) + dielectric * (one - dielectric_f0_);
    } else if (dielectric_weight_ > 0) {
      const Vec3 dielectric = (one + dielectric_f0_ * k) * dielectric_weight_;
      o.fresnel_c0 = Vec3(0.0f) + dielectric * dielectric_f0_;
      o.fresnel_c1 = Vec3(0.0f) + dielectric * (one - dielectric_f0_);
    } else {
      const Vec3 metal = (one + metal_f0_ * k) * metal_weight_;
      o.fresnel_c0 = metal * metal_f0_ + Vec3(0.0f);
      o.fresnel_c1 = metal * (one - metal_f0_) + Vec3(0.0f);
    }
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
  if (glass_weight_ > 0) [[unlikely]] {
    // The glass lobe's albedo is about 1 (F plus 1 - F tinted): chosen by
    // its weight, bounded away from 0 and 1 while other lobes exist.
    const bool others = diffuse_weight_ > 0 || has_specular_;
    o.glass_prob = others ? std::clamp(glass_weight_, 0.05f, 0.95f) : 1.0f;
    if (!glass_delta_) {
      // Multiple-scattering compensation (glass_albedo.h).
      const float e =
          ggx::glass_albedo(ggx::glass_albedo_table(), glass_ior_, glass_entering_, alpha_, o.wo.z);
      o.glass_scale = 1.0f / std::max(e, 0.1f);
    }
  }
  if (coat_weight_ > 0) [[unlikely]] {
    // The coat's compensated albedo E_c(mu_o) = c (F0 A + B)(1 + F0 k) (a
    // mirror: c F(mu_o)); what it does not reflect reaches the rest. With
    // its own normal (clearcoatNormalTexture) the coat works in that
    // normal's frame, unless wo lies below it (then in the shading frame).
    o.coat_wo = o.wo;
    if (coat_normal_) [[unlikely]] {
      const Vec3 wo_c = coat_frame_.to_local(wo_w);
      if (wo_c.z > 0) {
        o.coat_wo = wo_c;
        o.coat_own_frame = true;
      }
    }
    const float mu_c = o.coat_wo.z;
    float e_c;
    if (coat_delta_) {
      e_c = coat_weight_ * coat_schlick(mu_c);
    } else {
      const ggx::Albedo a = ggx::albedo(coat_row_, mu_c);
      o.coat_fresnel = coat_weight_ * (1.0f + kCoatF0 * a.k());
      e_c = o.coat_fresnel * (kCoatF0 * a.a + a.b);
      o.coat_smith_r = ggx::smith_r(o.coat_wo, coat_alpha_);
    }
    e_c = std::clamp(e_c, 0.0f, 1.0f);
    o.coat_scale = 1.0f - e_c;
    o.coat_prob = std::clamp(e_c, 0.05f, 0.95f);
  }
  if (sheen_weight_ > 0) [[unlikely]] {
    // The sheen's albedo is max(C) E(mu_o) at most; the layers beneath
    // receive the rest (KHR_materials_sheen's albedo scaling). The Charlie
    // lobe reflects more than it receives within a few degrees of the
    // horizon at low roughness (E up to 2.9 at roughness 0.07): there it
    // is scaled down to albedo 1.
    const float e_lobe = sheen::albedo(sheen::albedo_table(), sheen_roughness_, mu);
    o.sheen_norm = e_lobe > 1.0f ? 1.0f / e_lobe : 1.0f;
    const float e = std::clamp(sheen_weight_ * std::min(e_lobe, 1.0f), 0.0f, 1.0f);
    o.sheen_scale = 1.0f - e;
    o.sheen_prob = std::clamp(e, 0.05f, 0.95f);
    o.sheen_lambda_o = sheen::lambda(mu, sheen_alpha_);
  }
  // The rough specular and glass lobes share alpha, and so these.
  if ((has_specular_ && !delta_specular_) || (glass_weight_ > 0 && !glass_delta_)) {
    o.smith_r = ggx::smith_r(o.wo, alpha_);
    o.inv_4_cos_o = 1.0f / (4.0f * o.wo.z);
  }
  if (has_specular_ && !delta_specular_) {
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
    const ReflectionTerms r = reflection_terms(wo, wi, alpha_, o.smith_r);
    const Vec3 fr = o.fresnel_c0 + o.fresnel_c1 * schlick_weight(r.wo_h);
    f += fr * (r.d * r.g * o.inv_4_cos_o);  // times cos(wi) / cos(wi) cancels
    if (r.wo_h > 0) p += r.d * o.specular_pdf_scale;
  }
  // Glass code stays out of line: opaque materials pay one branch.
  if (glass_weight_ > 0) [[unlikely]] {
    p *= 1.0f - o.glass_prob;
    if (!glass_delta_) add_glass_reflection(o, wi, &f, &p);
  }
  *pdf_out = p;
  return f;
}

[[gnu::noinline]] void Bsdf::add_glass_reflection(const Outgoing& o, Vec3 wi, Vec3* f,
                                                  float* pdf) const {
  const ReflectionTerms r = reflection_terms(o.wo, wi, alpha_, o.smith_r);
  if (!(r.wo_h > 0)) return;
  const float fr = fresnel_dielectric(r.wo_h, eta_);
  *f += Vec3(glass_weight_ * o.glass_scale * fr * r.d * r.g * o.inv_4_cos_o);
  // VNDF pdf of h times the reflection Jacobian 1 / (4 wo.h), times the
  // probability F of reflecting.
  *pdf += o.glass_prob * fr * r.d / (2.0f * (o.wo.z + o.smith_r));
}

[[gnu::noinline]] Vec3 Bsdf::evaluate_refraction(const Outgoing& o, Vec3 wi, float* pdf_out) const {
  *pdf_out = 0;
  const Vec3 wo = o.wo;
  // The generalised half vector (Walter et al. 2007, eq. 16), on wo's side.
  Vec3 h = wo + wi * eta_;
  const float len2 = dot(h, h);
  if (!(len2 > 0)) return Vec3(0);
  h = h * (1.0f / std::sqrt(len2));
  if (h.z < 0) h = -h;
  const float wo_h = dot(wo, h), wi_h = dot(wi, h);
  // Both directions on their own sides of the microfacet.
  if (!(wo_h > 0) || !(wi_h < 0)) return Vec3(0);
  const float ft = 1.0f - fresnel_dielectric(wo_h, eta_);
  const float d = ggx::D(h, alpha_);
  const float g = ggx::G2_from_r(wo.z, o.smith_r, -wi.z, ggx::smith_r(wi, alpha_));
  // dh/dwi (eq. 17): |wi.h| / (wi.h + wo.h / eta)^2.
  const float den = wi_h + wo_h / eta_;
  const float jacobian = -wi_h / (den * den);
  // f |cos wi| = (1 - F) D G |wo.h| dh/dwi / (|wo.z| eta^2) (eq. 21, radiance).
  const float value =
      glass_weight_ * o.glass_scale * ft * d * g * wo_h * jacobian / (wo.z * eta_ * eta_);
  const float p = o.glass_prob * ft * 2.0f * wo_h * d / (wo.z + o.smith_r) * jacobian;
  if (!std::isfinite(value) || !std::isfinite(p)) return Vec3(0);
  *pdf_out = p;
  return glass_tint_ * value;
}

Vec3 Bsdf::evaluate(const Outgoing& o, Vec3 wi_w, float* pdf_out) const {
  Vec3 f = evaluate_base(o, wi_w, pdf_out);
  if (sheen_weight_ > 0) [[unlikely]]
    add_sheen(o, wi_w, &f, pdf_out);
  if (coat_weight_ > 0) [[unlikely]]
    add_coat(o, wi_w, &f, pdf_out);
  return f;
}

[[gnu::noinline]] void Bsdf::add_sheen(const Outgoing& o, Vec3 wi_w, Vec3* f, float* pdf) const {
  if (!o.valid) return;
  *f = *f * o.sheen_scale;
  *pdf *= 1.0f - o.sheen_prob;
  if (dot(wi_w, ng_) <= 0) return;
  const Vec3 wi = frame_.to_local(wi_w);
  if (wi.z <= 0) return;
  *f += sheen_color_ * (o.sheen_norm * sheen::eval_cos(o.wo, wi, sheen_alpha_, o.sheen_lambda_o));
  *pdf += o.sheen_prob * wi.z * kInvPi;  // cosine-weighted
}

[[gnu::noinline]] void Bsdf::add_coat(const Outgoing& o, Vec3 wi_w, Vec3* f, float* pdf) const {
  if (!o.valid) return;
  *f = *f * o.coat_scale;
  *pdf *= 1.0f - o.coat_prob;
  if (coat_delta_ || dot(wi_w, ng_) <= 0) return;
  const Vec3 wi = coat_frame(o).to_local(wi_w);
  if (wi.z <= 0) return;
  const Vec3 wo = o.coat_wo;
  const ReflectionTerms r = reflection_terms(wo, wi, coat_alpha_, o.coat_smith_r);
  if (!(r.wo_h > 0)) return;
  *f += Vec3(o.coat_fresnel * coat_schlick(r.wo_h) * r.d * r.g / (4.0f * wo.z));
  *pdf += o.coat_prob * r.d / (2.0f * (wo.z + o.coat_smith_r));
}

Vec3 Bsdf::evaluate_base(const Outgoing& o, Vec3 wi_w, float* pdf_out) const {
  *pdf_out = 0;
  if (!o.valid) return Vec3(0);
  // Reflection with both directions above the geometric surface, refraction
  // with wi below both surfaces, so that light never leaks through a
  // surface because of a bent shading normal.
  const float side = dot(wi_w, ng_);
  if (side <= 0) {
    if (glass_weight_ > 0 && !glass_delta_ && side < 0) [[unlikely]] {
      const Vec3 wi = frame_.to_local(wi_w);
      if (wi.z < 0) return evaluate_refraction(o, wi, pdf_out);
    }
    return Vec3(0);
  }
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

[[gnu::noinline]] BsdfSample Bsdf::sample_glass(const Outgoing& o, float u_lobe, Vec2 u,
                                                bool direction_only) const {
  BsdfSample s;
  const Vec3 wo = o.wo;
  if (glass_delta_) {
    // A smooth interface: reflect with probability F, else refract; F
    // cancels in the weights.
    const float fr = fresnel_dielectric(wo.z, eta_);
    Vec3 wi;
    if (u_lobe < fr) {
      if (!mirror(wo, &s.wi)) return s;
      s.weight = Vec3(glass_weight_ / o.glass_prob);
    } else {
      if (!refract_through(wo, Vec3(0, 0, 1), wo.z, eta_, &wi)) return s;
      s.wi = frame_.to_world(wi);
      if (dot(s.wi, ng_) >= 0) return s;
      s.weight = glass_tint_ * (glass_weight_ / (o.glass_prob * eta_ * eta_));
    }
    s.is_delta = true;
    s.valid = is_finite(s.weight);
    return s;
  }
  const Vec3 h = ggx::sample_vndf(wo, alpha_, u);
  const float wo_h = dot(wo, h);
  const float fr = fresnel_dielectric(wo_h, eta_);
  Vec3 wi;
  if (u_lobe < fr) {
    wi = reflect(wo, h);
    if (wi.z <= 0) return s;
  } else {
    if (!refract_through(wo, h, wo_h, eta_, &wi) || wi.z >= 0) return s;
  }
  s.wi = frame_.to_world(wi);
  if (direction_only) {
    s.valid = true;
    return s;
  }
  // Only reached without a coat or sheen (sample_layered asks for the direction
  // alone): the base is the whole material.
  Vec3 f = evaluate_base(o, s.wi, &s.pdf);
  if (!(s.pdf > 0)) return s;
  s.weight = f / s.pdf;
  s.valid = is_finite(s.weight);
  return s;
}

BsdfSample Bsdf::sample(const Outgoing& o, float u_lobe, Vec2 u) const {
  if (coat_weight_ > 0 || sheen_weight_ > 0) [[unlikely]]
    return sample_layered(o, u_lobe, u);
  return sample_base(o, u_lobe, u);
}

[[gnu::noinline]] BsdfSample Bsdf::sample_layered(const Outgoing& o, float u_lobe, Vec2 u) const {
  BsdfSample s;
  if (!o.valid) return s;
  // Without a coat coat_prob is 0 and coat_scale 1; without a sheen
  // likewise sheen_prob and sheen_scale (and rest_of(u, 0) is u).
  const float pc = o.coat_prob, ps = o.sheen_prob;
  if (u_lobe < pc) {
    const Vec3 wo_c = o.coat_wo;
    if (coat_delta_) {
      if (!mirror(coat_frame(o), wo_c, &s.wi)) return s;
      s.weight = Vec3(coat_weight_ * coat_schlick(wo_c.z) / o.coat_prob);
      s.is_delta = true;
      s.valid = is_finite(s.weight);
      return s;
    }
    const Vec3 wi = reflect(wo_c, ggx::sample_vndf(wo_c, coat_alpha_, u));
    if (wi.z <= 0) return s;
    s.wi = coat_frame(o).to_world(wi);
  } else {
    const float ub = rest_of(u_lobe, pc);
    if (ub < ps) {
      const Vec3 wi = cosine_hemisphere(u);
      if (wi.z <= 0) return s;
      s.wi = frame_.to_world(wi);
    } else {
      s = sample_base(o, rest_of(ub, ps), u, /*direction_only=*/true);
      if (!s.valid) return s;
      if (s.is_delta) {
        s.weight = s.weight * (o.coat_scale * o.sheen_scale / ((1.0f - pc) * (1.0f - ps)));
        s.valid = is_finite(s.weight);
        return s;
      }
      s.valid = false;
    }
  }
  // Weighed against everything the material does in that direction.
  const Vec3 f = evaluate(o, s.wi, &s.pdf);
  if (!(s.pdf > 0)) return s;
  s.weight = f / s.pdf;
  s.valid = is_finite(s.weight);
  return s;
}

BsdfSample Bsdf::sample_base(const Outgoing& o, float u_lobe, Vec2 u, bool direction_only) const {
  BsdfSample s;
  if (!o.valid) return s;
  if (glass_weight_ > 0) [[unlikely]] {
    if (u_lobe < o.glass_prob) return sample_glass(o, u_lobe / o.glass_prob, u, direction_only);
    u_lobe = rest_of(u_lobe, o.glass_prob);
  }
  Vec3 wi;
  if (!reflection_direction(o, u_lobe, u, &s, &wi)) return s;
  if (direction_only) [[unlikely]] {
    s.valid = true;
    return s;
  }
  float pdf;
  const Vec3 f = evaluate_local(o, wi, &pdf);
  finish_sample(&s, f, pdf);
  return s;
}

bool Bsdf::reflection_direction(const Outgoing& o, float u_lobe, Vec2 u, BsdfSample* s,
                                Vec3* wi_out) const {
  const Vec3 wo = o.wo;
  const float ps = o.specular_prob;
  Vec3 wi;
  if (u_lobe < ps) {
    if (delta_specular_) {
      if (!mirror(wo, &s->wi)) return false;
      // h = n, so wo.h = mu_o.
      s->weight = (o.fresnel_c0 + o.fresnel_c1 * schlick_weight(wo.z)) / ps;
      if (glass_weight_ > 0) [[unlikely]]
        s->weight = s->weight / (1.0f - o.glass_prob);
      s->is_delta = true;
      s->valid = is_finite(s->weight);
      return false;
    }
    // The compensated lobe is the single-scattering lobe scaled by a factor
    // of wo alone, so visible normals sample it as well as before.
    Vec3 h = ggx::sample_vndf(wo, alpha_, u);
    wi = reflect(wo, h);
  } else {
    wi = cosine_hemisphere(u);
  }
  if (wi.z <= 0) return false;
  s->wi = frame_.to_world(wi);
  if (dot(s->wi, ng_) <= 0) return false;
  *wi_out = wi;
  return true;
}

bool Bsdf::sample_direction(const Outgoing& o, float u_lobe, Vec2 u, BsdfSample* s,
                            Vec3* wi) const {
  *s = BsdfSample();
  if (!o.valid) return false;
  return reflection_direction(o, u_lobe, u, s, wi);
}

bool Bsdf::evaluate_direction(const Outgoing& o, Vec3 wi_w, Vec3* wi) const {
  // evaluate_base()'s way to evaluate_local() (no glass, coat or sheen).
  if (!o.valid || dot(wi_w, ng_) <= 0) return false;
  *wi = frame_.to_local(wi_w);
  return !(wi->z <= 0);
}

void Bsdf::evaluate_lanes(int n, const Bsdf* const* bsdf, const Outgoing* const* out,
                          const Vec3* wi, Vec3* f, float* pdf) {
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (use_simd()) {
    int k = 0;
    for (; k < n; k += 8)
      if (!evaluate_lanes_avx2(std::min(8, n - k), bsdf + k, out + k, wi + k, f + k, pdf + k))
        break;
    if (k >= n) return;
    for (; k < n; ++k) f[k] = bsdf[k]->evaluate_local(*out[k], wi[k], &pdf[k]);
    return;
  }
#endif
  for (int k = 0; k < n; ++k) f[k] = bsdf[k]->evaluate_local(*out[k], wi[k], &pdf[k]);
}

void Bsdf::outgoing_lanes(int n, const Bsdf* const* bsdf, const Vec3* wo, Outgoing* const* out) {
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (use_simd()) {
    int k = 0;
    for (; k < n; k += 8)
      if (!outgoing_lanes_avx2(std::min(8, n - k), bsdf + k, wo + k, out + k)) break;
    for (; k < n; ++k) *out[k] = bsdf[k]->outgoing(wo[k]);
    return;
  }
#endif
  for (int k = 0; k < n; ++k) *out[k] = bsdf[k]->outgoing(wo[k]);
}

#ifdef DOFARM_HAVE_AVX2_KERNELS
namespace {

// Eight floats or ints, each at its lane's byte offset from `base`.
DOFARM_AVX2 inline __m256 gather8(const void* base, __m256i offsets) {
  return _mm256_i32gather_ps(static_cast<const float*>(base), offsets, 1);
}
DOFARM_AVX2 inline __m256i gather8i(const void* base, __m256i offsets) {
  return _mm256_i32gather_epi32(static_cast<const int*>(base), offsets, 1);
}
// mask ? a : b, lane by lane.
DOFARM_AVX2 inline __m256 select8(__m256 mask, __m256 a, __m256 b) {
  return _mm256_blendv_ps(b, a, mask);
}
DOFARM_AVX2 inline __m256 sub8(__m256 x, __m256 y) { return _mm256_sub_ps(x, y); }
DOFARM_AVX2 inline __m256 div8(__m256 x, __m256 y) { return _mm256_div_ps(x, y); }
DOFARM_AVX2 inline __m256 gt8(__m256 x, __m256 y) { return _mm256_cmp_ps(x, y, _CMP_GT_OQ); }
// std::max(0.0f, v) and std::min(1.0f, v) as the standard library defines
// them (v where the comparison holds, else the constant; NaN gives the
// constant), which max_ps(v, c) and min_ps(v, c) are.
DOFARM_AVX2 inline __m256 max0_8(__m256 v) { return _mm256_max_ps(v, _mm256_setzero_ps()); }
DOFARM_AVX2 inline __m256 min1_8(__m256 v) { return _mm256_min_ps(v, k8(1.0f)); }
// schlick_weight() in lanes.
DOFARM_AVX2 inline __m256 schlick_weight8(__m256 c) {
  const __m256 m = sub8(k8(1.0f), min1_8(max0_8(c)));
  const __m256 m2 = mul8(m, m);
  return mul8(mul8(m2, m2), m);
}
// The byte offsets of p[k] from p[0] for the active lanes (0 for the
// others, whose p[k] are not read), as 32-bit lanes; false where one does
// not fit in 32 bits.
DOFARM_AVX2 inline bool offsets8(const void* const* p, __m256i active, __m256i* out) {
  const __m256i m_lo = _mm256_cvtepi32_epi64(_mm256_castsi256_si128(active));
  const __m256i m_hi = _mm256_cvtepi32_epi64(_mm256_extracti128_si256(active, 1));
  const auto* q = reinterpret_cast<const long long*>(p);
  const __m256i base =
      _mm256_set1_epi64x(static_cast<long long>(reinterpret_cast<uintptr_t>(p[0])));
  const __m256i d_lo =
      _mm256_and_si256(_mm256_sub_epi64(_mm256_maskload_epi64(q, m_lo), base), m_lo);
  const __m256i d_hi =
      _mm256_and_si256(_mm256_sub_epi64(_mm256_maskload_epi64(q + 4, m_hi), base), m_hi);
  // In range where d + 2^31, as unsigned, has no upper half.
  const __m256i bias = _mm256_set1_epi64x(0x80000000LL);
  const __m256i upper = _mm256_or_si256(_mm256_srli_epi64(_mm256_add_epi64(d_lo, bias), 32),
                                        _mm256_srli_epi64(_mm256_add_epi64(d_hi, bias), 32));
  if (!_mm256_testz_si256(upper, upper)) return false;
  const __m256i low_halves = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
  *out = _mm256_set_m128i(_mm256_castsi256_si128(_mm256_permutevar8x32_epi32(d_hi, low_halves)),
                          _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(d_lo, low_halves)));
  return true;
}
// A bool member of each lane's record, as a lane mask (its byte nonzero).
DOFARM_AVX2 inline __m256 flag8(const bool* p, __m256i offsets) {
  const __m256i v = _mm256_and_si256(gather8i(p, offsets), _mm256_set1_epi32(0xff));
  return _mm256_castsi256_ps(
      _mm256_xor_si256(_mm256_cmpeq_epi32(v, _mm256_setzero_si256()), _mm256_set1_epi32(-1)));
}
// ggx::albedo()'s mix, p + (q - p) t.
DOFARM_AVX2 inline __m256 mix8(__m256 p, __m256 q, __m256 t) {
  return add8(p, mul8(sub8(q, p), t));
}
// The table's float at index at + plus, per lane.
DOFARM_AVX2 inline __m256 entry8(const float* table, __m256i at, int plus) {
  return _mm256_i32gather_ps(table, _mm256_add_epi32(at, _mm256_set1_epi32(plus)), 4);
}
// specular_albedo(mu) in lanes: a mirror's Schlick terms {1 - w, w} where
// `delta`, else ggx::albedo() of the lane's row (index `row`, weight
// `row_t`) at mu.
DOFARM_AVX2 inline void specular_albedo8(__m256 delta, __m256i row, __m256 row_t, __m256 mu,
                                         __m256* a, __m256* b) {
  const __m256 w_mu = schlick_weight8(mu);
  const __m256 x = mul8(_mm256_sqrt_ps(min1_8(max0_8(mu))), k8(float(ggx::AlbedoTable::kMu - 1)));
  const __m256i j =
      _mm256_min_epi32(_mm256_cvttps_epi32(x), _mm256_set1_epi32(ggx::AlbedoTable::kMu - 2));
  const __m256 s = sub8(x, _mm256_cvtepi32_ps(j));
  const float* table = &ggx::albedo_table().entry[0][0].a;
  // Float index of entry [row][j].a; .b follows, then [row][j + 1].
  const __m256i lo = _mm256_slli_epi32(
      _mm256_add_epi32(_mm256_mullo_epi32(row, _mm256_set1_epi32(ggx::AlbedoTable::kMu)), j), 1);
  const __m256i hi = _mm256_add_epi32(lo, _mm256_set1_epi32(2 * ggx::AlbedoTable::kMu));
  const __m256 a_lo = mix8(entry8(table, lo, 0), entry8(table, lo, 2), s);
  const __m256 b_lo = mix8(entry8(table, lo, 1), entry8(table, lo, 3), s);
  const __m256 a_hi = mix8(entry8(table, hi, 0), entry8(table, hi, 2), s);
  const __m256 b_hi = mix8(entry8(table, hi, 1), entry8(table, hi, 3), s);
  *a = select8(delta, sub8(k8(1.0f), w_mu), mix8(a_lo, a_hi, row_t));
  *b = select8(delta, w_mu, mix8(b_lo, b_hi, row_t));
}
// Albedo::k() in lanes, (1 - E) / E with E at least 1e-3; 0 where `delta`.
DOFARM_AVX2 inline __m256 albedo_k8(__m256 delta, __m256 a, __m256 b) {
  const __m256 e = _mm256_max_ps(k8(1e-3f), add8(a, b));
  return select8(delta, _mm256_setzero_ps(), div8(sub8(k8(1.0f), e), e));
}
// base_transmission() for a grey F0 under a dielectric layer:
// max(0, 1 - s (f0 A + B)(1 + f0 k)).
DOFARM_AVX2 inline __m256 through8(__m256 s, __m256 f0, __m256 a, __m256 b, __m256 k) {
  return max0_8(sub8(k8(1.0f), mul8(s, mul8(add8(mul8(f0, a), b), add8(k8(1.0f), mul8(f0, k))))));
}
// ggx::smith_r() in lanes.
DOFARM_AVX2 inline __m256 smith_r8(const __m256* w, __m256 a2) {
  return _mm256_sqrt_ps(add8(mul8(w[2], w[2]), mul8(a2, add8(mul8(w[0], w[0]), mul8(w[1], w[1])))));
}
// luminance() in lanes.
DOFARM_AVX2 inline __m256 luminance8(const __m256* c) {
  return add8(add8(mul8(k8(0.2126f), c[0]), mul8(k8(0.7152f), c[1])), mul8(k8(0.0722f), c[2]));
}
// dot(a, b) in lanes, summed in dot()'s order.
DOFARM_AVX2 inline __m256 dot8(const __m256* a, const __m256* b) {
  return add8(add8(mul8(a[0], b[0]), mul8(a[1], b[1])), mul8(a[2], b[2]));
}

}  // namespace

DOFARM_AVX2 bool Bsdf::evaluate_lanes_avx2(int n, const Bsdf* const* bsdf,
                                           const Outgoing* const* out, const Vec3* wi_in,
                                           Vec3* f_out, float* pdf_out) {
  // Each lane's records as byte offsets from lane 0's (lanes past n repeat
  // lane 0); gathers read a field of every lane at once.
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i active = _mm256_cmpgt_epi32(_mm256_set1_epi32(n), lane);
  __m256i offb, offo;
  if (!offsets8(reinterpret_cast<const void* const*>(bsdf), active, &offb) ||
      !offsets8(reinterpret_cast<const void* const*>(out), active, &offo))
    return false;
  const __m256i offw =
      _mm256_and_si256(_mm256_mullo_epi32(lane, _mm256_set1_epi32(int(sizeof(Vec3)))), active);
  const Bsdf& b = *bsdf[0];
  const Outgoing& o = *out[0];
  const __m256 wi[3] = {gather8(&wi_in[0].x, offw), gather8(&wi_in[0].y, offw),
                        gather8(&wi_in[0].z, offw)};
  const __m256 wo[3] = {gather8(&o.wo.x, offo), gather8(&o.wo.y, offo), gather8(&o.wo.z, offo)};
  const __m256 zero = _mm256_setzero_ps();
  const __m256 delta = flag8(&b.delta_specular_, offb);
  const __m256 rough = _mm256_andnot_ps(delta, flag8(&b.has_specular_, offb));
  const __m256 diffuse = gt8(gather8(&b.diffuse_weight_, offb), zero);
  const __m256 dielectric = gt8(gather8(&b.dielectric_weight_, offb), zero);

  // p = (1 - ps) wi.z / pi.
  __m256 p = mul8(mul8(sub8(k8(1.0f), gather8(&o.specular_prob, offo)), wi[2]), k8(kInvPi));

  // The base: o.diffuse (1 - E_s(mu_i)) wi.z under a dielectric layer, else
  // o.diffuse wi.z. E_s(mu_i) from specular_albedo(wi.z): a mirror's
  // Schlick terms, else the table's bilinear lookup (ggx::albedo).
  const __m256 mu = wi[2];
  __m256 e_a, e_b;
  specular_albedo8(delta, gather8i(&b.row_.index, offb), gather8(&b.row_.t, offb), mu, &e_a, &e_b);
  const __m256 through =
      through8(gather8(&b.specular_factor_, offb), gather8(&b.dielectric_f0_.x, offb), e_a, e_b,
               albedo_k8(delta, e_a, e_b));
  const __m256 t_mu = mul8(through, mu);
  __m256 f[3];
  const float* od = &o.diffuse.x;
  for (int c = 0; c < 3; ++c) {
    const __m256 d = gather8(od + c, offo);
    const __m256 base = select8(dielectric, mul8(d, t_mu), mul8(d, mu));
    f[c] = select8(diffuse, add8(zero, base), zero);
  }

  // The rough specular lobe (reflection_terms(), D, G2, Schlick).
  __m256 sum[3], h[3];
  for (int c = 0; c < 3; ++c) sum[c] = add8(wo[c], wi[c]);
  const __m256 inv_len = div8(k8(1.0f), _mm256_sqrt_ps(dot8(sum, sum)));
  for (int c = 0; c < 3; ++c) h[c] = mul8(sum[c], inv_len);
  const __m256 wo_h = dot8(wo, h);
  const __m256 alpha = gather8(&b.alpha_, offb);
  const __m256 a2 = mul8(alpha, alpha);
  const __m256 tt = add8(div8(add8(mul8(h[0], h[0]), mul8(h[1], h[1])), a2), mul8(h[2], h[2]));
  __m256 dd = div8(k8(1.0f), mul8(mul8(mul8(k8(kPi), a2), tt), tt));
  const __m256 finite = _mm256_cmp_ps(_mm256_andnot_ps(k8(-0.0f), dd),
                                      k8(std::numeric_limits<float>::infinity()), _CMP_LT_OQ);
  dd = select8(_mm256_and_ps(gt8(h[2], zero), finite), dd, zero);
  const __m256 ro = gather8(&o.smith_r, offo);
  const __m256 ri = smith_r8(wi, a2);
  const __m256 den = add8(mul8(wi[2], ro), mul8(wo[2], ri));
  const __m256 g_ok =
      _mm256_and_ps(_mm256_and_ps(gt8(wo[2], zero), gt8(wi[2], zero)), gt8(den, zero));
  const __m256 g = select8(g_ok, min1_8(div8(mul8(mul8(k8(2.0f), wo[2]), wi[2]), den)), zero);
  const __m256 w_oh = schlick_weight8(wo_h);
  const __m256 scale = mul8(mul8(dd, g), gather8(&o.inv_4_cos_o, offo));
  const float* c0 = &o.fresnel_c0.x;
  const float* c1 = &o.fresnel_c1.x;
  for (int c = 0; c < 3; ++c) {
    const __m256 fr = add8(gather8(c0 + c, offo), mul8(gather8(c1 + c, offo), w_oh));
    f[c] = select8(rough, add8(f[c], mul8(fr, scale)), f[c]);
  }
  p = select8(_mm256_and_ps(rough, gt8(wo_h, zero)),
              add8(p, mul8(dd, gather8(&o.specular_pdf_scale, offo))), p);

  alignas(32) float fx[8], fy[8], fz[8], pp[8];
  _mm256_store_ps(fx, f[0]);
  _mm256_store_ps(fy, f[1]);
  _mm256_store_ps(fz, f[2]);
  _mm256_store_ps(pp, p);
  for (int k = 0; k < n; ++k) {
    f_out[k] = Vec3(fx[k], fy[k], fz[k]);
    pdf_out[k] = pp[k];
  }
  return true;
}
DOFARM_AVX2 bool Bsdf::outgoing_lanes_avx2(int n, const Bsdf* const* bsdf, const Vec3* wo_in,
                                           Outgoing* const* out) {
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i active = _mm256_cmpgt_epi32(_mm256_set1_epi32(n), lane);
  __m256i offb;
  if (!offsets8(reinterpret_cast<const void* const*>(bsdf), active, &offb)) return false;
  const __m256i offw =
      _mm256_and_si256(_mm256_mullo_epi32(lane, _mm256_set1_epi32(int(sizeof(Vec3)))), active);
  const Bsdf& b = *bsdf[0];
  const __m256 zero = _mm256_setzero_ps(), one = k8(1.0f);
  __m256 v[3], t[3], bt[3], nn[3], ng[3];
  for (int c = 0; c < 3; ++c) {
    v[c] = gather8(&wo_in[0].x + c, offw);
    t[c] = gather8(&b.frame_.t.x + c, offb);
    bt[c] = gather8(&b.frame_.b.x + c, offb);
    nn[c] = gather8(&b.frame_.n.x + c, offb);
    ng[c] = gather8(&b.ng_.x + c, offb);
  }
  // o.wo = frame_.to_local(wo), valid above both surfaces.
  const __m256 wo[3] = {dot8(v, t), dot8(v, bt), dot8(v, nn)};
  const __m256 valid = _mm256_and_ps(gt8(wo[2], zero), gt8(dot8(v, ng), zero));
  const __m256 delta = flag8(&b.delta_specular_, offb);
  const __m256 specular = flag8(&b.has_specular_, offb);
  // e = specular_albedo(mu) where there is a specular lobe, else {0, 0}.
  __m256 e_a, e_b;
  specular_albedo8(delta, gather8i(&b.row_.index, offb), gather8(&b.row_.t, offb), wo[2], &e_a,
                   &e_b);
  e_a = select8(specular, e_a, zero);
  e_b = select8(specular, e_b, zero);
  const __m256 k = albedo_k8(delta, e_a, e_b);
  // The Fresnel terms with Turquin's compensation, of the parts present.
  const __m256 mw = gather8(&b.metal_weight_, offb), dw = gather8(&b.dielectric_weight_, offb);
  const __m256 metal_on = gt8(mw, zero), dielectric_on = gt8(dw, zero);
  const __m256 both = _mm256_and_ps(metal_on, dielectric_on);
  const __m256 df0 = gather8(&b.dielectric_f0_.x, offb);
  const __m256 dielectric = mul8(add8(one, mul8(df0, k)), dw);
  const __m256 d0 = mul8(dielectric, df0), d1 = mul8(dielectric, sub8(one, df0));
  const __m256 e_e = add8(e_a, e_b);
  __m256 c0[3], c1[3], albedo[3];
  for (int c = 0; c < 3; ++c) {
    const __m256 mf0 = gather8(&b.metal_f0_.x + c, offb);
    const __m256 metal = mul8(add8(one, mul8(mf0, k)), mw);
    const __m256 m0 = mul8(metal, mf0), m1 = mul8(metal, sub8(one, mf0));
    c0[c] = select8(both, add8(m0, d0), select8(dielectric_on, add8(zero, d0), add8(m0, zero)));
    c1[c] = select8(both, add8(m1, d1), select8(dielectric_on, add8(zero, d1), add8(m1, zero)));
    albedo[c] = add8(mul8(c0[c], e_e), mul8(c1[c], e_b));
  }
  // The base: what the dielectric layer lets through, and the lobe choice.
  const __m256 diffuse_on = gt8(gather8(&b.diffuse_weight_, offb), zero);
  const __m256 through =
      select8(dielectric_on, through8(gather8(&b.specular_factor_, offb), df0, e_a, e_b, k), one);
  __m256 diffuse[3], dc[3];
  for (int c = 0; c < 3; ++c) {
    dc[c] = gather8(&b.diffuse_color_.x + c, offb);
    diffuse[c] = mul8(dc[c], mul8(through, gather8(&b.diffuse_norm_.x + c, offb)));
  }
  const __m256 fs = luminance8(albedo);
  const __m256 sum = add8(fs, mul8(luminance8(dc), through));
  const __m256 ratio = div8(fs, sum);
  const __m256 clamped = select8(_mm256_cmp_ps(ratio, k8(0.05f), _CMP_LT_OQ), k8(0.05f),
                                 select8(gt8(ratio, k8(0.95f)), k8(0.95f), ratio));
  const __m256 mixed = select8(gt8(sum, zero), clamped, k8(0.5f));
  __m256 ps = select8(diffuse_on, select8(specular, mixed, zero), select8(specular, one, zero));
  ps = select8(valid, ps, zero);
  // The rough lobe's terms.
  const __m256 alpha = gather8(&b.alpha_, offb);
  const __m256 smith = smith_r8(wo, mul8(alpha, alpha));
  const __m256 inv4 = div8(one, mul8(k8(4.0f), wo[2]));
  const __m256 pdf_scale = div8(ps, mul8(k8(2.0f), add8(wo[2], smith)));

  // Lane by lane into the records: what a valid one's readers read.
  alignas(32) float lanes[17][8];
  const __m256 rows[17] = {wo[0], wo[1], wo[2], c0[0],      c0[1],      c0[2],
                           c1[0], c1[1], c1[2], diffuse[0], diffuse[1], diffuse[2],
                           ps,    smith, inv4,  pdf_scale,  valid};
  for (int r = 0; r < 17; ++r) _mm256_store_ps(lanes[r], rows[r]);
  for (int j = 0; j < n; ++j) {
    Outgoing& o = *out[j];
    o.wo = Vec3(lanes[0][j], lanes[1][j], lanes[2][j]);
    o.valid = std::bit_cast<uint32_t>(lanes[16][j]) != 0;
    o.specular_prob = lanes[12][j];
    if (!o.valid) continue;
    o.fresnel_c0 = Vec3(lanes[3][j], lanes[4][j], lanes[5][j]);
    o.fresnel_c1 = Vec3(lanes[6][j], lanes[7][j], lanes[8][j]);
    o.diffuse = Vec3(lanes[9][j], lanes[10][j], lanes[11][j]);
    o.smith_r = lanes[13][j];
    o.inv_4_cos_o = lanes[14][j];
    o.specular_pdf_scale = lanes[15][j];
  }
  return true;
}
#endif

}  // namespace dofarm::render
