// Small vector math shared by the renderer, the job spec and the tests.
// Float on purpose: it is what Embree traces with. Accumulators that need more
// precision use double explicitly at the call site.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace dofarm {

inline constexpr float kPi = 3.14159265358979323846f;
inline constexpr float kInvPi = 1.0f / kPi;
inline constexpr float kTwoPi = 2.0f * kPi;

struct Vec2 {
  float x = 0, y = 0;
  constexpr Vec2() = default;
  constexpr Vec2(float x_, float y_) : x(x_), y(y_) {}
  Vec2 operator+(Vec2 o) const { return {x + o.x, y + o.y}; }
  Vec2 operator-(Vec2 o) const { return {x - o.x, y - o.y}; }
  Vec2 operator*(float s) const { return {x * s, y * s}; }
};

struct Vec3 {
  float x = 0, y = 0, z = 0;
  constexpr Vec3() = default;
  constexpr explicit Vec3(float s) : x(s), y(s), z(s) {}
  constexpr Vec3(float x_, float y_, float z_) : x(x_), y(y_), z(z_) {}
  float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  float& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
  Vec3 operator+(Vec3 o) const { return {x + o.x, y + o.y, z + o.z}; }
  Vec3 operator-(Vec3 o) const { return {x - o.x, y - o.y, z - o.z}; }
  Vec3 operator*(Vec3 o) const { return {x * o.x, y * o.y, z * o.z}; }
  Vec3 operator/(Vec3 o) const { return {x / o.x, y / o.y, z / o.z}; }
  Vec3 operator*(float s) const { return {x * s, y * s, z * s}; }
  Vec3 operator/(float s) const { return {x / s, y / s, z / s}; }
  Vec3 operator-() const { return {-x, -y, -z}; }
  Vec3& operator+=(Vec3 o) {
    x += o.x;
    y += o.y;
    z += o.z;
    return *this;
  }
  Vec3& operator*=(Vec3 o) {
    x *= o.x;
    y *= o.y;
    z *= o.z;
    return *this;
  }
  Vec3& operator*=(float s) {
    x *= s;
    y *= s;
    z *= s;
    return *this;
  }
};
inline Vec3 operator*(float s, Vec3 v) { return v * s; }

inline float dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 cross(Vec3 a, Vec3 b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline float length(Vec3 v) { return std::sqrt(dot(v, v)); }
inline float length_squared(Vec3 v) { return dot(v, v); }
// Returns `fallback` for zero or non-finite input instead of producing NaN.
inline Vec3 normalize(Vec3 v, Vec3 fallback = Vec3(0, 0, 1)) {
  float l2 = dot(v, v);
  if (!(l2 > 0.0f) || !std::isfinite(l2)) return fallback;
  return v / std::sqrt(l2);
}
inline Vec3 vmin(Vec3 a, Vec3 b) {
  return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)};
}
inline Vec3 vmax(Vec3 a, Vec3 b) {
  return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)};
}
inline float max_component(Vec3 v) { return std::max(v.x, std::max(v.y, v.z)); }
inline float max_abs(Vec3 v) {
  return std::max(std::fabs(v.x), std::max(std::fabs(v.y), std::fabs(v.z)));
}
inline float luminance(Vec3 c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }
inline bool is_finite(Vec3 v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}
inline Vec3 lerp(Vec3 a, Vec3 b, float t) { return a * (1.0f - t) + b * t; }
inline float clamp01(float v) { return std::min(1.0f, std::max(0.0f, v)); }
inline float safe_sqrt(float v) { return std::sqrt(std::max(0.0f, v)); }
inline Vec3 reflect(Vec3 wo, Vec3 n) { return n * (2.0f * dot(wo, n)) - wo; }

// Orthonormal basis around a unit normal (Duff et al. 2017, "Building an
// Orthonormal Basis, Revisited").
struct Frame {
  Vec3 t, b, n;
  Frame() : t(1, 0, 0), b(0, 1, 0), n(0, 0, 1) {}
  explicit Frame(Vec3 n_) : n(n_) {
    float sign = std::copysign(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float bb = n.x * n.y * a;
    t = Vec3(1.0f + sign * n.x * n.x * a, sign * bb, -sign * n.x);
    b = Vec3(bb, sign + n.y * n.y * a, -n.y);
  }
  Vec3 to_local(Vec3 v) const { return {dot(v, t), dot(v, b), dot(v, n)}; }
  Vec3 to_world(Vec3 v) const { return t * v.x + b * v.y + n * v.z; }
};

// Unit quaternion for camera rotation; slerp between keyframes.
struct Quat {
  float w = 1, x = 0, y = 0, z = 0;
  Vec3 rotate(Vec3 v) const {
    Vec3 u(x, y, z);
    Vec3 t = cross(u, v) * 2.0f;
    return v + t * w + cross(u, t);
  }
};
Quat quat_from_axes(Vec3 right, Vec3 up, Vec3 back);  // columns of a rotation matrix
Quat quat_look_at(Vec3 from, Vec3 to, Vec3 up);       // camera looks down -z
Quat slerp(Quat a, Quat b, float t);
Quat quat_from_euler_deg(Vec3 xyz_deg);  // intrinsic X, then Y, then Z

}  // namespace dofarm
