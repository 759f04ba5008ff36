// What a moving scene costs per frame: Scene::at_time() poses the moving
// meshes (pose(), worker/render/scene_motion.h) and builds the frame's BVH
// and lights again, once per frame and worker. Here a grid of N triangles
// under one rotating node, lit by a constant environment: the seconds of
// pose() alone, of at_time() (pose and build), and of rendering that
// frame's reference at 256 x 256 and --spp samples on --threads threads,
// with the share at_time() adds to the frame. A scene where nothing but the
// camera moves pays none of it (at_time() returns the scene itself).
// `--moving lamp`: the grid stands still and a point lamp circles above it
// on the turning node; such a pose shares the loaded scene's BVH and
// builds only its lights again.
// Asserts nothing; the machine is shared, so read the shares, not the
// absolute seconds.
//
// Usage: pose_cost [--spp 16] [--threads 2] [--triangles 20000,200000,2000000]
//                  [--moving grid|lamp]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "worker/render/render_job.h"
#include "worker/render/scene.h"
#include "worker/render/scene_motion.h"

namespace {

using dofarm::Quat;
using dofarm::Vec2;
using dofarm::Vec3;
using namespace dofarm::render;

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// A wavy n x n grid of quads (2 n^2 triangles) in the xz plane, 4 m wide,
// moved as a whole by one node that turns about y over 2 s; or (lamp) the
// grid still and a point lamp 1 m up, 1 m off the axis, on that node.
SceneData moving_grid(int n, bool lamp) {
  SceneData d;
  std::vector<Vec3> p, nrm;
  std::vector<uint32_t> idx;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) {
      const float x = 4.0f * float(i) / float(n) - 2.0f, z = 4.0f * float(j) / float(n) - 2.0f;
      p.emplace_back(x, 0.1f * std::sin(3.0f * x) * std::cos(2.0f * z), z);
      nrm.emplace_back(0.0f, 1.0f, 0.0f);
    }
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const uint32_t a = uint32_t(j * (n + 1) + i), b = a + 1, c = a + uint32_t(n + 1), e = c + 1;
      idx.insert(idx.end(), {a, c, b, b, c, e});
    }
  Material m;
  m.base_color = Vec3(0.7f);
  d.add_mesh(p, nrm, {}, idx, m);
  auto motion = std::make_shared<SceneMotion>();
  MotionNode node;
  node.rotation_keys.times = {0.0f, 2.0f};
  const float h = std::sqrt(0.5f);
  node.rotation_keys.values = {Quat{}, Quat{h, 0, h, 0}};
  motion->nodes.push_back(node);
  if (lamp) {
    PunctualLight l;
    l.position = Vec3(1, 1, 0);
    l.intensity = Vec3(1.0f);
    d.lights.push_back(l);
    MovingLight ml;
    ml.position = l.position;
    motion->lights.push_back(ml);
  } else {
    MovingPart part;
    part.vertex_count = uint32_t(p.size());
    part.index_count = uint32_t(idx.size());
    motion->parts.push_back(part);
    motion->positions = p;
    motion->normals = nrm;
  }
  d.motion = motion;
  return d;
}

dofarm::JobSpec spec_of(int spp) {
  dofarm::JobSpec s;
  s.spec_path = "pose_cost";
  s.scene = "pose_cost";
  s.width = s.height = 256;
  s.frame_start = 0;
  s.frame_end = 48;
  s.fps = 24;
  s.versions = 1;
  s.reference_spp = spp;
  s.albedo_ref_spp = 1;
  dofarm::CameraKey k;
  k.position = Vec3(0, 4, 4);
  k.look_at = Vec3(0, 0, 0);
  k.fov_deg = 50;
  k.focal_distance = 5.6f;
  s.camera_keys.push_back(k);
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  int spp = 16, threads = 2;
  bool lamp = false;
  std::vector<int> triangles = {20000, 200000, 2000000};
  for (int i = 1; i < argc; ++i) {
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "pose_cost: %s needs a value\n", argv[i]);
        std::exit(2);
      }
      return argv[++i];
    };
    if (!std::strcmp(argv[i], "--spp")) {
      spp = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--threads")) {
      threads = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--moving")) {
      const std::string what = value();
      if (what != "grid" && what != "lamp") {
        std::fprintf(stderr, "pose_cost: --moving is grid or lamp, not '%s'\n", what.c_str());
        return 2;
      }
      lamp = what == "lamp";
    } else if (!std::strcmp(argv[i], "--triangles")) {
      triangles.clear();
      std::stringstream list(value());
      for (std::string t; std::getline(list, t, ',');) triangles.push_back(std::atoi(t.c_str()));
    } else {
      std::fprintf(stderr,
                   "usage: pose_cost [--spp 16] [--threads 2] [--triangles 20000,200000] "
                   "[--moving grid|lamp]\n");
      return 2;
    }
  }
  const dofarm::JobSpec spec = spec_of(spp);
  RenderOptions options;
  options.threads = threads;
  options.reference_only = true;
  std::printf(
      "| triangles (%s moves) | pose() s | at_time() s (pose + BVH + lights) | frame render s (%d "
      "spp, 256^2, %d threads) | at_time / render |\n",
      lamp ? "a lamp" : "the grid", spp, threads);
  std::printf("| --- | --- | --- | --- | --- |\n");
  for (int t : triangles) {
    const int n = std::max(1, int(std::lround(std::sqrt(double(t) / 2.0))));
    auto scene =
        std::make_shared<Scene>(moving_grid(n, lamp), std::make_unique<Environment>(Vec3(1.0f)));
    auto t0 = std::chrono::steady_clock::now();
    const SceneData posed = pose(scene->data(), 0.5f);
    const double pose_s = seconds_since(t0);
    // Frame 12 (0.5 s): at_time() builds the pose; render_frame() then finds it cached.
    t0 = std::chrono::steady_clock::now();
    auto at = scene->at_time(frame_time(spec, 12));
    const double at_s = seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    render_frame(*scene, spec, 12, std::nullopt, options);
    const double render_s = seconds_since(t0);
    std::printf("| %zu | %.4f | %.4f | %.3f | %.3f |\n", posed.triangle_count(), pose_s, at_s,
                render_s, at_s / render_s);
  }
  return 0;
}
