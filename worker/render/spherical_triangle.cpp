#include "worker/render/spherical_triangle.h"

#include <algorithm>
#include <cmath>

namespace dofarm::render {
namespace {

struct D3 {
  double x = 0, y = 0, z = 0;
};
D3 operator+(D3 a, D3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
D3 operator-(D3 a, D3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
D3 operator*(D3 a, double s) { return {a.x * s, a.y * s, a.z * s}; }
double dot(D3 a, D3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
D3 cross(D3 a, D3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
D3 to_d3(Vec3 v) { return {v.x, v.y, v.z}; }

// v / |v|; false for a zero or non-finite v.
bool unit(D3 v, D3* out) {
  const double l2 = dot(v, v);
  if (!(l2 > 0) || !std::isfinite(l2)) return false;
  *out = v * (1.0 / std::sqrt(l2));
  return true;
}

// The unit directions from `from` to the three vertices.
bool directions(Vec3 from, Vec3 a, Vec3 b, Vec3 c, D3* A, D3* B, D3* C) {
  const D3 o = to_d3(from);
  return unit(to_d3(a) - o, A) && unit(to_d3(b) - o, B) && unit(to_d3(c) - o, C);
}

double clamp1(double x) { return std::clamp(x, -1.0, 1.0); }

}  // namespace

double spherical_triangle_solid_angle(Vec3 from, Vec3 a, Vec3 b, Vec3 c) {
  D3 A, B, C;
  if (!directions(from, a, b, c, &A, &B, &C)) return 0.0;
  const double triple = std::fabs(dot(A, cross(B, C)));
  const double denominator = 1.0 + dot(A, B) + dot(B, C) + dot(C, A);
  // atan2 keeps the result right beyond a hemisphere (denominator <= 0).
  const double omega = 2.0 * std::atan2(triple, denominator);
  return std::isfinite(omega) && omega > 0 ? omega : 0.0;
}

bool sample_spherical_triangle(Vec3 from, Vec3 a, Vec3 b, Vec3 c, double solid_angle, Vec2 u,
                               Vec3* dir) {
  D3 A, B, C;
  if (!(solid_angle > 0) || !directions(from, a, b, c, &A, &B, &C)) return false;
  // The angle at vertex A between the arcs AB and AC, from the normals of
  // the two great circles.
  D3 n_ab, n_ac;
  if (!unit(cross(A, B), &n_ab) || !unit(cross(A, C), &n_ac)) return false;
  const double cos_alpha = clamp1(dot(n_ab, n_ac));
  const double alpha = std::acos(cos_alpha);
  const double sin_alpha = std::sin(alpha);
  const double cos_c = clamp1(dot(A, B));  // the arc AB, opposite C

  // Arvo's step 1: C' on the arc AC such that the triangle A B C' has area
  // u1 * Omega.
  const double sub_area = double(u.x) * solid_angle;
  const double s = std::sin(sub_area - alpha), t = std::cos(sub_area - alpha);
  const double uu = t - cos_alpha, vv = s + sin_alpha * cos_c;
  const double denominator = (vv * s + uu * t) * sin_alpha;
  if (!(std::fabs(denominator) > 0)) return false;
  const double q = clamp1(((vv * t - uu * s) * cos_alpha - vv) / denominator);
  D3 c_perp;  // the unit tangent at A towards C
  if (!unit(C - A * dot(C, A), &c_perp)) return false;
  const D3 C1 = A * q + c_perp * std::sqrt(std::max(0.0, 1.0 - q * q));

  // Step 2: the point on the arc B C' at cosine z from B.
  const double z = 1.0 - double(u.y) * (1.0 - dot(C1, B));
  D3 b_perp;  // the unit tangent at B towards C'
  if (!unit(C1 - B * dot(C1, B), &b_perp)) return false;  // C' = B: degenerate
  D3 p;
  if (!unit(B * z + b_perp * std::sqrt(std::max(0.0, 1.0 - z * z)), &p)) return false;
  *dir = Vec3(float(p.x), float(p.y), float(p.z));
  return is_finite(*dir);
}

}  // namespace dofarm::render
