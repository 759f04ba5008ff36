#include "worker/render/camera.h"

#include <algorithm>
#include <cmath>

namespace dofarm::render {

namespace {
Quat to_quat(const float r[4]) { return {r[0], r[1], r[2], r[3]}; }
Quat conjugate(Quat q) { return {q.w, -q.x, -q.y, -q.z}; }
}  // namespace

Camera::Camera(const CameraState& s, int width, int height)
    : state_(s), width_(width), height_(height) {
  rotation_ = to_quat(s.rotation);
  inverse_rotation_ = conjugate(rotation_);
  position_ = Vec3(s.position[0], s.position[1], s.position[2]);
  tan_half_fov_ = std::tan(0.5f * s.fov_deg * kPi / 180.0f);
  aspect_ = float(width) / float(height);
}

Vec3 Camera::film_direction(Vec2 film) const {
  float sx = (2.0f * film.x / float(width_) - 1.0f) * tan_half_fov_ * aspect_;
  float sy = (1.0f - 2.0f * film.y / float(height_)) * tan_half_fov_;
  return {sx, sy, -1.0f};
}

Ray Camera::pinhole_ray(Vec2 film) const {
  return {position_, normalize(rotation_.rotate(film_direction(film)))};
}

Ray Camera::generate_ray(Vec2 film, Vec2 lens) const {
  if (!has_lens()) return pinhole_ray(film);                  // bit-identical to the pinhole
  Vec3 focus = film_direction(film) * state_.focal_distance;  // on the plane z = -S
  Vec2 d = sample_concentric_disk(lens) * state_.aperture;
  Vec3 origin(d.x, d.y, 0.0f);
  // A rotation keeps lengths: one normalisation, after it, is enough.
  return {position_ + rotation_.rotate(origin), normalize(rotation_.rotate(focus - origin))};
}

float Camera::coc_pixels(float z) const {
  float a = state_.aperture, s = state_.focal_distance;
  if (a <= 0) return 0;
  float ratio = z > 0 ? std::fabs(z - s) / z : 1.0f;  // |1 - S/z|, -> 1 as z -> inf
  return a * ratio * float(height_) / (s * tan_half_fov_);
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
  return {r * std::cos(theta), r * std::sin(theta)};
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

CameraState camera_for_frame(const JobSpec& spec, const SceneData& scene, int frame) {
  CameraState s;
  s.frame = frame;
  s.time = float(frame) / spec.fps;
  size_t i0, i1;
  float w;
  const auto& keys = spec.camera_keys;
  auto key_frame = [](const CameraKey& k) { return float(k.frame); };
  bracket(keys, float(frame), key_frame, &i0, &i1, &w);
  if (!keys.empty()) {
    s.focal_distance = keys[i0].focal_distance * (1 - w) + keys[i1].focal_distance * w;
    s.aperture = keys[i0].aperture * (1 - w) + keys[i1].aperture * w;
  }
  if (spec.camera_from_scene && !scene.camera_track.empty()) {
    const auto& track = scene.camera_track;
    size_t j0, j1;
    float v;
    bracket(
        track, s.time, [](const CameraTrackKey& k) { return k.time; }, &j0, &j1, &v);
    store(&s, lerp(track[j0].position, track[j1].position, v),
          slerp(track[j0].rotation, track[j1].rotation, v));
    s.fov_deg = track[j0].yfov_deg * (1 - v) + track[j1].yfov_deg * v;
    if (keys.empty()) s.aperture = 0;
  } else if (!keys.empty()) {
    store(&s, lerp(keys[i0].position, keys[i1].position, w),
          slerp(key_rotation(keys[i0]), key_rotation(keys[i1]), w));
    s.fov_deg = keys[i0].fov_deg * (1 - w) + keys[i1].fov_deg * w;
  }
  return s;
}

}  // namespace dofarm::render
