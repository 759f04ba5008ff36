// Renderer throughput against the raw Embree rate, for each bundled scene.
//
// (a) The renderer: one frame of the job through render_frame() with all
//     threads; RenderStats gives the camera paths (pixels x (versions +
//     reference spp)) and every ray the renderer traced (closest-hit and
//     shadow, albedo and aux rays included), counted inside Scene.
// (b) Raw rays: N incoherent rays, origins uniform in the scene's bounding
//     sphere (Scene::center/radius), directions uniform on the sphere, traced
//     with Scene::intersect (closest hit, which also builds the hit record:
//     normals, uvs, material and texture lookups) and with Scene::occluded
//     (any hit), on the same number of threads.
// The ratio renderer rays/s / raw rays/s says how much of the time the
// renderer spends outside ray traversal (sampling, BSDFs, lights, buffers).
// The raw rate is weighted by the renderer's own closest/shadow mix.
//
// Usage: render_throughput [--size W] [--rays N] [--threads T] [--repeats R]
// Prints figures; asserts nothing.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "common/jobspec.h"
#include "worker/render/render_job.h"
#include "worker/render/scene.h"

namespace {

using dofarm::JobSpec;
using dofarm::Vec3;
using dofarm::render::Ray;
using dofarm::render::RayCount;
using dofarm::render::RenderOptions;
using dofarm::render::RenderStats;
using dofarm::render::Scene;
using dofarm::render::SurfaceHit;
using Clock = std::chrono::steady_clock;

struct Args {
  int size = 256;  // image width; height keeps the job's aspect ratio
  int64_t rays = 2'000'000;
  int threads = 0;  // 0 = all hardware threads, as the renderer's default
  int repeats = 2;  // the best of R timings is reported (shared machines)
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
    } else if (!std::strcmp(argv[i], "--repeats")) {
      a.repeats = int(value("--repeats"));
    } else {
      std::fprintf(stderr,
                   "usage: render_throughput [--size 256] [--rays 2000000] [--threads 0] "
                   "[--repeats 2]\n");
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
  double shadow_fraction = 0;  // of the rays traced on the calling thread
};

RendererFigures measure_renderer(const Scene& scene, const JobSpec& spec, int frame,
                                 const Args& args) {
  RendererFigures out;
  out.seconds = 1e300;
  for (int r = 0; r < args.repeats; ++r) {
    RenderStats stats;
    RenderOptions options;
    options.threads = args.threads;
    options.stats = &stats;
    // The calling thread renders its share of the blocks; its own counter
    // gives the closest/shadow mix (the total comes from RenderStats).
    const RayCount before = dofarm::render::thread_ray_count();
    dofarm::render::render_frame(scene, spec, frame, std::nullopt, options);
    const RayCount after = dofarm::render::thread_ray_count();
    const double caller_total = double(after.total() - before.total());
    if (caller_total > 0) out.shadow_fraction = double(after.shadow - before.shadow) / caller_total;
    out.paths = stats.paths;
    out.rays = stats.rays;
    out.seconds = std::min(out.seconds, stats.seconds);
  }
  return out;
}

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

struct RawFigures {
  double seconds = 0;
  int64_t hits = 0;
};

// Threads take chunks of the ray array from a shared counter, like the
// renderer's blocks.
template <class Trace>
RawFigures trace_all(const std::vector<Ray>& rays, int threads, int repeats, Trace&& trace) {
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
        for (int64_t i = begin; i < end; ++i) local += trace(rays[size_t(i)]) ? 1 : 0;
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
  auto scene = dofarm::render::load_scene(spec);
  const double load_s = seconds_since(t0);
  const int threads =
      args.threads > 0 ? args.threads : int(std::max(1u, std::thread::hardware_concurrency()));

  std::printf("\n== %s (jobs/%s, frame %d, %dx%d, %zu triangles, load + BVH %.2f s, %d threads)\n",
              name, job, frame, spec.width, spec.height, scene->data().indices.size() / 3, load_s,
              threads);

  // (a) the renderer
  const RendererFigures rf = measure_renderer(*scene, spec, frame, args);
  const double paths_per_s = rf.paths / rf.seconds;
  const double rays_per_s = rf.rays / rf.seconds;
  const double rays_per_path = double(rf.rays) / double(rf.paths);
  std::printf(
      "renderer: versions %d + reference %d spp (+ albedo_ref %d spp, aux), best of %d: %.3f s\n",
      spec.versions, spec.reference_spp, spec.albedo_ref_spp, args.repeats, rf.seconds);
  std::printf("  paths %llu  rays %llu  (%.2f rays/path, %.0f%% shadow rays)\n",
              (unsigned long long)rf.paths, (unsigned long long)rf.rays, rays_per_path,
              100.0 * rf.shadow_fraction);
  std::printf("  %.3f Mpaths/s  %.3f Mrays/s\n", paths_per_s * 1e-6, rays_per_s * 1e-6);

  // (b) raw rays
  const std::vector<Ray> rays = random_rays(*scene, args.rays, 0x0dfa'2b00'7ea5'5eedULL);
  const float t_max = 2.0f * scene->radius();  // across the whole bounding sphere
  const RawFigures closest = trace_all(rays, threads, args.repeats, [&](const Ray& ray) {
    SurfaceHit hit;
    return scene->intersect(ray, &hit);
  });
  const RawFigures shadow = trace_all(rays, threads, args.repeats, [&](const Ray& ray) {
    return scene->occluded(ray.o, ray.d, t_max);
  });
  const double closest_rate = double(args.rays) / closest.seconds;
  const double shadow_rate = double(args.rays) / shadow.seconds;
  std::printf("raw random rays (%lld, origins in the bounding sphere, best of %d):\n",
              (long long)args.rays, args.repeats);
  std::printf("  Scene::intersect (closest + hit record): %.3f Mrays/s  (%.0f%% hit)\n",
              closest_rate * 1e-6, 100.0 * closest.hits / double(args.rays));
  std::printf("  Scene::occluded  (any hit):              %.3f Mrays/s  (%.0f%% occluded)\n",
              shadow_rate * 1e-6, 100.0 * shadow.hits / double(args.rays));

  // The raw rate of the renderer's own mix: the time the raw tracer would
  // need for the same numbers of closest and shadow rays.
  const double f = rf.shadow_fraction;
  const double mix_rate = 1.0 / ((1.0 - f) / closest_rate + f / shadow_rate);
  std::printf("  raw rate at the renderer's mix (%.0f%% shadow):  %.3f Mrays/s\n", 100.0 * f,
              mix_rate * 1e-6);
  std::printf(
      "ratio renderer / raw: %.0f%% of the mix rate, %.0f%% of the closest-hit rate"
      "  (target >= 50%%)\n",
      100.0 * rays_per_s / mix_rate, 100.0 * rays_per_s / closest_rate);
}

}  // namespace

int main(int argc, char** argv) {
  const Args args = parse_args(argc, argv);
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // progress shows when piped to a file
  std::printf("render_throughput: size %d, %lld raw rays, threads %d (0 = all = %u)\n", args.size,
              (long long)args.rays, args.threads, std::thread::hardware_concurrency());
  try {
    // Frames in the middle of each sequence: the lens is open (aperture > 0).
    run_scene("cornell", "cornell.toml", 48, args);
    run_scene("courtyard", "courtyard.toml", 24, args);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "render_throughput: %s\n", e.what());
    return 1;
  }
  return 0;
}
