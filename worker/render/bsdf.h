// The material model at one surface point: glTF 2.0 metallic-roughness
// (appendix B) as the mix metallic * metal + (1 - metallic) * dielectric,
// made energy-conserving:
//
// - Both parts share one GGX specular lobe shape (Walter et al. 2007,
//   height-correlated Smith G2 of Heitz 2014, sampled through visible normals,
//   Heitz 2018) with Schlick's Fresnel: F0 = the base colour for the metal,
//   ((ior - 1) / (ior + 1))^2 for the dielectric.
// - Multiple scattering between microfacets, which the single-scattering lobe
//   loses (about 70% at roughness 1 and normal incidence), is put back by Turquin 2019's scaling
//   of that lobe, f_ss (1 + F0 (1 - E(mu_o)) / E(mu_o)), with E the lobe's
//   directional albedo for F = 1 (microfacet_albedo.h): a white metal reflects
//   exactly 1 at every roughness and angle, and the lobe is sampled as before.
// - The dielectric's Lambertian base lies under its specular layer and
//   receives what that layer does not reflect (Kulla & Conty 2017):
//   base (1 - E_s(mu_o)) (1 - E_s(mu_i)) / (pi (1 - E_s_avg)), E_s the
//   compensated specular albedo for the dielectric's F0, so that a white
//   dielectric reflects exactly 1 too and the lobe stays reciprocal.
// - Below ggx::kDeltaAlpha the specular lobe is a perfect mirror (a delta
//   lobe: no eval, no NEE); its albedo is F(mu) and the base's layering uses that.
// - F0 = 0 (IOR 1, or a black metal) is no interface: that part has no
//   specular lobe (Schlick's curve would still rise to 1 at grazing angles).
// - KHR_materials_specular (Specular below) scales the dielectric's lobe:
//   F = s (F0' + (1 - F0') w) per channel, F0' = min(F0_ior c, 1), i.e. the
//   extension's F0 = s F0' and F90 = s. Its albedo, and so what the base
//   receives, is then per channel; a white base still reflects exactly 1
//   in every channel. With s = 1 and c = 1 (no extension) every value is
//   bit for bit what it was without it.
//
// - KHR_materials_transmission (Transmission below) makes a share t of the
//   dielectric a rough glass interface, as Cycles 3.4's Principled BSDF
//   does: f = metallic * metal + (1 - metallic) [(1 - t) layered + t glass].
//   The glass reflects F and refracts 1 - F of the light with the exact
//   dielectric Fresnel F (with total internal reflection), both through
//   the same GGX microfacets (Walter et al. 2007: the generalised half
//   vector of eq. 16, the Jacobian of eq. 17, the BTDF of eq. 21, with the
//   1 / eta^2 radiance scaling); the refracted light is tinted by the base
//   colour. Rough glass loses what multiple scattering between microfacets
//   would return; the lobe is scaled by 1 / E(mu_o), its directional albedo
//   (glass_albedo.h), which gives it back (docs/renderer.md has the figures).
//   Below kDeltaAlpha it is a delta lobe; at IOR 1 it lets light through
//   unbent (no interface).
// - KHR_materials_clearcoat (Clearcoat below): a coat of strength c and its
//   own roughness over everything else: a GGX lobe with F0 = 0.04 (IOR
//   1.5), compensated for multiple scattering as the specular lobe is, and
//   the material beneath scaled by 1 - E_c(mu_o), E_c the coat's albedo,
//   so that a white material under a coat still returns exactly 1 (as
//   Turquin's compensation, it depends on wo alone). With a normal of its
//   own (clearcoatNormalTexture) the coat's lobe, albedo and what it lets
//   through are all taken in that normal's frame, while wo lies above it
//   (else in the shading frame).
//
// - KHR_materials_sheen (SheenLayer below): a Charlie microfibre lobe of
//   colour C and its own roughness over the base, beneath the coat
//   (sheen.h); the base scaled by 1 - max(C) E_sheen(mu_o), so that a white
//   material under a white sheen returns exactly 1. Sampled
//   cosine-weighted.
//
// docs/renderer.md (Materials) has the equations and the furnace figures.
// All directions are in world space; the BSDF works in the shading frame.
#pragma once

#include "common/math.h"
#include "worker/render/microfacet_albedo.h"

namespace dofarm::render {

struct BsdfSample {
  Vec3 wi;
  Vec3 weight;    // f * |cos| / pdf (for a delta lobe: F / probability)
  float pdf = 0;  // solid angle; 0 for a delta lobe
  bool is_delta = false;
  bool valid = false;
};

// glTF KHR_materials_specular's factors: the strength s of the dielectric's
// specular layer (specularFactor) and the colour c its F0 is multiplied by
// (specularColorFactor).
struct SpecularLayer {
  float factor = 1.0f;
  Vec3 color{1.0f};
};

// The unpolarised Fresnel reflectance of a smooth dielectric interface for
// light meeting it at cos_i > 0 from the side of IOR n1, eta = n2 / n1; 1
// under total internal reflection.
float fresnel_dielectric(float cos_i, float eta);
// Refraction of wo (on h's side, cos_oh = wo.h > 0) through a microfacet of
// normal h into the medium of relative IOR eta (far over near); false under
// total internal reflection.
bool refract_through(Vec3 wo, Vec3 h, float cos_oh, float eta, Vec3* wi);

// glTF KHR_materials_transmission's factor t, and on which side of the
// surface the outgoing direction lies: `entering` = on its front side (the
// side its winding faces, glTF 3.7.2.1), so the material's IOR lies beyond;
// otherwise the ray is inside and the medium beyond has IOR 1.
struct TransmissionLayer {
  float factor = 0.0f;
  bool entering = true;
};

// glTF KHR_materials_clearcoat's clearcoatFactor and
// clearcoatRoughnessFactor, and the coat's own shading normal
// (clearcoatNormalTexture), unit and on wo's side of the geometric surface;
// zero = the material's shading normal.
struct ClearcoatLayer {
  float factor = 0.0f;
  float roughness = 0.0f;
  Vec3 normal{0.0f};
};

// glTF KHR_materials_sheen's sheenColorFactor and sheenRoughnessFactor
// (sheen.h).
struct SheenLayer {
  Vec3 color{0.0f};
  float roughness = 0.0f;
};

// What a Bsdf takes from its material's scalar factors alone: everything but
// the base colour, the normals and the side the light arrives from. The same
// at every point of a material whose scalar factors are not textured, so
// Scene computes it once per material (Scene::bsdf_constants) and a hit adds
// only its own colour and frame (bench/README.md, "A hit's BSDF in
// lanes"). The members are the Bsdf's own (it derives from this), named as
// its members are.
class BsdfConstants {
 public:
  BsdfConstants(float metallic, float roughness, float ior, const SpecularLayer& specular = {},
                float transmission = 0.0f, const ClearcoatLayer& clearcoat = {},
                const SheenLayer& sheen = {});

 protected:
  ggx::AlbedoRow row_;  // the rough specular lobe's (unused for a mirror)
  Vec3 dielectric_f0_;  // from the IOR, times the specular colour (clamped to 1)
  // 1 / (pi (1 - E_s_avg)); 1 / pi without an interface. Only read where
  // the base has a colour.
  Vec3 diffuse_norm_;
  float metallic_;           // clamped to [0, 1]
  float diffuse_scale_;      // (1 - metallic)(1 - t): the base colour's share in the base lobe
  float dielectric_weight_;  // of the dielectric's specular lobe: (1 - metallic) s, 0 for IOR 1
  float specular_factor_;    // s, or 0 without a dielectric interface
  float alpha_;
  bool grey_f0_;  // the same F0 in every channel (no specular colour)
  bool delta_specular_;
  bool in_lanes_;  // Bsdf::in_lanes()
  // The glass lobe (KHR_materials_transmission).
  bool glass_delta_ = false;
  float glass_weight_ = 0;  // (1 - metallic) t
  float glass_ior_ = 1;     // the material's IOR
  // The clearcoat (KHR_materials_clearcoat).
  float coat_weight_ = 0;  // c
  float coat_alpha_;
  bool coat_delta_;
  ggx::AlbedoRow coat_row_;
  // The sheen (KHR_materials_sheen), between the base and the coat.
  float sheen_weight_ = 0;  // max(C); 0 = no sheen
  Vec3 sheen_color_;
  float sheen_roughness_ = 0;
  float sheen_alpha_ = 0;
};

class Bsdf : private BsdfConstants {
 public:
  // `ns` shading normal, `ng` geometric normal, both facing wo's side.
  Bsdf(Vec3 ns, Vec3 ng, Vec3 base_color, float metallic, float roughness, float ior,
       const SpecularLayer& specular = {}, const TransmissionLayer& transmission = {},
       const ClearcoatLayer& clearcoat = {}, const SheenLayer& sheen = {})
      : Bsdf(BsdfConstants(metallic, roughness, ior, specular, transmission.factor, clearcoat,
                           sheen),
             ns, ng, base_color, transmission.entering, clearcoat.normal) {}
  // The same from its material's constants: bit for bit the Bsdf of the
  // constructor above given the factors `k` was computed from.
  // `entering` and `coat_normal` are TransmissionLayer's and
  // ClearcoatLayer's.
  Bsdf(const BsdfConstants& k, Vec3 ns, Vec3 ng, Vec3 base_color, bool entering = true,
       Vec3 coat_normal = Vec3(0.0f));

  // What depends on the outgoing direction alone (its local form, the
  // compensated Fresnel, the base's share, lobe probability, Smith term),
  // computed once per path vertex and shared by the light sample's
  // evaluate() and sample().
  // Only `valid` and `specular_prob` have values from the start; the rest
  // is written where the material has the lobe that reads it (the layers'
  // terms by set_layer_defaults() first, for a material with a layer), so
  // an opaque material's vertex pays for no defaults it never reads.
  struct Outgoing {
    Vec3 wo;  // local
    // The specular lobe's Fresnel factor, multiple-scattering compensation
    // included: fresnel_c0 + fresnel_c1 (1 - wo.h)^5, per channel.
    Vec3 fresnel_c0, fresnel_c1;
    Vec3 diffuse;                  // base lobe's f / (1 - E_s(mu_i)), per channel
    float specular_prob = 0;       // of choosing the specular lobe in sample()
    float smith_r;                 // ggx::smith_r(wo, alpha)
    float inv_4_cos_o;             // 1 / (4 wo.z), of the microfacet BRDF
    float specular_pdf_scale;      // specular lobe's pdf over D(h)
    float glass_prob;              // of choosing the glass lobe in sample()
    float glass_scale;             // 1 / E_glass(mu_o): multiple-scattering compensation
    float coat_prob;               // of choosing the clearcoat lobe in sample()
    float coat_scale;              // 1 - E_c(mu_o): what the coat lets through
    float coat_fresnel;            // c (1 + F0 k_c(mu_o)): the coat lobe's factor
    float coat_smith_r;
    // wo in the coat's frame (its own normal where it has one and wo lies
    // above it; else wo) and which frame that is.
    Vec3 coat_wo;
    bool coat_own_frame;
    float sheen_prob;              // of choosing the sheen lobe in sample(), under the coat
    float sheen_scale;             // 1 - max(C) E_sheen(mu_o): what the sheen lets through
    float sheen_norm;              // 1 / E_sheen(mu_o) where that exceeds 1 (grazing), else 1
    float sheen_lambda_o;          // the sheen's shadowing Lambda(mu_o) (sheen.h)
    bool valid = false;            // above both the shading and the geometric surface
    // The layers' terms as a material without those layers has them: no
    // glass, coat or sheen to choose, all light let through.
    void set_layer_defaults() {
      glass_prob = 0;
      glass_scale = 1;
      coat_prob = 0;
      coat_scale = 1;
      coat_fresnel = 0;
      coat_smith_r = 0;
      coat_own_frame = false;
      sheen_prob = 0;
      sheen_scale = 1;
      sheen_norm = 1;
      sheen_lambda_o = 0;
    }
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
  // Several paths' vertices at once (PathBatch, worker/render/integrator.cpp).
  // in_lanes(): this BSDF's evaluation can run in a lane of
  // evaluate_lanes() (no glass, coat or sheen, and a grey F0).
  bool in_lanes() const { return in_lanes_; }
  // evaluate() in two steps, for a BSDF in_lanes(): false where it is 0
  // (with pdf 0) without evaluating; else true, and *wi the local
  // direction to evaluate in lanes.
  bool evaluate_direction(const Outgoing& o, Vec3 wi_w, Vec3* wi) const;
  // sample() in two steps, for a BSDF in_lanes(): false where the sample is
  // complete (a delta lobe's, or invalid) in *s; else true, with s->wi set
  // and *wi its local form, whose evaluation (evaluate_lanes) finish_sample()
  // turns into the sample.
  bool sample_direction(const Outgoing& o, float u_lobe, Vec2 u, BsdfSample* s, Vec3* wi) const;
  static void finish_sample(BsdfSample* s, Vec3 f, float pdf) {
    s->pdf = pdf;
    if (!(pdf > 0)) return;
    s->weight = f / pdf;
    s->valid = is_finite(s->weight);
  }
  // bsdf[k]->evaluate_local(*out[k], wi[k], &pdf[k]) for k < n, eight at
  // a time in AVX2 lanes where the CPU has them (each lane the
  // scalar arithmetic in its order, so the same bits; simd.h), else one by
  // one. Every bsdf[k] in_lanes(), every wi[k] from evaluate_direction()
  // or sample_direction().
  static void evaluate_lanes(int n, const Bsdf* const* bsdf, const Outgoing* const* out,
                             const Vec3* wi, Vec3* f, float* pdf);
  bool has_non_delta() const {
    return diffuse_weight_ > 0 || (has_specular_ && !delta_specular_) ||
           (glass_weight_ > 0 && !glass_delta_) || (coat_weight_ > 0 && !coat_delta_) ||
           sheen_weight_ > 0;
  }

 private:
  // evaluate() with both directions local and above the surfaces.
  Vec3 evaluate_local(const Outgoing& o, Vec3 wi, float* pdf) const;
  // evaluate_lanes() of n <= 8 in AVX2 lanes; false where it cannot (lanes
  // too far apart in memory for 32-bit gather offsets).
  static bool evaluate_lanes_avx2(int n, const Bsdf* const* bsdf, const Outgoing* const* out,
                                  const Vec3* wi, Vec3* f, float* pdf);
  // The glass lobe for wi below the surface (refraction), rough glass only.
  Vec3 evaluate_refraction(const Outgoing& o, Vec3 wi, float* pdf) const;
  // The glass lobe's reflection, added to f and *pdf (wi above the surface).
  void add_glass_reflection(const Outgoing& o, Vec3 wi, Vec3* f, float* pdf) const;
  // `direction_only` (for sample_layered, which weighs the direction
  // against the whole material itself): a non-delta direction comes back
  // valid with only wi set, not evaluated. Delta samples are complete.
  BsdfSample sample_glass(const Outgoing& o, float u_lobe, Vec2 u,
                          bool direction_only = false) const;
  // wo (local to `frame`) mirrored about its normal, in world space; false
  // where that lies below the geometric surface.
  bool mirror(Vec3 wo, Vec3* wi_w) const { return mirror(frame_, wo, wi_w); }
  bool mirror(const Frame& frame, Vec3 wo, Vec3* wi_w) const {
    *wi_w = frame.to_world(Vec3(-wo.x, -wo.y, wo.z));
    return dot(*wi_w, ng_) > 0;
  }
  // The frame the coat's lobe works in for this wo.
  const Frame& coat_frame(const Outgoing& o) const {
    return o.coat_own_frame ? coat_frame_ : frame_;
  }
  // Everything but the clearcoat (evaluate() and sample() add it).
  Vec3 evaluate_base(const Outgoing& o, Vec3 wi, float* pdf) const;
  BsdfSample sample_base(const Outgoing& o, float u_lobe, Vec2 u,
                         bool direction_only = false) const;
  // sample_base()'s reflection lobes (specular or base) for a valid o: false
  // where the sample is complete in *s (a delta lobe's, or none); else true,
  // with s->wi set and *wi its local form, still to be evaluated.
  bool reflection_direction(const Outgoing& o, float u_lobe, Vec2 u, BsdfSample* s, Vec3* wi) const;
  // sample() with a coat or a sheen over the base: picks a layer's lobe for
  // the direction, then weighs it against the whole material.
  BsdfSample sample_layered(const Outgoing& o, float u_lobe, Vec2 u) const;
  void add_coat(const Outgoing& o, Vec3 wi, Vec3* f, float* pdf) const;
  void add_sheen(const Outgoing& o, Vec3 wi, Vec3* f, float* pdf) const;
  // Single-scattering albedo terms A, B of the specular lobe at mu.
  ggx::Albedo specular_albedo(float mu) const;
  // 1 - E_s(mu) from mu's A and B: what the dielectric's specular layer lets
  // through to the base (1 without a dielectric interface), per channel.
  Vec3 base_transmission(const ggx::Albedo& e) const;

  // What the hit adds to its material's constants.
  Frame frame_;
  Vec3 ng_;
  Vec3 metal_f0_;       // the base colour
  float metal_weight_;  // metallic; 0 for a black metal (no interface)
  Vec3 diffuse_color_;  // (1 - metallic) * base_color
  float diffuse_weight_;
  bool has_specular_;
  float eta_ = 1;  // IOR beyond the surface over IOR on wo's side
  bool glass_entering_ = true;
  Vec3 glass_tint_;           // the base colour, which tints refracted light
  bool coat_normal_ = false;  // the coat has its own normal, coat_frame_'s
  Frame coat_frame_;
};

}  // namespace dofarm::render
