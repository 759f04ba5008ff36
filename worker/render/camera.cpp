#include "worker/render/camera.h"

#include <fmt/format.h>

#include <algorithm>
#include <cfloat>
#include <cmath>

#include "common/error.h"
#include "common/thin_lens.h"
#include "worker/render/scene_motion.h"
#include "worker/render/trig.h"

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
  if (clip_.near > 0 || std::isfinite(clip_.far)) {
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
