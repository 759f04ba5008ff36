// The job spec (jobs/README.md documents every key and its default).
// load_job_spec() parses a TOML file plus --set overrides, checks every value
// and throws SpecError naming file:line:col and the key on the first problem.
// Defaults live here, in the struct, and nowhere else.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "common/error.h"
#include "common/math.h"

namespace dofarm {

// How a camera key sets the distance the lens focuses at (jobs/README.md,
// "Lens and focus"). kNone only for a pinhole key, which records 1.
enum class FocusMode { kNone, kDistance, kPoint, kAuto };

struct CameraKey {
  int frame = 0;
  int index = 0;  // its place among the file's [[camera.key]] tables, for messages
  Vec3 position{0, 0, 0};
  // Exactly one of look_at / rotation is set after parsing.
  std::optional<Vec3> look_at;
  std::optional<Vec3> rotation_deg;  // Euler XYZ, degrees; camera looks down -z
  Vec3 up{0, 1, 0};
  float fov_deg = 40.0f;          // vertical field of view, (0, 180)
  // Lens: a radius, or an f-number (1 scene unit = 1 m, as in glTF/Blender).
  float aperture = 0.0f;          // lens radius, scene units, >= 0; 0 = pinhole
  float fstop = 0.0f;             // > 0: f-number N; radius = focal_length / (2 N)
  float focal_length_mm = 0.0f;   // with fstop; 0 = from the fov and sensor_width
  float sensor_width_mm = 36.0f;  // spans the image's longer side (Blender's auto fit)
  // Focus: set whenever the key has a lens (load_job_spec checks it).
  FocusMode focus = FocusMode::kNone;
  float focal_distance = 1.0f;  // kDistance (kNone records 1), > 0, scene units
  Vec3 focus_point{0, 0, 0};    // kPoint: world space
  bool has_lens() const { return aperture > 0 || fstop > 0; }
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

  // [image]; with camera.from_scene a size the spec does not give follows
  // the scene camera's aspect ratio (complete_spec_from_scene in
  // worker/job_resolve.h fills it in; the canonical spec always has both).
  int width = 512;
  int height = 512;
  bool width_given = false;
  bool height_given = false;

  // [frames]
  int frame_start = 0;
  int frame_end = 0;   // inclusive
  int per_shard = 16;
  float fps = 24.0f;   // maps frames to glTF animation time

  // [camera]
  bool camera_from_scene = false;
  // [camera] name: which of the scene's cameras (by its node's name, as
  // Blender names the object); empty = the file's first.
  std::string camera_name;
  std::vector<CameraKey> camera_keys;  // sorted by frame, frames unique

  // [environment]
  std::optional<EnvironmentSpec> environment;

  // [lights]: what a glTF file cannot say about its KHR_lights_punctual
  // lamps (Blender's exporter drops a lamp's Radius and a Sun's Angle).
  // light_radius > 0: point and spot lamps are disks of this radius (scene
  // units) facing the lit point, as Cycles 3.4 renders a lamp with a
  // radius: soft shadows. sun_angle_deg > 0: directional lights are discs
  // of this angular diameter (degrees). 0 (the default): points and
  // parallel light, as the file says (docs/renderer.md, "Lamp size").
  float light_radius = 0.0f;
  float sun_angle_deg = 0.0f;
  // [[lights.lamp]]: one lamp's size by its name in the scene (the glTF
  // node's), over the two above; a value not given (< 0) keeps theirs.
  // Checked against the scene when it loads (load_job_scene_data).
  struct LampSize {
    std::string name;
    float radius = -1.0f;         // point and spot lamps
    float sun_angle_deg = -1.0f;  // directional lights
    int index = 0;                // in the file, for messages (lights.lamp.N)
  };
  std::vector<LampSize> lamp_sizes;

  // [buffers]
  int versions = 10;
  int reference_spp = 1024;        // used when reference_error is 0
  float reference_error = 0.0f;    // > 0: per-pixel relative std. error target
  int reference_max_spp = 65536;   // cap when reference_error is used
  // > 0 (only with reference_error): a pixel also stops once the standard
  // error of its mean in display space (sRGB of the luminance, the space the
  // SSIM and PSNR scores read) is at most this, after at least 1024 samples
  // (docs/renderer.md, "Adaptive references").
  float reference_display_error = 0.0f;
  // > 0: the reference's samples are clamped (biased, opt-in): everything
  // but directly seen emission, at most this in its largest channel
  // (docs/renderer.md, "How converged is the reference"). 0: unbiased.
  float reference_clamp = 0.0f;
  int albedo_ref_spp = 24;

  // [render]
  int max_depth = 16;              // path vertices after the camera
  int rr_start_depth = 3;          // Russian roulette from this bounce on
  SamplerKind sampler = SamplerKind::kSobol;

  // [farm]
  int tile = 64;
  float task_seconds = 0.0f;       // > 0: size tiles to take about this long

  // Where keys that are checked again once the scene is loaded (image size,
  // camera.from_scene, focus keys) are set: "camera.key.0.focus" -> file:line:col.
  std::map<std::string, FileLoc> key_locations;
  // The location of `key`, or the spec file alone when it is not recorded.
  FileLoc where(const std::string& key) const;

  // 64 bits: safe for any int range, not only the limits below.
  int64_t frame_count() const { return int64_t(frame_end) - frame_start + 1; }
};

// The brightest radiance a spec or an environment map may give (emission,
// environment colour times intensity, a map's texel times intensity): far
// above any physical scene (the sun's disk is about 2e7 W/(m^2 sr) in
// luminance units), far enough below float's 3.4e38 that sums and squares of
// samples stay finite.
inline constexpr float kMaxRadiance = 1e12f;

// The limits of one batch (jobs/README.md, "Limits"); load_job_spec() refuses
// a spec beyond them and the planner refuses a plan beyond them (the
// planner's arithmetic is 64-bit, safe for any int frame range).
//
// Frame numbers: 0 to 2^24 - 1. The shard's camera table and the animation
// time (frame / fps) are 32-bit floats, exact for integers up to 2^24 only;
// a larger frame number would be stored as another one.
// image.width and image.height, given or derived from the scene camera.
inline constexpr int kMaxImageSide = 16384;
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

// The batch's task count against kMaxTasksPerBatch and kMaxTilesPerShard at
// the spec's image size and tile (load_job_spec runs it; run it again after
// changing the size): throws a SpecError blaming the key that made it too large.
void check_batch_size(const JobSpec& spec);

// Parses `path` and applies `overrides` ("a.b=value", applied in order, each
// checked like the file). Throws SpecError on any bad input.
JobSpec load_job_spec(const std::filesystem::path& path,
                      const std::vector<std::string>& overrides = {});

// Parses TOML text as if it were the file `virtual_path` (for tests and for
// specs received over the network).
JobSpec parse_job_spec(const std::string& toml_text, const std::filesystem::path& virtual_path,
                       const std::vector<std::string>& overrides = {});

}  // namespace dofarm
