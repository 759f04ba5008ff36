#include "common/math.h"

namespace dofarm {

// Shepperd's method: numerically stable for every rotation.
Quat quat_from_axes(Vec3 r, Vec3 u, Vec3 f) {
  // Matrix columns are r, u, f: m[row][col].
  float m00 = r.x, m01 = u.x, m02 = f.x;
  float m10 = r.y, m11 = u.y, m12 = f.y;
  float m20 = r.z, m21 = u.z, m22 = f.z;
  Quat q;
  float trace = m00 + m11 + m22;
  if (trace > 0) {
    float s = std::sqrt(trace + 1.0f) * 2.0f;
    q = {0.25f * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s};
  } else if (m00 > m11 && m00 > m22) {
    float s = std::sqrt(1.0f + m00 - m11 - m22) * 2.0f;
    q = {(m21 - m12) / s, 0.25f * s, (m01 + m10) / s, (m02 + m20) / s};
  } else if (m11 > m22) {
    float s = std::sqrt(1.0f + m11 - m00 - m22) * 2.0f;
    q = {(m02 - m20) / s, (m01 + m10) / s, 0.25f * s, (m12 + m21) / s};
  } else {
    float s = std::sqrt(1.0f + m22 - m00 - m11) * 2.0f;
    q = {(m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25f * s};
  }
  float n = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  return {q.w / n, q.x / n, q.y / n, q.z / n};
}

Quat quat_look_at(Vec3 from, Vec3 to, Vec3 up) {
  Vec3 back = normalize(from - to, Vec3(0, 0, 1));
  Vec3 right = cross(up, back);
  if (length_squared(right) < 1e-12f) right = cross(Vec3(0, 0, 1), back);  // looking along up
  if (length_squared(right) < 1e-12f) right = Vec3(1, 0, 0);
  right = normalize(right);
  Vec3 true_up = cross(back, right);
  return quat_from_axes(right, true_up, back);
}

Quat slerp(Quat a, Quat b, float t) {
  float d = a.w * b.w + a.x * b.x + a.y * b.y + a.z * b.z;
  if (d < 0) {  // take the short way round
    b = {-b.w, -b.x, -b.y, -b.z};
    d = -d;
  }
  float wa, wb;
  if (d > 0.9995f) {  // nearly parallel: lerp, then renormalise
    wa = 1 - t;
    wb = t;
  } else {
    float theta = std::acos(std::min(1.0f, d));
    float s = std::sin(theta);
    wa = std::sin((1 - t) * theta) / s;
    wb = std::sin(t * theta) / s;
  }
  Quat q{wa * a.w + wb * b.w, wa * a.x + wb * b.x, wa * a.y + wb * b.y, wa * a.z + wb * b.z};
  float n = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  return {q.w / n, q.x / n, q.y / n, q.z / n};
}

static Quat mul(Quat a, Quat b) {
  return {
      a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z, a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
      a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x, a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w};
}

Quat quat_from_euler_deg(Vec3 e) {
  auto axis = [](float deg, int i) {
    float h = deg * kPi / 360.0f;
    Quat q{std::cos(h), 0, 0, 0};
    (i == 0 ? q.x : i == 1 ? q.y : q.z) = std::sin(h);
    return q;
  };
  return mul(mul(axis(e.x, 0), axis(e.y, 1)), axis(e.z, 2));
}

}  // namespace dofarm
