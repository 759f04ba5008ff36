// Distant environment light: an equirectangular HDR map (or a constant
// colour) with importance sampling proportional to luminance * sin(theta)
// (pbrt-v3 section 14.2.4). Lookups are nearest-texel, the exact function the
// sampling distribution describes, so MIS weights and pdfs agree exactly.
//
// Mapping: +y is up; theta = acos(d.y) from the zenith; phi = atan2(d.x, -d.z),
// so the map's centre column (u = 0.5) is seen looking down -z; `rotation`
// turns the map about +y.
#pragma once

#include <memory>
#include <vector>

#include "common/exr_io.h"
#include "common/jobspec.h"
#include "common/math.h"
#include "worker/render/distribution.h"

namespace dofarm::render {

struct EnvSample {
  Vec3 wi;  // direction towards the environment
  Vec3 radiance;
  float pdf = 0;  // solid angle
};

class Environment {
 public:
  // Loads the map (RuntimeError naming the file on failure).
  static std::unique_ptr<Environment> from_spec(const EnvironmentSpec& spec);
  Environment(RgbImage image, float intensity, float rotation_deg);
  explicit Environment(Vec3 constant_radiance);

  Vec3 eval(Vec3 dir) const;
  EnvSample sample(Vec2 u) const;
  // A hint: starts loading what sample(u) will read first (the map's tables
  // are larger than the caches; a caller with other work to do before it
  // samples can hide that wait).
  void prefetch_sample(Vec2 u) const {
    if (!texels_.empty()) distribution_.prefetch(u);
  }
  float pdf(Vec3 dir) const;
  // eval() and pdf() at once, from one direction-to-texel mapping and one
  // memory access (an escaped ray under MIS needs both).
  Vec3 eval(Vec3 dir, float* pdf) const;
  // Mean radiance luminance over the sphere (for light selection by power).
  float mean_luminance() const { return mean_luminance_; }
  bool is_black() const { return mean_luminance_ <= 0; }

 private:
  Vec2 dir_to_uv(Vec3 d) const;
  Vec3 uv_to_dir(Vec2 uv) const;
  // Radiance and the sampling pdf over the unit square of one texel, side
  // by side: one cache line serves both.
  struct Texel {
    float r, g, b;
    float pdf_uv;
  };
  const Texel& texel(Vec2 uv) const;

  int width_ = 0, height_ = 0;
  std::vector<Texel> texels_;  // row 0 = top; empty for a constant environment
  Vec3 constant_{0};
  float rotation_ = 0;  // radians
  Distribution2D distribution_;
  float mean_luminance_ = 0;
};

}  // namespace dofarm::render
