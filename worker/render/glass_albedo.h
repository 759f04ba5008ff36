// Directional albedo of the single-scattering rough glass lobe (bsdf.h,
// KHR_materials_transmission): what it reflects plus what it refracts, in
// importance form (the refracted part without the 1 / eta^2 radiance
// scaling, which cancels for light that enters and leaves a closed
// object),
//   E(mu) = ∫ [F G2 / G1](reflected) + [(1 - F) G2 / G1](refracted) over
//           the visible normals of wo,
// with the exact dielectric Fresnel F. Single scattering loses what light
// scattered between microfacets would return: little when smooth, half
// of it at roughness 1 from inside, where many microfacets reflect totally
// into the material. The BSDF scales the glass lobe by 1 / E(mu_o), the
// compensation Turquin 2019 gives for conductors (there 1 + F0 (1 - E) / E;
// for glass, whose lobe should return everything, 1 / E), so that a white
// glass object in a uniform environment returns exactly what it receives
// at every roughness, and samples it as before.
//
// The table holds E on 17 IORs (n = 1 + k / 8, 1 to 3; beyond, the
// nearest) for light arriving from outside (eta = n) and from inside
// (eta = 1 / n), times 32 x 32 nodes in (alpha^(1/4), sqrt(mu)) as
// microfacet_albedo.h lays them out, computed on first use by
// deterministic stratified quadrature over visible normals (only scenes
// with rough glass pay for it, about 0.6 s once per process), and is read
// trilinearly.
#pragma once

namespace dofarm::render::ggx {

struct GlassAlbedoTable {
  static constexpr int kIor = 17;        // n_k = 1 + k / 8
  static constexpr int kRoughness = 32;  // alpha^(1/4)_i = i / 31
  static constexpr int kMu = 32;         // sqrt(mu)_j = j / 31
  float e[2][kIor][kRoughness][kMu];     // [0: from outside, 1: from inside]
};

// Thread-safe; built on the first call.
const GlassAlbedoTable& glass_albedo_table();

// The table with `n` x `n` stratified visible normals per entry
// (glass_albedo_table() uses n = 16); for tests.
GlassAlbedoTable compute_glass_albedo_table(int n);

// E at (ior, side, alpha, mu), trilinear in (n, alpha^(1/4), sqrt(mu)).
float glass_albedo(const GlassAlbedoTable& table, float ior, bool entering, float alpha, float mu);

// One entry by quadrature: `eta` = IOR beyond over IOR on wo's side.
double glass_albedo_by_quadrature(float eta, float alpha, float mu, int n);

}  // namespace dofarm::render::ggx
