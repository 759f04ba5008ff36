// The job spec (jobs/README.md documents every key and its default).
// load_job_spec() parses a TOML file plus --set overrides, checks every value
// and throws SpecError naming file:line:col and the key on the first problem.
// Defaults live here, in the struct, and nowhere else.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "common/math.h"

namespace dofarm {

struct CameraKey {
  int frame = 0;
  Vec3 position{0, 0, 0};
  // Exactly one of look_at / rotation is set after parsing.
  std::optional<Vec3> look_at;
  std::optional<Vec3> rotation_deg;  // Euler XYZ, degrees; camera looks down -z
  Vec3 up{0, 1, 0};
  float fov_deg = 40.0f;          // vertical field of view, (0, 180)
  float focal_distance = 1.0f;    // > 0, scene units
  float aperture = 0.0f;          // lens radius, scene units, >= 0; 0 = pinhole
};

struct EnvironmentSpec {
  std::filesystem::path map;      // absolute; empty when `color` is used
  std::optional<Vec3> color;      // constant radiance instead of a map
  float intensity = 1.0f;         // >= 0
  float rotation_deg = 0.0f;      // about +y
};

enum class SamplerKind { kSobol, kIndependent };

struct JobSpec {
  std::filesystem::path spec_path;  // the TOML file (absolute)
  std::filesystem::path scene;      // absolute, resolved relative to spec_path
  uint64_t seed = 0;

  // [image]
  int width = 512;
  int height = 512;

  // [frames]
  int frame_start = 0;
  int frame_end = 0;   // inclusive
  int per_shard = 16;
  float fps = 24.0f;   // maps frames to glTF animation time

  // [camera]
  bool camera_from_scene = false;
  std::vector<CameraKey> camera_keys;  // sorted by frame, frames unique

  // [environment]
  std::optional<EnvironmentSpec> environment;

  // [buffers]
  int versions = 10;
  int reference_spp = 1024;        // used when reference_error is 0
  float reference_error = 0.0f;    // > 0: per-pixel relative std. error target
  int reference_max_spp = 65536;   // cap when reference_error is used
  int albedo_ref_spp = 24;

  // [render]
  int max_depth = 16;              // path vertices after the camera
  int rr_start_depth = 3;          // Russian roulette from this bounce on
  SamplerKind sampler = SamplerKind::kSobol;

  // [farm]
  int tile = 64;
  float task_seconds = 0.0f;       // > 0: size tiles to take about this long

  // 64 bits: safe for any int range, not only the limits below.
  int64_t frame_count() const { return int64_t(frame_end) - frame_start + 1; }
};

// The limits of one batch (jobs/README.md, "Limits"); load_job_spec() refuses
// a spec beyond them and the planner refuses a plan beyond them (the
// planner's arithmetic is 64-bit, safe for any int frame range).
//
// Frame numbers: 0 to 2^24 - 1. The shard's camera table and the animation
// time (frame / fps) are 32-bit floats, exact for integers up to 2^24 only;
// a larger frame number would be stored as another one.
inline constexpr int64_t kMaxFrameNumber = (int64_t(1) << 24) - 1;
inline constexpr int64_t kMaxFramesPerBatch = 1'000'000;
// The task limit bounds the coordinator's memory (each task of a running
// batch is held in memory, about 100-200 bytes with its dependencies) and the
// job store; one tile per frame always fits: frames + shards <= 2 *
// kMaxFramesPerBatch.
inline constexpr int64_t kMaxTasksPerBatch = 2'000'000;
// A pack task's inputs (every tile of its shard's frames) travel in one
// message of at most 1 MiB (protocol::kMaxPackInputs); frames.per_shard is at
// most this too, so one tile per frame always fits.
inline constexpr int64_t kMaxTilesPerShard = 4096;

// Tasks of the batch when every frame is cut into side x side tiles: one
// render task per tile and frame plus one pack task per shard. 64-bit and
// overflow-free for any int inputs with side > 0 and per_shard > 0.
int64_t batch_task_count(const JobSpec& spec, int tile_side);
// Render tasks of the largest shard, the inputs of its pack task.
int64_t shard_tile_count(const JobSpec& spec, int tile_side);

// Parses `path` and applies `overrides` ("a.b=value", applied in order, each
// checked like the file). Throws SpecError on any bad input.
JobSpec load_job_spec(const std::filesystem::path& path,
                      const std::vector<std::string>& overrides = {});

// Parses TOML text as if it were the file `virtual_path` (for tests and for
// specs received over the network).
JobSpec parse_job_spec(const std::string& toml_text, const std::filesystem::path& virtual_path,
                       const std::vector<std::string>& overrides = {});

}  // namespace dofarm
