#include "worker/render/environment.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "worker/render/simd.h"
#include "worker/render/trig.h"
#include "worker/render/trig8.h"

namespace dofarm::render {

std::unique_ptr<Environment> Environment::from_spec(const EnvironmentSpec& spec) {
  if (spec.color) return std::make_unique<Environment>(*spec.color * spec.intensity);
  RgbImage image = load_rgb_image(spec.map, /*srgb=*/true);
  // A texel brighter than kMaxRadiance (common/jobspec.h) is refused here,
  // naming the file, rather than risking an Inf in a buffer after the frame
  // has been rendered.
  for (size_t i = 0; i < image.rgb.size(); ++i) {
    const double v = double(image.rgb[i]) * spec.intensity;
    if (v > kMaxRadiance) {
      const size_t texel = i / 3;
      throw RuntimeError(fmt::format(
          "\"{}\": texel ({}, {}) has radiance {:g} (times intensity {:g}), above the {:g} a "
          "radiance may be (it keeps every buffer finite)",
          spec.map.string(), texel % size_t(image.width), texel / size_t(image.width),
          double(image.rgb[i]), spec.intensity, kMaxRadiance));
    }
  }
  return std::make_unique<Environment>(std::move(image), spec.intensity, spec.rotation_deg);
}

Environment::Environment(Vec3 c) : constant_(c) {
  if (!is_finite(c) || c.x < 0 || c.y < 0 || c.z < 0) constant_ = Vec3(0);
  constant_ = Vec3(std::min(constant_.x, kMaxRadiance), std::min(constant_.y, kMaxRadiance),
                   std::min(constant_.z, kMaxRadiance));
  mean_luminance_ = luminance(constant_);
}

Environment::Environment(RgbImage image, float intensity, float rotation_deg)
    : width_(image.width), height_(image.height), rotation_(rotation_deg * kPi / 180.0f) {
  const int w = width_, h = height_;
  std::vector<float> weights(size_t(w) * h);
  double sum = 0, solid_angle = 0;
  for (int y = 0; y < h; ++y) {
    float sin_theta = std::sin(kPi * (float(y) + 0.5f) / float(h));
    for (int x = 0; x < w; ++x) {
      float* t = &image.rgb[(size_t(y) * w + x) * 3];
      for (int c = 0; c < 3; ++c) {
        float v = t[c] * intensity;
        // No NaN, Inf or negative light; from_spec refuses a file beyond
        // kMaxRadiance, an image built in code is clamped to it.
        t[c] = std::isfinite(v) && v > 0 ? std::min(v, kMaxRadiance) : 0.0f;
      }
      float lum = luminance(Vec3(t[0], t[1], t[2]));
      weights[size_t(y) * w + x] = lum * sin_theta;
      sum += double(lum) * sin_theta;
      solid_angle += sin_theta;
    }
  }
  mean_luminance_ = solid_angle > 0 ? float(sum / solid_angle) : 0.0f;

  // Texel weights by block (0 past the map's edge), block sums.
  blocks_w_ = (w + kBlock - 1) / kBlock;
  blocks_h_ = (h + kBlock - 1) / kBlock;
  auto weight = [&](int x, int y) -> double {
    if (x >= w || y >= h) return 0.0;
    const float v = weights[size_t(y) * w + x];
    return std::isfinite(v) && v > 0 ? double(v) : 0.0;
  };
  std::vector<double> block_sums(size_t(blocks_w_) * blocks_h_);
  for (int by = 0; by < blocks_h_; ++by)
    for (int bx = 0; bx < blocks_w_; ++bx) {
      double s = 0;
      for (int y = 0; y < kBlock; ++y)
        for (int x = 0; x < kBlock; ++x) s += weight(bx * kBlock + x, by * kBlock + y);
      block_sums[size_t(by) * blocks_w_ + bx] = s;
    }
  block_distribution_ = CompactDistribution2D(block_sums, blocks_w_, blocks_h_);

  // Centre directions and the angular radius of a block. A direction of a
  // block (theta within d_theta / 2 of the centre's, phi within d_phi / 2)
  // is reached from the centre along its meridian (at most d_theta / 2)
  // and then along its circle of latitude (sin(theta) |phi - phi_c| <=
  // d_phi / 2): the angle between them is at most r = (d_theta + d_phi) / 2.
  // A centre more than 90 degrees + r from n (cos < -sin r) leaves the
  // whole block below the plane of n; 1e-3 more covers the rounding of
  // the centres and of the samples' directions (uv_to_dir, directions8:
  // errors near 1e-6).
  block_row_trig_.resize(size_t(blocks_h_));
  for (int by = 0; by < blocks_h_; ++by) {
    const double theta = kPi * (double(by) + 0.5) * kBlock / double(h);
    block_row_trig_[size_t(by)] = Vec2(float(std::sin(theta)), float(std::cos(theta)));
  }
  block_column_trig_.resize(size_t(blocks_w_));
  for (int bx = 0; bx < blocks_w_; ++bx) {
    const double phi =
        ((double(bx) + 0.5) * kBlock / double(w) - 0.5) * 2.0 * kPi + double(rotation_);
    block_column_trig_[size_t(bx)] = Vec2(float(std::sin(phi)), float(std::cos(phi)));
  }
  const double radius = 0.5 * (kPi * kBlock / double(h) + 2.0 * kPi * kBlock / double(w));
  below_cos_ = radius < 0.5 * kPi ? float(-std::sin(radius) - 1e-3) : -2.0f;

  // Each block's inversion tables, and each texel's pdf over the map's unit
  // square from exactly the probabilities sampling uses: the block's pmf
  // (CompactDistribution2D), then the row's and the column's share as the float
  // tables give them. A block of weight 0 (the coarse table never picks it
  // unless the whole map is black) gets uniform tables.
  blocks_.resize(size_t(blocks_w_) * blocks_h_);
  const double texel_area_inv = double(w) * double(h);  // uv area of a texel: 1 / (w h)
  for (int by = 0; by < blocks_h_; ++by)
    for (int bx = 0; bx < blocks_w_; ++bx) {
      const size_t cell = size_t(by) * blocks_w_ + bx;
      Block& b = blocks_[cell];
      double row_w[kBlock] = {0, 0, 0, 0}, col_w[kBlock][kBlock];
      for (int y = 0; y < kBlock; ++y)
        for (int x = 0; x < kBlock; ++x) {
          col_w[y][x] = weight(bx * kBlock + x, by * kBlock + y);
          row_w[y] += col_w[y][x];
        }
      // Cumulative shares as floats; the probability of entry k is then
      // cdf[k] - cdf[k - 1] in float, which is what inversion delivers.
      auto fill = [](const double* wts, float* cdf, float* prob) {
        double total = 0;
        for (int k = 0; k < kBlock; ++k) total += wts[k];
        double run = 0;
        float prev = 0.0f;
        for (int k = 0; k < kBlock; ++k) {
          run += wts[k];
          const float c = k == kBlock - 1 ? 1.0f
                          : total > 0     ? float(std::min(1.0, run / total))
                                          : float(k + 1) / float(kBlock);
          if (k < kBlock - 1) cdf[k] = c;
          prob[k] = c - prev;
          prev = c;
        }
      };
      float row_p[kBlock], col_p[kBlock][kBlock];
      fill(row_w, b.row_cdf, row_p);
      for (int y = 0; y < kBlock; ++y) fill(col_w[y], b.column_cdf[y], col_p[y]);
      b.unused = 0;
      const double block_p = block_distribution_.pmf(cell);
      for (int y = 0; y < kBlock; ++y)
        for (int x = 0; x < kBlock; ++x) {
          const int tx = bx * kBlock + x, ty = by * kBlock + y;
          Texel& t = b.texel[y * kBlock + x];
          if (tx >= w || ty >= h) {
            t = {0, 0, 0, 0};
            continue;
          }
          const float* rgb = &image.rgb[(size_t(ty) * w + tx) * 3];
          const double p = block_p * double(row_p[y]) * double(col_p[y][x]) * texel_area_inv;
          t = {rgb[0], rgb[1], rgb[2], float(p)};
        }
    }
}

Environment::Choice Environment::choose(Vec2 u, Vec3 n) const {
  Choice c;
  c.u = u;
  if (blocks_.empty()) return c;
  c.block = uint32_t(block_distribution_.sample_discrete(u, &c.r));
  // The centre's cosine with n, for a unit n only (anything else: not below).
  const float n2 = dot(n, n);
  if (n2 > 0.999f && n2 < 1.001f) {
    const Vec2 t = block_row_trig_[c.block / uint32_t(blocks_w_)];
    const Vec2 p = block_column_trig_[c.block % uint32_t(blocks_w_)];
    const Vec3 centre(t.x * p.x, t.y, -t.x * p.y);
    c.below = dot(centre, n) < below_cos_;
  }
  if (!c.below) {
    const char* b = reinterpret_cast<const char*>(&blocks_[c.block]);
    for (size_t line = 0; line < sizeof(Block); line += 64) __builtin_prefetch(b + line);
  }
  return c;
}

Environment::Located Environment::locate(Vec3 dir) const {
  Located at;
  if (blocks_.empty()) return at;
  const Vec2 uv = dir_to_uv(dir);
  const int x = std::clamp(int(uv.x * float(width_)), 0, width_ - 1);
  const int y = std::clamp(int(uv.y * float(height_)), 0, height_ - 1);
  at.texel = &texel(x, y);
  __builtin_prefetch(at.texel);
  return at;
}

#ifdef DOFARM_HAVE_AVX2_KERNELS
namespace {

// std::clamp(int(c * n), 0, n - 1) in lanes.
DOFARM_AVX2 inline __m256i texel_index8(__m256 c, int n) {
  const __m256i i = _mm256_cvttps_epi32(mul8(c, k8(float(n))));
  return _mm256_min_epi32(_mm256_max_epi32(i, _mm256_setzero_si256()), _mm256_set1_epi32(n - 1));
}

// locate()'s texel coordinates of eight directions (x, y, z in turn, eight
// floats each): dir_to_uv() in lanes, then the scaling and clamping.
DOFARM_AVX2 void texel_coords8(const float* d, float rotation, int width, int height, int32_t* xs,
                               int32_t* ys) {
  const __m256 x = _mm256_load_ps(d), y = _mm256_load_ps(d + 8), z = _mm256_load_ps(d + 16);
  const __m256 theta = atan2_8(_mm256_sqrt_ps(add8(mul8(x, x), mul8(z, z))), y);
  const __m256 phi =
      _mm256_sub_ps(atan2_8(x, _mm256_xor_ps(z, _mm256_set1_ps(-0.0f))), k8(rotation));
  __m256 u = add8(_mm256_div_ps(phi, k8(kTwoPi)), k8(0.5f));
  u = _mm256_sub_ps(u, _mm256_floor_ps(u));
  const __m256 v = mul8(theta, k8(kInvPi));
  _mm256_store_si256(reinterpret_cast<__m256i*>(xs), texel_index8(u, width));
  _mm256_store_si256(reinterpret_cast<__m256i*>(ys), texel_index8(v, height));
}

}  // namespace
#endif

void Environment::locate(const Vec3* dirs, int n, Located* out) const {
  if (blocks_.empty()) {
    for (int k = 0; k < n; ++k) out[k] = Located();
    return;
  }
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (n > 1 && use_simd()) {
    for (int first = 0; first < n; first += 8) {
      const int m = std::min(8, n - first);
      alignas(32) float d[24];
      for (int k = 0; k < 8; ++k) {  // lanes past m repeat the last direction
        const Vec3 v = dirs[first + std::min(k, m - 1)];
        d[k] = v.x;
        d[8 + k] = v.y;
        d[16 + k] = v.z;
      }
      alignas(32) int32_t xs[8], ys[8];
      texel_coords8(d, rotation_, width_, height_, xs, ys);
      for (int k = 0; k < m; ++k) {
        out[first + k].texel = &texel(xs[k], ys[k]);
        __builtin_prefetch(out[first + k].texel);
      }
    }
    return;
  }
#endif
  for (int k = 0; k < n; ++k) out[k] = locate(dirs[k]);
}

Vec2 Environment::dir_to_uv(Vec3 d) const {
  // atan2 rather than acos(d.y): well conditioned at the poles too, where
  // the pdf's 1 / sin(theta) magnifies any error in theta.
  float theta = precise_atan2(std::sqrt(d.x * d.x + d.z * d.z), d.y);
  float phi = precise_atan2(d.x, -d.z) - rotation_;
  float u = phi / kTwoPi + 0.5f;
  u -= std::floor(u);
  return {u, theta * kInvPi};
}

Vec3 Environment::uv_to_dir(Vec2 uv) const {
  float theta = uv.y * kPi, phi = (uv.x - 0.5f) * kTwoPi + rotation_;
  float st, ct, sp, cp;
  precise_sincos(theta, &st, &ct);
  precise_sincos(phi, &sp, &cp);
  return {st * sp, ct, -st * cp};
}

Vec3 Environment::eval(Vec3 dir) const { return eval(locate(dir)); }

Vec3 Environment::eval(const Located& at) const {
  if (!at.texel) return constant_;
  return {at.texel->r, at.texel->g, at.texel->b};
}

Vec3 Environment::eval(Vec3 dir, float* pdf_out) const { return eval(locate(dir), dir, pdf_out); }

Vec3 Environment::eval(const Located& at, Vec3 dir, float* pdf_out) const {
  if (!at.texel) {
    *pdf_out = 1.0f / (4.0f * kPi);
    return constant_;
  }
  const Texel& t = *at.texel;
  const float r = std::sqrt(dir.x * dir.x + dir.z * dir.z);
  const float sin_theta = r / std::sqrt(r * r + dir.y * dir.y);
  *pdf_out = !(sin_theta > 0) ? 0.0f : t.pdf_uv / (2.0f * kPi * kPi * sin_theta);
  return {t.r, t.g, t.b};
}

EnvSample Environment::sample(const Choice& choice) const {
  const Vec2 u = choice.u;
  if (blocks_.empty()) {  // uniform sphere
    EnvSample s;
    float z = 1.0f - 2.0f * u.x, r = safe_sqrt(1.0f - z * z), phi = kTwoPi * u.y;
    s.wi = Vec3(r * std::cos(phi), z, r * std::sin(phi));
    s.radiance = constant_;
    s.pdf = 1.0f / (4.0f * kPi);
    return s;
  }
  const Picked p = pick(choice);
  if (!p.texel) return EnvSample();
  return finish(p, uv_to_dir(p.uv));
}

Environment::Picked Environment::pick(const Choice& choice) const {
  // The block (choose()), then its row and column by inversion, each step
  // passing on its number rescaled to [0, 1) within the chosen entry.
  Vec2 r = choice.r;
  const size_t cell = choice.block;
  const Block& b = blocks_[cell];
  auto pick_entry = [](const float* cdf, float* v) {
    // Entries of probability 0 have equal bounds and are never picked.
    const int k = int(*v >= cdf[0]) + int(*v >= cdf[1]) + int(*v >= cdf[2]);
    const float lo = k > 0 ? cdf[k - 1] : 0.0f, hi = k < kBlock - 1 ? cdf[k] : 1.0f;
    *v = hi > lo ? std::clamp((*v - lo) / (hi - lo), 0.0f, 0x1.fffffep-1f) : 0.5f;
    return k;
  };
  const int row = pick_entry(b.row_cdf, &r.y);
  const int column = pick_entry(b.column_cdf[row], &r.x);
  const Texel& t = b.texel[row * kBlock + column];
  const int x = int(cell % size_t(blocks_w_)) * kBlock + column;
  const int y = int(cell / size_t(blocks_w_)) * kBlock + row;
  Picked p;
  if (!(t.pdf_uv > 0) || x >= width_ || y >= height_) return p;  // pdf 0: the caller skips it
  p.texel = &t;
  p.uv = Vec2((float(x) + r.x) / float(width_), (float(y) + r.y) / float(height_));
  return p;
}

EnvSample Environment::finish(const Picked& p, Vec3 wi) const {
  EnvSample s;
  s.wi = wi;
  // sin(theta) as uv_to_dir() has it: the length of the direction's xz part.
  const float sin_theta = std::sqrt(s.wi.x * s.wi.x + s.wi.z * s.wi.z);
  if (!(sin_theta > 0)) return s;
  const Texel& t = *p.texel;
  s.radiance = Vec3(t.r, t.g, t.b);
  s.pdf = t.pdf_uv / (2.0f * kPi * kPi * sin_theta);
  return s;
}

#ifdef DOFARM_HAVE_AVX2_KERNELS
namespace {

// uv_to_dir() of eight points (u, then v, eight floats each) in lanes;
// the directions' x, y, z in turn.
DOFARM_AVX2 void directions8(const float* uv, float rotation, float* d) {
  const __m256 u = _mm256_load_ps(uv), v = _mm256_load_ps(uv + 8);
  const __m256 theta = mul8(v, k8(kPi));
  const __m256 phi = add8(mul8(_mm256_sub_ps(u, k8(0.5f)), k8(kTwoPi)), k8(rotation));
  __m256 st, ct, sp, cp;
  sincos8(theta, &st, &ct);
  sincos8(phi, &sp, &cp);
  _mm256_store_ps(d, mul8(st, sp));
  _mm256_store_ps(d + 8, ct);
  _mm256_store_ps(d + 16, mul8(_mm256_xor_ps(st, _mm256_set1_ps(-0.0f)), cp));
}

}  // namespace
#endif

void Environment::sample(const Choice* choices, int n, EnvSample* out) const {
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (!blocks_.empty() && n > 1 && use_simd()) {
    for (int first = 0; first < n; first += 8) {
      const int m = std::min(8, n - first);
      Picked picked[8];
      alignas(32) float uv[16] = {}, d[24];
      for (int k = 0; k < m; ++k) {
        picked[k] = pick(choices[first + k]);
        uv[k] = picked[k].uv.x;
        uv[8 + k] = picked[k].uv.y;
      }
      directions8(uv, rotation_, d);
      for (int k = 0; k < m; ++k)
        out[first + k] =
            picked[k].texel ? finish(picked[k], Vec3(d[k], d[8 + k], d[16 + k])) : EnvSample();
    }
    return;
  }
#endif
  for (int k = 0; k < n; ++k) out[k] = sample(choices[k]);
}

float Environment::pdf(Vec3 dir) const {
  float p;
  eval(dir, &p);
  return p;
}

}  // namespace dofarm::render
