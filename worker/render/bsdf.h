// The material model at one surface point: glTF metallic-roughness mapped
// onto a Lambertian diffuse lobe plus a GGX specular lobe (Walter et al.
// 2007; sampled through visible normals, Heitz 2018). Dielectric F0 comes
// from the IOR, metals use the base colour as F0 (glTF 2.0 appendix B).
// The diffuse lobe is weighted by (1 - F(n.wo)) (1 - F(n.wi)) so that no
// combination of parameters creates energy. Below ggx::kDeltaAlpha the
// specular lobe is a perfect mirror (a delta lobe: no eval, no NEE).
//
// All directions are in world space; the BSDF works in the shading frame.
#pragma once

#include "common/math.h"

namespace dofarm::render {

struct BsdfSample {
  Vec3 wi;
  Vec3 weight;    // f * |cos| / pdf (for a delta lobe: F / probability)
  float pdf = 0;  // solid angle; 0 for a delta lobe
  bool is_delta = false;
  bool valid = false;
};

class Bsdf {
 public:
  // `ns` shading normal, `ng` geometric normal, both facing wo's side.
  Bsdf(Vec3 ns, Vec3 ng, Vec3 base_color, float metallic, float roughness, float ior);

  // What depends on the outgoing direction alone (its local form, Fresnel,
  // lobe probability, Smith term), computed once per path vertex and shared
  // by the light sample's evaluate() and sample().
  struct Outgoing {
    Vec3 wo;                       // local
    Vec3 fresnel;                  // F(n.wo), per channel (0 without a specular lobe)
    float specular_prob = 0;       // of choosing the specular lobe in sample()
    float smith_r = 0;             // ggx::smith_r(wo, alpha)
    float inv_4_cos_o = 0;         // 1 / (4 wo.z), of the microfacet BRDF
    float specular_pdf_scale = 0;  // specular lobe's pdf over D(h)
    bool valid = false;            // above both the shading and the geometric surface
  };
  Outgoing outgoing(Vec3 wo) const;

  Vec3 eval(Vec3 wo, Vec3 wi) const;  // f(wo, wi) * |cos(ns, wi)|, non-delta part
  float pdf(Vec3 wo, Vec3 wi) const;  // of sample(), non-delta part
  // Both at once, sharing the half-vector, D, G and Fresnel terms (NEE needs
  // both for every light sample).
  Vec3 evaluate(Vec3 wo, Vec3 wi, float* pdf) const;
  Vec3 evaluate(const Outgoing& o, Vec3 wi, float* pdf) const;
  BsdfSample sample(Vec3 wo, float u_lobe, Vec2 u) const;
  BsdfSample sample(const Outgoing& o, float u_lobe, Vec2 u) const;
  bool has_non_delta() const { return diffuse_weight_ > 0 || (has_specular_ && !delta_specular_); }

 private:
  // evaluate() with both directions local and above the surfaces.
  Vec3 evaluate_local(const Outgoing& o, Vec3 wi, float* pdf) const;
  Frame frame_;
  Vec3 ng_;
  Vec3 diffuse_color_;  // (1 - metallic) * base_color
  Vec3 f0_;
  float alpha_;
  float diffuse_weight_;
  float diffuse_luminance_;
  bool delta_specular_;
  bool has_specular_;
};

}  // namespace dofarm::render
