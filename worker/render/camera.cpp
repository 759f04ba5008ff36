#include "worker/render/camera.h"

#include <fmt/format.h>

#include <algorithm>
#include <cfloat>
#include <cmath>

#include "common/error.h"
#include "common/thin_lens.h"
#include "worker/render/scene_motion.h"
#include "worker/render/simd.h"
#include "worker/render/trig.h"
#include "worker/render/trig8.h"

namespace dofarm::render {

namespace {
Quat to_quat(const float r[4]) { return {r[0], r[1], r[2], r[3]}; }
Quat conjugate(Quat q) { return {q.w, -q.x, -q.y, -q.z}; }
}  // namespace

Camera::Camera(const CameraState& s, int width, int height, CameraClip clip)
    : state_(s), clip_(clip), width_(width), height_(height) {
  rotation_ = to_quat(s.rotation);
  inverse_rotation_ = conjugate(rotation_);
  position_ = Vec3(s.position[0], s.position[1], s.position[2]);
  tan_half_fov_ = std::tan(0.5f * s.fov_deg * kPi / 180.0f);
  aspect_ = float(width) / float(height);
  if (s.orthographic()) ortho_half_height_ = 0.5f * s.ortho_height;
}

Vec3 Camera::film_point(Vec2 film) const {
  float sx = (2.0f * film.x / float(width_) - 1.0f) * ortho_half_height_ * aspect_;
  float sy = (1.0f - 2.0f * film.y / float(height_)) * ortho_half_height_;
  return {sx, sy, -clip_.near};
}

Ray Camera::ortho_clipped(Ray ray, Vec3 view_dir) const {
  // The ray leaves the near plane; its view depth grows by cos_axis per
  // unit of t from there.
  if (std::isfinite(clip_.far)) {
    const float cos_axis = -view_dir.z / length(view_dir);
    ray.t_max = (clip_.far - clip_.near) / cos_axis;
    if (!(ray.t_max >= 0)) ray.t_max = std::numeric_limits<float>::infinity();
  }
  return ray;
}

Vec3 Camera::film_direction(Vec2 film) const {
  float sx = (2.0f * film.x / float(width_) - 1.0f) * tan_half_fov_ * aspect_;
  float sy = (1.0f - 2.0f * film.y / float(height_)) * tan_half_fov_;
  return {sx, sy, -1.0f};
}

Ray Camera::clipped(Ray ray, Vec3 view_dir) const {
  if (clips()) {
    // View depth grows along the ray by cos_axis per unit of t.
    const float cos_axis = -view_dir.z / length(view_dir);
    ray.t_min = clip_.near > 0 ? clip_.near / cos_axis : 0.0f;
    ray.t_max = clip_.far / cos_axis;
    if (!(ray.t_min >= 0) || !std::isfinite(ray.t_min)) ray.t_min = 0;
    if (!(ray.t_max >= ray.t_min)) ray.t_max = std::numeric_limits<float>::infinity();
  }
  return ray;
}

Ray Camera::pinhole_ray(Vec2 film) const {
  if (ortho_half_height_ > 0) {
    const Vec3 axis(0.0f, 0.0f, -1.0f);
    return ortho_clipped({position_ + rotation_.rotate(film_point(film)), rotation_.rotate(axis)},
                         axis);
  }
  const Vec3 fd = film_direction(film);
  return clipped({position_, normalize(rotation_.rotate(fd))}, fd);
}

Ray Camera::generate_ray(Vec2 film, Vec2 lens) const {
  if (!has_lens()) return pinhole_ray(film);  // bit-identical to the pinhole
  if (ortho_half_height_ > 0) {
    // The lens point d beside the film point looks at the film point's
    // place on the focal plane S beyond the lens plane: direction (-d, -S).
    // The lens plane is the near clipping plane, as Cycles has it (its
    // rays leave Clip Start, and its Focus Distance counts from there;
    // bench/README.md, "Orthographic cameras").
    const Vec2 d = sample_concentric_disk(lens) * state_.aperture;
    const Vec3 origin = film_point(film) + Vec3(d.x, d.y, 0.0f);
    Vec3 dir(-d.x, -d.y, -state_.focal_distance);
    const float len2 = dot(dir, dir);
    if (!(len2 >= FLT_MIN && len2 <= FLT_MAX)) {
      const double v[3] = {-double(d.x), -double(d.y), -double(state_.focal_distance)};
      const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      dir = len > 0 ? Vec3(float(v[0] / len), float(v[1] / len), float(v[2] / len))
                    : Vec3(0.0f, 0.0f, -1.0f);
    }
    return ortho_clipped({position_ + rotation_.rotate(origin), normalize(rotation_.rotate(dir))},
                         dir);
  }
  const Vec3 fd = film_direction(film);
  Vec3 focus = fd * state_.focal_distance;  // on the plane z = -S
  Vec2 d = sample_concentric_disk(lens) * state_.aperture;
  Vec3 origin(d.x, d.y, 0.0f);
  Vec3 dir = focus - origin;
  // An extreme focus distance or lens (S = 1e-38) can make the float vector
  // underflow to zero or overflow; the same direction in double stays exact
  // enough to normalise.
  const float len2 = dot(dir, dir);
  if (!(len2 >= FLT_MIN && len2 <= FLT_MAX)) {
    const double S = state_.focal_distance;
    const double v[3] = {double(fd.x) * S - d.x, double(fd.y) * S - d.y, double(fd.z) * S};
    const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    dir = len > 0 ? Vec3(float(v[0] / len), float(v[1] / len), float(v[2] / len)) : fd;
  }
  // A rotation keeps lengths: one normalisation, after it, is enough.
  return clipped({position_ + rotation_.rotate(origin), normalize(rotation_.rotate(dir))}, dir);
}

namespace {

#ifdef DOFARM_HAVE_AVX2_KERNELS
// A perspective camera with a lens, as generate_rays() needs it.
struct LensCamera {
  float width, height, tan_half_fov, aspect, focal_distance, aperture;
  Quat rotation;
  Vec3 position;
  bool clip;
  float near, far;
};

// cross() in lanes (V3x8, dot8: trig8.h).
DOFARM_AVX2 inline V3x8 cross8(V3x8 a, V3x8 b) {
  return {_mm256_sub_ps(_mm256_mul_ps(a.y, b.z), _mm256_mul_ps(a.z, b.y)),
          _mm256_sub_ps(_mm256_mul_ps(a.z, b.x), _mm256_mul_ps(a.x, b.z)),
          _mm256_sub_ps(_mm256_mul_ps(a.x, b.y), _mm256_mul_ps(a.y, b.x))};
}
// Quat::rotate: v + t w + cross(u, t), t = 2 cross(u, v).
DOFARM_AVX2 inline V3x8 rotate8(const Quat& q, V3x8 v) {
  const V3x8 u{_mm256_set1_ps(q.x), _mm256_set1_ps(q.y), _mm256_set1_ps(q.z)};
  const __m256 two = _mm256_set1_ps(2.0f), w = _mm256_set1_ps(q.w);
  V3x8 t = cross8(u, v);
  t = {_mm256_mul_ps(t.x, two), _mm256_mul_ps(t.y, two), _mm256_mul_ps(t.z, two)};
  const V3x8 c = cross8(u, t);
  return {_mm256_add_ps(_mm256_add_ps(v.x, _mm256_mul_ps(t.x, w)), c.x),
          _mm256_add_ps(_mm256_add_ps(v.y, _mm256_mul_ps(t.y, w)), c.y),
          _mm256_add_ps(_mm256_add_ps(v.z, _mm256_mul_ps(t.z, w)), c.z)};
}
// generate_ray() of a perspective lens camera in eight lanes; returns the
// lanes whose rays are complete (bit k set), the others need
// generate_ray()'s fallbacks (a direction that under- or overflows).
DOFARM_AVX2 int lens_rays_avx2(const LensCamera& cam, const float* in, float* out) {
  const __m256 fx = _mm256_load_ps(in), fy = _mm256_load_ps(in + 8), ux = _mm256_load_ps(in + 16),
               uy = _mm256_load_ps(in + 24);
  const __m256 one = _mm256_set1_ps(1.0f), two = _mm256_set1_ps(2.0f);
  const __m256 zero = _mm256_setzero_ps(), S = _mm256_set1_ps(cam.focal_distance);
  // film_direction(), times the focal distance.
  const __m256 tan = _mm256_set1_ps(cam.tan_half_fov);
  const __m256 sx = _mm256_mul_ps(
      _mm256_mul_ps(
          _mm256_sub_ps(_mm256_div_ps(_mm256_mul_ps(two, fx), _mm256_set1_ps(cam.width)), one),
          tan),
      _mm256_set1_ps(cam.aspect));
  const __m256 sy = _mm256_mul_ps(
      _mm256_sub_ps(one, _mm256_div_ps(_mm256_mul_ps(two, fy), _mm256_set1_ps(cam.height))), tan);
  const V3x8 focus{_mm256_mul_ps(sx, S), _mm256_mul_ps(sy, S),
                   _mm256_mul_ps(_mm256_set1_ps(-1.0f), S)};
  // sample_concentric_disk(), times the aperture.
  const __m256 ox = _mm256_sub_ps(_mm256_mul_ps(two, ux), one);
  const __m256 oy = _mm256_sub_ps(_mm256_mul_ps(two, uy), one);
  const __m256 centre =
      _mm256_and_ps(_mm256_cmp_ps(ox, zero, _CMP_EQ_OQ), _mm256_cmp_ps(oy, zero, _CMP_EQ_OQ));
  const __m256 abs_mask = _mm256_set1_ps(-0.0f);
  const __m256 x_major =
      _mm256_cmp_ps(_mm256_andnot_ps(abs_mask, ox), _mm256_andnot_ps(abs_mask, oy), _CMP_GT_OQ);
  const __m256 r = _mm256_blendv_ps(oy, ox, x_major);
  const __m256 quarter_pi = _mm256_set1_ps(kPi / 4.0f);
  const __m256 theta = _mm256_blendv_ps(
      _mm256_sub_ps(_mm256_set1_ps(kPi / 2.0f), _mm256_mul_ps(quarter_pi, _mm256_div_ps(ox, oy))),
      _mm256_mul_ps(quarter_pi, _mm256_div_ps(oy, ox)), x_major);
  __m256 s, c;
  sincos8(theta, &s, &c);
  const __m256 aperture = _mm256_set1_ps(cam.aperture);
  const __m256 dx = _mm256_mul_ps(_mm256_blendv_ps(_mm256_mul_ps(r, c), zero, centre), aperture);
  const __m256 dy = _mm256_mul_ps(_mm256_blendv_ps(_mm256_mul_ps(r, s), zero, centre), aperture);
  // The ray from the lens point towards the focus point.
  const V3x8 origin{dx, dy, zero};
  const V3x8 dir{_mm256_sub_ps(focus.x, dx), _mm256_sub_ps(focus.y, dy),
                 _mm256_sub_ps(focus.z, zero)};
  const __m256 len2 = dot8(dir, dir);
  __m256 ok = _mm256_and_ps(_mm256_cmp_ps(len2, _mm256_set1_ps(FLT_MIN), _CMP_GE_OQ),
                            _mm256_cmp_ps(len2, _mm256_set1_ps(FLT_MAX), _CMP_LE_OQ));
  const V3x8 o = rotate8(cam.rotation, origin);
  const V3x8 d = rotate8(cam.rotation, dir);
  const __m256 l2 = dot8(d, d);
  ok = _mm256_and_ps(ok, _mm256_and_ps(_mm256_cmp_ps(l2, zero, _CMP_GT_OQ), is_finite8(l2)));
  const __m256 len = _mm256_sqrt_ps(l2);
  _mm256_store_ps(out, _mm256_add_ps(_mm256_set1_ps(cam.position.x), o.x));
  _mm256_store_ps(out + 8, _mm256_add_ps(_mm256_set1_ps(cam.position.y), o.y));
  _mm256_store_ps(out + 16, _mm256_add_ps(_mm256_set1_ps(cam.position.z), o.z));
  _mm256_store_ps(out + 24, _mm256_div_ps(d.x, len));
  _mm256_store_ps(out + 32, _mm256_div_ps(d.y, len));
  _mm256_store_ps(out + 40, _mm256_div_ps(d.z, len));
  // clipped(): the view depths between the planes.
  __m256 t_min = zero, t_max = _mm256_set1_ps(std::numeric_limits<float>::infinity());
  if (cam.clip) {
    const __m256 cos_axis = _mm256_div_ps(_mm256_xor_ps(dir.z, abs_mask), _mm256_sqrt_ps(len2));
    if (cam.near > 0) t_min = _mm256_div_ps(_mm256_set1_ps(cam.near), cos_axis);
    t_max = _mm256_div_ps(_mm256_set1_ps(cam.far), cos_axis);
    const __m256 keep_min =
        _mm256_and_ps(_mm256_cmp_ps(t_min, zero, _CMP_GE_OQ), is_finite8(t_min));
    t_min = _mm256_and_ps(t_min, keep_min);  // else 0
    t_max = _mm256_blendv_ps(_mm256_set1_ps(std::numeric_limits<float>::infinity()), t_max,
                             _mm256_cmp_ps(t_max, t_min, _CMP_GE_OQ));
  }
  _mm256_store_ps(out + 48, t_min);
  _mm256_store_ps(out + 56, t_max);
  return _mm256_movemask_ps(ok);
}
#endif

}  // namespace

void Camera::generate_rays(const Vec2* film, const Vec2* lens, int n, Ray* out) const {
#ifdef DOFARM_HAVE_AVX2_KERNELS
  if (n >= 1 && n <= 8 && has_lens() && !(ortho_half_height_ > 0) && use_simd()) {
    const LensCamera cam{
        float(width_),   float(height_), tan_half_fov_, aspect_, state_.focal_distance,
        state_.aperture, rotation_,      position_,     clips(), clip_.near,
        clip_.far};
    alignas(32) float in[32], rays[64];
    for (int k = 0; k < 8; ++k) {  // lanes past n repeat the first point
      const int j = k < n ? k : 0;
      in[k] = film[j].x;
      in[8 + k] = film[j].y;
      in[16 + k] = lens[j].x;
      in[24 + k] = lens[j].y;
    }
    const int complete = lens_rays_avx2(cam, in, rays);
    for (int k = 0; k < n; ++k) {
      if (!((complete >> k) & 1)) {
        out[k] = generate_ray(film[k], lens[k]);
        continue;
      }
      out[k].o = Vec3(rays[k], rays[8 + k], rays[16 + k]);
      out[k].d = Vec3(rays[24 + k], rays[32 + k], rays[40 + k]);
      out[k].t_min = rays[48 + k];
      out[k].t_max = rays[56 + k];
    }
    return;
  }
#endif
  for (int k = 0; k < n; ++k) out[k] = generate_ray(film[k], lens[k]);
}

float Camera::coc_pixels(float z) const {
  if (ortho_half_height_ > 0) {
    if (!(z > 0) && std::isfinite(clip_.far)) z = clip_.far;
    // Depths from the lens plane (the near clipping plane).
    return ortho_coc_diameter_pixels(state_.aperture, state_.focal_distance, state_.ortho_height,
                                     height_, z > 0 ? std::max(z - clip_.near, FLT_MIN) : z);
  }
  return coc_diameter_pixels(state_.aperture, state_.focal_distance, tan_half_fov_, height_, z);
}

float Camera::view_depth(Vec3 p) const { return -to_view(p - position_).z; }

Vec3 Camera::to_view(Vec3 w) const { return inverse_rotation_.rotate(w); }

Vec2 sample_concentric_disk(Vec2 u) {
  float ox = 2.0f * u.x - 1.0f, oy = 2.0f * u.y - 1.0f;
  if (ox == 0 && oy == 0) return {0, 0};
  float r, theta;
  if (std::fabs(ox) > std::fabs(oy)) {
    r = ox;
    theta = (kPi / 4.0f) * (oy / ox);
  } else {
    r = oy;
    theta = kPi / 2.0f - (kPi / 4.0f) * (ox / oy);
  }
  float s, c;
  precise_sincos(theta, &s, &c);
  return {r * c, r * s};
}

namespace {

// Index of the last key at or before `t` and the blend weight to the next.
template <typename T, typename Time>
void bracket(const std::vector<T>& keys, float t, Time time_of, size_t* i0, size_t* i1, float* w) {
  *i0 = 0;
  *i1 = 0;
  *w = 0;
  if (keys.empty()) return;
  if (t <= time_of(keys.front())) return;
  if (t >= time_of(keys.back())) {
    *i0 = *i1 = keys.size() - 1;
    return;
  }
  size_t i = 0;
  while (i + 1 < keys.size() && time_of(keys[i + 1]) <= t) ++i;
  *i0 = i;
  *i1 = std::min(i + 1, keys.size() - 1);
  float span = time_of(keys[*i1]) - time_of(keys[i]);
  *w = span > 0 ? (t - time_of(keys[i])) / span : 0.0f;
}

Quat key_rotation(const CameraKey& k) {
  if (k.look_at) return quat_look_at(k.position, *k.look_at, k.up);
  if (k.rotation_deg) return quat_from_euler_deg(*k.rotation_deg);
  return {};
}

void store(CameraState* s, Vec3 p, Quat q) {
  s->position[0] = p.x;
  s->position[1] = p.y;
  s->position[2] = p.z;
  s->rotation[0] = q.w;
  s->rotation[1] = q.x;
  s->rotation[2] = q.y;
  s->rotation[3] = q.z;
}

}  // namespace

float fitted_vertical_fov(float yfov_deg, float camera_aspect, int width, int height) {
  if (!(camera_aspect > 0) || width <= 0 || height <= 0) return yfov_deg;
  if (describe_aspect_mismatch(camera_aspect, width, height).empty()) return yfov_deg;
  // Half-extents of the film at unit distance: (t a, t); the fov spans the
  // longer one, L, and the image's longer side gets L.
  const double t = std::tan(0.5 * double(yfov_deg) * M_PI / 180.0);
  const double longer = t * std::max(double(camera_aspect), 1.0);
  const double image_aspect = double(width) / height;
  const double tv = image_aspect >= 1 ? longer / image_aspect : longer;
  return float(2.0 * std::atan(tv) * 180.0 / M_PI);
}

float fitted_ortho_height(float ymag, float camera_aspect, int width, int height) {
  const float own = 2.0f * ymag;
  if (!(camera_aspect > 0) || width <= 0 || height <= 0) return own;
  if (describe_aspect_mismatch(camera_aspect, width, height).empty()) return own;
  // The film's half-extents (ymag a, ymag); its longer one spans the
  // image's longer side.
  const double longer = double(ymag) * std::max(double(camera_aspect), 1.0);
  const double image_aspect = double(width) / height;
  return float(2.0 * (image_aspect >= 1 ? longer / image_aspect : longer));
}

ImageSize image_size_for_aspect(float camera_aspect, int width, int height) {
  constexpr int kDefaultSide = 512;
  if (!(camera_aspect > 0))
    return {width > 0 ? width : kDefaultSide, height > 0 ? height : kDefaultSide};
  auto side = [](double v) { return int(std::max(1.0, std::min(std::round(v), 1e9))); };
  if (width > 0 && height > 0) return {width, height};
  if (width > 0) return {width, side(width / double(camera_aspect))};
  if (height > 0) return {side(height * double(camera_aspect)), height};
  if (camera_aspect >= 1) return {kDefaultSide, side(kDefaultSide / double(camera_aspect))};
  return {side(kDefaultSide * double(camera_aspect)), kDefaultSide};
}

namespace {

// "16:9" when a small ratio of integers gives `a` to 0.1%, else "1.234:1".
std::string ratio_text(double a) {
  for (int q = 1; q <= 32; ++q) {
    const double p = std::round(a * q);
    if (p >= 1 && std::fabs(p / q - a) <= 1e-3 * a) return fmt::format("{}:{}", int(p), q);
  }
  return fmt::format("{:.3f}:1", a);
}

std::string share(double f, const char* side) {
  if (std::fabs(f - 1) < 1e-4) return fmt::format("the camera's full {}", side);
  std::string pct = fmt::format("{:.0f}", f * 100);
  if (pct == "100") pct = fmt::format("{:.1f}", f * 100);
  if (f < 1) return fmt::format("the middle {}% of the camera's {}", pct, side);
  return fmt::format("{}% of the camera's {} (more than the camera frames)", pct, side);
}

}  // namespace

std::string describe_aspect_mismatch(float camera_aspect, int width, int height,
                                     bool orthographic) {
  if (!(camera_aspect > 0) || width <= 0 || height <= 0) return "";
  // The size either side derives from the other is a match: rounding to
  // whole pixels is not a crop.
  const double a = camera_aspect;
  if (std::lround(width / a) == height || std::lround(height * a) == width) return "";
  const double longer = std::max(a, 1.0), image_aspect = double(width) / height;
  const double xr = image_aspect >= 1 ? longer : longer * image_aspect;
  const double yr = image_aspect >= 1 ? longer / image_aspect : longer;
  return fmt::format(
      "the scene camera is {} but the image is {}x{} ({}): as in Blender (sensor fit auto: the "
      "{} spans the longer side), the image shows {} and {}",
      ratio_text(a), width, height, ratio_text(image_aspect),
      orthographic ? "Orthographic Scale" : "field of view", share(xr / a, "width"),
      share(yr, "height"));
}

float lens_radius(const CameraKey& key, float vertical_fov_deg, int width, int height,
                  bool orthographic) {
  if (!(key.fstop > 0)) return key.aperture;
  // Cycles (blender/camera.cpp): an orthographic camera's aperture radius
  // is 1 / (2 N); measured against Cycles in bench/README.md.
  if (orthographic) return float(std::min(1.0 / (2.0 * double(key.fstop)), double(FLT_MAX)));
  double focal_mm = key.focal_length_mm;
  if (!(focal_mm > 0)) {
    // Blender: fov = 2 atan(sensor / (2 f)) across the sensor-fitted side,
    // here the image's longer side.
    const double tv = std::tan(0.5 * double(vertical_fov_deg) * M_PI / 180.0);
    const double t_longer = tv * std::max(1.0, double(width) / height);
    focal_mm = key.sensor_width_mm / (2.0 * t_longer);
  }
  return fstop_lens_radius(focal_mm, key.fstop);
}

namespace {

// The focus distance of `key` for the frame's camera `s` (pose and fov set),
// from its lens plane at view depth `lens_plane` (an orthographic camera's
// near clipping plane, else 0).
float focus_distance(const JobSpec& spec, const CameraKey& key, const CameraState& s,
                     const Autofocus& autofocus, float lens_plane) {
  const std::string prefix = fmt::format("camera.key.{}.", key.index);
  switch (key.focus) {
    case FocusMode::kNone:
    case FocusMode::kDistance:
      return key.focal_distance;
    case FocusMode::kPoint: {
      const Quat q = conjugate(to_quat(s.rotation));
      const Vec3 p = key.focus_point - Vec3(s.position[0], s.position[1], s.position[2]);
      const float depth = -q.rotate(p).z - lens_plane;
      if (!(depth > 0) || !std::isfinite(depth)) {
        throw SpecError(
            spec.where(prefix + "focus_point"), prefix + "focus_point",
            lens_plane > 0
                ? fmt::format("the point is not beyond the orthographic camera's near clipping "
                              "plane at frame {} (view depth {:g}, the plane at {:g}): its "
                              "depth cannot be the focus distance",
                              s.frame, depth + lens_plane, lens_plane)
                : fmt::format("the point is not in front of the camera at frame {} (view "
                              "depth {:g}): its depth cannot be the focus distance",
                              s.frame, depth));
      }
      return depth;
    }
    case FocusMode::kAuto: {
      DOFARM_CHECK_OP(bool(autofocus), ==, true);
      std::optional<float> depth = autofocus(s);
      if (depth) *depth -= lens_plane;  // a camera ray starts at or beyond it
      if (!depth || !(*depth > 0) || !std::isfinite(*depth)) {
        throw SpecError(spec.where(prefix + "focus"), prefix + "focus",
                        fmt::format("autofocus at frame {}: the ray through the image centre "
                                    "hits nothing; use focal_distance or focus_point",
                                    s.frame));
      }
      return *depth;
    }
  }
  return key.focal_distance;
}

}  // namespace

std::string no_scene_camera_message(const SceneData& scene, const std::string& scene_path) {
  // Blender's glTF exporter writes the scene's cameras only with Include >
  // Cameras ticked, which Blender 3.4 leaves off.
  const bool blender_without_any = scene.camera_refused.empty() && written_by_blender(scene);
  return "the scene \"" + scene_path + "\" has no camera" +
         (scene.camera_refused.empty() ? std::string()
                                       : " that dofarm can render: " + scene.camera_refused) +
         (blender_without_any
              ? " (Blender writes its cameras into glTF only with Include > Cameras ticked)"
              : "") +
         "; add one to it, or set camera.from_scene = false and give the pose in "
         "[[camera.key]]";
}

CameraClip camera_clip(const JobSpec& spec, const SceneData& scene) {
  if (!spec.camera_from_scene || !scene.scene_camera) return {};
  return {scene.scene_camera->znear, scene.scene_camera->zfar};
}

CameraState camera_for_frame(const JobSpec& spec, const SceneData& scene, int frame,
                             const Autofocus& autofocus) {
  CameraState s;
  s.frame = frame;
  s.time = frame_time(spec, frame);
  size_t i0, i1;
  float w;
  const auto& keys = spec.camera_keys;
  auto key_frame = [](const CameraKey& k) { return float(k.frame); };
  bracket(keys, float(frame), key_frame, &i0, &i1, &w);
  if (spec.camera_from_scene) {
    const auto& track = scene.camera_track;
    if (track.empty()) {
      throw SpecError(spec.where("camera.from_scene"), "camera.from_scene",
                      no_scene_camera_message(scene, scene.source.string()));
    }
    if (scene.scene_camera) {
      // The camera's node posed at the frame's time by the file's samplers
      // (splines and moving parents included), not interpolated between keys.
      const CameraTrackKey key = scene.scene_camera->at(s.time);
      if (!is_finite(key.position)) {
        throw SpecError(spec.where("camera.from_scene"), "camera.from_scene",
                        fmt::format("the scene camera \"{}\" has a non-finite position at "
                                    "frame {}",
                                    scene.scene_camera->name, frame));
      }
      store(&s, key.position, key.rotation);
      if (key.ymag > 0) {
        s.fov_deg = 0;
        s.ortho_height = fitted_ortho_height(key.ymag, key.aspect, spec.width, spec.height);
      } else {
        s.fov_deg = fitted_vertical_fov(key.yfov_deg, key.aspect, spec.width, spec.height);
      }
    } else {
      size_t j0, j1;
      float v;
      bracket(
          track, s.time, [](const CameraTrackKey& k) { return k.time; }, &j0, &j1, &v);
      store(&s, lerp(track[j0].position, track[j1].position, v),
            slerp(track[j0].rotation, track[j1].rotation, v));
      if (track[j0].ymag > 0) {
        s.fov_deg = 0;
        s.ortho_height = fitted_ortho_height(track[j0].ymag * (1 - v) + track[j1].ymag * v,
                                             track[j0].aspect, spec.width, spec.height);
      } else {
        s.fov_deg = fitted_vertical_fov(track[j0].yfov_deg * (1 - v) + track[j1].yfov_deg * v,
                                        track[j0].aspect, spec.width, spec.height);
      }
    }
  } else if (!keys.empty()) {
    store(&s, lerp(keys[i0].position, keys[i1].position, w),
          slerp(key_rotation(keys[i0]), key_rotation(keys[i1]), w));
    s.fov_deg = keys[i0].fov_deg * (1 - w) + keys[i1].fov_deg * w;
  }
  if (!keys.empty()) {
    // Each key's lens for this frame's camera, then blended; a key of weight
    // 0 is not evaluated (its focus point may be behind this frame's camera).
    const bool ortho = s.orthographic();
    const float r0 = lens_radius(keys[i0], s.fov_deg, spec.width, spec.height, ortho);
    const float r1 = w > 0 ? lens_radius(keys[i1], s.fov_deg, spec.width, spec.height, ortho) : r0;
    const float lens_plane = ortho ? camera_clip(spec, scene).near : 0.0f;
    const float d0 = focus_distance(spec, keys[i0], s, autofocus, lens_plane);
    const float d1 =
        w > 0 && i1 != i0 ? focus_distance(spec, keys[i1], s, autofocus, lens_plane) : d0;
    s.focal_distance = d0 * (1 - w) + d1 * w;
    s.aperture = r0 * (1 - w) + r1 * w;
  }
  return s;
}

}  // namespace dofarm::render
