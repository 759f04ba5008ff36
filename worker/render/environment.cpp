#include "worker/render/environment.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "common/error.h"

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
  distribution_ = Distribution2D(weights, w, h);
  // The pdf is constant over a texel: Distribution2D::pdf at its centre is the
  // value it gives anywhere inside it.
  texels_.resize(size_t(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const size_t i = size_t(y) * w + x;
      const Vec2 centre((float(x) + 0.5f) / float(w), (float(y) + 0.5f) / float(h));
      texels_[i] = {image.rgb[i * 3], image.rgb[i * 3 + 1], image.rgb[i * 3 + 2],
                    distribution_.pdf(centre)};
    }
}

Vec2 Environment::dir_to_uv(Vec3 d) const {
  float theta = std::acos(std::clamp(d.y, -1.0f, 1.0f));
  float phi = std::atan2(d.x, -d.z) - rotation_;
  float u = phi / kTwoPi + 0.5f;
  u -= std::floor(u);
  return {u, theta * kInvPi};
}

Vec3 Environment::uv_to_dir(Vec2 uv) const {
  float theta = uv.y * kPi, phi = (uv.x - 0.5f) * kTwoPi + rotation_;
  float st = std::sin(theta);
  return {st * std::sin(phi), std::cos(theta), -st * std::cos(phi)};
}

const Environment::Texel& Environment::texel(Vec2 uv) const {
  int x = std::clamp(int(uv.x * float(width_)), 0, width_ - 1);
  int y = std::clamp(int(uv.y * float(height_)), 0, height_ - 1);
  return texels_[size_t(y) * width_ + x];
}

Vec3 Environment::eval(Vec3 dir) const {
  if (texels_.empty()) return constant_;
  const Texel& t = texel(dir_to_uv(dir));
  return {t.r, t.g, t.b};
}

Vec3 Environment::eval(Vec3 dir, float* pdf_out) const {
  if (texels_.empty()) {
    *pdf_out = 1.0f / (4.0f * kPi);
    return constant_;
  }
  const Vec2 uv = dir_to_uv(dir);
  const Texel& t = texel(uv);
  const float sin_theta = std::sin(uv.y * kPi);
  *pdf_out = sin_theta <= 0 ? 0.0f : t.pdf_uv / (2.0f * kPi * kPi * sin_theta);
  return {t.r, t.g, t.b};
}

EnvSample Environment::sample(Vec2 u) const {
  EnvSample s;
  if (texels_.empty()) {  // uniform sphere
    float z = 1.0f - 2.0f * u.x, r = safe_sqrt(1.0f - z * z), phi = kTwoPi * u.y;
    s.wi = Vec3(r * std::cos(phi), z, r * std::sin(phi));
    s.radiance = constant_;
    s.pdf = 1.0f / (4.0f * kPi);
    return s;
  }
  float pdf_uv;
  size_t cell;
  Vec2 uv = distribution_.sample(u, &pdf_uv, &cell);
  float sin_theta = std::sin(uv.y * kPi);
  if (pdf_uv <= 0 || sin_theta <= 0) return s;  // pdf 0: the caller skips it
  s.wi = uv_to_dir(uv);
  // The texel of the sampled cell, by index rather than through uv: the
  // same texel, and its load need not wait for uv (sampling waits on memory).
  const Texel& t = texels_[cell];
  s.radiance = Vec3(t.r, t.g, t.b);
  s.pdf = pdf_uv / (2.0f * kPi * kPi * sin_theta);
  return s;
}

float Environment::pdf(Vec3 dir) const {
  float p;
  eval(dir, &p);
  return p;
}

}  // namespace dofarm::render
