// Synthetic shards for trainer tests: no renderer needed. Each frame is a
// smooth colour field drifting over time, noisy versions add deterministic
// per-pixel noise, aux buffers are simple analytic fields.
#pragma once

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "common/image.h"
#include "common/shard.h"

namespace dofarm::trainer::testing {

// An empty folder for one test, removed when the process exits. Named per
// process: ctest runs the tests of one binary in parallel processes.
inline std::filesystem::path scratch_dir(const std::string& name) {
  struct Registry {
    std::vector<std::filesystem::path> dirs;
    ~Registry() {
      std::error_code ec;
      for (const auto& d : dirs) std::filesystem::remove_all(d, ec);
    }
  };
  static Registry registry;
  std::filesystem::path d = std::filesystem::temp_directory_path() /
                            ("dofarm_trainer_" + std::to_string(::getpid()) + "_" + name);
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  registry.dirs.push_back(d);
  return d;
}

inline FrameBuffers synthetic_frame(int frame, int w, int h, int versions, uint64_t seed) {
  FrameBuffers fb;
  fb.allocate(w, h, versions);
  fb.rect = Rect{0, 0, w, h};
  fb.camera.frame = frame;
  fb.camera.focal_distance = 2.0f;
  fb.camera.aperture = 0.05f;
  std::mt19937_64 rng(seed * 1000003u + uint64_t(frame));
  std::exponential_distribution<float> noise(1.0f);
  const size_t n = size_t(w) * h;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      size_t p = size_t(y) * w + x;
      float u = (x + 0.5f * frame) / w, v = float(y) / h;
      for (int c = 0; c < 3; ++c) {
        float albedo = 0.2f + 0.6f * (0.5f + 0.5f * std::sin(6.0f * u + 2.0f * c));
        float light = 0.5f + 0.4f * std::cos(4.0f * v + c);
        fb.albedo_ref[c * n + p] = albedo;
        fb.reference[c * n + p] = albedo * light;
        fb.reference_half[c * n + p] = albedo * light;  // a converged reference
        fb.normal[c * n + p] = c == 2 ? 1.0f : 0.0f;
        for (int k = 0; k < versions; ++k) {
          size_t i = (size_t(k) * 3 + c) * n + p;
          fb.albedo[i] = albedo;
          fb.noisy[i] = albedo * light * noise(rng);  // unbiased 1-spp-like noise
        }
      }
      fb.reference_var[p] = 1e-4f;
      fb.depth[p] = 1.0f + 2.0f * v;
      fb.roughness[p] = u;
      fb.coc[p] = 8.0f * std::abs(fb.depth[p] - 2.0f);
    }
  return fb;
}

inline void write_synthetic_shard(const std::filesystem::path& path, int frames, int w, int h,
                                  int versions, uint64_t seed, int frame_start = 0) {
  ShardInfo info;
  info.batch_id = "test";
  info.scene_id = "synthetic";
  info.width = w;
  info.height = h;
  info.versions = versions;
  info.seed = seed;
  info.frame_start = frame_start;
  info.frame_end = frame_start + frames - 1;
  std::vector<FrameBuffers> fbs;
  for (int f = 0; f < frames; ++f)
    fbs.push_back(synthetic_frame(frame_start + f, w, h, versions, seed));
  write_shard(path, info, fbs);
}

}  // namespace dofarm::trainer::testing
