// Where a frame's per-sample variance comes from (issues 11 and 13): renders
// a tile of one frame with N paths per pixel through trace_path() with a
// PathObserver (worker/render/integrator.h) and prints
//   - k, the mean over pixels of Var(sample luminance) / mean²: the relative
//     variance of one sample (the reference ceiling is about 1 / (1 + k/n)
//     for n samples per half, bench/README.md);
//   - the share of k of each term of the estimator, by technique (emission
//     seen through delta bounces, emission reached by BSDF sampling, NEE,
//     environment) and path depth (the variance of that term alone, so the
//     shares need not sum to 1: the rest is covariance);
//   - the heavy tail: the share of the squared deviations carried by samples
//     above 4, 16, 64, 256 times their pixel's mean, how rare they are, and
//     which path kinds make the samples above 16x (by the term with the
//     largest luminance in the sample; vertices classed D (rough: alpha >=
//     0.25), G (glossy) or E (emitter));
//   - the share carried by samples that survived roulette with weight > 2.
// Usage: path_variance --job FILE [--frame F] [--tile X,Y,W,H] [--spp N]
//                      [--seed S] [--threads 2] [--lambert] [--area-lights] [--max-depth D]
//                      [--block 64] [--mark-box X0,Y0,Z0,X1,Y1,Z1]
// --area-lights: every triangle light sampled by area (Scene::set_solid_angle_lights).
// --mark-box: vertices inside the box are printed in lower case (d, g, e) in
// the path kinds, to tell a region's share (e.g. the gap above a light).
// --block B: the relative variance is also measured from the spread of the
// means of consecutive blocks of B samples (B a power of two: each block is a
// (0,m,2)-net per slot with the Sobol' sampler), times B: what the sampler's
// stratification leaves of k, the variance that sets the error of a render.
// Prints figures; asserts nothing.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench/bench_scene.h"
#include "common/jobspec.h"
#include "worker/render/camera.h"
#include "worker/render/environment.h"
#include "worker/render/integrator.h"
#include "worker/render/render_job.h"
#include "worker/render/sampler.h"
#include "worker/render/scene.h"
#include "worker/render/scene_data.h"

namespace {

using dofarm::render::PathObserver;
using dofarm::render::SurfaceHit;
using dofarm::Vec3;

constexpr int kDepths = 8;  // depth buckets 0..6 and 7+
constexpr int kKinds = 4;
constexpr int kTerms = kDepths * kKinds;
const char* kKindNames[kKinds] = {"emitted (camera/delta)", "emission via BSDF (MIS)",
                                  "NEE (MIS)", "environment"};

struct SampleRecord : PathObserver {
  double term[kTerms] = {};
  std::string signature;  // vertex classes, one letter per hit
  int best_term = -1;
  double best_value = -1;
  std::string best_signature;
  float min_survive = 1;
  bool has_box = false;
  Vec3 box_lo, box_hi;

  void reset() {
    std::fill(term, term + kTerms, 0.0);
    signature.clear();
    best_term = -1;
    best_value = -1;
    min_survive = 1;
  }
  void vertex(int, const SurfaceHit& hit) override {
    char c = 'D';
    if (dofarm::max_component(hit.emission) > 0)
      c = 'E';
    else if (hit.roughness * hit.roughness < 0.25f)
      c = 'G';
    if (has_box && hit.p.x >= box_lo.x && hit.p.y >= box_lo.y && hit.p.z >= box_lo.z &&
        hit.p.x <= box_hi.x && hit.p.y <= box_hi.y && hit.p.z <= box_hi.z)
      c = char(c - 'A' + 'a');  // lower case: inside the --mark-box
    signature.push_back(c);
  }
  void contribution(Kind kind, int depth, Vec3 value) override {
    const int t = std::min(depth, kDepths - 1) * kKinds + int(kind);
    const double l = dofarm::luminance(value);
    term[t] += l;
    if (l > best_value) {
      best_value = l;
      best_term = t;
      best_signature = signature;
    }
  }
  void roulette(int, float survive, bool survived) override {
    if (survived) min_survive = std::min(min_survive, survive);
  }
};

struct Totals {
  double k = 0;  // sum over pixels of relative variance per sample
  double k_block = 0;  // the same from the spread of block means (stratified)
  double term_k_block[kTerms] = {};
  double term_k[kTerms] = {};
  double term_mean[kTerms] = {};  // sum over pixels of term mean / pixel mean
  int pixels = 0;
  static constexpr int kTails = 4;
  double tail_sq[kTails] = {}, tail_count[kTails] = {};
  double total_sq = 0, total_count = 0;
  double rr_sq = 0, rr_count = 0;
  std::map<std::string, double> heavy;  // path kind -> squared deviation (above 16x)

  void merge(const Totals& o) {
    k += o.k;
    k_block += o.k_block;
    for (int t = 0; t < kTerms; ++t) term_k_block[t] += o.term_k_block[t];
    for (int t = 0; t < kTerms; ++t) {
      term_k[t] += o.term_k[t];
      term_mean[t] += o.term_mean[t];
    }
    pixels += o.pixels;
    for (int i = 0; i < kTails; ++i) {
      tail_sq[i] += o.tail_sq[i];
      tail_count[i] += o.tail_count[i];
    }
    total_sq += o.total_sq;
    total_count += o.total_count;
    rr_sq += o.rr_sq;
    rr_count += o.rr_count;
    for (const auto& [key, v] : o.heavy) heavy[key] += v;
  }
};

const double kTailFactor[Totals::kTails] = {4, 16, 64, 256};

void usage() {
  std::fprintf(stderr,
               "usage: path_variance --job FILE [--frame F] [--tile X,Y,W,H] [--spp N] "
               "[--seed S] [--threads 2] [--lambert] [--area-lights] [--max-depth D] [--block 64] [--mark-box X0,Y0,Z0,X1,Y1,Z1]\n");
  std::exit(2);
}

}  // namespace

int main(int argc, char** argv) {
  std::string job;
  int frame = -1, threads = 2, spp = 1024, max_depth = 0, block = 64;
  int tx = 0, ty = 0, tw = -1, th = -1;
  long long seed = -1;
  bool lambert = false, area_lights = false, has_box = false;
  float box[6] = {};
  for (int i = 1; i < argc; ++i) {
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage();
      return argv[++i];
    };
    if (!std::strcmp(argv[i], "--job")) {
      job = value();
    } else if (!std::strcmp(argv[i], "--frame")) {
      frame = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--tile")) {
      if (std::sscanf(value().c_str(), "%d,%d,%d,%d", &tx, &ty, &tw, &th) != 4) usage();
    } else if (!std::strcmp(argv[i], "--spp")) {
      spp = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--seed")) {
      seed = std::atoll(value().c_str());
    } else if (!std::strcmp(argv[i], "--threads")) {
      threads = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--mark-box")) {
      if (std::sscanf(value().c_str(), "%f,%f,%f,%f,%f,%f", &box[0], &box[1], &box[2], &box[3],
                      &box[4], &box[5]) != 6)
        usage();
      has_box = true;
    } else if (!std::strcmp(argv[i], "--block")) {
      block = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--max-depth")) {
      max_depth = std::atoi(value().c_str());
    } else if (!std::strcmp(argv[i], "--lambert")) {
      lambert = true;
    } else if (!std::strcmp(argv[i], "--area-lights")) {
      area_lights = true;
    } else {
      usage();
    }
  }
  if (job.empty() || threads < 1 || block < 1 || spp < 2 * block) usage();

  try {
    dofarm::JobSpec spec = dofarm::load_job_spec(job);
    if (frame < 0) frame = spec.frame_start;
    if (seed >= 0) spec.seed = uint64_t(seed);
    if (max_depth > 0) spec.max_depth = max_depth;
    if (tw < 0) {
      tw = spec.width;
      th = spec.height;
    }
    const std::shared_ptr<const dofarm::render::Scene> scene =
        dofarm::bench::load_bench_scene(spec, lambert, area_lights);
    const dofarm::render::Camera camera(dofarm::render::frame_camera(*scene, spec, frame),
                                        spec.width, spec.height,
                                        dofarm::render::camera_clip(spec, scene->data()));

    Totals totals;
    std::mutex mu;
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t) {
      pool.emplace_back([&, t] {
        Totals local;
        SampleRecord rec;
        dofarm::render::IntegratorSettings settings;
        settings.max_depth = spec.max_depth;
        settings.rr_start_depth = spec.rr_start_depth;
        settings.observer = &rec;
        rec.has_box = has_box;
        rec.box_lo = Vec3(box[0], box[1], box[2]);
        rec.box_hi = Vec3(box[3], box[4], box[5]);
        std::vector<double> lum(static_cast<size_t>(spp)), terms(static_cast<size_t>(spp) * kTerms);
        std::vector<std::string> kinds(static_cast<size_t>(spp));
        std::vector<float> survive(static_cast<size_t>(spp));
        for (int y = ty + t; y < ty + th; y += threads) {
          for (int x = tx; x < tx + tw; ++x) {
            dofarm::render::PixelSampler s(spec.sampler, spec.seed, frame, x, y,
                                           dofarm::render::Stream::kReference);
            double sum = 0;
            for (int i = 0; i < spp; ++i) {
              s.start_sample(uint32_t(i));
              const dofarm::Vec2 j = s.get2d();
              const dofarm::Vec2 film(float(x) + j.x, float(y) + j.y);
              const dofarm::render::Ray ray = camera.has_lens()
                                                  ? camera.generate_ray(film, s.get2d())
                                                  : camera.pinhole_ray(film);
              rec.reset();
              lum[size_t(i)] = dofarm::luminance(dofarm::render::trace_path(*scene, ray, s, settings));
              sum += lum[size_t(i)];
              std::copy(rec.term, rec.term + kTerms, terms.begin() + ptrdiff_t(i) * kTerms);
              kinds[size_t(i)] =
                  rec.best_term < 0
                      ? "-"
                      : rec.best_signature + " " + kKindNames[rec.best_term % kKinds];
              survive[size_t(i)] = rec.min_survive;
            }
            const double mean = sum / spp;
            if (!(mean > 1e-6)) continue;
            const double m2 = mean * mean;
            double var = 0;
            for (int i = 0; i < spp; ++i) {
              const double d = lum[size_t(i)] - mean;
              const double sq = d * d / m2;
              var += sq;
              local.total_sq += sq;
              for (int q = 0; q < Totals::kTails; ++q)
                if (lum[size_t(i)] > kTailFactor[q] * mean) {
                  local.tail_sq[q] += sq;
                  local.tail_count[q] += 1;
                }
              if (lum[size_t(i)] > 16 * mean) local.heavy[kinds[size_t(i)]] += sq;
              if (survive[size_t(i)] < 0.5f) {
                local.rr_sq += sq;
                local.rr_count += 1;
              }
            }
            local.total_count += spp;
            local.k += var / (spp - 1);
            // The spread of the means of consecutive blocks of `block`
            // samples (each block a (0,m,2)-net per slot with the Sobol'
            // sampler), times the block size: the relative variance per
            // sample that the sampler's stratification leaves.
            const int blocks = spp / block;
            auto block_k = [&](auto value) {
              double bs = 0, bq = 0;
              for (int b = 0; b < blocks; ++b) {
                double m = 0;
                for (int i = b * block; i < (b + 1) * block; ++i) m += value(i);
                m /= block;
                bs += m;
                bq += m * m;
              }
              const double bm = bs / blocks;
              return std::max(0.0, (bq - blocks * bm * bm) / (blocks - 1)) * block / m2;
            };
            local.k_block += block_k([&](int i) { return lum[size_t(i)]; });
            for (int term = 0; term < kTerms; ++term) {
              double ts = 0, tq = 0;
              for (int i = 0; i < spp; ++i) {
                const double v = terms[size_t(i) * kTerms + term];
                ts += v;
                tq += v * v;
              }
              const double tm = ts / spp;
              local.term_mean[term] += tm / mean;
              local.term_k[term] += std::max(0.0, (tq - spp * tm * tm) / (spp - 1)) / m2;
              local.term_k_block[term] +=
                  block_k([&](int i) { return terms[size_t(i) * kTerms + term]; });
            }
            local.pixels += 1;
          }
        }
        std::lock_guard<std::mutex> lock(mu);
        totals.merge(local);
      });
    }
    for (std::thread& th_ : pool) th_.join();

    const double k = totals.k / std::max(1, totals.pixels);
    std::printf("frame %d tile %d,%d,%d,%d spp %d pixels %d\n", frame, tx, ty, tw, th, spp,
                totals.pixels);
    std::printf("k = mean relative variance per sample: %.2f (ceiling ~ 1/(1+k/n), n per half)\n",
                k);
    std::printf("k from the spread of %d-sample block means (what stratification leaves): %.2f\n",
                block, totals.k_block / std::max(1, totals.pixels));
    std::printf("\nterm (depth, technique)          mean share   share of k   share of block k\n");
    for (int term = 0; term < kTerms; ++term) {
      const double share = totals.term_k[term] / std::max(1e-30, totals.k);
      const double ms = totals.term_mean[term] / std::max(1, totals.pixels);
      if (share < 0.005 && ms < 0.005) continue;
      std::printf("  depth %d%s %-26s %8.3f %12.3f %12.3f\n", term / kKinds,
                  term / kKinds == kDepths - 1 ? "+" : " ", kKindNames[term % kKinds], ms, share,
                  totals.term_k_block[term] / std::max(1e-30, totals.k_block));
    }
    std::printf("\nheavy tail (sample luminance over its pixel's mean):\n");
    for (int q = 0; q < Totals::kTails; ++q)
      std::printf("  > %4.0fx: %.5f%% of samples carry %.3f of the squared deviation\n",
                  kTailFactor[q], 100.0 * totals.tail_count[q] / totals.total_count,
                  totals.tail_sq[q] / totals.total_sq);
    std::printf("  roulette survivors weighted > 2x: %.3f%% of samples, %.3f of the squared "
                "deviation\n",
                100.0 * totals.rr_count / totals.total_count, totals.rr_sq / totals.total_sq);
    std::vector<std::pair<double, std::string>> heavy;
    for (const auto& [key, v] : totals.heavy) heavy.push_back({v, key});
    std::sort(heavy.rbegin(), heavy.rend());
    std::printf("\nsamples above 16x: share of all squared deviation by path (vertices D/G/E, "
                "largest term):\n");
    for (size_t i = 0; i < heavy.size() && i < 15; ++i)
      std::printf("  %.3f  %s\n", heavy[i].first / totals.total_sq, heavy[i].second.c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "path_variance: %s\n", e.what());
    return 2;
  }
  return 0;
}
