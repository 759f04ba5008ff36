#include "worker/render/render_job.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cfloat>
#include <chrono>
#include <cmath>
#include <exception>
#include <mutex>
#include <thread>

#include "common/cpus.h"
#include "common/error.h"
#include "common/exr_io.h"
#include "common/progress.h"
#include "worker/render/integrator.h"
#include "worker/render/scene.h"

namespace dofarm::render {

namespace {

// A double for a float buffer: clamped into float's finite range (a
// reference of 2^16 samples of radiance up to kMaxRadiance has a second
// moment far beyond it). NaN never reaches here (trace_path returns finite
// samples), but would become 0 rather than poison the frame.
float to_buffer(double v) {
  if (std::isnan(v)) return 0.0f;
  return float(std::clamp(v, -double(FLT_MAX), double(FLT_MAX)));
}

// Running mean and sum of squared deviations (Welford), in double: a
// reference accumulates up to 2^16 samples.
struct Welford {
  double mean = 0, m2 = 0;
  void add(double x, int n) {
    double d = x - mean;
    mean += d / n;
    m2 += d * (x - mean);
  }
  // Variance of the mean of n samples.
  double variance_of_mean(int n) const { return n > 1 ? m2 / (double(n - 1) * n) : 0.0; }
};

// Per-pixel sums, and mean and variance of the luminance and, for the
// display-space rule, of each channel.
struct PixelAccumulator {
  explicit PixelAccumulator(bool per_channel) : per_channel_(per_channel) {}
  double sum[3] = {0, 0, 0};
  Welford lum;
  Welford channel[3];
  int n = 0;
  void add(Vec3 c) {
    for (int i = 0; i < 3; ++i) sum[i] += c[i];
    ++n;
    lum.add(luminance(c), n);
    if (per_channel_)
      for (int i = 0; i < 3; ++i) channel[i].add(c[i], n);
  }
  double variance_of_mean() const { return lum.variance_of_mean(n); }
  double relative_error() const {
    return std::sqrt(variance_of_mean()) / std::max(std::fabs(lum.mean), 1e-3);
  }
  // Standard error of the mean in display space, by the delta method: each
  // channel's standard error times the slope of the sRGB curve (IEC
  // 61966-2-1, the encoding trainer/metrics.h scores in, channel by channel)
  // at that channel's mean; the largest of the three. Above 1 the scores
  // clamp; the slope at 1 is kept there, so a bright pixel is never judged
  // converged by the clamp alone (its relative error decides).
  double display_error() const {
    double worst = 0;
    for (const Welford& c : channel)
      worst = std::max(worst, std::sqrt(c.variance_of_mean(n)) * srgb_slope(c.mean));
    return worst;
  }

  static double srgb_slope(double v) {
    if (v <= 0.0031308) return 12.92;
    return 1.055 / 2.4 * std::pow(std::min(v, 1.0), 1.0 / 2.4 - 1.0);
  }

 private:
  bool per_channel_;
};

// The display-space rule applies from this many samples on: it stops dark
// pixels far earlier than the relative rule, and the sample variance of a
// heavy-tailed estimator read from few samples can miss the rare bright
// paths entirely (a premature stop biases the pixel low). 1024 samples are
// about 2% of a study tile's time (docs/renderer.md, "Adaptive references").
constexpr int kReferenceDisplayMinSpp = 1024;

class PixelRenderer {
 public:
  PixelRenderer(const Scene& scene, const JobSpec& spec, const Camera& camera, int frame,
                bool reference_only)
      : scene_(scene), spec_(spec), camera_(camera), frame_(frame), reference_only_(reference_only) {
    settings_.max_depth = spec.max_depth;
    settings_.rr_start_depth = spec.rr_start_depth;
    // The reference alone may be clamped (opt-in, biased); the noisy inputs
    // never are.
    reference_settings_ = settings_;
    reference_settings_.sample_clamp = spec.reference_clamp;
  }

  // Exact for a fixed reference spp; for an error target, the cap.
  uint64_t paths_per_pixel_hint() const {
    return (reference_only_ ? 0 : uint64_t(spec_.versions)) +
           uint64_t(spec_.reference_error > 0 ? spec_.reference_max_spp : spec_.reference_spp);
  }

  void render(int x, int y, FrameBuffers& out, size_t plane_index) const {
    const Slot px{plane_index, out.plane()};
    if (!reference_only_) render_inputs(x, y, out, px);
    render_reference(x, y, out, px);
  }

 private:
  // The pixel's index in each plane of the output buffers.
  struct Slot {
    size_t i, plane;
    void put3(std::vector<float>& buf, size_t base, Vec3 v) const {
      buf[base + i] = v.x;
      buf[base + plane + i] = v.y;
      buf[base + 2 * plane + i] = v.z;
    }
  };

  // The aux buffers, the noisy versions with their albedo, and albedo_ref.
  void render_inputs(int x, int y, FrameBuffers& out, const Slot& px) const {
    const size_t i = px.i;
    // Aux buffers: the pinhole ray through the pixel centre.
    Ray center = camera_.pinhole_ray(Vec2(float(x) + 0.5f, float(y) + 0.5f));
    SurfaceHit hit;
    if (scene_.intersect(center, &hit)) {
      px.put3(out.normal, 0, normalize(camera_.to_view(hit.ns)));
      float z = camera_.view_depth(hit.p);
      out.depth[i] = z;
      out.roughness[i] = hit.roughness;
      out.coc[i] = camera_.coc_pixels(z);
    } else {
      out.coc[i] = camera_.coc_pixels(0.0f);
    }

    // Noisy versions: one path each, with the albedo of the same primary ray.
    PixelSampler noisy(spec_.sampler, spec_.seed, frame_, x, y, Stream::kNoisy);
    CameraPacket cp;
    for (int v0 = 0; v0 < spec_.versions; v0 += Scene::kPacket) {
      camera_packet(noisy, x, y, v0, std::min(Scene::kPacket, spec_.versions - v0), &cp);
      Vec3 L[Scene::kPacket], albedo[Scene::kPacket];
      trace_paths(scene_, cp.rays, cp.primaries, cp.n, noisy, cp.first, cp.slots, settings_, L,
                  albedo);
      for (int k = 0; k < cp.n; ++k) {
        size_t base = size_t(v0 + k) * 3 * px.plane;
        px.put3(out.noisy, base, L[k]);
        px.put3(out.albedo, base, albedo[k]);
      }
    }

    // Albedo at N samples through the lens: the primary hit only.
    PixelSampler alb(spec_.sampler, spec_.seed, frame_, x, y, Stream::kAlbedoRef);
    Vec3 albedo_sum(0);
    for (int s0 = 0; s0 < spec_.albedo_ref_spp; s0 += Scene::kPacket) {
      camera_packet(alb, x, y, s0, std::min(Scene::kPacket, spec_.albedo_ref_spp - s0), &cp);
      for (int k = 0; k < cp.n; ++k)
        albedo_sum += primary_albedo(cp.found[k] ? &cp.hits[k] : nullptr);
    }
    const float n_alb = float(spec_.albedo_ref_spp);
    px.put3(out.albedo_ref, 0,
         Vec3(to_buffer(albedo_sum.x / n_alb), to_buffer(albedo_sum.y / n_alb),
              to_buffer(albedo_sum.z / n_alb)));
  }

  void render_reference(int x, int y, FrameBuffers& out, const Slot& px) const {

    // Reference: a fixed sample count, or batches until the relative standard
    // error of the pixel's mean luminance meets the target. The stopping rule
    // only looks at this pixel's samples, so it is deterministic too.
    //
    // The mean of the first half of the samples is kept as well:
    // reference_half (A). With B = 2 * reference - A, the mean of the second
    // half, A and B are two estimates of the pixel from disjoint samples, so
    // their difference measures how far the reference itself is from
    // converged (trainer/ceiling.h). Halves by index range, not even/odd:
    // with the shuffled Sobol' sampler the even-indexed samples of a slot all
    // fall in one half of its first coordinate (the index's lowest bit is
    // the point's first digit), so an even/odd split would compare two
    // strata of the pixel, not two estimates of it. The first 2^m samples
    // and the next 2^m are each a (0,m,2)-net per slot (sampler.h), so each
    // half is as well stratified as a reference of its own. A has
    // ceil(n/2) samples; for an even n (adaptive batches of 64 always are)
    // B is exactly the mean of the other n/2.
    PixelSampler ref(spec_.sampler, spec_.seed, frame_, x, y, Stream::kReference);
    PixelAccumulator acc(spec_.reference_display_error > 0);
    const bool adaptive = spec_.reference_error > 0;
    const int target = adaptive ? spec_.reference_max_spp : spec_.reference_spp;
    const int batch = 64;
    // Sums of the first (target + 1) / 2 samples (all taken: the half of a
    // fixed count or of the cap) and, when adaptive, of every 32k samples
    // (stopping after 64k samples, the half is 32k).
    const int half_of_target = (target + 1) / 2;
    std::array<double, 3> half_sum{};
    std::vector<std::array<double, 3>> sums_at_32;
    if (adaptive) sums_at_32.reserve(size_t(target / 32));
    // Camera rays a packet at a time (a divisor of the batch: the stopping
    // rule never leaves a traced camera ray unused).
    static_assert(batch % Scene::kPacket == 0);
    static_assert(Scene::kPacket <= kMaxPaths);
    CameraPacket cp;
    bool stop = false;
    for (int s0 = 0; s0 < target && !stop; s0 += Scene::kPacket) {
      camera_packet(ref, x, y, s0, std::min(Scene::kPacket, target - s0), &cp);
      // The packet's paths traced together; a stop falls on a packet's end.
      Vec3 L[Scene::kPacket];
      trace_paths(scene_, cp.rays, cp.primaries, cp.n, ref, cp.first, cp.slots, reference_settings_,
                  L);
      for (int k = 0; k < cp.n; ++k) {
        const int s = s0 + k;
        acc.add(L[k]);
        if (s + 1 == half_of_target) half_sum = {acc.sum[0], acc.sum[1], acc.sum[2]};
        if (adaptive && (s + 1) % 32 == 0)
          sums_at_32.push_back({acc.sum[0], acc.sum[1], acc.sum[2]});
        if (adaptive && (s + 1) % batch == 0 && converged(acc)) {
          stop = true;
          break;
        }
      }
    }
    int half_n = half_of_target;
    if (acc.n < target) {  // stopped early: after a whole batch, so acc.n = 64k
      half_n = acc.n / 2;
      half_sum = sums_at_32[size_t(half_n / 32 - 1)];
    }
    Vec3 mean(to_buffer(acc.sum[0] / acc.n), to_buffer(acc.sum[1] / acc.n),
              to_buffer(acc.sum[2] / acc.n));
    px.put3(out.reference, 0, mean);
    px.put3(out.reference_half, 0,
         Vec3(to_buffer(half_sum[0] / half_n), to_buffer(half_sum[1] / half_n),
              to_buffer(half_sum[2] / half_n)));
    out.reference_var[px.i] = to_buffer(acc.variance_of_mean());
  }

  // The adaptive reference's stopping rule: the relative standard error of
  // the luminance, or, when the job sets reference_display_error, the
  // standard error in display space, whichever is met first.
  bool converged(const PixelAccumulator& acc) const {
    if (acc.relative_error() <= spec_.reference_error) return true;
    return spec_.reference_display_error > 0 && acc.n >= kReferenceDisplayMinSpp &&
           acc.display_error() <= spec_.reference_display_error;
  }

  // The camera rays of samples [first, first + n) of a pixel (n at most
  // Scene::kPacket) and their closest hits, traced as one packet: the rays
  // of one pixel through the lens nearly share an origin and a direction,
  // so Embree's packet traversal visits the nodes they pass once for all of
  // them (bench/README.md, "Camera rays as packets").
  struct CameraPacket {
    int n = 0;
    uint32_t first = 0;
    uint32_t slots = 0;  // sampler slots each camera ray consumed
    Ray rays[Scene::kPacket];
    // Left unconstructed: intersect_packet writes every field of a found
    // hit, and nothing reads the others.
    union {
      SurfaceHit hits[Scene::kPacket];
    };
    CameraPacket() {}
    bool found[Scene::kPacket];
    // What the path from camera ray k continues (trace_paths, which starts
    // each path's numbers past the camera's slots: those it would draw had
    // it traced its camera ray itself).
    PrimaryHit primaries[Scene::kPacket];
  };
  // Fills a CameraPacket. Each ray: pixel jitter (box filter), then the
  // lens only when there is one. With a lens, the jitter and the lens point
  // are one 4D Sobol' point (get4d()): whether a ray sees a defocused edge
  // depends on both together, and one 4D point stratifies them jointly
  // where two padded 2D points stratify each alone (bench/README.md, "Pixel
  // and lens as one 4D point"). The jitter is the same either way. With a
  // lens the packet's numbers are drawn in one batch
  // (PixelSampler::get4d_samples) and its rays made in one batch
  // (Camera::generate_rays): the numbers and rays of each sample drawn and
  // made alone.
  void camera_packet(PixelSampler& s, int x, int y, int first, int n, CameraPacket* cp) const {
    cp->n = n;
    cp->first = uint32_t(first);
    const Vec2 pixel{float(x), float(y)};
    if (camera_.has_lens()) {
      Vec2 film[Scene::kPacket], lens[Scene::kPacket];
      s.get4d_samples(uint32_t(first), n, film, lens);
      for (int k = 0; k < n; ++k) film[k] = pixel + film[k];
      camera_.generate_rays(film, lens, n, cp->rays);
    } else {
      for (int k = 0; k < n; ++k) {
        s.start_sample(uint32_t(first + k));
        cp->rays[k] = camera_.pinhole_ray(pixel + s.get2d());
      }
    }
    cp->slots = s.slots_used();  // the same for every sample: a fixed count
    scene_.intersect_packet(cp->rays, n, cp->hits, cp->found);
    for (int k = 0; k < n; ++k) cp->primaries[k] = {cp->found[k], &cp->hits[k]};
  }

  const Scene& scene_;
  const JobSpec& spec_;
  const Camera& camera_;
  int frame_;
  bool reference_only_;
  IntegratorSettings settings_, reference_settings_;
};

}  // namespace

CameraState frame_camera(const Scene& scene, const JobSpec& spec, int frame) {
  auto autofocus = [&](const CameraState& pose) -> std::optional<float> {
    const Camera pinhole(pose, spec.width, spec.height, camera_clip(spec, scene.data()));
    SurfaceHit hit;
    const Vec2 centre(0.5f * float(spec.width), 0.5f * float(spec.height));
    // The scene as it is at the frame's time (moving meshes).
    if (!scene.at_time(frame_time(spec, frame))->intersect(pinhole.pinhole_ray(centre), &hit))
      return std::nullopt;
    return pinhole.view_depth(hit.p);
  };
  return camera_for_frame(spec, scene.data(), frame, autofocus);
}

Rect checked_rect(const JobSpec& spec, int frame, std::optional<Rect> tile) {
  const FileLoc loc{spec.spec_path.string()};
  if (frame < spec.frame_start || frame > spec.frame_end)
    throw SpecError(loc, "frame",
                    "frame " + std::to_string(frame) + " is outside the job's range " +
                        std::to_string(spec.frame_start) + ".." + std::to_string(spec.frame_end));
  Rect r{0, 0, spec.width, spec.height};
  if (tile) {
    r = *tile;
    if (r.w <= 0 || r.h <= 0 || r.x < 0 || r.y < 0 || r.x + r.w > spec.width ||
        r.y + r.h > spec.height)
      throw SpecError(loc, "tile",
                      "tile " + std::to_string(r.x) + "," + std::to_string(r.y) + "," +
                          std::to_string(r.w) + "," + std::to_string(r.h) + " is not inside the " +
                          std::to_string(spec.width) + "x" + std::to_string(spec.height) +
                          " image");
  }
  return r;
}

FrameBuffers render_frame(const Scene& loaded, const JobSpec& spec, int frame,
                          std::optional<Rect> tile, const RenderOptions& options) {
  const Rect rect = checked_rect(spec, frame, tile);
  // The scene at the frame's time: itself unless its meshes or lights move.
  const std::shared_ptr<const Scene> posed = loaded.at_time(frame_time(spec, frame));
  const Scene& scene = *posed;
  FrameBuffers out;
  out.allocate(rect.w, rect.h, spec.versions);
  out.rect = rect;
  out.camera = frame_camera(scene, spec, frame);
  const Camera camera(out.camera, spec.width, spec.height, camera_clip(spec, scene.data()));
  const PixelRenderer pixels(scene, spec, camera, frame, options.reference_only);

  // Blocks of block_size^2 pixels handed out to a pool of threads; each pixel
  // writes only its own slots, so the result is the same for any schedule.
  const int bs = std::max(1, options.block_size);
  const int bx = (rect.w + bs - 1) / bs, by = (rect.h + bs - 1) / bs;
  const int blocks = bx * by;
  int threads = options.threads > 0 ? options.threads : cpus_available();
  threads = std::clamp(threads, 1, std::max(1, blocks));
  std::atomic<int> next{0};
  std::atomic<uint64_t> rays{0}, shadow_rays{0}, light_samples{0}, light_samples_skipped{0};
  std::optional<Progress> progress;
  if (options.progress)
    progress.emplace("frame " + std::to_string(frame), int64_t(blocks), "blocks");
  const auto t0 = std::chrono::steady_clock::now();
  std::exception_ptr error;
  std::mutex error_mutex;
  auto cancelled = [&] {
    return (options.cancel && options.cancel->load(std::memory_order_relaxed)) ||
           (options.cancel_also && options.cancel_also->load(std::memory_order_relaxed));
  };
  auto work = [&] {
    const RayCount before = thread_ray_count();
    try {
      for (int b = next++; b < blocks; b = next++) {
        int x0 = (b % bx) * bs, y0 = (b / bx) * bs;
        // Checked per pixel: a block of reference pixels at tens of
        // thousands of samples takes seconds, and a stopped worker should
        // hand its task back at once.
        for (int y = y0; y < std::min(y0 + bs, rect.h); ++y)
          for (int x = x0; x < std::min(x0 + bs, rect.w); ++x) {
            if (cancelled()) throw Cancelled();
            pixels.render(rect.x + x, rect.y + y, out, size_t(y) * rect.w + x);
          }
        if (progress) progress->advance();
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
      next = blocks;
    }
    const RayCount after = thread_ray_count();
    rays += after.total() - before.total();
    shadow_rays += after.shadow - before.shadow;
    light_samples += after.light_samples - before.light_samples;
    light_samples_skipped += after.light_samples_skipped - before.light_samples_skipped;
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
  if (progress) progress->finish();
  if (options.stats) {
    options.stats->rays += rays;
    options.stats->shadow_rays += shadow_rays;
    options.stats->light_samples += light_samples;
    options.stats->light_samples_skipped += light_samples_skipped;
    options.stats->paths += uint64_t(rect.w) * rect.h * pixels.paths_per_pixel_hint();
    options.stats->threads = threads;
    options.stats->seconds +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  return out;
}

FrameBuffers render_frame(const JobSpec& spec, int frame, std::optional<Rect> tile,
                          const RenderOptions& options) {
  checked_rect(spec, frame, tile);  // fail on bad input before loading anything
  auto scene = load_scene(spec);
  return render_frame(*scene, spec, frame, tile, options);
}

namespace {
// The reference's sample count or stopping rule, as the EXR header states it.
std::string reference_rule(const JobSpec& spec) {
  if (spec.reference_error <= 0) return std::to_string(spec.reference_spp);
  std::string rule = "error<=" + std::to_string(spec.reference_error);
  if (spec.reference_display_error > 0)
    rule += " or display_error<=" + std::to_string(spec.reference_display_error);
  return rule + " max_spp=" + std::to_string(spec.reference_max_spp);
}
}  // namespace

void render_frame_to_exr(const JobSpec& spec, int frame, std::optional<Rect> tile,
                         const std::filesystem::path& out, const RenderOptions& options,
                         const Scene* scene) {
  auto t0 = std::chrono::steady_clock::now();
  FrameBuffers fb = scene ? render_frame(*scene, spec, frame, tile, options)
                          : render_frame(spec, frame, tile, options);
  double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::map<std::string, std::string> attrs = {
      {"dofarm.renderer_version", DOFARM_VERSION},
      {"dofarm.job", spec.spec_path.string()},
      {"dofarm.scene", spec.scene.string()},
      {"dofarm.seed", std::to_string(spec.seed)},
      {"dofarm.image", std::to_string(spec.width) + "x" + std::to_string(spec.height)},
      {"dofarm.spp.reference", reference_rule(spec)},
      {"dofarm.spp.albedo_ref", std::to_string(spec.albedo_ref_spp)},
      {"dofarm.render_seconds", std::to_string(seconds)},
  };
  write_frame_exr(out, fb, attrs, FrameExtent{spec.width, spec.height});
}

}  // namespace dofarm::render
