// Bsdf's evaluations of several paths' vertices at once
// (Bsdf::evaluate_lanes; PathBatch in worker/render/integrator.cpp), in
// AVX2 lanes where the CPU has them: each lane does the scalar code's
// operations (bsdf.cpp) in their order, with no fused multiply-add, so a
// lane's results are the scalar ones bit for bit (simd.h;
// Bsdf.EvaluationsInLanesAreEachBsdfsOwn). The outgoing terms
// (Bsdf::outgoing) stay scalar: in lanes they saved no time (the courtyard
// 1.2% faster without them in render_spp, the same within 1% in
// render_throughput; bench/README.md, "ab_time.sh").
#include <algorithm>
#include <bit>
#include <cstdint>

#include "worker/render/bsdf.h"
#include "worker/render/simd.h"
#include "worker/render/trig8.h"

namespace dofarm::render {

namespace {

// Runs lanes(first, m) over n items eight at a time where the CPU has AVX2
// (false: that batch cannot run in lanes), and one(k) for every item the
// lanes did not do.
template <class Lanes, class One>
void in_lanes_of_eight(int n, Lanes&& lanes, One&& one) {
  int k = 0;
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (use_simd())
    for (; k < n; k += 8)
      if (!lanes(k, std::min(8, n - k))) break;
#endif
  for (; k < n; ++k) one(k);
}

}  // namespace

void Bsdf::evaluate_lanes(int n, const Bsdf* const* bsdf, const Outgoing* const* out,
                          const Vec3* wi, Vec3* f, float* pdf) {
  in_lanes_of_eight(
      n,
      [&](int k, int m) {
#ifdef DOFARM_HAVE_AVX2_KERNELS
        return evaluate_lanes_avx2(m, bsdf + k, out + k, wi + k, f + k, pdf + k);
#else
        return false;
#endif
      },
      [&](int k) { f[k] = bsdf[k]->evaluate_local(*out[k], wi[k], &pdf[k]); });
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
// A Vec3 member of each lane's record.
DOFARM_AVX2 inline V3x8 gather_vec8(const Vec3* first, __m256i offsets) {
  return {gather8(&first->x, offsets), gather8(&first->y, offsets), gather8(&first->z, offsets)};
}
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
// The lanes in use: the first n of eight.
DOFARM_AVX2 inline __m256i active8(int n) {
  return _mm256_cmpgt_epi32(_mm256_set1_epi32(n), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
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
// The offsets of the active lanes' entries of a Vec3 array.
DOFARM_AVX2 inline __m256i vec3_offsets8(__m256i active) {
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  return _mm256_and_si256(_mm256_mullo_epi32(lane, _mm256_set1_epi32(int(sizeof(Vec3)))), active);
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
// ggx::detail::sin2() and ggx::smith_r() in lanes.
DOFARM_AVX2 inline __m256 sin2_8(V3x8 w) { return add8(mul8(w.x, w.x), mul8(w.y, w.y)); }
DOFARM_AVX2 inline __m256 smith_r8(V3x8 w, __m256 a2) {
  return _mm256_sqrt_ps(add8(mul8(w.z, w.z), mul8(a2, sin2_8(w))));
}

}  // namespace

DOFARM_AVX2 bool Bsdf::evaluate_lanes_avx2(int n, const Bsdf* const* bsdf,
                                           const Outgoing* const* out, const Vec3* wi_in,
                                           Vec3* f_out, float* pdf_out) {
  // Each lane's records as byte offsets from lane 0's (lanes past n repeat
  // lane 0); gathers read a field of every lane at once.
  const __m256i active = active8(n);
  __m256i offb, offo;
  if (!offsets8(reinterpret_cast<const void* const*>(bsdf), active, &offb) ||
      !offsets8(reinterpret_cast<const void* const*>(out), active, &offo))
    return false;
  const Bsdf& b = *bsdf[0];
  const Outgoing& o = *out[0];
  const V3x8 wi = gather_vec8(wi_in, vec3_offsets8(active));
  const V3x8 wo = gather_vec8(&o.wo, offo);
  const __m256 zero = _mm256_setzero_ps();
  const __m256 delta = flag8(&b.delta_specular_, offb);
  const __m256 rough = _mm256_andnot_ps(delta, flag8(&b.has_specular_, offb));
  const __m256 diffuse = gt8(gather8(&b.diffuse_weight_, offb), zero);
  const __m256 dielectric = gt8(gather8(&b.dielectric_weight_, offb), zero);

  // p = (1 - ps) wi.z / pi.
  __m256 p = mul8(mul8(sub8(k8(1.0f), gather8(&o.specular_prob, offo)), wi.z), k8(kInvPi));

  // The base: o.diffuse (1 - E_s(mu_i)) wi.z under a dielectric layer, else
  // o.diffuse wi.z. E_s(mu_i) from specular_albedo(wi.z): a mirror's
  // Schlick terms, else the table's bilinear lookup (ggx::albedo).
  const __m256 mu = wi.z;
  __m256 e_a, e_b;
  specular_albedo8(delta, gather8i(&b.row_.index, offb), gather8(&b.row_.t, offb), mu, &e_a, &e_b);
  const __m256 through =
      through8(gather8(&b.specular_factor_, offb), gather8(&b.dielectric_f0_.x, offb), e_a, e_b,
               albedo_k8(delta, e_a, e_b));
  const __m256 t_mu = mul8(through, mu);
  const V3x8 d = gather_vec8(&o.diffuse, offo);
  auto base = [&](__m256 dc) DOFARM_AVX2 {  // f += the base lobe's channel
    return select8(diffuse, add8(zero, select8(dielectric, mul8(dc, t_mu), mul8(dc, mu))), zero);
  };
  V3x8 f{base(d.x), base(d.y), base(d.z)};

  // The rough specular lobe (reflection_terms(), D, G2, Schlick).
  const V3x8 sum{add8(wo.x, wi.x), add8(wo.y, wi.y), add8(wo.z, wi.z)};
  const __m256 inv_len = div8(k8(1.0f), _mm256_sqrt_ps(dot8(sum, sum)));
  const V3x8 h{mul8(sum.x, inv_len), mul8(sum.y, inv_len), mul8(sum.z, inv_len)};
  const __m256 wo_h = dot8(wo, h);
  const __m256 alpha = gather8(&b.alpha_, offb);
  const __m256 a2 = mul8(alpha, alpha);
  const __m256 tt = add8(div8(sin2_8(h), a2), mul8(h.z, h.z));
  __m256 dd = div8(k8(1.0f), mul8(mul8(mul8(k8(kPi), a2), tt), tt));
  dd = select8(_mm256_and_ps(gt8(h.z, zero), is_finite8(dd)), dd, zero);
  const __m256 ro = gather8(&o.smith_r, offo);
  const __m256 ri = smith_r8(wi, a2);
  const __m256 den = add8(mul8(wi.z, ro), mul8(wo.z, ri));
  const __m256 g_ok =
      _mm256_and_ps(_mm256_and_ps(gt8(wo.z, zero), gt8(wi.z, zero)), gt8(den, zero));
  const __m256 g = select8(g_ok, min1_8(div8(mul8(mul8(k8(2.0f), wo.z), wi.z), den)), zero);
  const __m256 w_oh = schlick_weight8(wo_h);
  const __m256 scale = mul8(mul8(dd, g), gather8(&o.inv_4_cos_o, offo));
  const V3x8 c0 = gather_vec8(&o.fresnel_c0, offo), c1 = gather_vec8(&o.fresnel_c1, offo);
  auto specular = [&](__m256 fc, __m256 c0c, __m256 c1c) DOFARM_AVX2 {
    return select8(rough, add8(fc, mul8(add8(c0c, mul8(c1c, w_oh)), scale)), fc);
  };
  f = {specular(f.x, c0.x, c1.x), specular(f.y, c0.y, c1.y), specular(f.z, c0.z, c1.z)};
  p = select8(_mm256_and_ps(rough, gt8(wo_h, zero)),
              add8(p, mul8(dd, gather8(&o.specular_pdf_scale, offo))), p);

  alignas(32) float fx[8], fy[8], fz[8], pp[8];
  _mm256_store_ps(fx, f.x);
  _mm256_store_ps(fy, f.y);
  _mm256_store_ps(fz, f.z);
  _mm256_store_ps(pp, p);
  for (int k = 0; k < n; ++k) {
    f_out[k] = Vec3(fx[k], fy[k], fz[k]);
    pdf_out[k] = pp[k];
  }
  return true;
}

#endif

}  // namespace dofarm::render
