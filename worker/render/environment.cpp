#include "worker/render/environment.h"

#include <cmath>

namespace dofarm::render {

std::unique_ptr<Environment> Environment::from_spec(const EnvironmentSpec& spec) {
  if (spec.color) return std::make_unique<Environment>(*spec.color * spec.intensity);
  return std::make_unique<Environment>(load_rgb_image(spec.map, /*srgb=*/true), spec.intensity,
                                       spec.rotation_deg);
}

Environment::Environment(Vec3 c) : constant_(c) {
  if (!is_finite(c) || c.x < 0 || c.y < 0 || c.z < 0) constant_ = Vec3(0);
  mean_luminance_ = luminance(constant_);
}

Environment::Environment(RgbImage image, float intensity, float rotation_deg)
    : image_(std::move(image)), rotation_(rotation_deg * kPi / 180.0f) {
  const int w = image_.width, h = image_.height;
  std::vector<float> weights(size_t(w) * h);
  double sum = 0, solid_angle = 0;
  for (int y = 0; y < h; ++y) {
    float sin_theta = std::sin(kPi * (float(y) + 0.5f) / float(h));
    for (int x = 0; x < w; ++x) {
      float* t = &image_.rgb[(size_t(y) * w + x) * 3];
      for (int c = 0; c < 3; ++c) {
        float v = t[c] * intensity;
        t[c] = std::isfinite(v) && v > 0 ? v : 0.0f;  // no NaN, Inf or negative light
      }
      float lum = luminance(Vec3(t[0], t[1], t[2]));
      weights[size_t(y) * w + x] = lum * sin_theta;
      sum += double(lum) * sin_theta;
      solid_angle += sin_theta;
    }
  }
  mean_luminance_ = solid_angle > 0 ? float(sum / solid_angle) : 0.0f;
  distribution_ = Distribution2D(weights, w, h);
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

Vec3 Environment::texel(Vec2 uv) const {
  int x = std::clamp(int(uv.x * float(image_.width)), 0, image_.width - 1);
  int y = std::clamp(int(uv.y * float(image_.height)), 0, image_.height - 1);
  const float* t = &image_.rgb[(size_t(y) * image_.width + x) * 3];
  return {t[0], t[1], t[2]};
}

Vec3 Environment::eval(Vec3 dir) const {
  if (image_.rgb.empty()) return constant_;
  return texel(dir_to_uv(dir));
}

EnvSample Environment::sample(Vec2 u) const {
  EnvSample s;
  if (image_.rgb.empty()) {  // uniform sphere
    float z = 1.0f - 2.0f * u.x, r = safe_sqrt(1.0f - z * z), phi = kTwoPi * u.y;
    s.wi = Vec3(r * std::cos(phi), z, r * std::sin(phi));
    s.radiance = constant_;
    s.pdf = 1.0f / (4.0f * kPi);
    return s;
  }
  float pdf_uv;
  Vec2 uv = distribution_.sample(u, &pdf_uv);
  float sin_theta = std::sin(uv.y * kPi);
  if (pdf_uv <= 0 || sin_theta <= 0) return s;  // pdf 0: the caller skips it
  s.wi = uv_to_dir(uv);
  s.radiance = texel(uv);
  s.pdf = pdf_uv / (2.0f * kPi * kPi * sin_theta);
  return s;
}

float Environment::pdf(Vec3 dir) const {
  if (image_.rgb.empty()) return 1.0f / (4.0f * kPi);
  Vec2 uv = dir_to_uv(dir);
  float sin_theta = std::sin(uv.y * kPi);
  if (sin_theta <= 0) return 0;
  return distribution_.pdf(uv) / (2.0f * kPi * kPi * sin_theta);
}

}  // namespace dofarm::render
