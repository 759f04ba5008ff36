// Error against time for the two samplers (SamplerKind::kSobol: shuffled
// Owen-scrambled Sobol'; kIndependent: hashed random numbers).
//
// For each scene a reference is rendered with the Sobol' sampler at high spp;
// then the `reference` buffer is rendered at 4, 16, 64, 256 spp with each
// sampler and another seed, and compared with it: RMSE over all pixels and
// channels of linear radiance, and relative MSE, mean of (x - r)^2 / (r^2 +
// 0.01) (Rousselle et al. 2011; the trainer's metric). Seconds are the
// render_frame() wall time of one render (versions = 1 and albedo_ref_spp = 1
// are rendered too, the same for both samplers). Below 64 spp the render is
// repeated with other seeds (64 / spp renders) and the MSE is their mean;
// "MSE ratio" is independent MSE / this row's MSE at the same spp.
//
// Scenes, all at a frame with the lens open (depth of field):
//   cornell      jobs/cornell.toml frame 48 (area light, aperture 0.08)
//   courtyard    jobs/courtyard.toml frame 24 (HDRI, aperture 0.08)
//   cornell_sky  the Cornell geometry with its light switched off, lit by a
//                constant white sky through the open side: smooth lighting,
//                so the error is dominated by the lens and pixel integrals
//
// Usage: sampler_convergence [--size W] [--reference-spp N] [--threads T]
//                            [--scenes cornell,courtyard,cornell_sky]
// Prints figures; asserts nothing. Nothing is cached: every run renders its
// references again.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "common/jobspec.h"
#include "worker/render/environment.h"
#include "worker/render/render_job.h"
#include "worker/render/scene.h"
#include "worker/render/scene_data.h"

namespace {

using dofarm::FrameBuffers;
using dofarm::JobSpec;
using dofarm::SamplerKind;
using dofarm::Vec3;
using dofarm::render::RenderOptions;
using dofarm::render::RenderStats;
using dofarm::render::Scene;

struct Args {
  int size = 96;  // image width; height keeps the job's aspect ratio
  int reference_spp = 4096;
  int threads = 0;
  std::vector<std::string> scenes = {"cornell", "courtyard", "cornell_sky"};
};

[[noreturn]] void usage() {
  std::fprintf(stderr,
               "usage: sampler_convergence [--size 96] [--reference-spp 4096] [--threads 0]\n"
               "                           [--scenes cornell,courtyard,cornell_sky]\n");
  std::exit(2);
}

Args parse_args(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    if (i + 1 >= argc) usage();
    const char* flag = argv[i];
    const char* value = argv[++i];
    if (!std::strcmp(flag, "--size")) {
      a.size = std::atoi(value);
    } else if (!std::strcmp(flag, "--reference-spp")) {
      a.reference_spp = std::atoi(value);
    } else if (!std::strcmp(flag, "--threads")) {
      a.threads = std::atoi(value);
    } else if (!std::strcmp(flag, "--scenes")) {
      a.scenes.clear();
      std::stringstream list(value);
      for (std::string s; std::getline(list, s, ',');) a.scenes.push_back(s);
    } else {
      usage();
    }
  }
  if (a.size < 8 || a.reference_spp < 1 || a.threads < 0 || a.scenes.empty()) usage();
  return a;
}

JobSpec bench_spec(const char* job, const Args& args) {
  JobSpec spec = dofarm::load_job_spec(std::string(DOFARM_SOURCE_DIR) + "/jobs/" + job);
  const int full_w = spec.width, full_h = spec.height;
  spec.width = args.size;
  spec.height = std::max(1, int(std::lround(double(args.size) * full_h / full_w)));
  spec.versions = 1;
  spec.albedo_ref_spp = 1;
  spec.reference_error = 0;
  return spec;
}

// The Cornell geometry without emitters, under a constant white sky.
std::shared_ptr<const Scene> sky_lit(const JobSpec& spec) {
  dofarm::render::SceneData data = dofarm::render::load_job_scene_data(spec);
  for (auto& m : data.materials) {
    m.emission = Vec3(0);
    m.emission_tex.index = -1;
  }
  return std::make_shared<Scene>(std::move(data),
                                 std::make_unique<dofarm::render::Environment>(Vec3(1.0f)));
}

struct Rendered {
  std::vector<float> reference;
  std::vector<float> variance;
  double seconds = 0;
};

Rendered render(const Scene& scene, JobSpec spec, int frame, SamplerKind kind, int spp,
                uint64_t seed, int threads) {
  spec.sampler = kind;
  spec.reference_spp = spp;
  spec.seed = seed;
  RenderStats stats;
  RenderOptions options;
  options.threads = threads;
  options.stats = &stats;
  FrameBuffers fb = dofarm::render::render_frame(scene, spec, frame, std::nullopt, options);
  return {std::move(fb.reference), std::move(fb.reference_var), stats.seconds};
}

struct Error {
  double rmse = 0, rel_mse = 0;
};

Error compare(const std::vector<float>& x, const std::vector<float>& r) {
  double se = 0, rel = 0;
  for (size_t i = 0; i < r.size(); ++i) {
    const double d = double(x[i]) - r[i];
    se += d * d;
    rel += d * d / (double(r[i]) * r[i] + 0.01);
  }
  return {std::sqrt(se / r.size()), rel / r.size()};
}

const char* kind_name(SamplerKind k) { return k == SamplerKind::kSobol ? "sobol" : "independent"; }

void run_scene(const std::string& name, const Args& args) {
  const bool sky = name == "cornell_sky";
  const char* job = name == "courtyard" ? "courtyard.toml" : "cornell.toml";
  const int frame = name == "courtyard" ? 24 : 48;
  const JobSpec spec = bench_spec(job, args);
  const auto scene = sky ? sky_lit(spec) : dofarm::render::load_scene(spec);

  std::printf("\n== %s (jobs/%s, frame %d, %dx%d%s)\n", name.c_str(), job, frame, spec.width,
              spec.height, sky ? ", emitters off, constant sky radiance 1" : "");
  const Rendered ref =
      render(*scene, spec, frame, SamplerKind::kSobol, args.reference_spp, spec.seed, args.threads);
  double mean = 0, floor = 0;
  for (float v : ref.reference) mean += v;
  for (float v : ref.variance) floor += v;
  mean /= ref.reference.size();
  floor /= ref.variance.size();
  // reference_var is the sample variance over n: for Sobol' an upper bound on
  // the reference's own squared error, which every MSE below includes.
  std::printf(
      "reference: sobol %d spp, %.1f s, mean radiance %.4f, its own RMSE <= %.5f "
      "(sqrt of mean reference_var)\n",
      args.reference_spp, ref.seconds, mean, std::sqrt(floor));

  std::printf("%-12s %5s %9s %10s %11s %10s %8s\n", "sampler", "spp", "seconds", "RMSE", "rel. MSE",
              "MSE ratio", "renders");
  const int spps[] = {4, 16, 64, 256};
  std::vector<double> independent_mse;
  for (SamplerKind kind : {SamplerKind::kIndependent, SamplerKind::kSobol}) {
    for (size_t i = 0; i < std::size(spps); ++i) {
      // Low spp renders are repeated with further seeds (at least 64 spp in
      // all) and their MSE averaged, so one firefly does not decide a row.
      // Every seed differs from the reference's, so the two are independent.
      const int repeats = std::max(1, 64 / spps[i]);
      Error e;
      double seconds = 0;
      for (int k = 0; k < repeats; ++k) {
        const uint64_t seed = spec.seed + 1000 + 100 * i + k;
        const Rendered r = render(*scene, spec, frame, kind, spps[i], seed, args.threads);
        const Error one = compare(r.reference, ref.reference);
        e.rmse += one.rmse * one.rmse / repeats;  // mean MSE for now
        e.rel_mse += one.rel_mse / repeats;
        seconds += r.seconds / repeats;
      }
      e.rmse = std::sqrt(e.rmse);
      const double mse = e.rmse * e.rmse;
      if (kind == SamplerKind::kIndependent) independent_mse.push_back(mse);
      // MSE ratio: independent / this sampler, at the same spp.
      std::printf("%-12s %5d %9.3f %10.5f %11.5f %10.2f %8d\n", kind_name(kind), spps[i], seconds,
                  e.rmse, e.rel_mse, independent_mse[i] / mse, repeats);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  const Args args = parse_args(argc, argv);
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // progress shows when piped to a file
  std::printf("sampler_convergence: width %d, reference %d spp, threads %d (0 = all)\n", args.size,
              args.reference_spp, args.threads);
  const auto t0 = std::chrono::steady_clock::now();
  try {
    for (const std::string& name : args.scenes) {
      if (name != "cornell" && name != "courtyard" && name != "cornell_sky") usage();
      run_scene(name, args);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "sampler_convergence: %s\n", e.what());
    return 1;
  }
  std::printf("\ntotal %.1f s\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  return 0;
}
