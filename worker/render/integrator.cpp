#include "worker/render/integrator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>
#include <type_traits>

#include "worker/render/bsdf.h"
#include "worker/render/scratch.h"
#include "worker/render/simd.h"

namespace dofarm::render {

namespace {

float power_heuristic(float f, float g) {
  float f2 = f * f, g2 = g * g;
  if (std::isinf(f2)) return 1.0f;
  return f2 + g2 > 0 ? f2 / (f2 + g2) : 0.0f;
}

}  // namespace

Vec3 primary_albedo(const SurfaceHit* hit) {
  if (!hit || max_component(hit->emission) > 0) return Vec3(1);
  return hit->base_color;
}

namespace {

// One path of a batch between its vertices, and what its present vertex
// has found so far.
struct PathLane {
  PixelSampler::Position numbers;  // where its next numbers come from
  Ray ray;
  const PrimaryHit* primary = nullptr;  // its camera ray's hit, when already traced
  Vec3* albedo = nullptr;
  Vec3 L{0}, beta{1};
  Vec3 seen{0};              // emission the camera ray itself reaches (never clamped)
  bool delta_bounce = true;  // the camera ray counts as one: nothing to weigh against
  float prev_bsdf_pdf = 0;
  Vec3 prev_p;
  int depth = 0;
  // The pass that takes the path on: PathBatch::trace, arrive, then escape
  // or shade.
  enum class Next { kTrace, kArrive, kEscape, kShade, kDone } next = Next::kTrace;
  // The present vertex.
  PixelSampler::VertexNumbers u{};
  Scene::LightChoice light_choice;
  const SurfaceHit* hit = nullptr;  // `traced` or the camera packet's hit; null: escaped
  // Left unconstructed: Scene::intersect writes every field of a hit (and
  // nothing reads it after a miss), so a path pays for no default values
  // it would overwrite.
  union {
    SurfaceHit traced;
  };
  // Between PathBatch::prepare and shade: the hit's BSDF, what it computed
  // for the outgoing direction, and the light sample (when `lit`).
  // Left unconstructed until then.
  union {
    Bsdf bsdf;
  };
  union {
    Bsdf::Outgoing out;
  };
  union {
    LightSample light;
  };
  bool lit = false;
  // Between PathBatch::shade_lanes' passes: the BSDF's value and pdf
  // towards the light sample, and the BSDF sample.
  Vec3 light_f;
  float light_bsdf_pdf;
  union {
    BsdfSample bounce;
  };
  PathLane() {}
};
static_assert(std::is_trivially_destructible_v<Bsdf>);
static_assert(std::is_trivially_destructible_v<PathLane>);

// Advances a batch of paths one vertex at a time, in passes over the batch
// per vertex:
//   trace          the vertex's numbers, and its ray traced;
//   arrive         what the ray found: a path that hit chooses its light
//                  sample (and the environment's map block, starting its
//                  load), adds emission and lamps passed; or it escaped;
//   (locate)       the escaping paths' environment texels, together
//                  (Environment::locate in lanes), starting their loads;
//   prepare        each hit's BSDF and its outgoing direction's terms;
//   sample_lights  the light samples, together (Scene::sample_lights),
//                  reading the blocks the choices loaded;
//   shade          next-event estimation and the bounce (the BSDF's
//                  evaluations in AVX2 lanes where interleaved:
//                  shade_lanes);
//   escape         the environment the escaping paths reach.
// Between a load's start and its use lie the other paths' passes, which
// hide it the way a ray traversal did when each path chose and located
// before tracing, without choosing for rays that escape or locating for
// rays that hit (bench/README.md, "Paths of a packet traced together").
// Each path draws its numbers from its own sample and slots and does its
// own arithmetic in the order a path traced alone would, so its estimate
// is the same bit for bit.
class PathBatch {
 public:
  // `interleave`: run() is given several paths to advance together;
  // otherwise one at a time.
  PathBatch(const Scene& scene, PixelSampler& sampler, const IntegratorSettings& settings,
            bool interleave)
      : interleave_(interleave),
        scene_(scene),
        sampler_(sampler),
        settings_(settings),
        env_(scene.environment()),
        use_nee_(settings.strategy != LightStrategy::kBsdfOnly),
        use_bsdf_hits_(settings.strategy != LightStrategy::kNeeOnly),
        use_mis_(settings.strategy == LightStrategy::kMis),
        lanes_(interleave && use_simd()) {}

  void run(PathLane* lanes, int n) const {
    Scratch<Environment::Located, kMaxPaths> located;
    int escaping[kMaxPaths];
    for (bool live = true; live;) {
      live = false;
      for (int k = 0; k < n; ++k)
        if (lanes[k].next == PathLane::Next::kTrace) trace(lanes[k]);
      int m = 0;
      for (int k = 0; k < n; ++k) {
        if (lanes[k].next != PathLane::Next::kArrive) continue;
        arrive(lanes[k]);
        if (lanes[k].next == PathLane::Next::kEscape) escaping[m++] = k;
      }
      if (m > 0) {
        // The escaping paths' texels, located together (and loading while
        // the others shade).
        Scratch<Vec3, kMaxPaths> dirs;
        for (int j = 0; j < m; ++j) dirs[j] = lanes[escaping[j]].ray.d;
        env_->locate(dirs.data(), m, located.data());
      }
      for (int k = 0; k < n; ++k)
        if (lanes[k].next == PathLane::Next::kShade) prepare(lanes[k]);
      if (interleave_) sample_lights(lanes, n);
      if (lanes_ && n > 1) {
        live = shade_lanes(lanes, n);
      } else {
        for (int k = 0; k < n; ++k) {
          if (lanes[k].next != PathLane::Next::kShade) continue;
          shade(lanes[k]);
          live = live || lanes[k].next == PathLane::Next::kTrace;
        }
      }
      for (int j = 0; j < m; ++j) escape(lanes[escaping[j]], located[j]);
    }
  }

  // The finished path's estimate: finite and non-negative, clamped when
  // the settings ask for it.
  Vec3 result(const PathLane& l) const {
    Vec3 L = l.L;
    if (!is_finite(L) || L.x < 0 || L.y < 0 || L.z < 0) return Vec3(0);
    if (settings_.sample_clamp > 0) [[unlikely]] {
      // A sample clamp (biased; JobSpec::reference_clamp): the rest of the
      // sample keeps its hue, its largest channel at most the bound.
      const Vec3 rest(std::max(L.x - l.seen.x, 0.0f), std::max(L.y - l.seen.y, 0.0f),
                      std::max(L.z - l.seen.z, 0.0f));
      const float m = max_component(rest);
      if (m > settings_.sample_clamp) L = l.seen + rest * (settings_.sample_clamp / m);
    }
    return L;
  }

 private:
  // The vertex's five numbers (light choice, light point, lobe, BSDF
  // direction, roulette) from its five slots at once
  // (PixelSampler::get_vertex: one batch, the numbers the single draws
  // give), then its ray. A fixed number of slots per bounce keeps the
  // sample streams of different paths aligned (better stratification with
  // Sobol'). A camera ray already traced (a packet) that escaped ends the
  // path here: its numbers are skipped, not computed.
  void trace(PathLane& l) const {
    const int depth = l.depth;
    if (depth < settings_.max_depth) {
      if (!(depth == 0 && l.primary && !l.primary->found)) {
        sampler_.seek(l.numbers);
        sampler_.get_vertex(&l.u);
      }
      l.numbers.slot += 5;
    }
    if (depth == 0 && l.primary) {
      // The camera ray's hit is read where the packet left it, not copied.
      l.hit = l.primary->found ? l.primary->hit : nullptr;
    } else {
      l.hit = scene_.intersect(l.ray, &l.traced) ? &l.traced : nullptr;
    }
    l.next = PathLane::Next::kArrive;
  }

  // What the vertex's ray found, up to shading: the light choice (which
  // starts loading what sampling it will read), emission and lamps passed;
  // or that it escaped to the environment.
  void arrive(PathLane& l) const {
    const int depth = l.depth;
    const bool found = l.hit != nullptr;
    if (found && use_nee_ && depth < settings_.max_depth)
      l.light_choice = scene_.choose_light(l.u.select, l.u.light, &l.hit->ng);
    if (depth == 0 && l.albedo) *l.albedo = primary_albedo(l.hit);
    // Lamps with a size that this bounce ray passes (not the camera ray:
    // Cycles does not show lamps to the camera either), weighed like an
    // emissive triangle's hit.
    if (depth > 0 && scene_.has_sized_lamps() && (l.delta_bounce || use_bsdf_hits_)) [[unlikely]] {
      const bool weigh = !l.delta_bounce && use_mis_;
      const float prev_pdf = l.prev_bsdf_pdf;
      const Vec3 le = scene_.lamps_along(
          l.prev_p, l.ray.d, found ? l.hit->t : std::numeric_limits<float>::infinity(),
          [&](float light_pdf) { return weigh ? power_heuristic(prev_pdf, light_pdf) : 1.0f; });
      l.L += l.beta * le;
      if (settings_.observer && max_component(le) > 0)
        settings_.observer->contribution(PathObserver::Kind::kBsdfHit, depth, l.beta * le);
    }
    if (!found) {
      if (env_ && (l.delta_bounce || use_bsdf_hits_)) {
        l.next = PathLane::Next::kEscape;
      } else {
        l.next = PathLane::Next::kDone;
      }
      return;
    }
    const SurfaceHit& hit = *l.hit;
    // KHR_materials_volume: a segment that ends on the inside of a mesh
    // whose material absorbs ran through that medium (closed meshes that do
    // not overlap): Beer-Lambert, exp(-sigma_a t).
    if (!hit.front && max_component(hit.attenuation) > 0) [[unlikely]] {
      const Vec3& s = hit.attenuation;
      l.beta =
          l.beta * Vec3(std::exp(-s.x * hit.t), std::exp(-s.y * hit.t), std::exp(-s.z * hit.t));
    }
    if (settings_.observer) settings_.observer->vertex(depth, hit);
    if (max_component(hit.emission) > 0 && (l.delta_bounce || use_bsdf_hits_)) {
      float w = 1.0f;
      if (!l.delta_bounce && use_mis_)
        w = power_heuristic(l.prev_bsdf_pdf, scene_.light_pdf(l.prev_p, hit));
      l.L += l.beta * hit.emission * w;
      if (depth == 0) l.seen = l.L;
      if (settings_.observer)
        settings_.observer->contribution(
            l.delta_bounce ? PathObserver::Kind::kEmitted : PathObserver::Kind::kBsdfHit, depth,
            l.beta * hit.emission * w);
    }
    l.next = depth >= settings_.max_depth ? PathLane::Next::kDone : PathLane::Next::kShade;
  }

  // The environment an escaping ray reaches, weighed against the light
  // sample that could have found the same direction; the path ends.
  void escape(PathLane& l, const Environment::Located& at) const {
    float w = 1.0f;
    Vec3 le;
    if (!l.delta_bounce && use_mis_) {
      float light_pdf;
      le = scene_.environment_radiance(at, l.ray.d, &light_pdf);
      w = power_heuristic(l.prev_bsdf_pdf, light_pdf);
    } else {
      le = env_->eval(at);
    }
    l.L += l.beta * le * w;
    if (l.depth == 0) l.seen = l.L;
    if (settings_.observer)
      settings_.observer->contribution(PathObserver::Kind::kEnvironment, l.depth, l.beta * le * w);
    l.next = PathLane::Next::kDone;
  }

  // The hit's BSDF, and whether it asks for a light sample.
  void prepare(PathLane& l) const {
    make_bsdf(l);
    new (&l.out) Bsdf::Outgoing(l.bsdf.outgoing(-l.ray.d));
    // A path alone takes its light sample here (sample_lights gathers a
    // batch's).
    if (l.lit && !interleave_) {
      if (rejected_below(l)) {
        l.lit = false;
        count_light_samples(1, 1);
        return;
      }
      l.lit = scene_.sample_light(l.hit->p, l.light_choice, &l.light);
      count_light_samples(l.lit ? 1 : 0);
    }
  }

  // Whether the light sample the path chose is certain to point below its
  // surface's geometric normal, which its BSDF rejects (a BSDF in lanes
  // evaluates nothing there: Bsdf::evaluate_direction): the sample is then
  // counted as taken, and neither made nor evaluated. Its estimate is the
  // same bit for bit (the rejected sample added nothing); what it saves is
  // the block record's load, the texel's choice and the direction, for
  // about half of the courtyard's sky samples (bench/README.md, "Light
  // samples the surface turns away").
  bool rejected_below(const PathLane& l) const {
    return l.light_choice.below() && l.bsdf.in_lanes();
  }

  // The hit's BSDF (its material's constants where it has them: the same
  // BSDF), and whether it asks for a light sample.
  void make_bsdf(PathLane& l) const {
    const SurfaceHit& hit = *l.hit;
    if (const BsdfConstants* k = scene_.bsdf_constants(hit.prim)) [[likely]] {
      new (&l.bsdf) Bsdf(*k, hit.ns, hit.ng, hit.base_color, hit.front, hit.coat_ns);
    } else {
      new (&l.bsdf) Bsdf(hit.ns, hit.ng, hit.base_color, hit.metallic, hit.roughness, hit.ior,
                         {hit.specular, hit.specular_color}, {hit.transmission, hit.front},
                         {hit.clearcoat, hit.clearcoat_roughness, hit.coat_ns},
                         {hit.sheen_color, hit.sheen_roughness});
    }
    l.lit = use_nee_ && l.bsdf.has_non_delta();
    if (l.lit) new (&l.light) LightSample;
  }

  // The light samples of the paths that asked, taken together
  // (Scene::sample_lights); they read what the light choices started
  // loading. A path whose sample fails is not lit.
  void sample_lights(PathLane* lanes, int n) const {
    Scratch<Vec3, kMaxPaths> from;
    const Scene::LightChoice* choices[kMaxPaths];
    LightSample* out[kMaxPaths];
    bool ok[kMaxPaths];
    int who[kMaxPaths], m = 0;
    uint64_t below = 0;  // samples rejected_below(): taken, not made
    for (int k = 0; k < n; ++k) {
      PathLane& l = lanes[k];
      if (l.next != PathLane::Next::kShade || !l.lit) continue;
      if (rejected_below(l)) {
        l.lit = false;
        ++below;
        continue;
      }
      from[m] = l.hit->p;
      choices[m] = &l.light_choice;
      out[m] = &l.light;
      who[m++] = k;
    }
    if (m > 0) scene_.sample_lights(m, from.data(), choices, out, ok);
    uint64_t taken = below;
    for (int j = 0; j < m; ++j) {
      lanes[who[j]].lit = ok[j];
      taken += ok[j] ? 1 : 0;
    }
    count_light_samples(taken, below);
  }

  // Next-event estimation with the light sample, then the bounce (or the
  // end of the path by roulette or an invalid sample).
  void shade(PathLane& l) const {
    if (l.lit) {
      float bsdf_pdf;
      const Vec3 f = l.bsdf.evaluate(l.out, l.light.wi, &bsdf_pdf);
      add_light(l, f, bsdf_pdf);
    }
    continue_path(l, l.bsdf.sample(l.out, l.u.lobe, l.u.bsdf));
  }

  // shade() of every path at a hit, with the BSDF evaluations of those
  // whose BSDF allows it done together in lanes (Bsdf::evaluate_lanes),
  // towards the light samples and in the sampled directions (which need
  // nothing from the light samples) in one call; then the shadow rays and
  // the bounces. Each path's numbers are shade()'s bit for bit, and its
  // rays are traced in the same order. Whether any path goes on.
  bool shade_lanes(PathLane* lanes, int n) const {
    int at[kMaxPaths], ns = 0;  // the paths at a hit
    for (int k = 0; k < n; ++k)
      if (lanes[k].next == PathLane::Next::kShade) at[ns++] = k;
    // Up to two evaluations per path: towards its light sample, in its
    // sampled direction.
    constexpr int kMax = 2 * kMaxPaths;
    const Bsdf* bsdfs[kMax];
    const Bsdf::Outgoing* outs[kMax];
    Scratch<Vec3, kMax> wi, f;
    float pdf[kMax];
    int light_at[kMaxPaths], bounce_at[kMaxPaths];  // where each path's are, or -1
    int m = 0;
    for (int i = 0; i < ns; ++i) {
      PathLane& l = lanes[at[i]];
      light_at[i] = bounce_at[i] = -1;
      const bool in_lanes = l.bsdf.in_lanes();
      if (l.lit) {
        if (!in_lanes) {
          l.light_f = l.bsdf.evaluate(l.out, l.light.wi, &l.light_bsdf_pdf);
        } else if (l.bsdf.evaluate_direction(l.out, l.light.wi, &wi[m])) {
          bsdfs[m] = &l.bsdf;
          outs[m] = &l.out;
          light_at[i] = m++;
        } else {
          l.light_f = Vec3(0);
          l.light_bsdf_pdf = 0;
        }
      }
      if (!in_lanes) {
        l.bounce = l.bsdf.sample(l.out, l.u.lobe, l.u.bsdf);
      } else if (l.bsdf.sample_direction(l.out, l.u.lobe, l.u.bsdf, &l.bounce, &wi[m])) {
        bsdfs[m] = &l.bsdf;
        outs[m] = &l.out;
        bounce_at[i] = m++;
      }
    }
    if (m > 0) Bsdf::evaluate_lanes(m, bsdfs, outs, wi.data(), f.data(), pdf);
    bool live = false;
    for (int i = 0; i < ns; ++i) {
      PathLane& l = lanes[at[i]];
      if (l.lit) {
        const int j = light_at[i];
        if (j >= 0) {
          add_light(l, f[j], pdf[j]);
        } else {
          add_light(l, l.light_f, l.light_bsdf_pdf);
        }
      }
      if (bounce_at[i] >= 0) Bsdf::finish_sample(&l.bounce, f[bounce_at[i]], pdf[bounce_at[i]]);
      continue_path(l, l.bounce);
      live = live || l.next == PathLane::Next::kTrace;
    }
    return live;
  }

  // Next-event estimation with the light sample, whose BSDF value is f
  // (pdf bsdf_pdf): its shadow ray, and what it adds.
  void add_light(PathLane& l, Vec3 f, float bsdf_pdf) const {
    if (!(max_component(f) > 0)) return;
    const SurfaceHit& hit = *l.hit;
    const LightSample& ls = l.light;
    const Vec3 origin = scene_.offset_origin(hit, ls.wi);
    Vec3 dir = ls.wi;
    float t_max = ls.distance;
    if (!std::isinf(ls.distance)) {
      // Aimed from the offset origin at the light point itself. Along
      // ls.wi from the moved origin the ray would reach the light's
      // plane earlier by the offset over the cosine, which exceeds the
      // 1e-4 margin below for a surface close to and parallel with the
      // light (a ceiling 2 cm above a light's back face: the light
      // itself occluded every sample, and NEE lost its share of that
      // light; tests/render/test_integrator.cpp).
      const Vec3 to = hit.p + ls.wi * ls.distance - origin;
      const float len = length(to);
      if (len > 0) dir = to / len;
      t_max = len * (1.0f - 1e-4f);
    }
    if (scene_.occluded(origin, dir, t_max)) return;
    float w = use_mis_ && !ls.is_delta ? power_heuristic(ls.pdf, bsdf_pdf) : 1.0f;
    l.L += l.beta * f * ls.radiance * (w / ls.pdf);
    if (settings_.observer)
      settings_.observer->contribution(PathObserver::Kind::kLight, l.depth,
                                       l.beta * f * ls.radiance * (w / ls.pdf));
  }

  // The bounce along the BSDF sample bs, or the end of the path (an
  // invalid sample, or roulette).
  void continue_path(PathLane& l, const BsdfSample& bs) const {
    const int depth = l.depth;
    l.next = PathLane::Next::kDone;
    if (!bs.valid) return;
    l.beta *= bs.weight;
    if (!(max_component(l.beta) > 0) || !is_finite(l.beta)) return;
    l.delta_bounce = bs.is_delta;
    l.prev_bsdf_pdf = bs.pdf;
    l.prev_p = l.hit->p;

    if (depth + 1 >= settings_.rr_start_depth) {
      // A weight window's lower bound (Vorba and Krivanek 2016, sec. 4, with
      // a constant window and no splitting): a path whose throughput is at
      // least rr_threshold always continues; below it, it survives with
      // probability max(beta) / rr_threshold and is then weighted up to the
      // threshold, so the expectation is unchanged (E[beta'] = q beta / q).
      const float survive = std::min(1.0f, max_component(l.beta) / settings_.rr_threshold);
      if (settings_.observer && survive < 1)
        settings_.observer->roulette(depth, survive, l.u.roulette < survive);
      if (l.u.roulette >= survive) return;
      l.beta = l.beta / survive;
    }
    l.ray = {scene_.offset_origin(*l.hit, bs.wi), bs.wi};
    l.depth = depth + 1;
    l.next = PathLane::Next::kTrace;
  }

  const bool interleave_;
  const Scene& scene_;
  PixelSampler& sampler_;
  const IntegratorSettings& settings_;
  const Environment* env_;
  const bool use_nee_, use_bsdf_hits_, use_mis_;
  const bool lanes_;  // interleaved, with AVX2 lanes: shade_lanes()
};

}  // namespace

Vec3 trace_path(const Scene& scene, const Ray& camera_ray, PixelSampler& sampler,
                const IntegratorSettings& settings, Vec3* albedo, const PrimaryHit* primary) {
  PathLane lane;
  lane.numbers = sampler.position();
  lane.ray = camera_ray;
  lane.primary = primary;
  lane.albedo = albedo;
  const PathBatch batch(scene, sampler, settings, /*interleave=*/false);
  batch.run(&lane, 1);
  sampler.seek(lane.numbers);
  return batch.result(lane);
}

void trace_paths(const Scene& scene, const Ray* camera_rays, const PrimaryHit* primaries, int n,
                 PixelSampler& sampler, uint32_t first, uint32_t slots,
                 const IntegratorSettings& settings, Vec3* radiance, Vec3* albedos) {
  // Interleaved where it pays: the paths' loads from an environment map,
  // which outgrows the caches, are hidden behind each other's work (the
  // courtyard's renderer 15-20% faster). In a scene without one the paths
  // run one after another, each keeping the traversal's working set to
  // itself (interleaved, the Cornell box's renderer and the replay of its
  // rays were 4-6% slower); an observer follows one path at a time too.
  // The estimates are the same either way (bench/README.md, "Paths of a
  // packet traced together").
  const Environment* env = scene.environment();
  const bool interleave = !settings.observer && env && env->has_map();
  const PathBatch batch(scene, sampler, settings, interleave);
  // kMaxPaths at a time; only the lanes in use are constructed.
  union Lanes {
    PathLane lane[kMaxPaths];
    Lanes() {}
  } storage;
  PathLane* lanes = storage.lane;
  for (int k0 = 0; k0 < n; k0 += kMaxPaths) {
    const int m = std::min(kMaxPaths, n - k0);
    for (int j = 0; j < m; ++j) {
      const int k = k0 + j;
      PathLane& l = *new (&lanes[j]) PathLane();
      sampler.start_sample(first + uint32_t(k));
      sampler.skip(slots);
      l.numbers = sampler.position();
      l.ray = camera_rays[k];
      l.primary = primaries ? &primaries[k] : nullptr;
      l.albedo = albedos ? &albedos[k] : nullptr;
    }
    if (interleave) {
      batch.run(lanes, m);
    } else {
      for (int j = 0; j < m; ++j) batch.run(&lanes[j], 1);
    }
    for (int j = 0; j < m; ++j) radiance[k0 + j] = batch.result(lanes[j]);
  }
}

}  // namespace dofarm::render
