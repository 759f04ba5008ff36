#include "worker/render/scene.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <string>

#include "common/error.h"
#include "worker/render/camera.h"
#include "worker/render/sampler.h"
#include "worker/render/scene_motion.h"
#include "worker/render/spherical_triangle.h"
#include "worker/render/trig.h"

namespace dofarm::render {

namespace {

// The one boundary for Embree errors (STYLE.md 4): the callback records the
// first error, and the code that called Embree turns it into an exception.
void embree_error(void* user, RTCError code, const char* str) {
  auto* msg = static_cast<std::string*>(user);
  if (msg->empty()) msg->assign(str ? str : "unknown Embree error");
  (void)code;
}

thread_local RayCount t_rays;

// An Embree ray from o along d over [0, t_max], visible to every geometry.
RTCRay embree_ray(Vec3 o, Vec3 d, float t_max, float t_min = 0.0f) {
  RTCRay r;
  r.org_x = o.x;
  r.org_y = o.y;
  r.org_z = o.z;
  r.dir_x = d.x;
  r.dir_y = d.y;
  r.dir_z = d.z;
  r.tnear = t_min;
  r.tfar = t_max;
  r.mask = 0xffffffffu;
  r.flags = 0;
  r.time = 0;
  return r;
}

Vec3 texture_mean(const Texture& t) {
  double s[3] = {0, 0, 0};
  size_t n = size_t(t.width) * t.height;
  for (size_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) s[c] += t.rgb[i * 3 + c];
  return n ? Vec3(float(s[0] / n), float(s[1] / n), float(s[2] / n)) : Vec3(0);
}

// Embree calls this for every candidate hit of the scene's triangles, in
// closest-hit and shadow queries alike (it is set only when a material has
// an alpha mask); a hit on a cut-out point is rejected, so the ray goes on
// as if the surface were not there.
// The scene it asks is the one tracing, read from the query's context
// (Embree hands the filter the context the query was given), not the one
// that built the BVH: a pose that moves only lamps traces through the
// loaded scene's BVH and may outlive that scene.
void alpha_mask_filter(const RTCFilterFunctionNArguments* args) {
  const Scene* scene = reinterpret_cast<const Scene::EmbreeContext*>(args->context)->scene;
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] != -1) continue;
    // The ray's origin and direction, bit for bit: its key for BLEND.
    const float f[6] = {RTCRayN_org_x(args->ray, args->N, i), RTCRayN_org_y(args->ray, args->N, i),
                        RTCRayN_org_z(args->ray, args->N, i), RTCRayN_dir_x(args->ray, args->N, i),
                        RTCRayN_dir_y(args->ray, args->N, i), RTCRayN_dir_z(args->ray, args->N, i)};
    if (scene->cut_out(RTCHitN_primID(args->hit, args->N, i), RTCHitN_u(args->hit, args->N, i),
                       RTCHitN_v(args->hit, args->N, i), f))
      args->valid[i] = 0;
  }
}

// Whether some material cuts out by its alpha (the BVH then needs Embree's
// filter, alpha_mask_filter).
bool has_alpha_masks(const SceneData& data) {
  return std::any_of(data.materials.begin(), data.materials.end(),
                     [](const Material& m) { return m.alpha_mask; });
}

}  // namespace

bool Scene::cut_out(uint32_t prim, float b1, float b2, const float (&ray)[6]) const {
  const Material& m = data_.materials[data_.tri_material[prim]];
  if (!m.alpha_mask) return false;
  float alpha = m.base_alpha;
  if (m.base_color_tex.present()) {
    const uint32_t* idx = &data_.indices[size_t(prim) * 3];
    const Vec2 uv = texcoord(idx, 1.0f - b1 - b2, b1, b2, m.base_color_tex.uv.set);
    alpha *= textures()[m.base_color_tex.index].alpha_lookup(m.base_color_tex.uv.apply(uv));
  }
  if (!m.alpha_blend) return alpha < m.alpha_cutoff;
  uint64_t key = 0;
  for (float v : ray) key = hash_combine(key, std::bit_cast<uint32_t>(v));
  // 24 bits of the hash: a float in [0, 1).
  const float u = float(hash_combine(key, prim) >> 40) * 0x1p-24f;
  return u >= alpha;
}

Scene::Scene(SceneData data, std::unique_ptr<Environment> environment)
    : data_(std::move(data)), environment_(std::move(environment)) {
  textures_ = std::make_shared<const std::vector<Texture>>(std::move(data_.textures));
  data_.textures.clear();
  build();
}

Scene::Scene(SceneData posed, std::shared_ptr<const std::vector<Texture>> textures,
             std::shared_ptr<const Environment> environment, float time,
             std::shared_ptr<const Bvh> bvh)
    : data_(std::move(posed)),
      textures_(std::move(textures)),
      environment_(std::move(environment)),
      pose_time_(time),
      bvh_(std::move(bvh)) {
  build();
}

struct Scene::Bvh {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  bool packets = false;  // the Embree build traces rtcIntersect8 as 8-wide packets
  Bvh() = default;
  Bvh(const Bvh&) = delete;
  Bvh& operator=(const Bvh&) = delete;
  ~Bvh() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }
};

std::shared_ptr<const Scene> Scene::at_time(float time) const {
  // Not owned: the caller holds this scene for as long as it uses it.
  if (!data_.motion || time == pose_time_)
    return std::shared_ptr<const Scene>(std::shared_ptr<const Scene>(), this);
  // A pose has no rest data to pose again from.
  DOFARM_CHECK(std::isnan(pose_time_));
  std::lock_guard<std::mutex> lock(posed_mutex_);
  for (const auto& [t, scene] : posed_)
    if (t == time) return scene;
  // Built under the lock: whoever else asks wants the same pose or waits
  // for its BVH in any case. Where only lamps move, every triangle stays
  // where it was loaded and the pose traces through this scene's BVH (with
  // alpha masks too: the filter asks the tracing scene, embree_context()).
  auto scene =
      std::shared_ptr<const Scene>(new Scene(pose(data_, time), textures_, environment_, time,
                                             data_.motion->parts.empty() ? bvh_ : nullptr));
  if (posed_.size() >= 2) posed_.erase(posed_.begin());
  posed_.emplace_back(time, scene);
  return scene;
}

void Scene::build() {
  const FileLoc loc{data_.source.string()};
  if (data_.triangle_count() == 0) throw SpecError(loc, "scene", "the scene has no triangles");
  DOFARM_CHECK(data_.uvs.empty() || data_.uvs.size() == data_.positions.size());
  DOFARM_CHECK(data_.uvs1.empty() || data_.uvs1.size() == data_.positions.size());

  // Bounds, for ray offsets and the environment's share of the light power.
  Vec3 lo(std::numeric_limits<float>::max()), hi(-std::numeric_limits<float>::max());
  for (Vec3 p : data_.positions) {
    if (!is_finite(p)) throw SpecError(loc, "scene", "a vertex position is NaN or infinite");
    lo = vmin(lo, p);
    hi = vmax(hi, p);
  }
  center_ = (lo + hi) * 0.5f;
  radius_ = std::max(0.5f * length(hi - lo), 1e-30f);
  offset_scale_ = 1e-5f;

  // Each material's BSDF constants, where no texture varies its scalar
  // factors over the surface.
  bsdf_constants_.clear();
  bsdf_constants_.reserve(data_.materials.size());
  material_bsdf_.assign(data_.materials.size(), nullptr);
  for (size_t i = 0; i < data_.materials.size(); ++i) {
    const Material& m = data_.materials[i];
    bsdf_constants_.emplace_back(m.metallic, m.roughness, m.ior,
                                 SpecularLayer{m.specular, m.specular_color}, m.transmission,
                                 ClearcoatLayer{m.clearcoat, m.clearcoat_roughness, Vec3(0.0f)},
                                 SheenLayer{m.sheen_color, m.sheen_roughness});
    const bool textured = m.metal_rough_tex.present() || m.transmission_tex.present() ||
                          m.clearcoat_tex.present() || m.clearcoat_rough_tex.present() ||
                          m.specular_tex.present() || m.specular_color_tex.present() ||
                          m.sheen_color_tex.present() || m.sheen_rough_tex.present();
    if (!textured) material_bsdf_[i] = &bsdf_constants_[i];
  }

  tri_normal_.resize(data_.triangle_count());
  for (uint32_t t = 0; t < data_.triangle_count(); ++t) {
    const uint32_t* idx = &data_.indices[size_t(t) * 3];
    const Vec3 p0 = data_.positions[idx[0]];
    tri_normal_[t] =
        normalize(cross(data_.positions[idx[1]] - p0, data_.positions[idx[2]] - p0), Vec3(0));
  }

  // Lights: every emissive triangle with a positive area, selected by power.
  std::vector<float> power;
  light_index_of_prim_.assign(data_.triangle_count(), -1);
  std::vector<Vec3> tex_mean(textures().size());
  for (size_t i = 0; i < textures().size(); ++i) tex_mean[i] = texture_mean(textures()[i]);
  for (uint32_t t = 0; t < data_.triangle_count(); ++t) {
    const Material& m = data_.materials[data_.tri_material[t]];
    if (!m.is_emissive()) continue;
    float area = triangle_area(t);
    if (!(area > 0) || !std::isfinite(area)) continue;  // degenerate: cannot be sampled
    Vec3 e = m.emission;
    if (m.emission_tex.present()) e = e * tex_mean[m.emission_tex.index];
    float p = luminance(e) * area * kPi;
    if (!(p > 0)) continue;
    light_index_of_prim_[t] = int(light_tris_.size());
    light_tris_.push_back(t);
    light_tri_area_.push_back(area);
    {
      const uint32_t* idx = &data_.indices[size_t(t) * 3];
      const Vec3 p0 = data_.positions[idx[0]], p1 = data_.positions[idx[1]],
                 p2 = data_.positions[idx[2]];
      light_tri_near_.push_back(
          {(p0 + p1 + p2) / 3.0f,
           std::max({length_squared(p1 - p0), length_squared(p2 - p1), length_squared(p0 - p2)})});
    }
    power.push_back(p);
  }
  // Punctual lights by the power they send into the scene: 4 pi I for a
  // point, I times the solid angle of the cone (to halfway between the inner
  // and outer angle) for a spot, and E times the scene's cross-section pi r^2
  // for a directional light. A light of zero power keeps a zero share.
  for (const PunctualLight& l : data_.lights) {
    const float i = luminance(l.intensity);
    float p = 0;
    switch (l.type) {
      case PunctualLight::Type::kPoint:
        p = 4.0f * kPi * i;
        break;
      case PunctualLight::Type::kSpot:
        p = 2.0f * kPi * (1.0f - 0.5f * (l.cos_inner + l.cos_outer)) * i;
        break;
      case PunctualLight::Type::kDirectional:
        p = kPi * radius_ * radius_ * i;
        break;
    }
    power.push_back(std::isfinite(p) && p > 0 ? p : 0.0f);
  }
  env_sampled_ = environment_ && !environment_->is_black();
  if (env_sampled_) power.push_back(kPi * kPi * radius_ * radius_ * environment_->mean_luminance());
  bool any_power = false;
  for (float p : power) any_power = any_power || p > 0;
  if (!any_power) {
    // Blender's glTF exporter leaves the lamps out unless "Punctual
    // Lights" is ticked, and never writes the World.
    const std::string ext = data_.source.extension().string();
    const bool gltf = ext == ".gltf" || ext == ".glb";
    throw SpecError(loc, "scene",
                    std::string("the scene has no light: no emissive triangle with area > 0, no "
                                "punctual light with a positive intensity and no environment") +
                        (gltf && data_.lights.empty()
                             ? " (the file has no KHR_lights_punctual lights: Blender's glTF "
                               "exporter writes its lamps only with Include > Punctual Lights "
                               "ticked, never its Area lamps (glTF has none: an emissive mesh "
                               "lights as one does) and never its World; the job's "
                               "[environment] can light the scene)"
                             : ""));
  }
  light_select_ = Distribution1D(power);
  if (env_sampled_) env_select_pmf_ = light_select_.pmf(power.size() - 1);
  sized_lamps_.clear();
  for (size_t i = 0; i < data_.lights.size(); ++i) {
    const PunctualLight& l = data_.lights[i];
    const bool sized =
        l.type == PunctualLight::Type::kDirectional ? l.cos_half_angle < 1.0f : l.radius > 0;
    if (sized && light_select_.pmf(light_tris_.size() + i) > 0) sized_lamps_.push_back(uint32_t(i));
  }

  if (!bvh_) build_bvh();
  rtc_scene_ = bvh_->scene;
}

void Scene::build_bvh() {
  // Embree: one static triangle geometry over copies of the vertices and
  // indices in buffers it owns (padded for its vector loads), so the BVH
  // lives on in the poses that share it.
  auto bvh = std::make_shared<Bvh>();
  bvh->device = rtcNewDevice("threads=1");  // our own pool parallelises; the BVH build is small
  if (!bvh->device) throw RuntimeError("Embree: cannot create a device");
  std::string err;
  rtcSetDeviceErrorFunction(bvh->device, embree_error, &err);
  bvh->packets = rtcGetDeviceProperty(bvh->device, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED) != 0;
  bvh->scene = rtcNewScene(bvh->device);
  rtcSetSceneFlags(bvh->scene, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(bvh->scene, RTC_BUILD_QUALITY_HIGH);
  RTCGeometry geom = rtcNewGeometry(bvh->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                               RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                                               data_.positions.size()));
  auto* indices = static_cast<uint32_t*>(
      rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                              3 * sizeof(uint32_t), data_.triangle_count()));
  if (!vertices || !indices) {
    rtcReleaseGeometry(geom);
    rtcSetDeviceErrorFunction(bvh->device, nullptr, nullptr);
    throw RuntimeError("Embree: cannot allocate the scene's buffers" +
                       (err.empty() ? std::string() : ": " + err));
  }
  for (size_t i = 0; i < data_.positions.size(); ++i) {
    vertices[i * 3 + 0] = data_.positions[i].x;
    vertices[i * 3 + 1] = data_.positions[i].y;
    vertices[i * 3 + 2] = data_.positions[i].z;
  }
  std::copy(data_.indices.begin(), data_.indices.end(), indices);
  if (has_alpha_masks(data_)) {
    rtcSetGeometryIntersectFilterFunction(geom, alpha_mask_filter);
    rtcSetGeometryOccludedFilterFunction(geom, alpha_mask_filter);
  }
  rtcCommitGeometry(geom);
  rtcAttachGeometry(bvh->scene, geom);
  rtcReleaseGeometry(geom);
  rtcCommitScene(bvh->scene);
  rtcSetDeviceErrorFunction(bvh->device, nullptr, nullptr);
  if (!err.empty()) throw RuntimeError("Embree: " + err);
  bvh_ = std::move(bvh);
}

Scene::~Scene() = default;

Vec2 Scene::texcoord(const uint32_t* idx, float b0, float b1, float b2, unsigned set) const {
  const std::vector<Vec2>& uvs = set == 1 && !data_.uvs1.empty() ? data_.uvs1 : data_.uvs;
  if (uvs.empty()) return {b1, b2};  // no texture coordinates: barycentrics
  return uvs[idx[0]] * b0 + uvs[idx[1]] * b1 + uvs[idx[2]] * b2;
}

float Scene::triangle_area(uint32_t t) const {
  const uint32_t* idx = &data_.indices[size_t(t) * 3];
  Vec3 p0 = data_.positions[idx[0]], p1 = data_.positions[idx[1]], p2 = data_.positions[idx[2]];
  return 0.5f * length(cross(p1 - p0, p2 - p0));
}

Vec3 Scene::normal_mapped(int tex, float scale, const uint32_t* idx, float b0, float b1, float b2,
                          Vec3 n, Vec2 st) const {
  // glTF 3.9.3: the texel's (2 rgb - 1) in the frame (t, b, n), x and y
  // times the map's scale; b = cross(n, t) w, t made orthogonal to the
  // interpolated n first (SceneData::tangents).
  if (!(dot(n, n) > 0.0f)) return n;  // a degenerate triangle: no frame
  const SceneData::Tangent& a = data_.tangents[idx[0]];
  const SceneData::Tangent& b = data_.tangents[idx[1]];
  const SceneData::Tangent& c = data_.tangents[idx[2]];
  Vec3 t = a.t * b0 + b.t * b1 + c.t * b2;
  t = t - n * dot(n, t);
  const float len = length(t);
  if (!(len > 1e-12f)) return n;
  t = t / len;
  const float w = a.w * b0 + b.w * b1 + c.w * b2 < 0.0f ? -1.0f : 1.0f;
  const Vec3 bt = cross(n, t) * w;
  const Vec3 texel = textures()[tex].lookup(st);
  const Vec3 v((2.0f * texel.x - 1.0f) * scale, (2.0f * texel.y - 1.0f) * scale,
               2.0f * texel.z - 1.0f);
  return normalize(t * v.x + bt * v.y + n * v.z, n);
}

Vec3 Scene::smooth_normal(const uint32_t* idx, float b0, float b1, float b2, Vec3 ng,
                          Vec3 d) const {
  if (data_.normals.empty()) return ng;
  Vec3 ns = normalize(
      data_.normals[idx[0]] * b0 + data_.normals[idx[1]] * b1 + data_.normals[idx[2]] * b2, ng);
  if (dot(ns, ng) < 0) ns = -ns;
  // A shading normal that faces away from the viewer (grazing views of
  // smoothed low-poly geometry) would make the BSDF reject every
  // direction; the geometric normal is the safe fallback.
  if (dot(ns, d) >= 0) ns = ng;
  return ns;
}

Vec3 Scene::mapped_normal(int tex, float scale, Vec2 st, uint32_t prim, const uint32_t* idx,
                          float b0, float b1, float b2, Vec3 ng, Vec3 d) const {
  // The interpolated normal (or the triangle's own) bent by the map, on
  // the surface's front side, then turned to the side the ray is on.
  Vec3 n = tri_normal_[prim];
  if (!data_.normals.empty())
    n = normalize(
        data_.normals[idx[0]] * b0 + data_.normals[idx[1]] * b1 + data_.normals[idx[2]] * b2, n);
  const Vec3 bent = normal_mapped(tex, scale, idx, b0, b1, b2, n, st);
  // A bent normal below the surface (a map that points into it) is not
  // mirrored out of it: the unbent one is used.
  if (dot(bent, tri_normal_[prim]) > 0) n = bent;
  Vec3 ns = dot(n, ng) < 0 ? -n : n;
  if (!(length(ns) > 0) || dot(ns, d) >= 0) ns = ng;
  return ns;
}

Vec3 Scene::material_emission(const Material& m, Vec2 uv) const {
  if (!m.is_emissive()) return Vec3(0);
  if (m.emission_tex.present())
    return m.emission * textures()[m.emission_tex.index].lookup(m.emission_tex.uv.apply(uv));
  return m.emission;
}

RayCount thread_ray_count() { return t_rays; }
void count_light_samples(uint64_t n, uint64_t skipped) {
  t_rays.light_samples += n;
  t_rays.light_samples_skipped += skipped;
}

bool Scene::intersect(const Ray& ray, SurfaceHit* hit) const {
  ++t_rays.closest;
  if (ray_sink_) [[unlikely]]
    ray_sink_->record({ray.o, ray.d, ray.t_max, false, ray.t_min});
  EmbreeContext ctx = embree_context();
  RTCRayHit rh;
  rh.ray = embree_ray(ray.o, ray.d, ray.t_max, ray.t_min);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(rtc_scene_, &ctx.rtc, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  complete_hit(ray, rh.hit.primID, rh.hit.u, rh.hit.v, rh.ray.tfar, hit);
  return true;
}

void Scene::intersect_packet(const Ray* rays, int n, SurfaceHit* hits, bool* found) const {
  if (!bvh_->packets || !packet_tracing_ || n == 1) {
    for (int k = 0; k < n; ++k) found[k] = intersect(rays[k], &hits[k]);
    return;
  }
  for (int first = 0; first < n; first += kPacket) {
    const int m = std::min(kPacket, n - first);
    t_rays.closest += uint64_t(m);
    if (ray_sink_) [[unlikely]]
      for (int k = 0; k < m; ++k) {
        const Ray& r = rays[first + k];
        ray_sink_->record({r.o, r.d, r.t_max, false, r.t_min, uint8_t(k == 0 ? m : 0)});
      }
    alignas(32) int valid[kPacket];
    alignas(32) RTCRayHit8 rh;
    embree_packet(rays + first, m, &rh, valid);
    // The default (incoherent) flag: RTC_INTERSECT_CONTEXT_FLAG_COHERENT's
    // traversal reported the wrong one of two walls side by side for
    // parallel rays along an axis (an orthographic camera;
    // OrthoCamera.AFrameShowsTheViewsRectangleWithItsDepthAndCoc).
    EmbreeContext ctx = embree_context();
    rtcIntersect8(valid, rtc_scene_, &ctx.rtc, &rh);
    for (int k = 0; k < m; ++k) {
      found[first + k] = rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID;
      if (found[first + k])
        complete_hit(rays[first + k], rh.hit.primID[k], rh.hit.u[k], rh.hit.v[k], rh.ray.tfar[k],
                     &hits[first + k]);
    }
  }
}

void Scene::embree_packet(const Ray* rays, int n, RTCRayHit8* rh, int* valid) {
  for (int k = 0; k < kPacket; ++k) {
    // Lanes past n are invalid (Embree neither reads nor writes them); they
    // repeat the last ray all the same.
    const Ray& r = rays[std::min(k, n - 1)];
    valid[k] = k < n ? -1 : 0;
    rh->ray.org_x[k] = r.o.x;
    rh->ray.org_y[k] = r.o.y;
    rh->ray.org_z[k] = r.o.z;
    rh->ray.tnear[k] = r.t_min;
    rh->ray.dir_x[k] = r.d.x;
    rh->ray.dir_y[k] = r.d.y;
    rh->ray.dir_z[k] = r.d.z;
    rh->ray.time[k] = 0;
    rh->ray.tfar[k] = r.t_max;
    rh->ray.mask[k] = 0xffffffffu;
    rh->ray.id[k] = 0;
    rh->ray.flags[k] = 0;
    rh->hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
    rh->hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
  }
}

void Scene::complete_hit(const Ray& ray, uint32_t prim, float b1, float b2, float t,
                         SurfaceHit* hit) const {
  const uint32_t* idx = &data_.indices[size_t(prim) * 3];
  const float b0 = 1.0f - b1 - b2;
  Vec3 p0 = data_.positions[idx[0]], p1 = data_.positions[idx[1]], p2 = data_.positions[idx[2]];
  hit->t = t;
  hit->prim = prim;
  // Barycentric position: more accurate than o + t d far from the origin.
  hit->p = p0 * b0 + p1 * b1 + p2 * b2;
  Vec3 ng = tri_normal_[prim];
  if (ng.x == 0 && ng.y == 0 && ng.z == 0) ng = -ray.d;
  hit->front = dot(ng, ray.d) <= 0;
  if (!hit->front) ng = -ng;
  hit->ng = ng;
  hit->uv = texcoord(idx, b0, b1, b2);
  hit->uv1 = data_.uvs1.empty() ? hit->uv : texcoord(idx, b0, b1, b2, 1);
  // Tangents exist only when some material has a normal map: other scenes
  // do not wait for the material here.
  const Material* mapped =
      data_.tangents.empty() ? nullptr : &data_.materials[data_.tri_material[prim]];
  const Vec3 ns =
      mapped && mapped->normal_tex.present()
          ? mapped_normal(mapped->normal_tex.index, mapped->normal_scale,
                          hit->uv_of(mapped->normal_tex.uv), prim, idx, b0, b1, b2, ng, ray.d)
          : smooth_normal(idx, b0, b1, b2, ng, ray.d);
  // KHR_materials_clearcoat: the coat has its own normal map, or none even
  // where the base has one (the extension: no normal mapping is applied to
  // the coat unless clearcoatNormalTexture is given).
  hit->coat_ns = Vec3(0.0f);
  if (mapped && mapped->clearcoat > 0 &&
      (mapped->normal_tex.present() || mapped->clearcoat_normal_tex.present())) [[unlikely]] {
    hit->coat_ns =
        mapped->clearcoat_normal_tex.present()
            ? mapped_normal(mapped->clearcoat_normal_tex.index, mapped->clearcoat_normal_scale,
                            hit->uv_of(mapped->clearcoat_normal_tex.uv), prim, idx, b0, b1, b2, ng,
                            ray.d)
            : smooth_normal(idx, b0, b1, b2, ng, ray.d);
  }
  hit->ns = ns;
  const Material& m = data_.materials[data_.tri_material[prim]];
  hit->base_color = m.base_color;
  hit->metallic = m.metallic;
  hit->roughness = m.roughness;
  hit->ior = m.ior;
  hit->specular = m.specular;
  hit->specular_color = m.specular_color;
  hit->transmission = m.transmission;
  hit->attenuation = m.attenuation;
  hit->clearcoat = m.clearcoat;
  hit->clearcoat_roughness = m.clearcoat_roughness;
  hit->sheen_color = m.sheen_color;
  hit->sheen_roughness = m.sheen_roughness;
  // Only textured materials pay for lookups.
  auto texel = [&](const TextureSlot& slot) {
    return textures()[slot.index].lookup(hit->uv_of(slot.uv));
  };
  if (m.base_color_tex.present()) hit->base_color = hit->base_color * texel(m.base_color_tex);
  if (m.metal_rough_tex.present()) {
    const Vec3 mr = texel(m.metal_rough_tex);
    hit->roughness *= mr.y;
    hit->metallic *= mr.z;
  }
  if (m.transmission_tex.present()) hit->transmission *= texel(m.transmission_tex).x;
  if (m.clearcoat_tex.present()) hit->clearcoat *= texel(m.clearcoat_tex).x;
  if (m.clearcoat_rough_tex.present()) hit->clearcoat_roughness *= texel(m.clearcoat_rough_tex).y;
  if (m.specular_tex.present())
    hit->specular *= textures()[m.specular_tex.index].alpha_lookup(hit->uv_of(m.specular_tex.uv));
  if (m.specular_color_tex.present())
    hit->specular_color = hit->specular_color * texel(m.specular_color_tex);
  if (m.sheen_color_tex.present()) hit->sheen_color = hit->sheen_color * texel(m.sheen_color_tex);
  if (m.sheen_rough_tex.present())
    hit->sheen_roughness *=
        textures()[m.sheen_rough_tex.index].alpha_lookup(hit->uv_of(m.sheen_rough_tex.uv));
  hit->emission = material_emission(m, m.emission_tex.uv.set == 1 ? hit->uv1 : hit->uv);
}

bool Scene::occluded(Vec3 origin, Vec3 dir, float t_max) const {
  ++t_rays.shadow;
  if (ray_sink_) [[unlikely]]
    ray_sink_->record({origin, dir, t_max, true});
  EmbreeContext ctx = embree_context();
  RTCRay r = embree_ray(origin, dir, t_max);
  rtcOccluded1(rtc_scene_, &ctx.rtc, &r);
  return r.tfar < 0;  // Embree sets tfar to -inf on a hit
}

Vec3 Scene::offset_origin(const SurfaceHit& hit, Vec3 dir) const {
  float eps = offset_scale_ * std::max(max_abs(hit.p), 1e-3f * radius_);
  return hit.p + hit.ng * (dot(dir, hit.ng) >= 0 ? eps : -eps);
}

Vec2 Scene::texcoord_at(const uint32_t* idx, Vec3 p, unsigned set) const {
  // Barycentrics of p (in the triangle's plane) from the edge vectors.
  const Vec3 p0 = data_.positions[idx[0]];
  const Vec3 e1 = data_.positions[idx[1]] - p0, e2 = data_.positions[idx[2]] - p0, d = p - p0;
  const float d11 = dot(e1, e1), d12 = dot(e1, e2), d22 = dot(e2, e2);
  const float d1 = dot(d, e1), d2 = dot(d, e2);
  const float det = d11 * d22 - d12 * d12;
  if (!(det > 0)) return texcoord(idx, 1, 0, 0, set);
  const float b1 = std::clamp((d22 * d1 - d12 * d2) / det, 0.0f, 1.0f);
  const float b2 = std::clamp((d11 * d2 - d12 * d1) / det, 0.0f, 1.0f - b1);
  return texcoord(idx, 1.0f - b1 - b2, b1, b2, set);
}

SceneData load_job_scene_data(const JobSpec& spec) {
  SceneData data = load_scene_data(spec.scene, spec.camera_name);
  // PunctualLight::cos_half_angle of a sun `degrees` across (1 for 0).
  auto cos_half_angle = [](float degrees) { return std::cos(0.5f * degrees * kPi / 180.0f); };
  for (PunctualLight& light : data.lights) {
    if (light.type == PunctualLight::Type::kDirectional)
      light.cos_half_angle = cos_half_angle(spec.sun_angle_deg);
    else
      light.radius = spec.light_radius;
  }
  // [[lights.lamp]]: one lamp by name, every light of that name (the glTF
  // node's); a name the scene does not have, or a size of the other kind,
  // is an error at the entry.
  for (const JobSpec::LampSize& size : spec.lamp_sizes) {
    const std::string at = fmt::format("lights.lamp.{}", size.index);
    bool found = false;
    for (PunctualLight& light : data.lights) {
      if (light.name != size.name) continue;
      found = true;
      const bool sun = light.type == PunctualLight::Type::kDirectional;
      if (sun && size.radius >= 0)
        throw SpecError(
            spec.where(at + ".radius"), at + ".radius",
            fmt::format("lamp \"{}\" is a directional light (a Sun): give sun_angle", size.name));
      if (!sun && size.sun_angle_deg >= 0)
        throw SpecError(spec.where(at + ".sun_angle"), at + ".sun_angle",
                        fmt::format("lamp \"{}\" is a point or spot lamp: give radius", size.name));
      if (sun)
        light.cos_half_angle = cos_half_angle(size.sun_angle_deg);
      else
        light.radius = size.radius;
    }
    if (!found) {
      std::vector<std::string> lamps;
      for (const PunctualLight& light : data.lights) lamps.push_back(light.name);
      const std::string names = quoted_list(lamps);
      throw SpecError(
          spec.where(at + ".name"), at + ".name",
          fmt::format("the scene {} has no lamp named \"{}\"; its lamps: {}", spec.scene.string(),
                      size.name, names.empty() ? std::string("none") : names));
    }
  }
  // Blender's exporter leaves out every lamp's size, which Blender
  // renders with (a new lamp's Radius is 0.25 m, 0.1 m for the lamp of
  // Blender's start-up scene, a Sun's Angle 0.526 degrees), and the World
  // (the start-up scene's is a uniform grey of 0.0509). A job that gives
  // neither is told, once, what renders differently and which keys say it.
  if (written_by_blender(data)) {
    std::vector<std::string> missing;
    if (!data.lights.empty() && spec.light_radius == 0 && spec.sun_angle_deg == 0 &&
        spec.lamp_sizes.empty())
      missing.push_back(
          "its lamps' Radius and Sun Angle (they render as points and parallel light, with "
          "hard shadows; set lights.radius in metres, Blender's default 0.25 or 0.1 for the "
          "start-up scene's lamp, and lights.sun_angle in degrees, default 0.526)");
    if (!spec.environment)
      missing.push_back(
          "its World (the scene renders without sky light, on black; set [environment], "
          "e.g. color = [0.0509, 0.0509, 0.0509] for the start-up scene's World)");
    if (!missing.empty()) {
      std::string what = missing[0];
      for (size_t i = 1; i < missing.size(); ++i) what += ", nor " + missing[i];
      spdlog::warn("{}: written by Blender, whose glTF export does not carry {}",
                   spec.scene.string(), what);
    }
  }
  return data;
}

std::shared_ptr<const Scene> load_scene(const JobSpec& spec) {
  SceneData data = load_job_scene_data(spec);
  std::unique_ptr<Environment> env;
  if (spec.environment) env = Environment::from_spec(*spec.environment);
  return std::make_shared<Scene>(std::move(data), std::move(env));
}

}  // namespace dofarm::render
