#include "worker/render/bsdf.h"

#include <algorithm>
#include <cmath>

#include "worker/render/glass_albedo.h"
#include "worker/render/microfacet.h"
#include "worker/render/sheen.h"
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
  // Reflection with both directions above the geometric surface
  // (evaluate_direction), refraction with wi below both surfaces, so that
  // light never leaks through a surface because of a bent shading normal.
  Vec3 wi;
  if (evaluate_direction(o, wi_w, &wi)) return evaluate_local(o, wi, pdf_out);
  if (glass_weight_ > 0 && !glass_delta_ && o.valid && dot(wi_w, ng_) < 0) [[unlikely]] {
    wi = frame_.to_local(wi_w);
    if (wi.z < 0) return evaluate_refraction(o, wi, pdf_out);
  }
  return Vec3(0);
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
  // wo and wi above both surfaces: the reflection evaluate_base() evaluates.
  if (!o.valid || dot(wi_w, ng_) <= 0) return false;
  *wi = frame_.to_local(wi_w);
  return !(wi->z <= 0);
}

}  // namespace dofarm::render
