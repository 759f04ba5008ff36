// Renders one frame (or one tile of it) of a job: the entry point that the
// `dofarm render` command, the worker and the tests share.
#pragma once

#include <atomic>
#include <filesystem>
#include <stdexcept>
#include <map>
#include <optional>
#include <string>

#include "common/image.h"
#include "common/jobspec.h"

namespace dofarm::render {

// What a render_frame() call did, for benchmarks and logs.
struct RenderStats {
  uint64_t paths = 0;  // camera paths traced (noisy versions + reference samples)
  uint64_t rays = 0;   // closest-hit + shadow rays, albedo and aux rays included
  uint64_t shadow_rays = 0;    // of those, next-event estimation's shadow rays
  uint64_t light_samples = 0;  // NEE's light samples (RayCount::light_samples)
  // Of those, the ones skipped below their surface (RayCount::light_samples_skipped)
  uint64_t light_samples_skipped = 0;
  double seconds = 0;
  int threads = 0;  // the threads the last render_frame() ran on
};

struct RenderOptions {
  int threads = 0;               // 0 = the CPUs this process may use (cpus_available)
  int block_size = 16;           // pixels per side of a thread-pool work item
  bool progress = false;         // log progress lines / a bar on a terminal
  RenderStats* stats = nullptr;  // filled in when set
  // Checked before every pixel: when either becomes true, render_frame()
  // throws Cancelled (a worker told to stop hands its task back; one whose
  // lease was taken away abandons it).
  const std::atomic<bool>* cancel = nullptr;
  const std::atomic<bool>* cancel_also = nullptr;
  // Render the reference buffer (and reference_half, reference_var) alone;
  // every other buffer stays zero. For benchmarks that compare the path
  // tracer's image with another renderer's (bench/render_spp): Cycles
  // renders its combined pass alone, and a farm frame's noisy versions,
  // albedo and aux rays are not part of that image. The reference's bytes
  // are those of a full render (its sample stream is its own).
  bool reference_only = false;
};

class Cancelled : public std::runtime_error {
 public:
  Cancelled() : std::runtime_error("render cancelled") {}
};

// Renders `frame` of `spec`, restricted to `tile` when given (default: the
// whole frame). Deterministic: the bytes do not depend on tile or threads.
// Throws SpecError for bad input (missing scene, frame out of range, tile
// outside the image) and RuntimeError for runtime failures.
FrameBuffers render_frame(const JobSpec& spec, int frame, std::optional<Rect> tile = std::nullopt,
                          const RenderOptions& options = {});

class Scene;
// The same with a scene already loaded (a worker keeps it across tasks).
// A scene whose meshes or lights move is rendered as it is at the frame's
// time (Scene::at_time).
FrameBuffers render_frame(const Scene& scene, const JobSpec& spec, int frame,
                          std::optional<Rect> tile = std::nullopt,
                          const RenderOptions& options = {});

// The camera of `frame` (camera_for_frame) with focus = "auto" resolved in
// `scene` at the frame's time: the view depth of the first hit of the
// pinhole ray through the centre of the image (deterministic: one ray, no
// sampling).
CameraState frame_camera(const Scene& scene, const JobSpec& spec, int frame);

// Checks that `frame` is in the job's range and `tile` inside the image;
// throws SpecError otherwise. Returns the rect to render.
Rect checked_rect(const JobSpec& spec, int frame, std::optional<Rect> tile);

// render_frame() then write_frame_exr() with the job's metadata in the header.
// `scene`: the job's scene, already loaded (null: loaded here).
void render_frame_to_exr(const JobSpec& spec, int frame, std::optional<Rect> tile,
                         const std::filesystem::path& out, const RenderOptions& options = {},
                         const Scene* scene = nullptr);

}  // namespace dofarm::render
