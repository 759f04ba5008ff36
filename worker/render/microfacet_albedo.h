// Directional albedo of the single-scattering GGX lobe (microfacet.h), the
// quantity that multiple-scattering compensation and energy-conserving
// layering are built on (Kulla & Conty 2017, "Revisiting Physically Based
// Shading at Imageworks"; Turquin 2019, "Practical multiple scattering
// compensation for microfacet models").
//
// With Schlick's Fresnel F = F0 + (1 - F0) w, w = (1 - wo.h)^5, the albedo
// of the single-scattering lobe for any F0 is F0 A + B, where
//   A(mu, alpha) = ∫ D G2 / (4 mu mu_i) (1 - w) mu_i dwi,
//   B(mu, alpha) = ∫ D G2 / (4 mu mu_i) w mu_i dwi,
// and E = A + B is the albedo with F = 1 (mu = wo.z). The table holds A and
// B on a 32 x 32 grid in (alpha^(1/4), sqrt(mu)), computed once at start-up by
// deterministic quadrature over visible normals (a function-local static,
// so every process builds the same bytes), and is read bilinearly. Both
// axes crowd their nodes where the albedo changes fastest: near the horizon,
// where a smooth surface's albedo drops within mu ~ alpha (masking), and at
// small alpha, where that drop moves with alpha; so grazing light is neither
// lost nor created by interpolation.
#pragma once

#include <algorithm>
#include <cmath>

#include "worker/render/microfacet.h"

namespace dofarm::render::ggx {

// The node layout of this table and of glass_albedo.h's: n nodes in equal
// steps of alpha^(1/4) and of sqrt(mu). A node's alpha and mu (mu at least
// `mu_floor`: mu = 0 has no visible normals), and where an alpha or a mu
// lies on its axis (in nodes, from 0 to n - 1).
inline float node_alpha(int i, int n) {
  const float x = float(i) / float(n - 1);
  return std::max(kMinAlpha, (x * x) * (x * x));
}
inline float node_mu(int j, int n, float mu_floor) {
  const float y = float(j) / float(n - 1);
  return std::max(y * y, mu_floor);
}
inline float alpha_axis(float alpha, int n) {
  return std::sqrt(std::sqrt(std::clamp(alpha, 0.0f, 1.0f))) * float(n - 1);  // NaN stays NaN
}
inline float mu_axis(float mu, int n) {
  return std::sqrt(std::clamp(mu, 0.0f, 1.0f)) * float(n - 1);
}

struct AlbedoTable {
  static constexpr int kMu = 32;         // nodes sqrt(mu)_j = j / (kMu - 1)
  static constexpr int kRoughness = 32;  // nodes alpha^(1/4)_i = i / (kRoughness - 1)
  struct Entry {
    float a, b;
  };
  Entry entry[kRoughness][kMu];
  // Cosine-weighted hemispherical averages 2 ∫ x(mu) mu dmu, per roughness
  // node, of x = A, B, A k, B k with k = (1 - E) / E (Turquin's compensation
  // factor without F0), taken over the same piecewise-linear A and B that
  // lookups return, so that the layered diffuse lobe's normalisation matches
  // what evaluation integrates (see bsdf.cpp).
  struct Averages {
    float a, b, ak, bk;
  };
  Averages average[kRoughness];
};

// Row 0 (alpha -> 0) is the smooth limit: E = 1, A = 1 - (1 - mu)^5,
// B = (1 - mu)^5. Thread-safe; the first call takes ~0.1 s.
const AlbedoTable& albedo_table();

// The table computed from scratch with `n` x `n` stratified visible-normal
// quadrature points per entry (albedo_table() uses n = 48); for tests.
AlbedoTable compute_albedo_table(int n);

// Where one alpha falls on the roughness axis: computed once per BSDF.
struct AlbedoRow {
  const AlbedoTable::Entry* lo = nullptr;  // row below
  const AlbedoTable::Entry* hi = nullptr;  // row above
  float t = 0;                             // weight of `hi`
  int index = 0;                           // of `lo`
};
inline AlbedoRow albedo_row(const AlbedoTable& table, float alpha) {
  float x = alpha_axis(alpha, AlbedoTable::kRoughness);  // NaN stays NaN: caught below
  if (!(x >= 0.0f)) x = 0.0f;
  AlbedoRow row;
  row.index = std::min(int(x), AlbedoTable::kRoughness - 2);
  row.t = std::min(x - float(row.index), 1.0f);
  row.lo = table.entry[row.index];
  row.hi = table.entry[row.index + 1];
  return row;
}

struct Albedo {
  float a = 0, b = 0;
  float e() const { return a + b; }
  // Turquin 2019's (1 - E) / E; E is bounded away from 0 (it is >= 0.3 for
  // every alpha <= 1 and mu in [0, 1]), the clamp only keeps a broken table finite.
  float k() const {
    float e = std::max(a + b, 1e-3f);
    return (1.0f - e) / e;
  }
};

// Bilinear lookup at mu in [0, 1] (clamped).
inline Albedo albedo(const AlbedoRow& row, float mu) {
  float x = mu_axis(mu, AlbedoTable::kMu);
  int j = std::min(int(x), AlbedoTable::kMu - 2);
  float s = x - float(j);
  auto mix = [](float p, float q, float t) { return p + (q - p) * t; };
  float a_lo = mix(row.lo[j].a, row.lo[j + 1].a, s);
  float b_lo = mix(row.lo[j].b, row.lo[j + 1].b, s);
  float a_hi = mix(row.hi[j].a, row.hi[j + 1].a, s);
  float b_hi = mix(row.hi[j].b, row.hi[j + 1].b, s);
  return {mix(a_lo, a_hi, row.t), mix(b_lo, b_hi, row.t)};
}

// The four averages of AlbedoTable at this row, linear in alpha^(1/4).
inline AlbedoTable::Averages albedo_averages(const AlbedoTable& table, const AlbedoRow& row) {
  const AlbedoTable::Averages& p = table.average[row.index];
  const AlbedoTable::Averages& q = table.average[row.index + 1];
  const float t = row.t;
  return {p.a + (q.a - p.a) * t, p.b + (q.b - p.b) * t, p.ak + (q.ak - p.ak) * t,
          p.bk + (q.bk - p.bk) * t};
}

}  // namespace dofarm::render::ggx
