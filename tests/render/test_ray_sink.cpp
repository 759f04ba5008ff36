// Scene's RaySink (what bench/render_throughput replays): it sees every ray
// the renderer counts, as the renderer asked for it, and changes nothing.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "tests/render/render_fixtures.h"

namespace dofarm::render {
namespace {

TEST(RaySink, SeesEveryCountedRayAndChangesNoPixel) {
  auto scene = testing::make_scene(testing::small_room(), testing::constant_env(0.3f));
  JobSpec spec = testing::make_spec(16, 12, Vec3(0.2f, 1, 3), Vec3(0, 0.9f, 0), 45, 3.0f, 0.05f);
  spec.versions = 2;
  RenderOptions options;
  options.threads = 2;
  options.block_size = 4;
  const FrameBuffers plain = render_frame(*scene, spec, 0, std::nullopt, options);

  testing::RayRecorder recorder;
  RenderStats stats;
  options.stats = &stats;
  scene->set_ray_sink(&recorder);
  const FrameBuffers recorded = render_frame(*scene, spec, 0, std::nullopt, options);
  scene->set_ray_sink(nullptr);
  EXPECT_TRUE(testing::same_bytes(plain, recorded));

  ASSERT_EQ(recorder.rays.size(), stats.rays);
  size_t shadow = 0, hits = 0;
  for (const TracedRay& r : recorder.rays) {
    ASSERT_TRUE(is_finite(r.o) && is_finite(r.d));
    ASSERT_NEAR(length(r.d), 1.0f, 1e-4f);
    if (r.shadow) {
      ++shadow;
      // Towards the emitter (finite) or the environment (infinite).
      ASSERT_GT(r.t_max, 0.0f);
      if (!scene->occluded(r.o, r.d, r.t_max)) ++hits;
    } else {
      ASSERT_TRUE(std::isinf(r.t_max));
      SurfaceHit hit;
      if (scene->intersect(Ray{r.o, r.d}, &hit)) ++hits;
    }
  }
  EXPECT_GT(shadow, 0u);
  EXPECT_LT(shadow, recorder.rays.size());
  EXPECT_EQ(stats.shadow_rays, shadow);
  EXPECT_GE(stats.light_samples, stats.shadow_rays);
  EXPECT_GT(hits, 0u);

  // Off again: nothing more arrives.
  const size_t before = recorder.rays.size();
  render_frame(*scene, spec, 0, std::nullopt, options);
  EXPECT_EQ(recorder.rays.size(), before);
}

// RenderStats' light samples, against a known answer: a camera that sees
// only a diffuse floor under a uniform sky, one vertex per path
// (max_depth 1). Every camera path then takes exactly one light sample (the
// sky's samples never fail), and the BSDF keeps those above the floor, half
// of the sky by its symmetry: half of the samples get a shadow ray. Once
// with a constant sky (the paths traced one by one) and once with a uniform
// map (sampled by its tables, the paths of a packet traced together).
TEST(RenderStats, CountsEveryLightSampleAndTheShadowRaysThatFollow) {
  for (const bool map : {false, true}) {
    SCOPED_TRACE(map ? "map" : "constant");
    SceneData d;
    add_quad(d, Vec3(0), Vec3(0, 0, 100), Vec3(100, 0, 0), testing::diffuse(Vec3(0.5f)));  // +y
    RgbImage sky;
    // Blocks of 4 x 4 texels small enough (22 degrees) for the light
    // samples they leave below the floor to be skipped, and counted, before
    // they are made (Environment::Choice::below).
    sky.width = 64;
    sky.height = 32;
    sky.rgb.assign(size_t(sky.width) * sky.height * 3, 1.0f);
    auto scene = testing::make_scene(std::move(d),
                                     map ? std::make_unique<Environment>(std::move(sky), 1.0f, 0.0f)
                                         : testing::constant_env(1.0f));
    JobSpec spec = testing::make_spec(16, 12, Vec3(0, 1, 0.5f), Vec3(0, 0, -0.5f), 40);
    spec.max_depth = 1;
    RenderOptions options;
    options.threads = 2;
    options.block_size = 4;
    RenderStats stats;
    options.stats = &stats;
    render_frame(*scene, spec, 0, std::nullopt, options);
    ASSERT_EQ(stats.paths, uint64_t(16 * 12 * (spec.versions + spec.reference_spp)));
    EXPECT_EQ(stats.light_samples, stats.paths);
    const double followed = double(stats.shadow_rays) / double(stats.light_samples);
    EXPECT_GT(followed, 0.45);
    EXPECT_LT(followed, 0.55);
    // The map's samples below the floor are mostly known to be so before
    // they are made: all but those of the block row just below the horizon,
    // whose blocks (22.5 degrees across, centres 11.25 degrees below it)
    // may reach above it; by solid angle about 31% of all samples. The
    // constant sky has no blocks and skips nothing. Skipped samples trace
    // nothing.
    const double skipped = double(stats.light_samples_skipped) / double(stats.light_samples);
    EXPECT_LE(stats.light_samples_skipped, stats.light_samples - stats.shadow_rays);
    if (map) {
      EXPECT_GT(skipped, 0.27);
      EXPECT_LT(skipped, 0.35);
    } else {
      EXPECT_EQ(stats.light_samples_skipped, 0u);
    }
  }
}

}  // namespace
}  // namespace dofarm::render
