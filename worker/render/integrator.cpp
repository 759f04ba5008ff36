#include "worker/render/integrator.h"

#include <cmath>
#include <limits>

#include "worker/render/bsdf.h"

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

Vec3 trace_path(const Scene& scene, const Ray& camera_ray, PixelSampler& sampler,
                const IntegratorSettings& settings, Vec3* albedo, const PrimaryHit* primary) {
  const bool use_nee = settings.strategy != LightStrategy::kBsdfOnly;
  const bool use_bsdf_hits = settings.strategy != LightStrategy::kNeeOnly;
  const bool use_mis = settings.strategy == LightStrategy::kMis;

  Vec3 L(0), beta(1);
  Vec3 seen(0);  // emission the camera ray itself reaches (never clamped)
  Ray ray = camera_ray;
  bool delta_bounce = true;  // the camera ray counts as one: nothing to weigh against
  float prev_bsdf_pdf = 0;
  Vec3 prev_p;
  const Environment* env = scene.environment();

  for (int depth = 0;; ++depth) {
    // This vertex's five numbers (light choice, light point, lobe, BSDF
    // direction, roulette) from its five slots at once, before its ray is
    // traced (PixelSampler::get_vertex: one batch, the numbers the single
    // draws give; nothing between consumes a slot). A fixed number of slots
    // per bounce keeps the sample streams of different paths aligned (better
    // stratification with Sobol'). For a bounce ray the light and the
    // environment block are chosen from them at once, so that what sampling
    // an environment map reads, which is larger than the caches, loads
    // during the traversal; likewise the texel an escaping bounce ray would
    // read. A camera ray's vertex chooses only once the ray has hit: in an
    // open scene many camera rays escape to the sky, and their choice would
    // be thrown away (the same choice either way; courtyard 5% more rays a
    // second, Cornell, where every camera ray hits, unchanged:
    // bench/README.md, "Where the courtyard's 50% would have to come
    // from"). A camera ray already traced (a packet) that escaped ends the
    // path here: its numbers are skipped, not computed.
    const bool known_escape = depth == 0 && primary && !primary->found;
    Scene::LightChoice light_choice;
    PixelSampler::VertexNumbers u{};
    if (depth < settings.max_depth) {
      if (known_escape) {
        sampler.skip(5);
      } else {
        sampler.get_vertex(&u);
      }
      if (use_nee && depth > 0) light_choice = scene.choose_light(u.select, u.light);
    }
    Environment::Located escape;
    if (env && depth > 0) escape = env->locate(ray.d);
    // The camera ray's hit is read where the packet left it, not copied.
    SurfaceHit traced;
    const SurfaceHit* at = &traced;
    bool found;
    if (depth == 0 && primary) {
      found = primary->found;
      if (found) at = primary->hit;
    } else {
      found = scene.intersect(ray, &traced);
    }
    const SurfaceHit& hit = *at;
    if (found && depth == 0 && use_nee && depth < settings.max_depth)
      light_choice = scene.choose_light(u.select, u.light);
    if (depth == 0 && albedo) *albedo = primary_albedo(found ? &hit : nullptr);
    // Lamps with a size that this bounce ray passes (not the camera ray:
    // Cycles does not show lamps to the camera either), weighed like an
    // emissive triangle's hit.
    if (depth > 0 && scene.has_sized_lamps() && (delta_bounce || use_bsdf_hits)) [[unlikely]] {
      const bool weigh = !delta_bounce && use_mis;
      const Vec3 le =
          scene.lamps_along(prev_p, ray.d, found ? hit.t : std::numeric_limits<float>::infinity(),
                            [&](float light_pdf) {
                              return weigh ? power_heuristic(prev_bsdf_pdf, light_pdf) : 1.0f;
                            });
      L += beta * le;
      if (settings.observer && max_component(le) > 0)
        settings.observer->contribution(PathObserver::Kind::kBsdfHit, depth, beta * le);
    }
    // KHR_materials_volume: a segment that ends on the inside of a mesh
    // whose material absorbs ran through that medium (closed meshes that do
    // not overlap): Beer-Lambert, exp(-sigma_a t).
    if (found && !hit.front && max_component(hit.attenuation) > 0) [[unlikely]] {
      const Vec3& s = hit.attenuation;
      beta = beta * Vec3(std::exp(-s.x * hit.t), std::exp(-s.y * hit.t), std::exp(-s.z * hit.t));
    }
    if (found && settings.observer) settings.observer->vertex(depth, hit);

    if (!found) {
      if (env && (delta_bounce || use_bsdf_hits)) {
        float w = 1.0f;
        Vec3 le;
        if (depth == 0) escape = env->locate(ray.d);
        if (!delta_bounce && use_mis) {
          float light_pdf;
          le = scene.environment_radiance(escape, ray.d, &light_pdf);
          w = power_heuristic(prev_bsdf_pdf, light_pdf);
        } else {
          le = env->eval(escape);
        }
        L += beta * le * w;
        if (depth == 0) seen = L;
        if (settings.observer)
          settings.observer->contribution(PathObserver::Kind::kEnvironment, depth, beta * le * w);
      }
      break;
    }
    if (max_component(hit.emission) > 0 && (delta_bounce || use_bsdf_hits)) {
      float w = 1.0f;
      if (!delta_bounce && use_mis)
        w = power_heuristic(prev_bsdf_pdf, scene.light_pdf(prev_p, hit));
      L += beta * hit.emission * w;
      if (depth == 0) seen = L;
      if (settings.observer)
        settings.observer->contribution(
            delta_bounce ? PathObserver::Kind::kEmitted : PathObserver::Kind::kBsdfHit, depth,
            beta * hit.emission * w);
    }
    if (depth >= settings.max_depth) break;

    const bool roulette = depth + 1 >= settings.rr_start_depth;

    Bsdf bsdf(hit.ns, hit.ng, hit.base_color, hit.metallic, hit.roughness, hit.ior,
              {hit.specular, hit.specular_color}, {hit.transmission, hit.front},
              {hit.clearcoat, hit.clearcoat_roughness, hit.coat_ns},
              {hit.sheen_color, hit.sheen_roughness});
    const Bsdf::Outgoing out = bsdf.outgoing(-ray.d);

    if (use_nee && bsdf.has_non_delta()) {
      LightSample ls;
      if (scene.sample_light(hit.p, light_choice, &ls)) {
        float bsdf_pdf;
        Vec3 f = bsdf.evaluate(out, ls.wi, &bsdf_pdf);
        if (max_component(f) > 0) {
          const Vec3 origin = scene.offset_origin(hit, ls.wi);
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
          if (!scene.occluded(origin, dir, t_max)) {
            float w = use_mis && !ls.is_delta ? power_heuristic(ls.pdf, bsdf_pdf) : 1.0f;
            L += beta * f * ls.radiance * (w / ls.pdf);
            if (settings.observer)
              settings.observer->contribution(PathObserver::Kind::kLight, depth,
                                              beta * f * ls.radiance * (w / ls.pdf));
          }
        }
      }
    }

    BsdfSample bs = bsdf.sample(out, u.lobe, u.bsdf);
    if (!bs.valid) break;
    beta *= bs.weight;
    if (!(max_component(beta) > 0) || !is_finite(beta)) break;
    delta_bounce = bs.is_delta;
    prev_bsdf_pdf = bs.pdf;
    prev_p = hit.p;

    if (roulette) {
      // A weight window's lower bound (Vorba and Krivanek 2016, sec. 4, with
      // a constant window and no splitting): a path whose throughput is at
      // least rr_threshold always continues; below it, it survives with
      // probability max(beta) / rr_threshold and is then weighted up to the
      // threshold, so the expectation is unchanged (E[beta'] = q beta / q).
      const float survive = std::min(1.0f, max_component(beta) / settings.rr_threshold);
      if (settings.observer && survive < 1)
        settings.observer->roulette(depth, survive, u.roulette < survive);
      if (u.roulette >= survive) break;
      beta = beta / survive;
    }
    ray = {scene.offset_origin(hit, bs.wi), bs.wi};
  }
  if (!is_finite(L) || L.x < 0 || L.y < 0 || L.z < 0) return Vec3(0);
  if (settings.sample_clamp > 0) [[unlikely]] {
    // A sample clamp (biased; JobSpec::reference_clamp): the rest of the
    // sample keeps its hue, its largest channel at most the bound.
    const Vec3 rest(std::max(L.x - seen.x, 0.0f), std::max(L.y - seen.y, 0.0f),
                    std::max(L.z - seen.z, 0.0f));
    const float m = max_component(rest);
    if (m > settings.sample_clamp) L = seen + rest * (settings.sample_clamp / m);
  }
  return L;
}

}  // namespace dofarm::render
