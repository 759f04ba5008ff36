// Renders one frame of a job at several sample counts and writes each image
// (the mean of N paths per pixel: the `reference` buffer of render_frame() at
// reference_spp = N) as a PFM, with the CPU and wall time of each render.
// bench/cycles_vs_dofarm.sh drives it against Blender Cycles; it is also the
// quickest way to measure the error of a renderer change at equal time.
//
// Usage: render_spp --job FILE [--frame F] --spp 16,32,... [--seed S]
//                   [--threads 2] [--out PREFIX] [--rr-start D] [--max-depth D]
//                   [--lambert] [--area-lights] [--perf-ctl FIFO]
// --lambert: every material of the scene becomes a pure Lambertian surface
// with its base colour (metallic 0, IOR 1: no specular interface, bsdf.h),
// emission kept. A glTF file cannot ask for that (dofarm reads IOR 1 as "not
// set", scene_data.cpp), and the matched-material comparison with Cycles
// needs it (bench/README.md, "cycles_vs_dofarm.sh").
// --area-lights: every triangle light sampled by area, also close to it (the
// estimator before solid-angle sampling, Scene::set_solid_angle_lights).
// --perf-ctl FIFO: writes "enable" to perf's control FIFO before each timed
// render and "disable" after it (`perf record --delay=-1
// --control=fifo:FIFO`), so a profile holds the timed renders only
// (bench/cycles/embree_share.sh).
// Writes PREFIX<N>.pfm (default PREFIX: dofarm_spp) and prints one line per
// render: "spp N cpu_s C wall_s W paths P rays R". Only the reference buffer
// is rendered (RenderOptions::reference_only). Scene loading and the BVH
// build are not timed; one warm-up render at 1 spp runs first (untimed).
// Prints figures; asserts nothing.
#include <time.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bench/bench_scene.h"
#include "common/jobspec.h"
#include "worker/render/environment.h"
#include "worker/render/render_job.h"
#include "worker/render/scene.h"
#include "worker/render/scene_data.h"

namespace {

double cpu_seconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

void usage() {
  std::fprintf(
      stderr,
      "usage: render_spp --job FILE [--frame F] --spp 16,32,64 [--seed S] "
      "[--threads 2] [--out PREFIX] [--rr-start D] [--max-depth D] [--lambert] [--area-lights] "
      "[--perf-ctl FIFO]\n");
  std::exit(2);
}

// PFM: a text header, then little-endian float RGB rows from the bottom up.
bool write_pfm(const std::string& path, const dofarm::FrameBuffers& fb) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return false;
  std::fprintf(f, "PF\n%d %d\n-1.0\n", fb.width, fb.height);
  const size_t plane = fb.plane();
  std::vector<float> row(size_t(fb.width) * 3);
  for (int y = fb.height - 1; y >= 0; --y) {
    for (int x = 0; x < fb.width; ++x) {
      const size_t i = size_t(y) * fb.width + x;
      for (int c = 0; c < 3; ++c) row[size_t(x) * 3 + c] = fb.reference[c * plane + i];
    }
    std::fwrite(row.data(), sizeof(float), row.size(), f);
  }
  return std::fclose(f) == 0;
}

// perf's control FIFO (perf record --control=fifo:PATH); nothing if empty.
void perf_control(const std::string& fifo, const char* command) {
  if (fifo.empty()) return;
  FILE* f = std::fopen(fifo.c_str(), "w");
  if (!f) {
    std::fprintf(stderr, "render_spp: cannot open %s\n", fifo.c_str());
    std::exit(1);
  }
  std::fprintf(f, "%s\n", command);
  std::fclose(f);
}

}  // namespace

int main(int argc, char** argv) {
  std::string job, out = "dofarm_spp", perf_ctl;
  std::vector<int> spps;
  int frame = -1, threads = 2, rr_start = 0, max_depth = 0;
  long long seed = -1;
  bool lambert = false, area_lights = false;
  for (int i = 1; i < argc; ++i) {
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage();
      return argv[++i];
    };
    if (!std::strcmp(argv[i], "--job")) {
      job = value();
    } else if (!std::strcmp(argv[i], "--frame")) {
      frame = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--spp")) {
      std::stringstream ss(value());
      for (std::string item; std::getline(ss, item, ',');) spps.push_back(std::atoi(item.c_str()));
    } else if (!std::strcmp(argv[i], "--seed")) {
      seed = std::atoll(value().c_str());
    } else if (!std::strcmp(argv[i], "--threads")) {
      threads = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--out")) {
      out = value();
    } else if (!std::strcmp(argv[i], "--rr-start")) {
      rr_start = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--max-depth")) {
      max_depth = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--lambert")) {
      lambert = true;
    } else if (!std::strcmp(argv[i], "--area-lights")) {
      area_lights = true;
    } else if (!std::strcmp(argv[i], "--perf-ctl")) {
      perf_ctl = value();
    } else {
      usage();
    }
  }
  if (job.empty() || spps.empty() || threads < 1) usage();
  for (int n : spps)
    if (n < 1) usage();

  try {
    dofarm::JobSpec spec = dofarm::load_job_spec(job);
    if (frame < 0) frame = spec.frame_start;
    if (seed >= 0) spec.seed = uint64_t(seed);
    if (rr_start > 0) spec.rr_start_depth = rr_start;
    if (max_depth > 0) spec.max_depth = max_depth;
    // Not rendered (reference_only below); kept minimal all the same.
    spec.versions = 1;
    spec.albedo_ref_spp = 1;
    spec.reference_error = 0;
    const std::shared_ptr<const dofarm::render::Scene> scene =
        dofarm::bench::load_bench_scene(spec, lambert, area_lights);

    dofarm::render::RenderOptions options;
    options.threads = threads;
    // The image compared is the reference buffer alone, as Cycles renders
    // its combined pass alone: no noisy versions, albedo or aux rays.
    options.reference_only = true;
    spec.reference_spp = 1;
    dofarm::render::render_frame(*scene, spec, frame, std::nullopt, options);  // warm-up

    for (int n : spps) {
      spec.reference_spp = n;
      dofarm::render::RenderStats stats;
      options.stats = &stats;
      perf_control(perf_ctl, "enable");
      const double c0 = cpu_seconds();
      const auto w0 = std::chrono::steady_clock::now();
      dofarm::FrameBuffers fb =
          dofarm::render::render_frame(*scene, spec, frame, std::nullopt, options);
      const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
      const double cpu = cpu_seconds() - c0;
      perf_control(perf_ctl, "disable");
      const std::string path = out + std::to_string(n) + ".pfm";
      if (!write_pfm(path, fb)) {
        std::fprintf(stderr, "render_spp: cannot write %s\n", path.c_str());
        return 1;
      }
      std::printf("spp %d cpu_s %.3f wall_s %.3f paths %llu rays %llu\n", n, cpu, wall,
                  (unsigned long long)stats.paths, (unsigned long long)stats.rays);
      std::fflush(stdout);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "render_spp: %s\n", e.what());
    return 2;
  }
  return 0;
}
