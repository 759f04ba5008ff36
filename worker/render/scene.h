// The render-ready scene: SceneData in an Embree BVH, plus its lights.
// Built once per (scene file, job) and shared read-only by all threads.
#pragma once

#include <embree3/rtcore.h>

#include <cmath>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

#include "common/jobspec.h"
#include "worker/render/bsdf.h"
#include "worker/render/camera.h"
#include "worker/render/distribution.h"
#include "worker/render/environment.h"
#include "worker/render/scene_data.h"

namespace dofarm::render {

// Everything the integrator needs at a ray hit, textures already applied.
struct SurfaceHit {
  float t = 0;
  Vec3 p;
  Vec3 ng;  // geometric normal, facing the incoming ray
  Vec3 ns;  // shading normal, same side as ng
  Vec2 uv;  // TEXCOORD_0 (barycentrics where the scene has none)
  Vec2 uv1;  // TEXCOORD_1 where the scene has it (SceneData::uvs1), else uv
  uint32_t prim = 0;
  Vec3 base_color;
  float metallic = 0, roughness = 0, ior = 1.5f;
  float specular = 1.0f;      // KHR_materials_specular specularFactor
  Vec3 specular_color{1.0f};  // and specularColorFactor
  float transmission = 0;     // KHR_materials_transmission transmissionFactor
  Vec3 attenuation;           // KHR_materials_volume absorption coefficient (per unit length)
  float clearcoat = 0, clearcoat_roughness = 0;  // KHR_materials_clearcoat
  Vec3 coat_ns;  // the coat's own shading normal where it differs from ns, else zero
  Vec3 sheen_color;                              // KHR_materials_sheen
  float sheen_roughness = 0;
  bool front = true;          // the ray hit the side the triangle's winding faces
  Vec3 emission;  // radiance leaving the surface (both faces emit)
  // Where a texture slot reads this hit: its set's coordinates, transformed.
  Vec2 uv_of(const UvTransform& t) const { return t.apply(t.set == 1 ? uv1 : uv); }
};

// One ray as the renderer asked Scene for it: a closest-hit query over
// [t_min, t_max] (a camera ray between clipping planes; else [0, inf)) or
// a shadow query over [0, t_max].
struct TracedRay {
  Vec3 o, d;
  float t_max = 0;
  bool shadow = false;
  float t_min = 0;
  // Closest-hit rays traced together as one Embree packet
  // (intersect_packet): the packet's size on its first ray, 0 on the others
  // and on every ray traced alone.
  uint8_t packet = 0;
};

// Receives every ray Scene traces while it is set (benchmarks replay a
// render's own rays, bench/render_throughput). Called from every render
// thread at once: implementations synchronise themselves.
class RaySink {
 public:
  virtual ~RaySink() = default;
  virtual void record(const TracedRay& ray) = 0;
};

struct LightSample {
  Vec3 wi;             // towards the light
  float distance = 0;  // to the light point (infinity for the environment)
  Vec3 radiance;
  float pdf = 0;  // solid angle, including the light-selection probability
  // A point, spot or directional light without a size: `pdf` is then the
  // selection probability alone and `radiance` the irradiance-giving
  // intensity over distance squared; no BSDF sample can hit it, so MIS does
  // not weigh it. A lamp with a size (PunctualLight::radius,
  // cos_half_angle) is an area light like any other: radiance and
  // solid-angle pdf, and BSDF samples reach it (Scene::lamps_along).
  bool is_delta = false;
};

class Scene {
 public:
  // Throws SpecError if the scene has no triangles or no light at all.
  Scene(SceneData data, std::unique_ptr<Environment> environment);
  ~Scene();
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  // The closest hit. On a hit every field of *hit is written (callers may
  // reuse a record without resetting it; CameraPackets.IntersectWritesEveryFieldOfAHit);
  // on a miss *hit is left as it was.
  bool intersect(const Ray& ray, SurfaceHit* hit) const;
  // intersect() of n rays at once: found[k] and hits[k] as intersect(rays[k],
  // &hits[k]) gives them (CameraPackets.HitsAreSingleRayHits: bit for bit,
  // but where a ray meets two triangles at exactly one distance, when either
  // may be reported). Traced kPacket at a time as one Embree packet
  // (rtcIntersect8), which for rays that nearly share an origin and a
  // direction, such as one pixel's camera rays through the lens, visits
  // each BVH node once for all of them (bench/README.md, "Camera rays as
  // packets"). Not marked coherent: Embree's coherent traversal returned
  // wrong hits for an orthographic camera's parallel rays. Counted and
  // recorded (a RaySink) one ray at a time, in order. Single rays where the
  // Embree build has no native 8-wide packets.
  static constexpr int kPacket = 8;
  void intersect_packet(const Ray* rays, int n, SurfaceHit* hits, bool* found) const;
  // Off: intersect_packet() traces one ray at a time (the same hits), for
  // tests and benchmarks that compare the two. Not to be changed while a
  // render uses the scene; a pose (at_time()) is a scene of its own and
  // traces packets.
  void set_packet_tracing(bool on) { packet_tracing_ = on; }
  // The Embree packet intersect_packet() traces for rays[0, n), n <= kPacket
  // (lanes past n invalid), for benchmarks that trace bare Embree;
  // `valid` has kPacket entries. Both 32-byte aligned.
  static void embree_packet(const Ray* rays, int n, RTCRayHit8* rh, int* valid);
  bool occluded(Vec3 origin, Vec3 dir, float t_max) const;
  // Origin for a ray leaving `hit` in direction `dir`, pushed off the surface
  // by an amount that scales with the coordinates (works from 1e-4 to 1e5).
  Vec3 offset_origin(const SurfaceHit& hit, Vec3 dir) const;
  // The BSDF constants of triangle `prim`'s material, computed once
  // (BsdfConstants); null where the material textures one of its scalar
  // factors, and each hit computes its own.
  const BsdfConstants* bsdf_constants(uint32_t prim) const {
    return material_bsdf_[data_.tri_material[prim]];
  }

  // The scene's data. Its `textures` are empty: the texels live in
  // textures(), shared by every pose of the scene.
  const SceneData& data() const { return data_; }
  const std::vector<Texture>& textures() const { return *textures_; }
  const Environment* environment() const { return environment_.get(); }
  // The scene at `time` seconds (a frame's time, frame_time()): this scene
  // itself where nothing moves (SceneData::motion is null), else a scene of
  // pose(data(), time) that shares this one's textures and environment,
  // built on first use and kept for the last two times asked for (a worker
  // renders the tiles of a frame or two at a time). Thread-safe.
  std::shared_ptr<const Scene> at_time(float time) const;
  bool has_lights() const { return !light_tris_.empty() || env_sampled_ || !data_.lights.empty(); }

  // Next-event estimation: pick a light by power (emissive triangles, the
  // punctual lights, the environment), then a point on it. A punctual light's
  // sample is_delta: its pdf is the selection probability alone.
  bool sample_light(Vec3 from, float u_select, Vec2 u, LightSample* out) const {
    return sample_light(from, choose_light(u_select, u), out);
  }
  // The same in two steps (a caller that traces a ray between them hides the
  // environment map's memory traffic behind it): choose_light() selects the
  // light and, for the environment, its map block (starting to load it);
  // sample_light(from, choice) gives exactly what sample_light(from,
  // u_select, u) gives. With `facing` (the unit geometric normal of the
  // surface that asks, facing the ray that arrived), an environment block
  // that lies wholly below that surface is marked (below()) and not
  // loaded: a BSDF that rejects every direction below its geometric normal
  // (Bsdf::in_lanes()) need not take the sample at all.
  struct LightChoice {
    size_t light = 0;  // index in the selection (triangles, punctual, environment)
    float pmf = 0;     // its selection probability
    Vec2 u;
    Environment::Choice env;  // when the environment was selected
    bool below() const { return env.below; }
  };
  LightChoice choose_light(float u_select, Vec2 u, const Vec3* facing = nullptr) const;
  bool sample_light(Vec3 from, const LightChoice& choice, LightSample* out) const;
  // sample_light(from[k], *choices[k], out[k]) for k < n at once, its
  // result in ok[k]: the same samples, the environment's taken together
  // (Environment::sample of several choices).
  void sample_lights(int n, const Vec3* from, const LightChoice* const* choices,
                     LightSample* const* out, bool* ok) const;
  // Solid-angle pdf that sample_light() would give to reaching `hit` (an
  // emissive triangle) from `from`.
  float light_pdf(Vec3 from, const SurfaceHit& hit) const;
  // The lamps with a size (a disk facing the lit point, a sun's disc) that
  // a ray from `from` along the unit `dir` passes before `t_max` (infinity:
  // the ray escapes, and a sun's disc can be seen): the sum of their
  // radiances, each times weight(its solid-angle pdf under sample_light(),
  // selection included). The lamps are emitters that neither block nor
  // scatter light (shadow rays ignore them too); a camera ray is not to
  // ask, as in Cycles, which does not show lamps to the camera.
  bool has_sized_lamps() const { return !sized_lamps_.empty(); }
  template <class Weight>
  Vec3 lamps_along(Vec3 from, Vec3 dir, float t_max, Weight weight) const {
    Vec3 sum(0);
    for (uint32_t i : sized_lamps_) {
      float pdf;
      const Vec3 le = lamp_hit(i, from, dir, t_max, &pdf);
      if (pdf > 0) sum += le * weight(pdf);
    }
    return sum;
  }
  // The environment's radiance towards `dir` (which must have one) and the
  // solid-angle pdf sample_light() would give to that direction (selection
  // probability included), from one lookup.
  Vec3 environment_radiance(Vec3 dir, float* pdf) const {
    return environment_radiance(environment_->locate(dir), dir, pdf);
  }
  // The same for a direction already located (Environment::locate).
  Vec3 environment_radiance(const Environment::Located& at, Vec3 dir, float* pdf) const;

  float radius() const { return radius_; }
  Vec3 center() const { return center_; }

  // Triangle lights close to the receiver are sampled by solid angle (on by
  // default; see by_solid_angle()). Off samples every triangle light by
  // area, the estimator before solid-angle sampling, kept for benchmarks
  // (render_spp --area-lights). Not to be changed while a render uses the
  // scene.
  void set_solid_angle_lights(bool on) { solid_angle_lights_ = on; }

  // Off (null) by default, then it costs one pointer test per ray. Not to be
  // changed while a render uses the scene.
  void set_ray_sink(RaySink* sink) { ray_sink_ = sink; }
  // The Embree scene, for benchmarks that trace with bare rtcIntersect1.
  RTCScene embree_scene() const { return rtc_scene_; }
  // The context every query of embree_scene() passes (&ctx.rtc), bare
  // queries too: the alpha-mask filter reads from it the scene that traces,
  // which need not be the one that built the BVH (a pose shares it).
  struct EmbreeContext {
    RTCIntersectContext rtc;  // first: what Embree is handed and hands back
    const Scene* scene = nullptr;
  };
  EmbreeContext embree_context() const {
    EmbreeContext ctx;
    rtcInitIntersectContext(&ctx.rtc);
    ctx.scene = this;
    return ctx;
  }
  // Whether this scene traces through `other`'s BVH (a pose that moves only
  // lamps shares the loaded scene's: at_time()).
  bool shares_bvh_with(const Scene& other) const { return bvh_ == other.bvh_; }
  // Whether a ray passes the point at barycentrics (b1, b2) of triangle
  // `prim` (an Embree filter function asks): its material's alpha (alpha =
  // base_alpha times the base colour texture's alpha) is below alpha_cutoff
  // (glTF alphaMode MASK), or, for BLEND, a uniform number drawn from a
  // hash of the ray (`ray`: its origin and direction, hashed only for
  // BLEND) and the triangle is at least alpha, so a ray stops with
  // probability alpha and the same ray always decides the same way. False
  // for materials without alpha.
  bool cut_out(uint32_t prim, float b1, float b2, const float (&ray)[6]) const;

 private:
  // The hit record of `ray`'s closest hit: triangle `prim` at barycentrics
  // (b1, b2), distance t, as Embree reported it.
  void complete_hit(const Ray& ray, uint32_t prim, float b1, float b2, float t,
                    SurfaceHit* hit) const;
  // m's emission where its emission texture reads `uv` (coordinates of the
  // texture's set, untransformed).
  Vec3 material_emission(const Material& m, Vec2 uv) const;
  // The unit normal n (front side, unflipped) bent by the normal map
  // `tex` of the given scale at the barycentrics (b0, b1, b2) of triangle
  // `idx`, the map read at `st` (transformed coordinates); n where it
  // cannot be.
  Vec3 normal_mapped(int tex, float scale, const uint32_t* idx, float b0, float b1, float b2,
                     Vec3 n, Vec2 st) const;
  // Shading normals at a hit on triangle `prim` (vertices `idx`) by a ray
  // along d, on the ray's side of the geometric normal ng (facing it):
  // interpolated from the vertex normals (ng without them), or that normal
  // bent by a normal map. ng where the result would face away from the ray.
  Vec3 smooth_normal(const uint32_t* idx, float b0, float b1, float b2, Vec3 ng, Vec3 d) const;
  Vec3 mapped_normal(int tex, float scale, Vec2 st, uint32_t prim, const uint32_t* idx, float b0,
                     float b1, float b2, Vec3 ng, Vec3 d) const;
  float triangle_area(uint32_t prim) const;
  // u: the light sample's numbers, for a lamp with a size.
  bool sample_punctual(const PunctualLight& light, Vec3 from, Vec2 u, LightSample* out) const;
  // Lamp data_.lights[i] (one with a size) where the ray (from, dir, t_max)
  // meets it: its radiance, and *pdf the solid-angle pdf sample_light()
  // gives that direction (0 where the ray misses it).
  Vec3 lamp_hit(uint32_t i, Vec3 from, Vec3 dir, float t_max, float* pdf) const;
  // Whether sample_light() and light_pdf() treat light triangle i, seen
  // from `from`, by its solid angle (worker/render/spherical_triangle.h)
  // rather than by area: where `from` is closer to the triangle's centroid
  // than its longest edge, the area pdf's r^2 / cos factor varies widely over
  // the triangle and grows without bound near it. Farther away it is bounded
  // and area sampling is cheaper (measured: bench/README.md, "Triangle
  // lights by solid angle").
  // Sets *solid_angle when true (0 where the triangle is seen edge-on, and
  // for a point in its plane: then neither technique samples it there).
  bool by_solid_angle(size_t i, Vec3 from, double* solid_angle) const;
  // Whether light i of the selection is the environment (after the
  // triangles and the punctual lights).
  bool is_environment_light(size_t i) const {
    return i >= light_tris_.size() + data_.lights.size();
  }
  // sample_light()'s result for an environment sample of selection
  // probability pmf (false: a sample of pdf 0).
  static bool environment_light(const EnvSample& es, float pmf, LightSample* out);
  // Texture coordinates of set `set` (TEXCOORD_0 or _1; set 0 where the
  // scene has no TEXCOORD_1) at barycentrics (b0, b1, b2) of the triangle `idx`.
  Vec2 texcoord(const uint32_t* idx, float b0, float b1, float b2, unsigned set = 0) const;
  // The same at a point p in the plane of the triangle `idx`.
  Vec2 texcoord_at(const uint32_t* idx, Vec3 p, unsigned set = 0) const;

  // Embree's device and BVH over a scene's triangles, which own copies of
  // the vertices and indices, so a pose can outlive the scene that built it.
  struct Bvh;
  // A pose of a moving scene at `time` (at_time()); `bvh`: the BVH of
  // triangles exactly where `posed` has them, or null to build one.
  Scene(SceneData posed, std::shared_ptr<const std::vector<Texture>> textures,
        std::shared_ptr<const Environment> environment, float time, std::shared_ptr<const Bvh> bvh);
  // The lights and their selection from data_, and the BVH unless bvh_ is
  // given.
  void build();
  void build_bvh();

  SceneData data_;
  std::shared_ptr<const std::vector<Texture>> textures_;
  std::shared_ptr<const Environment> environment_;
  float pose_time_ = std::nanf("");  // NaN: the scene as loaded
  mutable std::mutex posed_mutex_;
  mutable std::vector<std::pair<float, std::shared_ptr<const Scene>>> posed_;
  std::shared_ptr<const Bvh> bvh_;
  RTCScene rtc_scene_ = nullptr;  // bvh_'s
  bool packet_tracing_ = true;
  // Unit geometric normal of each triangle, cross(p1 - p0, p2 - p0); zero for
  // a degenerate one (a hit on it faces the ray instead).
  std::vector<Vec3> tri_normal_;
  std::vector<uint32_t> light_tris_;
  std::vector<float> light_tri_area_;
  struct NearLight {  // where a light triangle is sampled by solid angle
    Vec3 centroid;
    float edge2 = 0;  // its longest edge, squared
  };
  std::vector<NearLight> light_tri_near_;
  bool solid_angle_lights_ = true;
  std::vector<int> light_index_of_prim_;  // -1 where not a light
  // bsdf_constants(): per material, into bsdf_constants_ or null.
  std::vector<BsdfConstants> bsdf_constants_;
  std::vector<const BsdfConstants*> material_bsdf_;
  // Selection over light_tris_, then data_.lights, then (if sampled) the
  // environment.
  Distribution1D light_select_;
  std::vector<uint32_t> sized_lamps_;  // indices in data_.lights with a size and a share
  bool env_sampled_ = false;
  float env_select_pmf_ = 0;
  Vec3 center_{0};
  float radius_ = 1;
  float offset_scale_ = 1e-4f;
  RaySink* ray_sink_ = nullptr;
};

// Rays traced by the calling thread so far (closest-hit and shadow rays);
// per thread, so counting costs no synchronisation.
struct RayCount {
  uint64_t closest = 0;
  uint64_t shadow = 0;
  // Light samples next-event estimation took (a point or direction of
  // positive pdf); a shadow ray follows only those the BSDF does not
  // reject (facing away from the surface).
  uint64_t light_samples = 0;
  // Of those, the ones known to fall below their surface before they were
  // made (Environment::Choice::below), and so never made.
  uint64_t light_samples_skipped = 0;
  uint64_t total() const { return closest + shadow; }
};
RayCount thread_ray_count();
// Adds n to this thread's light samples (the integrator's), `skipped` of
// them never made.
void count_light_samples(uint64_t n, uint64_t skipped = 0);

// The job's scene file with what the job adds to it: its lamps' sizes
// ([lights]; a warning where a Blender file's lamps stay points).
SceneData load_job_scene_data(const JobSpec& spec);

// Loads the job's scene file (load_job_scene_data) and environment and
// builds the Scene.
std::shared_ptr<const Scene> load_scene(const JobSpec& spec);

}  // namespace dofarm::render
