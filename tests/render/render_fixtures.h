// Small scenes and job specs built in code for the renderer's tests.
#pragma once

#include <cmath>
#include <cstring>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "common/error.h"
#include "common/image.h"
#include "common/jobspec.h"
#include "worker/render/environment.h"
#include "worker/render/render_job.h"
#include "worker/render/scene.h"
#include "worker/render/shapes.h"

namespace dofarm::render::testing {

// A one-key job looking from `from` to `to`; small buffers by default.
inline JobSpec make_spec(int w, int h, Vec3 from, Vec3 to, float fov = 40.0f, float focal = 1.0f,
                         float aperture = 0.0f) {
  JobSpec s;
  s.spec_path = "test.toml";
  s.scene = "test-scene";
  s.seed = 11;
  s.width = w;
  s.height = h;
  s.frame_start = 0;
  s.frame_end = 0;
  s.versions = 2;
  s.reference_spp = 16;
  s.albedo_ref_spp = 4;
  CameraKey k;
  k.position = from;
  k.look_at = to;
  k.fov_deg = fov;
  k.focal_distance = focal;
  k.aperture = aperture;
  s.camera_keys.push_back(k);
  return s;
}

inline Material diffuse(Vec3 color, float ior = 1.5f) {
  Material m;
  m.base_color = color;
  m.metallic = 0;
  m.roughness = 1;
  m.ior = ior;
  return m;
}

// KHR_materials_transmission 1: glass of this roughness and IOR.
inline Material glass(float roughness, Vec3 color = Vec3(1), float ior = 1.5f) {
  Material m;
  m.base_color = color;
  m.metallic = 0;
  m.roughness = roughness;
  m.ior = ior;
  m.transmission = 1;
  return m;
}

inline Material emitter(Vec3 radiance) {
  Material m = diffuse(Vec3(0));
  m.emission = radiance;
  return m;
}

inline std::unique_ptr<Scene> make_scene(SceneData data, std::unique_ptr<Environment> env = {}) {
  return std::make_unique<Scene>(std::move(data), std::move(env));
}

inline std::unique_ptr<Environment> constant_env(float radiance) {
  return std::make_unique<Environment>(Vec3(radiance));
}

// A Cornell-like room, open towards +z, with a ceiling light and two objects.
inline SceneData small_room(float scale = 1.0f) {
  SceneData d;
  auto S = [scale](Vec3 v) { return v * scale; };
  Material white = diffuse(Vec3(0.7f));
  add_quad(d, S(Vec3(0, 0, 0)), S(Vec3(0, 0, 1)), S(Vec3(1, 0, 0)), white);   // floor
  add_quad(d, S(Vec3(0, 2, 0)), S(Vec3(1, 0, 0)), S(Vec3(0, 0, 1)), white);   // ceiling
  add_quad(d, S(Vec3(0, 1, -1)), S(Vec3(1, 0, 0)), S(Vec3(0, 1, 0)), white);  // back
  add_quad(d, S(Vec3(-1, 1, 0)), S(Vec3(0, 1, 0)), S(Vec3(0, 0, 1)),
           diffuse(Vec3(0.7f, 0.1f, 0.1f)));
  add_quad(d, S(Vec3(1, 1, 0)), S(Vec3(0, 0, 1)), S(Vec3(0, 1, 0)),
           diffuse(Vec3(0.1f, 0.7f, 0.1f)));
  add_quad(d, S(Vec3(0, 1.98f, 0)), S(Vec3(0.3f, 0, 0)), S(Vec3(0, 0, 0.3f)),
           emitter(Vec3(12, 11, 9)));  // faces down: cross(u, v) = -y
  Material metal;
  metal.base_color = Vec3(0.9f, 0.8f, 0.6f);
  metal.metallic = 1;
  metal.roughness = 0.3f;
  add_icosphere(d, S(Vec3(-0.4f, 0.4f, 0)), 0.4f * scale, 2, metal);
  Material plastic = diffuse(Vec3(0.2f, 0.5f, 0.8f));
  plastic.roughness = 0.4f;
  add_box(d, S(Vec3(0.1f, 0, -0.3f)), S(Vec3(0.7f, 0.8f, 0.3f)), plastic);
  return d;
}

// A frame camera at `from` looking at `to` (+y up), the rest as given.
inline CameraState posed_camera(Vec3 from, Vec3 to) {
  CameraState s;
  s.position[0] = from.x;
  s.position[1] = from.y;
  s.position[2] = from.z;
  const Quat q = quat_look_at(from, to, Vec3(0, 1, 0));
  s.rotation[0] = q.w;
  s.rotation[1] = q.x;
  s.rotation[2] = q.y;
  s.rotation[3] = q.z;
  return s;
}

// An opaque unit floor quad at y = 0 (default material) under an
// alphaMode BLEND quad of alpha `alpha` at y = 1, both over [0, 1] in x and z.
inline SceneData blend_over_floor(float alpha) {
  SceneData d;
  const std::vector<Vec2> uv = {{0, 0}, {0, 1}, {1, 1}, {1, 0}};
  const std::vector<uint32_t> idx = {0, 1, 2, 0, 2, 3};
  auto quad = [](float y) { return std::vector<Vec3>{{0, y, 0}, {0, y, 1}, {1, y, 1}, {1, y, 0}}; };
  Material floor, veil;
  veil.alpha_mask = veil.alpha_blend = true;
  veil.base_alpha = alpha;
  d.add_mesh(quad(0.0f), {}, uv, idx, floor);
  d.add_mesh(quad(1.0f), {}, uv, idx, veil);
  return d;
}

// Two walls side by side in the plane z = 0, facing +z: diffuse 0.2 for
// x < 0.55 and 0.8 beyond, their shared edge at x = 0.55, both 100 units
// tall (y from -50).
inline SceneData walls_side_by_side() {
  SceneData d;
  add_quad(d, Vec3(-50, -50, 0), Vec3(50.55f, 0, 0), Vec3(0, 100, 0), diffuse(Vec3(0.2f)));
  add_quad(d, Vec3(0.55f, -50, 0), Vec3(50, 0, 0), Vec3(0, 100, 0), diffuse(Vec3(0.8f)));
  return d;
}

// Keeps every ray a Scene traces while set (Scene::set_ray_sink), in the
// order they arrive.
class RayRecorder : public RaySink {
 public:
  void record(const TracedRay& ray) override {
    std::lock_guard<std::mutex> lock(mutex_);
    rays.push_back(ray);
  }
  std::vector<TracedRay> rays;

 private:
  std::mutex mutex_;
};

inline bool same_bytes(const FrameBuffers& a, const FrameBuffers& b) {
  for (const BufferInfo& info : buffer_infos()) {
    const auto& x = buffer_data(a, info.name);
    const auto& y = buffer_data(b, info.name);
    if (x.size() != y.size()) return false;
    if (std::memcmp(x.data(), y.data(), x.size() * sizeof(float)) != 0) return false;
  }
  return true;
}

}  // namespace dofarm::render::testing
