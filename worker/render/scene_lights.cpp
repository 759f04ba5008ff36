// Scene's lights: choosing one for next-event estimation (emissive
// triangles, punctual lamps with and without a size, the environment),
// sampling a point or direction on it, and the pdfs that multiple
// importance sampling weighs BSDF hits with. Split from scene.cpp, which
// builds the scene and traces its rays.
#include <algorithm>
#include <cmath>
#include <limits>

#include "worker/render/scene.h"
#include "worker/render/scratch.h"
#include "worker/render/spherical_triangle.h"
#include "worker/render/trig.h"

namespace dofarm::render {

namespace {
// Below this solid angle (a triangle seen nearly edge-on) sample_light()
// gives no sample and light_pdf() says 0, the same rule on both sides.
constexpr double kMinSolidAngle = 1e-12;
}  // namespace

Scene::LightChoice Scene::choose_light(float u_select, Vec2 u, const Vec3* facing) const {
  LightChoice c;
  c.u = u;
  c.light = light_select_.sample_discrete(u_select, &c.pmf);
  if (env_sampled_ && c.light >= light_tris_.size() + data_.lights.size())
    c.env = environment_->choose(u, facing ? *facing : Vec3(0.0f));
  return c;
}

void Scene::sample_lights(int n, const Vec3* from, const LightChoice* const* choices,
                          LightSample* const* out, bool* ok) const {
  // The environment's choices first (sample_light()'s environment branch
  // for each), then every other light alone.
  Scratch<Environment::Choice, kPacket> env;
  int lane[kPacket], m = 0;
  for (int k = 0; k < n; ++k) {
    const LightChoice& c = *choices[k];
    if (is_environment_light(c.light) && c.pmf > 0 && m < kPacket) {
      env[m] = c.env;
      lane[m++] = k;
    } else {
      ok[k] = sample_light(from[k], c, out[k]);
    }
  }
  if (m == 0) return;
  Scratch<EnvSample, kPacket> es;
  environment_->sample(env.data(), m, es.data());
  for (int j = 0; j < m; ++j) {
    const int k = lane[j];
    ok[k] = environment_light(es[j], choices[k]->pmf, out[k]);
  }
}

bool Scene::environment_light(const EnvSample& es, float pmf, LightSample* out) {
  out->is_delta = false;
  if (!(es.pdf > 0)) return false;
  out->wi = es.wi;
  out->distance = std::numeric_limits<float>::infinity();
  out->radiance = es.radiance;
  out->pdf = es.pdf * pmf;
  return true;
}

bool Scene::sample_light(Vec3 from, const LightChoice& choice, LightSample* out) const {
  const float pmf = choice.pmf;
  const size_t i = choice.light;
  const Vec2 u = choice.u;
  if (!(pmf > 0)) return false;
  out->is_delta = false;
  if (i >= light_tris_.size() && i < light_tris_.size() + data_.lights.size()) {
    if (!sample_punctual(data_.lights[i - light_tris_.size()], from, u, out)) return false;
    out->pdf = out->is_delta ? pmf : out->pdf * pmf;
    return std::isfinite(out->pdf) && out->pdf > 0;
  }
  if (is_environment_light(i)) return environment_light(environment_->sample(choice.env), pmf, out);
  const uint32_t t = light_tris_[i];
  const uint32_t* idx = &data_.indices[size_t(t) * 3];
  Vec3 p0 = data_.positions[idx[0]], p1 = data_.positions[idx[1]], p2 = data_.positions[idx[2]];
  double solid_angle;
  if (by_solid_angle(i, from, &solid_angle)) {
    // Uniform over the triangle's solid angle (Arvo 1995), then the point
    // where that direction meets the triangle's plane.
    if (!(solid_angle > kMinSolidAngle)) return false;
    Vec3 wi;
    if (!sample_spherical_triangle(from, p0, p1, p2, solid_angle, u, &wi)) return false;
    const Vec3 n = tri_normal_[t];
    const double along = double(dot(n, wi));
    const double dist = double(dot(n, p0 - from)) / along;
    if (!(dist > 0) || !std::isfinite(dist)) return false;
    const Material& m = data_.materials[data_.tri_material[t]];
    Vec2 uv;
    if (m.emission_tex.present())
      uv = texcoord_at(idx, from + wi * float(dist), m.emission_tex.uv.set);
    out->wi = wi;
    out->distance = float(dist);
    out->radiance = material_emission(m, uv);
    out->pdf = float(double(pmf) / solid_angle);
    return std::isfinite(out->pdf);
  }
  float su = std::sqrt(u.x);  // uniform over the triangle (Turk 1990)
  float b0 = 1.0f - su, b1 = u.y * su, b2 = 1.0f - b0 - b1;
  Vec3 p = p0 * b0 + p1 * b1 + p2 * b2;
  const Vec3 n = tri_normal_[t];  // not degenerate: lights have an area
  Vec3 d = p - from;
  float dist2 = length_squared(d);
  if (!(dist2 > 0) || !std::isfinite(dist2)) return false;
  float dist = std::sqrt(dist2);
  Vec3 wi = d / dist;
  float cos_l = std::fabs(dot(n, wi));
  if (!(cos_l > 1e-7f)) return false;
  const Material& m = data_.materials[data_.tri_material[t]];
  const Vec2 uv = texcoord(idx, b0, b1, b2, m.emission_tex.uv.set);
  out->wi = wi;
  out->distance = dist;
  out->radiance = material_emission(m, uv);
  out->pdf = pmf * dist2 / (cos_l * light_tri_area_[i]);
  return std::isfinite(out->pdf);
}

namespace {

// A sun of angular radius theta_m (cos_half_angle c < 1) as Cycles 3.4
// renders a Sun's Angle: a disc of uniform radiance E / (pi tan^2 theta_m),
// the Sun's Strength over the area of a disc of radius tan theta_m at unit
// distance (measured in Blender 3.4: 124.80 for Strength 3 and Angle 10
// degrees, 2.8657 for Angle 60; docs/renderer.md, "Lamp size"), so that a
// surface facing it receives E cos^2 theta_m. Sampled uniformly in its cone
// (pdf 1 / (2 pi (1 - cos theta_m)), Pharr et al., pbrt 3rd ed., 13.6.2).
Vec3 sun_radiance(const PunctualLight& sun) {
  const float c = sun.cos_half_angle;
  return sun.intensity * (c * c / (kPi * (1.0f - c) * (1.0f + c)));
}
float sun_cone_pdf(const PunctualLight& sun) {
  return 1.0f / (kTwoPi * (1.0f - sun.cos_half_angle));
}
// A lamp of radius r as Cycles 3.4 renders it: a disk of that radius facing
// the lit point, of radiance I / (pi r^2) (the same power as the point seen
// from afar).
Vec3 disk_radiance(const PunctualLight& lamp) {
  return lamp.intensity / (kPi * lamp.radius * lamp.radius);
}
// The solid-angle pdf of a point on that disk, uniform by area, seen from
// distance sqrt(dist2) at cosine cos_l to the disk's normal:
// dist2 / (cos_l pi r^2).
float disk_pdf(const PunctualLight& lamp, float dist2, float cos_l) {
  return dist2 / (cos_l * kPi * lamp.radius * lamp.radius);
}

}  // namespace

bool Scene::sample_punctual(const PunctualLight& light, Vec3 from, Vec2 u, LightSample* out) const {
  // A lamp without a size is a delta light: radiance is the irradiance it
  // gives over the selection probability alone (is_delta). A sized lamp
  // (PunctualLight::radius, cos_half_angle) is sampled by its own area or
  // cone like any area light: its radiance and solid-angle pdf, weighed by
  // MIS against the BSDF samples that reach it (lamps_along()).
  out->is_delta = true;
  if (light.type == PunctualLight::Type::kDirectional) {
    out->distance = std::numeric_limits<float>::infinity();
    const float c = light.cos_half_angle;
    if (!(c < 1.0f)) {
      out->wi = -light.direction;
      out->radiance = light.intensity;  // irradiance on a surface facing the light
      return true;
    }
    const float cos_t = 1.0f - u.x * (1.0f - c);
    const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
    float sp, cp;
    precise_sincos(kTwoPi * u.y, &sp, &cp);
    out->wi = normalize(Frame(-light.direction).to_world(Vec3(sin_t * cp, sin_t * sp, cos_t)));
    out->radiance = sun_radiance(light);
    out->pdf = sun_cone_pdf(light);
    out->is_delta = false;
    return is_finite(out->wi) && is_finite(out->radiance);
  }
  Vec3 d = light.position - from;
  float dist2 = length_squared(d);
  if (!(dist2 > 0) || !std::isfinite(dist2)) return false;
  float dist = std::sqrt(dist2);
  out->wi = d / dist;
  out->distance = dist;
  // Inverse-square law: irradiance I / d^2 on a surface facing the light.
  Vec3 radiance = light.intensity / dist2;
  if (light.radius > 0) {
    // The disk facing `from` (disk_radiance()), a point p on it uniform by
    // area (disk_pdf()), with cos_l = dist / |p - from| (p lies in the plane
    // through the centre normal to the centre's direction).
    const Vec2 disk = sample_concentric_disk(u) * light.radius;
    const Frame f(-out->wi);
    const Vec3 p = light.position + f.t * disk.x + f.b * disk.y;
    const Vec3 to = p - from;
    const float len2 = length_squared(to);
    if (!(len2 > 0) || !std::isfinite(len2)) return false;
    const float len = std::sqrt(len2);
    out->wi = to / len;
    out->distance = len;
    out->pdf = disk_pdf(light, len2, dist / len);
    out->is_delta = false;
    radiance = disk_radiance(light);
  }
  if (light.type == PunctualLight::Type::kSpot) {
    float falloff = spot_attenuation(light, dot(-out->wi, light.direction));
    if (!(falloff > 0)) return false;
    radiance = radiance * falloff;
  }
  out->radiance = radiance;
  return is_finite(radiance) && (out->is_delta || (std::isfinite(out->pdf) && out->pdf > 0));
}

Vec3 Scene::lamp_hit(uint32_t i, Vec3 from, Vec3 dir, float t_max, float* pdf) const {
  *pdf = 0;
  const PunctualLight& l = data_.lights[i];
  const float pmf = light_select_.pmf(light_tris_.size() + i);
  if (l.type == PunctualLight::Type::kDirectional) {
    // Seen only by a ray that escapes, inside the sun's cone.
    if (!std::isinf(t_max) || !(dot(dir, -l.direction) >= l.cos_half_angle)) return Vec3(0);
    *pdf = pmf * sun_cone_pdf(l);
    return sun_radiance(l);
  }
  // The disk through the lamp's centre c facing `from`: with m = c - from,
  // the plane dot(x - c, m) = 0 is reached at t = |m|^2 / dot(dir, m).
  const Vec3 m = l.position - from;
  const float dm = dot(dir, m);
  if (!(dm > 0)) return Vec3(0);
  const float m2 = length_squared(m);
  const float t = m2 / dm;
  if (!(t < t_max) || !std::isfinite(t)) return Vec3(0);
  const Vec3 q = from + dir * t;
  if (!(length_squared(q - l.position) <= l.radius * l.radius)) return Vec3(0);
  Vec3 le = disk_radiance(l);
  if (l.type == PunctualLight::Type::kSpot) {
    const float falloff = spot_attenuation(l, dot(-dir, l.direction));
    if (!(falloff > 0)) return Vec3(0);
    le = le * falloff;
  }
  // As sample_punctual(), with cos_l = dm / |m|.
  const float p = pmf * disk_pdf(l, t * t, dm / std::sqrt(m2));
  if (!(p > 0) || !std::isfinite(p) || !is_finite(le)) return Vec3(0);
  *pdf = p;
  return le;
}

bool Scene::by_solid_angle(size_t i, Vec3 from, double* solid_angle) const {
  if (!solid_angle_lights_) return false;
  if (length_squared(from - light_tri_near_[i].centroid) >= light_tri_near_[i].edge2) return false;
  const uint32_t* idx = &data_.indices[size_t(light_tris_[i]) * 3];
  const Vec3 p0 = data_.positions[idx[0]];
  const float plane = dot(tri_normal_[light_tris_[i]], from - p0);
  // A point in the triangle's plane within rounding (a point on the light
  // itself, or on a coplanar neighbour) would see it as a whole hemisphere
  // from the wrong side: no sample, and pdf 0 for MIS alike. The margin is
  // offset_origin()'s.
  if (std::fabs(plane) <= offset_scale_ * std::max(max_abs(from), 1e-3f * radius_)) {
    *solid_angle = 0;
    return true;
  }
  *solid_angle =
      spherical_triangle_solid_angle(from, p0, data_.positions[idx[1]], data_.positions[idx[2]]);
  return true;
}

float Scene::light_pdf(Vec3 from, const SurfaceHit& hit) const {
  int i = light_index_of_prim_[hit.prim];
  if (i < 0) return 0;
  double solid_angle;
  if (by_solid_angle(size_t(i), from, &solid_angle))
    return solid_angle > kMinSolidAngle ? float(double(light_select_.pmf(size_t(i))) / solid_angle)
                                        : 0.0f;
  Vec3 d = hit.p - from;
  float dist2 = length_squared(d);
  float cos_l = std::fabs(dot(hit.ng, d)) / std::sqrt(dist2);
  if (!(cos_l > 1e-7f)) return 0;
  return light_select_.pmf(size_t(i)) * dist2 / (cos_l * light_tri_area_[i]);
}

Vec3 Scene::environment_radiance(const Environment::Located& at, Vec3 dir, float* pdf) const {
  Vec3 le = environment_->eval(at, dir, pdf);
  *pdf = env_sampled_ ? env_select_pmf_ * *pdf : 0.0f;
  return le;
}

}  // namespace dofarm::render
