// Renderer throughput against the raw Embree rate, for each bundled scene.
//
// (a) The renderer: one frame of the job through render_frame() with all
//     threads; RenderStats gives the camera paths (pixels x (versions +
//     reference spp)) and every ray the renderer traced (closest-hit and
//     shadow, albedo and aux rays included), counted inside Scene, and how
//     many of its light samples were followed by a shadow ray.
// (b) Its own rays, replayed: the same frame rendered once more (untimed, one
//     thread) with a RaySink on the Scene that records every closest-hit and
//     shadow query in the order the renderer made it (camera rays, bounces,
//     NEE shadow rays with their t_max, albedo and aux rays). Those rays are
//     then traced again, on the same number of threads, in chunks of 4096
//     consecutive queries from a shared counter: once through
//     Scene::intersect / Scene::occluded / Scene::intersect_packet (the calls
//     the renderer makes, hit record included; camera rays in the packets
//     the renderer traced them in) and once through bare rtcIntersect1 /
//     rtcOccluded1 / rtcIntersect8.
// (c) Random rays (the old reference, kept for comparison): N incoherent rays,
//     origins uniform in the scene's bounding sphere, directions uniform on
//     the sphere, through Scene::intersect and Scene::occluded, weighted by the
//     renderer's closest/shadow mix.
// --constant-sky replaces the job's environment map by a grey sky of the
// map's mean luminance before anything is rendered: the same geometry,
// materials, camera and lens, with no map to sample or look up, so that
// the ratio shows what the map's tables and texels cost the renderer
// (bench/README.md, "What the courtyard's map costs").
// (a) is also timed with Scene::set_packet_tracing(false): the renderer as
// it is, but each camera ray traced alone (rtcIntersect1) instead of in the
// per-pixel packets of 8 (rtcIntersect8); the same rays, the same image.
// renderer rays/s / replayed rays/s says how much of the time the renderer
// spends outside ray queries (sampling, BSDFs, lights, buffers) on exactly
// its own workload.
//
// Each timed part runs inside a function of its own, never inlined
// (renderer_pass, replay_scene_pass, replay_bare_pass), so that
// bench/instruction_budget.sh can count the instructions of each exactly
// under callgrind (--toggle-collect).
//
// Usage: render_throughput [--size W] [--rays N] [--threads T] [--repeats R] [--area-lights]
//                          [--scene cornell|courtyard] [--constant-sky]
// Prints figures; asserts nothing.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "common/cpus.h"
#include "common/jobspec.h"
#include "worker/render/environment.h"
#include "worker/render/render_job.h"
#include "worker/render/scene.h"
#include "worker/render/scene_data.h"

namespace {

using dofarm::JobSpec;
using dofarm::Vec3;
using dofarm::render::Ray;
using dofarm::render::RenderOptions;
using dofarm::render::RenderStats;
using dofarm::render::Scene;
using dofarm::render::SurfaceHit;
using dofarm::render::TracedRay;
using Clock = std::chrono::steady_clock;

struct Args {
  int size = 256;  // image width; height keeps the job's aspect ratio
  int64_t rays = 2'000'000;
  int threads = 0;  // 0 = all hardware threads, as the renderer's default
  int repeats = 2;  // the best of R timings is reported (shared machines)
  bool area_lights = false;  // every triangle light by area (Scene::set_solid_angle_lights)
  std::string scene;         // empty: both scenes
  bool constant_sky = false;  // the map replaced by a grey sky of its mean luminance
};

Args parse_args(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    auto value = [&](const char* name) -> long long {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s: missing value\n", name);
        std::exit(2);
      }
      return std::atoll(argv[++i]);
    };
    if (!std::strcmp(argv[i], "--size")) {
      a.size = int(value("--size"));
    } else if (!std::strcmp(argv[i], "--rays")) {
      a.rays = value("--rays");
    } else if (!std::strcmp(argv[i], "--threads")) {
      a.threads = int(value("--threads"));
    } else if (!std::strcmp(argv[i], "--area-lights")) {
      a.area_lights = true;
    } else if (!std::strcmp(argv[i], "--constant-sky")) {
      a.constant_sky = true;
    } else if (!std::strcmp(argv[i], "--repeats")) {
      a.repeats = int(value("--repeats"));
    } else if (!std::strcmp(argv[i], "--scene") && i + 1 < argc) {
      a.scene = argv[++i];
      if (a.scene != "cornell" && a.scene != "courtyard") {
        std::fprintf(stderr, "render_throughput: --scene: \"%s\" is not cornell or courtyard\n",
                     a.scene.c_str());
        std::exit(2);
      }
    } else {
      std::fprintf(stderr,
                   "usage: render_throughput [--size 256] [--rays 2000000] [--threads 0] "
                   "[--repeats 2] [--area-lights] [--scene cornell|courtyard] [--constant-sky]\n");
      std::exit(2);
    }
  }
  if (a.size < 8 || a.rays < 1000 || a.threads < 0 || a.repeats < 1) {
    std::fprintf(stderr, "render_throughput: bad arguments\n");
    std::exit(2);
  }
  return a;
}

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

struct RendererFigures {
  double seconds = 0;  // best of the repeats
  uint64_t paths = 0, rays = 0;
  uint64_t shadow_rays = 0, light_samples = 0, light_samples_skipped = 0;
};

// Rays are generated before the clock starts, so the timing holds only
// traversal (and, for intersect, the hit record).
std::vector<Ray> random_rays(const Scene& scene, int64_t n, uint64_t seed) {
  std::vector<Ray> rays(static_cast<size_t>(n));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  const Vec3 c = scene.center();
  const float radius = scene.radius();
  for (Ray& ray : rays) {
    // Uniform in the ball: a uniform direction times radius * cbrt(u).
    auto direction = [&] {
      float z = 1.0f - 2.0f * uni(rng), phi = dofarm::kTwoPi * uni(rng);
      float s = std::sqrt(std::max(0.0f, 1.0f - z * z));
      return Vec3(s * std::cos(phi), s * std::sin(phi), z);
    };
    ray.o = c + direction() * (radius * std::cbrt(uni(rng)));
    ray.d = direction();
  }
  return rays;
}

// One query of the replay: a ray alone, or a packet of n rays from own[first].
struct Unit {
  uint32_t first = 0, n = 1;
};

struct RawFigures {
  double seconds = 0;
  int64_t hits = 0;
};

// Threads take chunks of the ray array from a shared counter, like the
// renderer's blocks.
template <class R, class Trace>
RawFigures trace_all(const std::vector<R>& rays, int threads, int repeats, Trace&& trace) {
  RawFigures best;
  best.seconds = 1e300;
  constexpr int64_t kChunk = 4096;
  const int64_t n = int64_t(rays.size());
  for (int r = 0; r < repeats; ++r) {
    std::atomic<int64_t> next{0};
    std::atomic<int64_t> hits{0};
    auto work = [&] {
      int64_t local = 0;
      for (int64_t begin = next.fetch_add(kChunk); begin < n; begin = next.fetch_add(kChunk)) {
        const int64_t end = std::min(n, begin + kChunk);
        for (int64_t i = begin; i < end; ++i) local += int64_t(trace(rays[size_t(i)]));
      }
      hits += local;
    };
    const auto t0 = Clock::now();
    std::vector<std::thread> pool;
    for (int t = 1; t < threads; ++t) pool.emplace_back(work);
    work();
    for (auto& t : pool) t.join();
    const double s = seconds_since(t0);
    if (s < best.seconds) best = {s, hits.load()};
  }
  return best;
}

// One render of the frame on `threads` threads, with its statistics.
RenderStats render_once(const Scene& scene, const JobSpec& spec, int frame, int threads) {
  RenderStats stats;
  RenderOptions options;
  options.threads = threads;
  options.stats = &stats;
  dofarm::render::render_frame(scene, spec, frame, std::nullopt, options);
  return stats;
}

// The timed parts, each in a function of its own that is never inlined
// (bench/instruction_budget.sh counts their instructions by name; the
// render without packets below is not one of them).
[[gnu::noinline]] RenderStats renderer_pass(const Scene& scene, const JobSpec& spec, int frame,
                                            int threads) {
  return render_once(scene, spec, frame, threads);
}

template <class Trace>
[[gnu::noinline]] RawFigures replay_scene_pass(const std::vector<Unit>& units, int threads,
                                               Trace&& trace) {
  return trace_all(units, threads, 1, trace);
}

template <class Trace>
[[gnu::noinline]] RawFigures replay_bare_pass(const std::vector<Unit>& units, int threads,
                                              Trace&& trace) {
  return trace_all(units, threads, 1, trace);
}

// Keeps every ray in the order it arrives; the capture render runs on one
// thread, so that is the renderer's own order.
class RayRecorder : public dofarm::render::RaySink {
 public:
  void record(const TracedRay& ray) override {
    std::lock_guard<std::mutex> lock(mutex_);
    rays_.push_back(ray);
  }
  std::vector<TracedRay> take() { return std::move(rays_); }

 private:
  std::mutex mutex_;
  std::vector<TracedRay> rays_;
};

struct Summary {
  std::string scene;
  double renderer = 0, replay_scene = 0, replay_bare = 0, random_mix = 0;  // rays/s
};
std::vector<Summary> g_summary;

void run_scene(const char* name, const char* job, int frame, const Args& args) {
  const std::string path = std::string(DOFARM_SOURCE_DIR) + "/jobs/" + job;
  JobSpec spec = dofarm::load_job_spec(path);
  const int full_w = spec.width, full_h = spec.height;
  spec.width = args.size;
  spec.height = std::max(1, int(std::lround(double(args.size) * full_h / full_w)));
  spec.versions = 4;
  spec.reference_spp = 16;
  spec.reference_error = 0;
  spec.albedo_ref_spp = 4;

  auto t0 = Clock::now();
  // As load_scene(), but not const: the capture sets a RaySink on it.
  std::unique_ptr<dofarm::render::Environment> env;
  if (spec.environment) env = dofarm::render::Environment::from_spec(*spec.environment);
  const bool replace_map = args.constant_sky && env && env->has_map();
  if (replace_map) env = std::make_unique<dofarm::render::Environment>(Vec3(env->mean_luminance()));
  auto scene = std::make_shared<Scene>(dofarm::render::load_job_scene_data(spec), std::move(env));
  scene->set_solid_angle_lights(!args.area_lights);
  const double load_s = seconds_since(t0);
  const int threads = args.threads > 0 ? args.threads : dofarm::cpus_available();

  std::printf("\n== %s (jobs/%s, frame %d, %dx%d, %zu triangles, load + BVH %.2f s, %d threads)\n",
              name, job, frame, spec.width, spec.height, scene->data().indices.size() / 3, load_s,
              threads);
  if (replace_map)
    std::printf(
        "the environment map replaced by a grey sky of its mean luminance, %.4g "
        "(--constant-sky)\n",
        double(scene->environment()->mean_luminance()));

  // The renderer's own rays, recorded by an untimed one-thread render (the
  // same rays as any thread count: renders are deterministic).
  RayRecorder recorder;
  {
    RenderOptions options;
    options.threads = 1;
    scene->set_ray_sink(&recorder);
    dofarm::render::render_frame(*scene, spec, frame, std::nullopt, options);
    scene->set_ray_sink(nullptr);
  }
  const std::vector<TracedRay> own = recorder.take();
  int64_t own_shadow = 0;
  for (const TracedRay& r : own) own_shadow += r.shadow ? 1 : 0;
  const double own_n = double(own.size());
  // Replayed as traced: a ray alone, or the camera rays of one packet
  // together (intersect_packet; rtcIntersect8 in the bare replay).
  std::vector<Unit> units;
  std::vector<Ray> own_rays;  // the closest-hit queries as Rays, for the packets
  own_rays.reserve(own.size());
  for (const TracedRay& r : own) own_rays.push_back(Ray{r.o, r.d, r.t_min, r.t_max});
  int64_t in_packets = 0;
  for (size_t i = 0; i < own.size();) {
    const uint32_t n =
        own[i].packet > 1 ? std::min<uint32_t>(own[i].packet, uint32_t(own.size() - i)) : 1;
    units.push_back({uint32_t(i), n});
    in_packets += n > 1 ? n : 0;
    i += n;
  }
  const std::vector<Ray> rays = random_rays(*scene, args.rays, 0x0dfa'2b00'7ea5'5eedULL);
  const float t_max = 2.0f * scene->radius();  // across the whole bounding sphere
  const RTCScene rtc = scene->embree_scene();

  // Each repeat times everything once, in turn, so that a burst of load on a
  // shared machine hits all figures alike; the best of each is kept.
  RendererFigures rf;
  rf.seconds = 1e300;
  double single_seconds = 1e300;
  RawFigures replay{1e300, 0}, bare{1e300, 0}, closest{1e300, 0}, shadow{1e300, 0};
  auto keep_best = [](RawFigures* best, RawFigures now) {
    if (now.seconds < best->seconds) *best = now;
  };
  for (int rep = 0; rep < args.repeats; ++rep) {
    {  // (a) the renderer, then the same with camera rays traced one at a time
      const RenderStats stats = renderer_pass(*scene, spec, frame, args.threads);
      rf.paths = stats.paths;
      rf.rays = stats.rays;
      rf.shadow_rays = stats.shadow_rays;
      rf.light_samples = stats.light_samples;
      rf.light_samples_skipped = stats.light_samples_skipped;
      rf.seconds = std::min(rf.seconds, stats.seconds);
      scene->set_packet_tracing(false);
      const RenderStats single = render_once(*scene, spec, frame, args.threads);
      scene->set_packet_tracing(true);
      single_seconds = std::min(single_seconds, single.seconds);
    }
    // (b) its own rays through the calls the renderer makes, then bare Embree
    keep_best(&replay, replay_scene_pass(units, threads, [&](const Unit& u) -> int64_t {
      const TracedRay& r = own[u.first];
      if (u.n > 1) {
        SurfaceHit hits[Scene::kPacket];
        bool found[Scene::kPacket];
        scene->intersect_packet(&own_rays[u.first], int(u.n), hits, found);
        return std::count(found, found + u.n, true);
      }
      if (r.shadow) return scene->occluded(r.o, r.d, r.t_max);
      SurfaceHit hit;
      return scene->intersect(Ray{r.o, r.d, r.t_min, r.t_max}, &hit);
    }));
    keep_best(&bare,
              replay_bare_pass(units, threads, [&](const Unit& u) -> int64_t {
                const TracedRay& r = own[u.first];
                Scene::EmbreeContext ctx = scene->embree_context();
                if (u.n > 1) {
                  alignas(32) int valid[Scene::kPacket];
                  alignas(32) RTCRayHit8 rh;
                  Scene::embree_packet(&own_rays[u.first], int(u.n), &rh, valid);
                  rtcIntersect8(valid, rtc, &ctx.rtc, &rh);
                  int64_t hits = 0;
                  for (uint32_t k = 0; k < u.n; ++k)
                    hits += rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID ? 1 : 0;
                  return hits;
                }
                if (r.shadow) {
                  RTCRay ray{r.o.x, r.o.y, r.o.z, 0.0f, r.d.x, r.d.y, r.d.z, 0.0f,
                             r.t_max, 0xffffffffu, 0, 0};
                  rtcOccluded1(rtc, &ctx.rtc, &ray);
                  return ray.tfar < 0;
                }
                RTCRayHit rh;
                rh.ray = {r.o.x, r.o.y, r.o.z,   r.t_min,     r.d.x, r.d.y,
                          r.d.z, 0.0f,  r.t_max, 0xffffffffu, 0,     0};
                rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
                rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
                rtcIntersect1(rtc, &ctx.rtc, &rh);
                return rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
              }));
    // (c) random rays, the old reference
    keep_best(&closest, trace_all(rays, threads, 1, [&](const Ray& ray) {
                SurfaceHit hit;
                return scene->intersect(ray, &hit);
              }));
    keep_best(&shadow, trace_all(rays, threads, 1, [&](const Ray& ray) {
                return scene->occluded(ray.o, ray.d, t_max);
              }));
  }

  const double paths_per_s = rf.paths / rf.seconds;
  const double rays_per_s = rf.rays / rf.seconds;
  const double rays_per_path = double(rf.rays) / double(rf.paths);
  std::printf(
      "renderer: versions %d + reference %d spp (+ albedo_ref %d spp, aux), best of %d: %.3f s\n",
      spec.versions, spec.reference_spp, spec.albedo_ref_spp, args.repeats, rf.seconds);
  std::printf("  paths %llu  rays %llu  (%.2f rays/path)\n", (unsigned long long)rf.paths,
              (unsigned long long)rf.rays, rays_per_path);
  std::printf("  %.3f Mpaths/s  %.3f Mrays/s\n", paths_per_s * 1e-6, rays_per_s * 1e-6);
  // A light sample the BSDF rejects (behind the surface) traces nothing; it
  // costs its sampling, unless it was known to fall below the surface
  // before it was made (Environment::Choice::below: skipped).
  auto share = [&](uint64_t part) {
    return rf.light_samples ? 100.0 * double(part) / double(rf.light_samples) : 0.0;
  };
  std::printf(
      "  light samples %llu, of which %.1f%% reached a shadow ray, %.1f%% skipped below "
      "their surface before they were made\n",
      (unsigned long long)rf.light_samples, share(rf.shadow_rays), share(rf.light_samples_skipped));
  std::printf(
      "  camera rays one at a time instead of in packets (Scene::set_packet_tracing): "
      "%.3f s, %.3f Mrays/s (packets %.2fx as fast)\n",
      single_seconds, rf.rays / single_seconds * 1e-6, single_seconds / rf.seconds);

  const double replay_rate = own_n / replay.seconds;
  const double bare_rate = own_n / bare.seconds;
  std::printf("the renderer's own rays, replayed (%zu recorded%s, %.1f%% shadow, %.0f%% hit or "
              "occluded, best of %d):\n",
              own.size(), own.size() == rf.rays ? ", = rays above" : ", != rays above!",
              100.0 * double(own_shadow) / own_n, 100.0 * double(replay.hits) / own_n,
              args.repeats);
  std::printf("  (%.1f%% of them camera rays in packets of up to %d, replayed as packets)\n",
              100.0 * double(in_packets) / own_n, Scene::kPacket);
  std::printf("  Scene::intersect/occluded (as the renderer):  %.3f Mrays/s\n",
              replay_rate * 1e-6);
  std::printf("  bare rtcIntersect1/rtcOccluded1:              %.3f Mrays/s\n", bare_rate * 1e-6);

  const double closest_rate = double(args.rays) / closest.seconds;
  const double shadow_rate = double(args.rays) / shadow.seconds;
  std::printf("random rays (%lld, origins in the bounding sphere, best of %d):\n",
              (long long)args.rays, args.repeats);
  std::printf("  Scene::intersect (closest + hit record): %.3f Mrays/s  (%.0f%% hit)\n",
              closest_rate * 1e-6, 100.0 * closest.hits / double(args.rays));
  std::printf("  Scene::occluded  (any hit):              %.3f Mrays/s  (%.0f%% occluded)\n",
              shadow_rate * 1e-6, 100.0 * shadow.hits / double(args.rays));
  // The random-ray rate at the renderer's own mix (the exact shadow fraction
  // of the recording): the time the random tracer would need for the same
  // numbers of closest and shadow rays.
  const double f = double(own_shadow) / own_n;
  const double mix_rate = 1.0 / ((1.0 - f) / closest_rate + f / shadow_rate);
  std::printf("  at the renderer's mix (%.0f%% shadow):  %.3f Mrays/s\n", 100.0 * f,
              mix_rate * 1e-6);

  std::printf(
      "ratio renderer / own rays replayed: %.0f%% (Scene), %.0f%% (bare Embree)"
      "  (target >= 50%%)\n",
      100.0 * rays_per_s / replay_rate, 100.0 * rays_per_s / bare_rate);
  std::printf(
      "ratio renderer / random rays: %.0f%% of the mix rate, %.0f%% of the closest-hit rate\n",
      100.0 * rays_per_s / mix_rate, 100.0 * rays_per_s / closest_rate);
  g_summary.push_back({name, rays_per_s, replay_rate, bare_rate, mix_rate});
}

}  // namespace

int main(int argc, char** argv) {
  const Args args = parse_args(argc, argv);
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // progress shows when piped to a file
  std::printf(
      "render_throughput: size %d, %lld raw rays, threads %d (0 = the CPUs it may use = %d)\n",
      args.size, (long long)args.rays, args.threads, dofarm::cpus_available());
  try {
    // Frames in the middle of each sequence: the lens is open (aperture > 0).
    if (args.scene.empty() || args.scene == "cornell")
      run_scene("cornell", "cornell.toml", 48, args);
    if (args.scene.empty() || args.scene == "courtyard")
      run_scene("courtyard", "courtyard.toml", 24, args);
    std::printf("\n| scene | renderer Mrays/s | own rays replayed (Scene) Mrays/s | ratio | "
                "own rays bare Embree Mrays/s | ratio | random rays at mix Mrays/s | ratio |\n");
    std::printf("| --- | --- | --- | --- | --- | --- | --- | --- |\n");
    for (const Summary& s : g_summary)
      std::printf("| %s | %.3f | %.3f | **%.0f%%** | %.3f | %.0f%% | %.3f | %.0f%% |\n",
                  s.scene.c_str(), s.renderer * 1e-6, s.replay_scene * 1e-6,
                  100.0 * s.renderer / s.replay_scene, s.replay_bare * 1e-6,
                  100.0 * s.renderer / s.replay_bare, s.random_mix * 1e-6,
                  100.0 * s.renderer / s.random_mix);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "render_throughput: %s\n", e.what());
    return 1;
  }
  return 0;
}
