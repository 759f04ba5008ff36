// Shared by the shard, manifest, inspect and checksum tests: a fresh folder
// per test and a small batch whose every value is distinct.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "common/shard.h"

namespace dofarm::shard_testing {

// 70x50 is deliberately not a multiple of the 64-pixel chunk edge, so edge
// chunks are partial in both directions.
inline constexpr int kW = 70, kH = 50, kV = 2, kFirstFrame = 10, kFrames = 3;

// A fresh, empty folder per test.
class TempDir {
 public:
  TempDir() {
    const auto* t = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = std::filesystem::temp_directory_path() / ("dofarm_shard_" + std::to_string(::getpid()) +
                                                      "_" + t->test_suite_name() + "_" + t->name());
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  const std::filesystem::path& path() const { return path_; }
  std::vector<std::string> files() const {
    std::vector<std::string> out;
    for (const auto& e : std::filesystem::directory_iterator(path_))
      out.push_back(e.path().filename());
    return out;
  }

 private:
  std::filesystem::path path_;
};

// Every value of every buffer is distinct (buffer, frame and element are all
// encoded), so any misplaced crop, swapped version or swapped frame shows.
// Integers below 2^24 are exact in float32.
inline FrameBuffers make_frame(int frame) {
  FrameBuffers fb;
  fb.allocate(kW, kH, kV);
  fb.rect = {0, 0, kW, kH};
  int bi = 0;
  for (const BufferInfo& b : buffer_infos()) {
    std::vector<float>& d = buffer_data(fb, b.name);
    for (size_t i = 0; i < d.size(); ++i) d[i] = float(bi * 1000000 + frame * 40000 + int(i));
    ++bi;
  }
  fb.camera.frame = frame;
  fb.camera.time = frame / 24.0f;
  fb.camera.position[0] = 0.5f * frame;
  fb.camera.position[1] = 1.0f;
  fb.camera.position[2] = 3.6f;
  fb.camera.rotation[0] = 0.9238795f;
  fb.camera.rotation[2] = 0.3826834f;
  fb.camera.fov_deg = 40.0f + frame;
  fb.camera.focal_distance = 3.6f;
  fb.camera.aperture = 0.05f;
  // Odd frames orthographic (no field of view, a view 2.5 units high).
  if (frame % 2) {
    fb.camera.fov_deg = 0.0f;
    fb.camera.ortho_height = 2.5f;
  }
  return fb;
}

inline std::vector<FrameBuffers> make_frames() {
  std::vector<FrameBuffers> frames;
  for (int f = 0; f < kFrames; ++f) frames.push_back(make_frame(kFirstFrame + f));
  return frames;
}

inline ShardInfo make_info() {
  ShardInfo info;
  info.batch_id = "batch-7f3a";
  info.scene_id = "cornell";
  info.scene_hash = "xxh64:00000000deadbeef";
  info.job_hash = "0123456789abcdef0123456789abcdef";
  info.width = kW;
  info.height = kH;
  info.versions = kV;
  info.spp_reference = 1024;
  info.spp_albedo_ref = 24;
  info.seed = 0xFEDCBA9876543210ull;  // above 2^63: checks the unsigned attribute
  info.frame_start = kFirstFrame;
  info.frame_end = kFirstFrame + kFrames - 1;
  info.renderer_version = "0.1.0";
  info.render_seconds = 12.5;
  return info;
}

// Overwrites `n` bytes in the middle of the file, where the chunk data lies.
inline void corrupt_middle(const std::filesystem::path& p, int n) {
  std::fstream f(p, std::ios::in | std::ios::out | std::ios::binary);
  auto mid = std::streamoff(std::filesystem::file_size(p) / 2);
  for (int i = 0; i < n; ++i) {
    f.seekg(mid + i);
    char c = 0;
    f.get(c);
    f.seekp(mid + i);
    f.put(char(c ^ 0xA5));
  }
}

}  // namespace dofarm::shard_testing
