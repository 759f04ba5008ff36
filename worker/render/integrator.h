// Unidirectional path tracing with next-event estimation and multiple
// importance sampling (Veach 1997, ch. 9, power heuristic with beta = 2),
// Russian roulette on the path throughput with a threshold.
#pragma once

#include "worker/render/camera.h"
#include "worker/render/sampler.h"
#include "worker/render/scene.h"

namespace dofarm::render {

// kMis is what the renderer uses; the other two exist so tests can check that
// all three estimate the same integral.
enum class LightStrategy { kMis, kNeeOnly, kBsdfOnly };

// A measurement hook (bench/path_variance): told of every surface a path
// hits, of every term it adds to its estimate and of every roulette decision.
// Null in the renderer, where it costs one untaken branch per event.
class PathObserver {
 public:
  enum class Kind {
    kEmitted,      // emission reached by the camera ray or after a delta bounce
    kBsdfHit,      // emission reached by BSDF sampling, MIS-weighted
    kLight,        // next-event estimation, MIS-weighted
    kEnvironment,  // environment reached by an escaping ray
  };
  virtual ~PathObserver() = default;
  virtual void vertex(int depth, const SurfaceHit& hit) = 0;
  virtual void contribution(Kind kind, int depth, Vec3 value) = 0;
  // `survive` < 1: the path was played for; it continues iff `survived`.
  virtual void roulette(int depth, float survive, bool survived) = 0;
};

struct IntegratorSettings {
  int max_depth = 16;  // surface interactions after the camera
  int rr_start_depth = 3;
  // Russian roulette never ends a path whose throughput (max over RGB) is at
  // least this; below, it survives with probability throughput / threshold.
  // 1 is the textbook rule (pbrt); 0.25 was measured the most efficient on
  // the bundled Cornell box (bench/README.md, "Russian roulette"): per-pixel
  // relative MSE x CPU time 29% lower than with 1 (no roulette: 12% higher).
  float rr_threshold = 0.25f;
  LightStrategy strategy = LightStrategy::kMis;
  PathObserver* observer = nullptr;  // measurements only (bench/path_variance)
  // > 0: a biased, opt-in clamp (JobSpec::reference_clamp): of each sample,
  // everything but what the camera ray itself sees emitted (a light or the
  // environment seen directly) is scaled down so that its largest channel
  // is at most this. 0 (the default) changes nothing.
  float sample_clamp = 0.0f;
};

// What the denoiser sees of the first surface: the reflectance used to
// demodulate radiance. Surfaces that emit and rays that escape get 1: their
// radiance is not reflected light.
Vec3 primary_albedo(const SurfaceHit* hit);

// Radiance along `ray`. Always finite and non-negative: a sample whose
// estimate is NaN or infinite (it should never happen) contributes 0.
// `albedo` (optional) receives primary_albedo() of the first hit.
// `primary` (optional): `ray`'s closest hit, already traced (a packet of
// camera rays, Scene::intersect_packet); the path goes on from it as if it
// had traced the ray itself, with the same numbers.
struct PrimaryHit {
  bool found = false;
  const SurfaceHit* hit = nullptr;  // when found
};
// The path continues `sampler`'s present sample from its present slot, and
// leaves the sampler after the last slot it consumed.
Vec3 trace_path(const Scene& scene, const Ray& ray, PixelSampler& sampler,
                const IntegratorSettings& settings, Vec3* albedo = nullptr,
                const PrimaryHit* primary = nullptr);

// trace_path() for samples first, ..., first + n - 1 of `sampler`'s pixel
// at once (kMaxPaths at a time): path k continues camera ray camera_rays[k],
// whose numbers took the sample's first `slots` slots, from
// primaries[k] (its hit, already traced; optional) and writes its estimate
// to radiance[k] and primary_albedo() to albedos[k] (optional). In a scene
// that samples an environment map the paths advance a vertex at a time
// together, so that what one path's light choice or escape starts loading
// from the map arrives while the others work (integrator.cpp, PathBatch);
// elsewhere, and with an observer, they run one after another. Either way
// each estimate is trace_path()'s for its sample bit for bit.
// Afterwards the sampler's position is undefined: start_sample() it.
constexpr int kMaxPaths = 8;
void trace_paths(const Scene& scene, const Ray* camera_rays, const PrimaryHit* primaries, int n,
                 PixelSampler& sampler, uint32_t first, uint32_t slots,
                 const IntegratorSettings& settings, Vec3* radiance, Vec3* albedos = nullptr);

}  // namespace dofarm::render
