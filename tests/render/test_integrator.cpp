// Known answers for the path tracer: the white furnace (diffuse, and every
// roughness and metallic of the energy-conserving material), and agreement
// of the three light-sampling strategies.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "tests/render/render_fixtures.h"
#include "tests/render/same_bits.h"
#include "worker/render/integrator.h"

namespace dofarm::render {
namespace {

using testing::make_scene;
using testing::make_spec;

struct Estimate {
  double mean = 0, std_error = 0;
  size_t n = 0;
};

// Mean luminance over the pixels whose pinhole ray hits the scene, with
// `spp` samples each, and the standard error of that mean over all samples.
Estimate estimate(const Scene& scene, const JobSpec& spec, int spp, LightStrategy strategy,
                  bool only_hits = true) {
  CameraState cs = camera_for_frame(spec, scene.data(), 0);
  Camera cam(cs, spec.width, spec.height);
  IntegratorSettings settings;
  settings.max_depth = spec.max_depth;
  settings.rr_start_depth = spec.rr_start_depth;
  settings.strategy = strategy;
  double sum = 0, sum2 = 0;
  size_t n = 0;
  for (int y = 0; y < spec.height; ++y)
    for (int x = 0; x < spec.width; ++x) {
      SurfaceHit hit;
      if (only_hits && !scene.intersect(cam.pinhole_ray({x + 0.5f, y + 0.5f}), &hit)) continue;
      PixelSampler sampler(spec.sampler, spec.seed, 0, x, y, Stream::kTest);
      for (int s = 0; s < spp; ++s) {
        sampler.start_sample(uint32_t(s));
        // The pixel centre: the furnace must see the object, not its silhouette.
        Vec3 L = trace_path(scene, cam.pinhole_ray({x + 0.5f, y + 0.5f}), sampler, settings);
        double l = luminance(L);
        sum += l;
        sum2 += l * l;
        ++n;
      }
    }
  Estimate e;
  e.n = n;
  e.mean = sum / double(n);
  double var = std::max(0.0, sum2 / double(n) - e.mean * e.mean);
  e.std_error = std::sqrt(var / double(n));
  return e;
}

JobSpec sphere_view() { return make_spec(24, 24, Vec3(0, 0, 4), Vec3(0, 0, 0), 20.0f); }

TEST(Integrator, WhiteFurnaceDiffuseSphereIsOne) {
  // Albedo 1 with IOR 1 is a pure Lambertian surface; a convex flat-shaded
  // sphere in a uniform environment of radiance 1 reflects exactly 1.
  SceneData d;
  add_icosphere(d, Vec3(0), 1.0f, 3, testing::diffuse(Vec3(1), /*ior=*/1.0f), /*smooth=*/false);
  auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
  for (LightStrategy s : {LightStrategy::kMis, LightStrategy::kNeeOnly, LightStrategy::kBsdfOnly}) {
    Estimate e = estimate(*scene, sphere_view(), 32, s);
    ASSERT_GT(e.n, 1000u);
    EXPECT_NEAR(e.mean, 1.0, 3.0 * e.std_error + 1e-6) << "strategy " << int(s);
  }
}

TEST(Integrator, WhiteFurnaceBackgroundIsExactlyTheEnvironment) {
  SceneData d;
  add_icosphere(d, Vec3(100, 0, 0), 0.1f, 1, testing::diffuse(Vec3(1)));
  auto scene = make_scene(std::move(d), testing::constant_env(0.75f));
  JobSpec spec = sphere_view();
  FrameBuffers fb = render_frame(*scene, spec, 0);
  for (float v : fb.reference) EXPECT_EQ(v, 0.75f);
  for (float v : fb.noisy) EXPECT_EQ(v, 0.75f);
}

// The energy-conserving material (bsdf.h): a white sphere of any roughness
// and metallic, dielectric ones with their specular coat included, reflects
// exactly what a uniform environment of radiance 1 sends it.
TEST(Integrator, WhiteFurnaceSpheresAreOneForEveryRoughnessAndMetallic) {
  for (float metallic : {0.0f, 0.5f, 1.0f}) {
    for (float roughness : {0.0f, 0.05f, 0.3f, 0.6f, 1.0f}) {
      SceneData d;
      Material m;
      m.base_color = Vec3(1);
      m.metallic = metallic;
      m.roughness = roughness;
      add_icosphere(d, Vec3(0), 1.0f, 3, m, /*smooth=*/false);
      auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
      Estimate e = estimate(*scene, sphere_view(), 128, LightStrategy::kMis);
      std::printf("  white furnace sphere, metallic %.1f roughness %.2f: %.5f +- %.5f\n", metallic,
                  roughness, e.mean, e.std_error);
      // 2e-3: the albedo table's own error (tests/render/test_bsdf.cpp).
      EXPECT_NEAR(e.mean, 1.0, 3.0 * e.std_error + 2e-3)
          << "metallic " << metallic << " roughness " << roughness;
      EXPECT_GE(e.mean, 0.99) << "metallic " << metallic << " roughness " << roughness;
    }
  }
}

// The same with next-event estimation alone and BSDF sampling alone: the
// compensated lobes are evaluated (NEE) exactly as they are sampled.
TEST(Integrator, WhiteFurnaceRoughSpheresAreOneForEveryStrategy) {
  for (float metallic : {0.0f, 0.5f, 1.0f}) {
    SceneData d;
    Material m;
    m.base_color = Vec3(1);
    m.metallic = metallic;
    m.roughness = 0.6f;
    add_icosphere(d, Vec3(0), 1.0f, 3, m, /*smooth=*/false);
    auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
    for (LightStrategy s : {LightStrategy::kNeeOnly, LightStrategy::kBsdfOnly}) {
      Estimate e = estimate(*scene, sphere_view(), 64, s);
      EXPECT_NEAR(e.mean, 1.0, 3.0 * e.std_error + 2e-3)
          << "metallic " << metallic << " strategy " << int(s);
    }
  }
}

TEST(Integrator, NeeBsdfAndMisAgree) {
  auto scene = make_scene(testing::small_room());
  JobSpec spec = make_spec(20, 20, Vec3(0, 1, 3.2f), Vec3(0, 0.9f, 0), 45.0f);
  Estimate mis = estimate(*scene, spec, 128, LightStrategy::kMis);
  Estimate nee = estimate(*scene, spec, 128, LightStrategy::kNeeOnly);
  Estimate bsdf = estimate(*scene, spec, 128, LightStrategy::kBsdfOnly);
  auto agree = [](const Estimate& a, const Estimate& b) {
    return std::fabs(a.mean - b.mean) / std::hypot(a.std_error, b.std_error);
  };
  EXPECT_LT(agree(mis, nee), 4.0) << mis.mean << " vs " << nee.mean;
  EXPECT_LT(agree(mis, bsdf), 4.0) << mis.mean << " vs " << bsdf.mean;
  EXPECT_LT(agree(nee, bsdf), 4.0) << nee.mean << " vs " << bsdf.mean;
  // MIS should be the least noisy of the three.
  EXPECT_LE(mis.std_error, 1.05 * bsdf.std_error);
}

// A surface close to and parallel with a light: the room's ceiling 2 cm
// above the back face of its light (both faces emit), seen by a camera in the
// gap. The shadow ray of a light sample starts at an origin pushed off the
// ceiling towards the light; it used to keep the direction from the unmoved
// point, crossed the light's plane before its end and was occluded by the
// light itself, so NEE alone returned almost nothing here (0.013 against
// 4.8 at a pixel of the room seen from outside) and MIS lost NEE's share.
TEST(Integrator, NeeReachesALightFromASurfaceCloseToItsPlane) {
  auto scene = make_scene(testing::small_room());
  JobSpec spec = make_spec(4, 4, Vec3(0, 1.99f, 0), Vec3(0, 2.0f, 0.005f), 20.0f);
  Estimate nee = estimate(*scene, spec, 512, LightStrategy::kNeeOnly);
  Estimate bsdf = estimate(*scene, spec, 512, LightStrategy::kBsdfOnly);
  Estimate mis = estimate(*scene, spec, 512, LightStrategy::kMis);
  ASSERT_EQ(bsdf.n, size_t(16 * 512));  // every pixel sees the ceiling
  EXPECT_GT(bsdf.mean, 1.0);           // lit by the light's back face
  EXPECT_LT(std::fabs(nee.mean - bsdf.mean), 4.0 * std::hypot(nee.std_error, bsdf.std_error))
      << nee.mean << " vs " << bsdf.mean;
  EXPECT_LT(std::fabs(mis.mean - bsdf.mean), 4.0 * std::hypot(mis.std_error, bsdf.std_error))
      << mis.mean << " vs " << bsdf.mean;
}

// Lamps with a size are area lights that both techniques reach: next-event
// estimation alone, BSDF samples alone and the two weighed by MIS must give
// the same image, with a glossy sphere (roughness 0.3) and diffuse walls lit
// by a disk lamp, a sized spot and a sun of 8 degrees through the room's
// open front, and nothing else (the ceiling light is switched off, so that
// a wrong weight shows in full).
TEST(Integrator, NeeBsdfAndMisAgreeOnLampsWithASize) {
  SceneData d = testing::small_room();
  for (Material& m : d.materials) m.emission = Vec3(0);
  PunctualLight lamp;
  lamp.type = PunctualLight::Type::kPoint;
  lamp.position = Vec3(0.3f, 1.4f, 0.4f);
  lamp.intensity = Vec3(2.0f, 1.5f, 1.0f);
  lamp.radius = 0.4f;
  d.lights.push_back(lamp);
  PunctualLight spot = lamp;
  spot.type = PunctualLight::Type::kSpot;
  spot.position = Vec3(-0.5f, 1.6f, 0.6f);
  spot.direction = normalize(Vec3(0.2f, -1, -0.3f));
  spot.cos_inner = std::cos(0.4f);
  spot.cos_outer = std::cos(0.7f);
  spot.radius = 0.1f;
  d.lights.push_back(spot);
  PunctualLight sun;
  sun.type = PunctualLight::Type::kDirectional;
  sun.direction = normalize(Vec3(-0.2f, -0.5f, -1));
  sun.intensity = Vec3(1.0f);
  sun.cos_half_angle = std::cos(4.0f * kPi / 180);
  d.lights.push_back(sun);
  auto scene = make_scene(std::move(d));
  ASSERT_TRUE(scene->has_sized_lamps());
  JobSpec spec = make_spec(16, 16, Vec3(0, 1, 3.2f), Vec3(0, 0.9f, 0), 45.0f);
  Estimate mis = estimate(*scene, spec, 256, LightStrategy::kMis);
  Estimate nee = estimate(*scene, spec, 256, LightStrategy::kNeeOnly);
  Estimate bsdf = estimate(*scene, spec, 256, LightStrategy::kBsdfOnly);
  EXPECT_LT(std::fabs(mis.mean - nee.mean), 4 * std::hypot(mis.std_error, nee.std_error))
      << mis.mean << " vs " << nee.mean;
  EXPECT_LT(std::fabs(mis.mean - bsdf.mean), 4 * std::hypot(mis.std_error, bsdf.std_error))
      << mis.mean << " vs " << bsdf.mean;
  EXPECT_LT(std::fabs(nee.mean - bsdf.mean), 4 * std::hypot(nee.std_error, bsdf.std_error))
      << nee.mean << " vs " << bsdf.mean;
}

TEST(Integrator, NeeBsdfAndMisAgreeUnderAnEnvironmentMap) {
  SceneData d;
  Material m;
  m.base_color = Vec3(0.8f);
  m.metallic = 0.5f;
  m.roughness = 0.3f;
  add_icosphere(d, Vec3(0), 1.0f, 3, m);
  add_quad(d, Vec3(0, -1, 0), Vec3(0, 0, -3), Vec3(3, 0, 0), testing::diffuse(Vec3(0.5f)));
  RgbImage img;
  img.width = 32;
  img.height = 16;
  img.rgb.assign(size_t(32) * 16 * 3, 0.2f);
  for (int c = 0; c < 3; ++c) img.rgb[(3 * 32 + 20) * 3 + c] = 500.0f;  // a small sun
  auto scene = make_scene(std::move(d), std::make_unique<Environment>(img, 1.0f, 30.0f));
  JobSpec spec = make_spec(16, 16, Vec3(0, 0.5f, 4), Vec3(0, 0, 0), 35.0f);
  Estimate mis = estimate(*scene, spec, 256, LightStrategy::kMis);
  Estimate nee = estimate(*scene, spec, 256, LightStrategy::kNeeOnly);
  Estimate bsdf = estimate(*scene, spec, 256, LightStrategy::kBsdfOnly);
  EXPECT_LT(std::fabs(mis.mean - nee.mean), 4 * std::hypot(mis.std_error, nee.std_error));
  EXPECT_LT(std::fabs(mis.mean - bsdf.mean), 4 * std::hypot(mis.std_error, bsdf.std_error));
}

// Inside a closed sphere whose surface emits E = 1 and reflects diffusely with
// albedo a (per channel), radiance is the same everywhere, and a path of at
// most D surface interactions gathers exactly sum_{k=0..D} a^k (emission seen
// directly plus k reflections): a known answer for Russian roulette, which
// must leave the expectation unchanged.
struct RouletteRun {
  Vec3 mean, std_error;
  uint64_t rays = 0;
};

RouletteRun render_inside_sphere(Vec3 albedo, const IntegratorSettings& settings, int spp) {
  SceneData d;
  Material m = testing::diffuse(albedo, /*ior=*/1.0f);  // IOR 1: a pure Lambertian surface
  m.emission = Vec3(1.0f);
  add_icosphere(d, Vec3(0), 1.0f, 2, m, /*smooth=*/false);
  auto scene = make_scene(std::move(d));
  JobSpec spec = make_spec(8, 8, Vec3(0), Vec3(0, 0, -1), 60.0f);
  Camera cam(camera_for_frame(spec, scene->data(), 0), spec.width, spec.height);
  double sum[3] = {0, 0, 0}, sum2[3] = {0, 0, 0};
  size_t n = 0;
  const uint64_t rays_before = thread_ray_count().total();
  for (int y = 0; y < spec.height; ++y)
    for (int x = 0; x < spec.width; ++x) {
      PixelSampler sampler(spec.sampler, spec.seed, 0, x, y, Stream::kTest);
      for (int s = 0; s < spp; ++s) {
        sampler.start_sample(uint32_t(s));
        Vec3 L = trace_path(*scene, cam.pinhole_ray({x + 0.5f, y + 0.5f}), sampler, settings);
        for (int c = 0; c < 3; ++c) {
          sum[c] += L[c];
          sum2[c] += double(L[c]) * L[c];
        }
        ++n;
      }
    }
  RouletteRun r;
  r.rays = thread_ray_count().total() - rays_before;
  for (int c = 0; c < 3; ++c) {
    double mean = sum[c] / double(n);
    r.mean[c] = float(mean);
    r.std_error[c] = float(std::sqrt(std::max(0.0, sum2[c] / double(n) - mean * mean) / double(n)));
  }
  return r;
}

double truncated_geometric(float a, int max_depth) {
  double s = 0, ak = 1;
  for (int k = 0; k <= max_depth; ++k, ak *= a) s += ak;
  return s;
}

IntegratorSettings roulette(int start_depth, float threshold) {
  IntegratorSettings s;
  s.max_depth = 16;
  s.rr_start_depth = start_depth;
  s.rr_threshold = threshold;
  return s;
}

TEST(Integrator, RouletteKeepsTheExpectationInsideAnEmittingSphere) {
  // Albedo per channel 0.8 / 0.5 / 0.2: the roulette decides on the largest
  // component, so the other two are weighted up by more than their own
  // throughput would suggest; each channel must still be right. Without the
  // division by the survival probability the red channel comes out at 2.44
  // instead of 4.89 with roulette from depth 1 below 1 (checked by breaking it).
  const Vec3 albedo(0.8f, 0.5f, 0.2f);
  const int spp = 256;
  const IntegratorSettings off = roulette(/*start_depth=*/17, 1.0f);  // past max_depth: none
  for (const IntegratorSettings& s : {off, roulette(1, 1.0f), roulette(1, 0.25f),
                                      roulette(3, 0.25f), roulette(2, 0.05f)}) {
    RouletteRun run = render_inside_sphere(albedo, s, spp);
    for (int c = 0; c < 3; ++c) {
      const double expected = truncated_geometric(albedo[c], s.max_depth);
      EXPECT_NEAR(run.mean[c], expected, 4.0 * run.std_error[c] + 1e-4 * expected)
          << "channel " << c << ", roulette from depth " << s.rr_start_depth << " below "
          << s.rr_threshold;
    }
  }
}

TEST(Integrator, RouletteEndsOnlyLowThroughputPaths) {
  const int spp = 16;
  // Albedo 1: the throughput never drops below the threshold, so no path may
  // end early: exactly the rays of a render without roulette.
  const uint64_t white_off = render_inside_sphere(Vec3(1.0f), roulette(17, 0.25f), spp).rays;
  const uint64_t white_on = render_inside_sphere(Vec3(1.0f), roulette(1, 0.25f), spp).rays;
  EXPECT_EQ(white_on, white_off);
  // Albedo 0.5: roulette must end paths (so the test above is not vacuous),
  // a lower threshold later than a higher one.
  const uint64_t off = render_inside_sphere(Vec3(0.5f), roulette(17, 1.0f), spp).rays;
  const uint64_t quarter = render_inside_sphere(Vec3(0.5f), roulette(1, 0.25f), spp).rays;
  const uint64_t one = render_inside_sphere(Vec3(0.5f), roulette(1, 1.0f), spp).rays;
  EXPECT_LT(quarter, off * 6 / 10);
  EXPECT_LT(one, quarter);
}

// The measurement hook of bench/path_variance: the terms it is told of are
// the whole estimate (their sum is what trace_path returns), every surface
// hit is reported once per depth, and observing changes no bit of a path.
struct RecordingObserver : PathObserver {
  Vec3 sum{0};
  int terms = 0, vertices = 0, last_depth = -1, roulettes = 0;
  bool depths_in_order = true;
  void vertex(int depth, const SurfaceHit&) override {
    depths_in_order = depths_in_order && depth == last_depth + 1;
    last_depth = depth;
    ++vertices;
  }
  void contribution(Kind, int, Vec3 value) override {
    sum += value;
    ++terms;
  }
  void roulette(int, float survive, bool) override {
    roulettes += survive < 1 ? 1 : 0;
  }
};

TEST(Integrator, ObserverSeesEveryTermOfTheEstimateAndChangesNothing) {
  auto scene = make_scene(testing::small_room());
  JobSpec spec = make_spec(8, 8, Vec3(0, 1, 3.2f), Vec3(0, 0.9f, 0), 45.0f);
  Camera cam(camera_for_frame(spec, scene->data(), 0), spec.width, spec.height);
  IntegratorSettings plain;
  plain.rr_start_depth = 1;
  int terms = 0, roulettes = 0;
  for (int y = 0; y < spec.height; ++y)
    for (int x = 0; x < spec.width; ++x)
      for (int s = 0; s < 16; ++s) {
        RecordingObserver obs;
        IntegratorSettings observed = plain;
        observed.observer = &obs;
        const Ray ray = cam.pinhole_ray({x + 0.5f, y + 0.5f});
        PixelSampler a(spec.sampler, spec.seed, 0, x, y, Stream::kTest);
        PixelSampler b(spec.sampler, spec.seed, 0, x, y, Stream::kTest);
        a.start_sample(uint32_t(s));
        b.start_sample(uint32_t(s));
        const Vec3 without = trace_path(*scene, ray, a, plain);
        const Vec3 with = trace_path(*scene, ray, b, observed);
        for (int c = 0; c < 3; ++c) {
          ASSERT_EQ(without[c], with[c]) << "pixel " << x << "," << y << " sample " << s;
          EXPECT_NEAR(obs.sum[c], with[c], 1e-5f * std::max(1.0f, with[c]));
        }
        EXPECT_TRUE(obs.depths_in_order);
        terms += obs.terms;
        roulettes += obs.roulettes;
      }
  EXPECT_GT(terms, 8 * 8 * 16);  // NEE at every vertex: more terms than paths
  EXPECT_GT(roulettes, 0);
}

// KHR_materials_transmission (bsdf.h): a white sphere of smooth glass in a
// uniform environment is invisible, as everything that enters leaves again
// (Fresnel reflection, refraction, total internal reflection and the
// 1 / eta^2 radiance scaling, which cancels on the way out, must all be
// right, and the ray must know whether it enters or leaves). NEE cannot
// reach through a delta interface, so this is BSDF sampling alone.
TEST(Integrator, WhiteFurnaceSmoothGlassSphereIsOne) {
  SceneData d;
  add_icosphere(d, Vec3(0), 1.0f, 3, testing::glass(0.0f), /*smooth=*/false);
  auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
  JobSpec spec = sphere_view();
  spec.max_depth = 64;
  Estimate e = estimate(*scene, spec, 64, LightStrategy::kMis);
  ASSERT_GT(e.n, 10000u);
  std::printf("  white furnace, smooth glass sphere: %.5f +- %.5f\n", e.mean, e.std_error);
  EXPECT_NEAR(e.mean, 1.0, 3.0 * e.std_error + 1e-4);
}

// Rough glass with NEE and BSDF sampling combined, its multiple-scattering
// compensation included (glass_albedo.h): it returns what it receives
// within the compensation table's error (tests/render/test_bsdf_glass.cpp).
TEST(Integrator, WhiteFurnaceRoughGlassSphereIsOne) {
  for (float roughness : {0.1f, 0.3f, 0.7f}) {
    SceneData d;
    add_icosphere(d, Vec3(0), 1.0f, 3, testing::glass(roughness), /*smooth=*/false);
    auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
    JobSpec spec = sphere_view();
    spec.max_depth = 64;
    Estimate e = estimate(*scene, spec, 64, LightStrategy::kMis);
    std::printf("  white furnace, glass sphere roughness %.1f: %.5f +- %.5f\n", roughness, e.mean,
                e.std_error);
    EXPECT_NEAR(e.mean, 1.0, 3.0 * e.std_error + 0.02) << "roughness " << roughness;
  }
}

// KHR_materials_clearcoat: a coat (mirror and rough) over white plastic and
// white metal keeps the furnace sphere at 1, with NEE and BSDF sampling.
// A white material of this metallic, roughness 0.5, made into the furnace
// sphere and estimated with NEE and BSDF sampling.
Material white_layered(float metallic) {
  Material m;
  m.base_color = Vec3(1);
  m.metallic = metallic;
  m.roughness = 0.5f;
  return m;
}
Estimate furnace_sphere(const Material& m) {
  SceneData d;
  add_icosphere(d, Vec3(0), 1.0f, 3, m, /*smooth=*/false);
  auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
  return estimate(*scene, sphere_view(), 64, LightStrategy::kMis);
}

TEST(Integrator, WhiteFurnaceClearcoatedSpheresAreOne) {
  for (float coat_roughness : {0.0f, 0.3f}) {
    for (float metallic : {0.0f, 1.0f}) {
      Material m = white_layered(metallic);
      m.clearcoat = 1.0f;
      m.clearcoat_roughness = coat_roughness;
      const Estimate e = furnace_sphere(m);
      EXPECT_NEAR(e.mean, 1.0, 3.0 * e.std_error + 3e-3)
          << "coat roughness " << coat_roughness << " metallic " << metallic;
    }
  }
}

// KHR_materials_sheen: a white sheen (fine and rough, the fine one under a
// coat too) over white plastic and white metal keeps the furnace sphere at
// 1 through the whole integrator, with NEE and BSDF sampling.
TEST(Integrator, WhiteFurnaceSheenSpheresAreOne) {
  for (float sheen_roughness : {0.1f, 1.0f}) {
    for (float metallic : {0.0f, 1.0f}) {
      Material m = white_layered(metallic);
      m.sheen_color = Vec3(1);
      m.sheen_roughness = sheen_roughness;
      if (sheen_roughness < 0.5f) m.clearcoat = 1.0f;
      const Estimate e = furnace_sphere(m);
      EXPECT_NEAR(e.mean, 1.0, 3.0 * e.std_error + 3e-3)
          << "sheen roughness " << sheen_roughness << " metallic " << metallic;
    }
  }
}

// IOR 1 is no interface: light crosses the sphere unbent, tinted by the
// base colour once on the way in and once on the way out; no noise at all.
TEST(Integrator, IorOneGlassSphereTintsTwiceAndBendsNothing) {
  SceneData d;
  add_icosphere(d, Vec3(0), 1.0f, 3, testing::glass(0.5f, Vec3(0.5f), /*ior=*/1.0f),
                /*smooth=*/false);
  auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
  Estimate e = estimate(*scene, sphere_view(), 4, LightStrategy::kMis);
  ASSERT_GT(e.n, 1000u);
  EXPECT_NEAR(e.mean, 0.25, 1e-6);
  EXPECT_LT(e.std_error, 1e-6);
}

// The sample clamp (JobSpec::reference_clamp, opt-in and biased): what the
// camera sees emitted directly is never clamped; the rest of a sample is
// scaled, hue kept, to at most the bound in its largest channel; off, it
// changes nothing.
TEST(Integrator, SampleClampBoundsAllButDirectlySeenEmission) {
  SceneData d;
  // A bright lamp (radiance 50, 25, 10) facing a white floor.
  add_quad(d, Vec3(0, 0, 0), Vec3(2, 0, 0), Vec3(0, 0, -2), testing::diffuse(Vec3(0.8f)));  // up
  add_quad(d, Vec3(0, 1, 0), Vec3(0.2f, 0, 0), Vec3(0, 0, 0.2f),
           testing::emitter(Vec3(50, 25, 10)));  // faces down
  auto scene = make_scene(std::move(d));
  IntegratorSettings plain, clamped;
  clamped.sample_clamp = 0.5f;
  int floor_samples = 0, above = 0;
  for (int i = 0; i < 256; ++i) {
    // Down at the floor from beside the lamp, and up into the lamp.
    const Ray at_floor{Vec3(0.5f, 0.5f, 0.0f),
                       normalize(Vec3(0.01f * (i % 16), -1, 0.01f * (i / 16)))};
    PixelSampler a(SamplerKind::kSobol, 5, 0, i, 0, Stream::kTest), b = a;
    a.start_sample(0);
    b.start_sample(0);
    const Vec3 lp = trace_path(*scene, at_floor, a, plain);
    const Vec3 lc = trace_path(*scene, at_floor, b, clamped);
    if (max_component(lp) > 0.5f) {
      ++above;
      EXPECT_NEAR(max_component(lc), 0.5f, 1e-5f);
      EXPECT_NEAR(lc.y / lc.x, lp.y / lp.x, 1e-4f);  // hue kept
    } else {
      EXPECT_EQ(lc.x, lp.x);
      EXPECT_EQ(lc.z, lp.z);
    }
    ++floor_samples;
  }
  EXPECT_GT(above, 10);
  EXPECT_EQ(floor_samples, 256);
  // The lamp seen directly keeps its radiance.
  PixelSampler s(SamplerKind::kSobol, 5, 0, 0, 0, Stream::kTest);
  s.start_sample(0);
  const Vec3 lamp = trace_path(*scene, {Vec3(0.1f, 0.5f, -0.1f), Vec3(0, 1, 0)}, s, clamped);
  EXPECT_GE(lamp.x, 50.0f);
  EXPECT_GE(lamp.y, 25.0f);
}

TEST(Integrator, SceneWithoutLightIsRefused) {
  SceneData d;
  d.source = "dark.gltf";
  add_icosphere(d, Vec3(0), 1.0f, 1, testing::diffuse(Vec3(0.5f)));
  try {
    Scene s(std::move(d), nullptr);
    FAIL() << "a scene without light was accepted";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find("dark.gltf"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("no light"), std::string::npos);
    // A glTF without lamps: the hint for files exported from Blender.
    EXPECT_NE(std::string(e.what()).find("Punctual Lights"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("Area lamps"), std::string::npos) << e.what();
  }
}

TEST(Integrator, EmptySceneIsRefused) {
  SceneData d;
  d.source = "empty.gltf";
  EXPECT_THROW(Scene(std::move(d), testing::constant_env(1)), SpecError);
}

// A material's BSDF constants, computed once by Scene (BsdfConstants), give
// every hit on it the BSDF its own factors give, bit for bit: values,
// pdfs and samples. Over every kind of material the constants cover
// (metal, mirror, layered dielectric, glass, half glass, a coat, a sheen,
// a specular colour, IOR 1, a black base), and a material with a textured
// scalar factor has none (each hit computes its own).
TEST(Integrator, MaterialBsdfConstantsAreEachHitsOwnBsdf) {
  SceneData d = testing::small_room();
  std::vector<Material> kinds(12, testing::diffuse(Vec3(0.7f, 0.6f, 0.5f)));
  kinds[1].metallic = 1.0f;
  kinds[1].roughness = 0.3f;
  kinds[2].metallic = 1.0f;
  kinds[2].roughness = 0.0f;
  kinds[3].roughness = 0.0f;
  kinds[4].transmission = 1.0f;
  kinds[4].roughness = 0.2f;
  kinds[5].transmission = 0.5f;
  kinds[5].roughness = 0.0f;
  kinds[6].clearcoat = 1.0f;
  kinds[6].clearcoat_roughness = 0.3f;
  kinds[7].sheen_color = Vec3(0.8f, 0.5f, 0.3f);
  kinds[7].sheen_roughness = 0.4f;
  kinds[8].specular = 0.7f;
  kinds[8].specular_color = Vec3(1.0f, 0.5f, 0.2f);
  kinds[9].ior = 1.0f;
  kinds[10].base_color = Vec3(0.0f);
  kinds[10].metallic = 0.5f;
  const size_t textured = 11;  // roughness and metallic from a texture
  Texture grey;
  grey.width = grey.height = 1;
  grey.rgb = {0.0f, 0.5f, 0.25f};
  d.textures.push_back(grey);
  kinds[textured].metal_rough_tex.index = 0;
  const size_t first = d.materials.size();
  for (const Material& m : kinds) d.materials.push_back(m);
  for (size_t t = 0; t < d.tri_material.size(); ++t)
    d.tri_material[t] = uint32_t(first + t % kinds.size());
  const auto scene = make_scene(std::move(d), testing::constant_env(0.3f));

  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<int> seen(kinds.size(), 0);
  for (int i = 0; i < 20000; ++i) {
    const Vec3 o = scene->center() + Vec3(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f) * 0.8f;
    const Vec3 dir = normalize(Vec3(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f), Vec3(0, 1, 0));
    SurfaceHit hit;
    if (!scene->intersect({o, dir}, &hit)) continue;
    const size_t kind = scene->data().tri_material[hit.prim] - first;
    ++seen[kind];
    const BsdfConstants* k = scene->bsdf_constants(hit.prim);
    if (kind == textured) {
      ASSERT_EQ(k, nullptr) << "a textured roughness has constants";
      continue;
    }
    ASSERT_NE(k, nullptr) << "material kind " << kind;
    const Bsdf from_constants(*k, hit.ns, hit.ng, hit.base_color, hit.front, hit.coat_ns);
    const Bsdf own(hit.ns, hit.ng, hit.base_color, hit.metallic, hit.roughness, hit.ior,
                   {hit.specular, hit.specular_color}, {hit.transmission, hit.front},
                   {hit.clearcoat, hit.clearcoat_roughness, hit.coat_ns},
                   {hit.sheen_color, hit.sheen_roughness});
    const Vec3 wo = -dir;
    const Bsdf::Outgoing oa = from_constants.outgoing(wo), ob = own.outgoing(wo);
    for (int j = 0; j < 4; ++j) {
      const Vec3 wi = normalize(Vec3(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f), hit.ns);
      float pa = -1, pb = -2;
      const Vec3 fa = from_constants.evaluate(oa, wi, &pa), fb = own.evaluate(ob, wi, &pb);
      ASSERT_TRUE(test::same_bits(fa, fb) && test::same_bits(pa, pb)) << "material kind " << kind;
      const float ul = u(rng);
      const Vec2 us(u(rng), u(rng));
      const BsdfSample sa = from_constants.sample(oa, ul, us), sb = own.sample(ob, ul, us);
      ASSERT_EQ(sa.valid, sb.valid) << "material kind " << kind;
      ASSERT_EQ(sa.is_delta, sb.is_delta) << "material kind " << kind;
      if (sa.valid) {
        ASSERT_TRUE(test::same_bits(sa.wi, sb.wi) && test::same_bits(sa.weight, sb.weight) &&
                    test::same_bits(sa.pdf, sb.pdf))
            << "material kind " << kind;
      }
    }
  }
  for (size_t kind = 0; kind < kinds.size(); ++kind)
    EXPECT_GT(seen[kind], 20) << "material kind " << kind << " was hardly hit";
}

}  // namespace
}  // namespace dofarm::render
