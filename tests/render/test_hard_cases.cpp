// Hard cases never put NaN or Inf (or negative radiance) into any buffer.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "common/error.h"
#include "common/exr_io.h"
#include "tests/render/render_fixtures.h"

namespace dofarm::render {
namespace {

using testing::make_scene;
using testing::make_spec;

void expect_clean(const FrameBuffers& fb, const char* what) {
  EXPECT_EQ(fb.count_non_finite(), 0u) << what;
  for (float v : fb.noisy) ASSERT_GE(v, 0.0f) << what;
  for (float v : fb.reference) ASSERT_GE(v, 0.0f) << what;
  for (float v : fb.reference_var) ASSERT_GE(v, 0.0f) << what;
}

FrameBuffers render_small(const Scene& scene, const JobSpec& spec) {
  RenderOptions opt;
  opt.threads = 2;
  return render_frame(scene, spec, 0, std::nullopt, opt);
}

TEST(HardCases, RoughnessZeroAndOne) {
  for (float roughness : {0.0f, 1e-4f, 0.03f, 1.0f}) {
    for (float metallic : {0.0f, 1.0f}) {
      SceneData d = testing::small_room();
      Material m;
      m.base_color = Vec3(0.9f);
      m.metallic = metallic;
      m.roughness = roughness;
      add_icosphere(d, Vec3(0.3f, 1.3f, 0.2f), 0.3f, 3, m);
      auto scene = make_scene(std::move(d));
      JobSpec spec = make_spec(16, 16, Vec3(0, 1, 3), Vec3(0, 1, 0), 50, 2.5f, 0.05f);
      FrameBuffers fb = render_small(*scene, spec);
      expect_clean(fb, "roughness sweep");
      float total = 0;
      for (float v : fb.reference) total += v;
      EXPECT_GT(total, 0.0f);
    }
  }
}

// Glass (KHR_materials_transmission, KHR_materials_volume) at the edges of
// what a scene may hold: IORs 1, barely above 1 and 1e4, smooth and rough,
// a smooth-shaded sphere (shading normals that disagree with the facets
// at the silhouette), absorption from none to total, the reference clamp
// at its smallest; and a light inside a glass box.
TEST(HardCases, GlassAtTheEdgesKeepsEveryBufferFinite) {
  for (float ior : {1.0f, 1.0001f, 1.5f, 1e4f}) {
    for (float roughness : {0.0f, 0.02f, 0.5f, 1.0f}) {
      for (float sigma : {0.0f, 3.0f, 1e30f}) {
        SceneData d = testing::small_room();
        Material m = testing::glass(roughness, Vec3(0.9f, 0.7f, 0.2f), ior);
        m.attenuation = Vec3(sigma, 0.0f, sigma * 0.5f);
        add_icosphere(d, Vec3(0.3f, 1.3f, 0.2f), 0.3f, 3, m, /*smooth=*/true);
        add_box(d, Vec3(-0.6f, 0.2f, -0.2f), Vec3(-0.2f, 0.6f, 0.2f), m);
        auto scene = make_scene(std::move(d));
        JobSpec spec = make_spec(12, 12, Vec3(0, 1, 3), Vec3(0, 1, 0), 50, 2.5f, 0.05f);
        spec.reference_clamp = sigma > 1 ? 1e-30f : 0.0f;
        expect_clean(render_small(*scene, spec), "glass");
      }
    }
  }
  // A lamp sealed in rough glass: reachable only by BSDF sampling through it.
  SceneData d;
  add_box(d, Vec3(-1, -1, -1), Vec3(1, 1, 1), testing::glass(0.4f));
  add_quad(d, Vec3(0, 0, 0), Vec3(0.2f, 0, 0), Vec3(0, 0, 0.2f), testing::emitter(Vec3(20)));
  add_quad(d, Vec3(0, -2, 0), Vec3(4, 0, 0), Vec3(0, 0, -4), testing::diffuse(Vec3(0.5f)));
  auto scene = make_scene(std::move(d));
  FrameBuffers fb = render_small(*scene, make_spec(12, 12, Vec3(0, 1, 5), Vec3(0, 0, 0)));
  expect_clean(fb, "lamp in glass");
  float total = 0;
  for (float v : fb.reference) total += v;
  EXPECT_GT(total, 0.0f);
}

TEST(HardCases, GrazingViewsAndBackFacingShadingNormals) {
  SceneData d;
  // A floor seen almost edge-on, with shading normals tilted far from the
  // geometric normal (some face away from the camera).
  std::vector<Vec3> p = {{-50, 0, -50}, {50, 0, -50}, {50, 0, 50}, {-50, 0, 50}};
  std::vector<Vec3> n = {normalize(Vec3(0.9f, 0.1f, 0)), normalize(Vec3(-0.9f, 0.1f, 0.2f)),
                         normalize(Vec3(0, 0.05f, 1)), normalize(Vec3(0, -0.2f, -1))};
  Material m;
  m.base_color = Vec3(0.8f);
  m.metallic = 0.5f;
  m.roughness = 0.2f;
  d.add_mesh(p, n, {}, {0, 2, 1, 0, 3, 2}, m);
  auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
  JobSpec spec = make_spec(24, 24, Vec3(0, 1e-3f, 10), Vec3(0, 0, -10), 30, 5.0f, 0.001f);
  expect_clean(render_small(*scene, spec), "grazing");
}

TEST(HardCases, DegenerateAndZeroAreaTriangles) {
  SceneData d = testing::small_room();
  Material m = testing::diffuse(Vec3(0.5f));
  Material e = testing::emitter(Vec3(100));
  add_triangle(d, Vec3(0, 1, 0), Vec3(0, 1, 0), Vec3(0, 1, 0), m);     // a point
  add_triangle(d, Vec3(0, 1, 0), Vec3(0.5f, 1, 0), Vec3(1, 1, 0), m);  // collinear
  add_triangle(d, Vec3(0, 1.2f, 0), Vec3(0, 1.2f, 0), Vec3(0.2f, 1.2f, 0),
               e);  // emissive, zero area
  add_triangle(d, Vec3(-0.2f, 0.5f, 0.5f), Vec3(0.2f, 0.5f, 0.5f), Vec3(0, 0.5f + 1e-9f, 0.5f), e);
  auto scene = make_scene(std::move(d));
  JobSpec spec = make_spec(16, 16, Vec3(0, 1, 3), Vec3(0, 1, 0), 50);
  expect_clean(render_small(*scene, spec), "degenerate");
}

TEST(HardCases, LightInsideAClosedBox) {
  SceneData d;
  add_box(d, Vec3(-1), Vec3(1), testing::diffuse(Vec3(0.95f)), Facing::kInward);
  add_icosphere(d, Vec3(0), 0.2f, 2, testing::emitter(Vec3(5)));
  // An occluder with the light sealed inside it: no light escapes.
  add_box(d, Vec3(0.5f, -0.9f, -0.1f), Vec3(0.7f, -0.7f, 0.1f), testing::diffuse(Vec3(0.5f)));
  add_icosphere(d, Vec3(0.6f, -0.8f, 0), 0.05f, 1, testing::emitter(Vec3(50)));
  auto scene = make_scene(std::move(d));
  JobSpec spec = make_spec(16, 16, Vec3(0, 0, 0.9f), Vec3(0, 0, 0), 90);
  spec.max_depth = 64;
  FrameBuffers fb = render_small(*scene, spec);
  expect_clean(fb, "light in a box");
}

TEST(HardCases, TinyAndHugeSceneScales) {
  for (float scale : {1e-4f, 1e5f}) {
    auto scene = make_scene(testing::small_room(scale));
    JobSpec spec = make_spec(16, 16, Vec3(0, 1, 3) * scale, Vec3(0, 1, 0) * scale, 50, 2.8f * scale,
                             0.05f * scale);
    FrameBuffers fb = render_small(*scene, spec);
    expect_clean(fb, "scale");
    // The same picture at any scale: light must not leak through walls nor be
    // lost to self-intersection. Compare the mean with the unit-scale room.
    auto unit = make_scene(testing::small_room(1.0f));
    JobSpec uspec = make_spec(16, 16, Vec3(0, 1, 3), Vec3(0, 1, 0), 50, 2.8f, 0.05f);
    FrameBuffers ufb = render_small(*unit, uspec);
    double a = 0, b = 0;
    for (size_t i = 0; i < fb.reference.size(); ++i) {
      a += fb.reference[i];
      b += ufb.reference[i];
    }
    EXPECT_NEAR(a / b, 1.0, 0.1) << "scale " << scale;
    for (size_t i = 0; i < fb.plane(); ++i)
      if (fb.depth[i] > 0) {
        EXPECT_NEAR(fb.depth[i] / ufb.depth[i], scale, 1e-3 * scale);
      }
  }
}

TEST(HardCases, EnvironmentWithOneVeryHotPixel) {
  RgbImage img;
  img.width = 64;
  img.height = 32;
  img.rgb.assign(size_t(64) * 32 * 3, 0.05f);
  for (int c = 0; c < 3; ++c) img.rgb[(size_t(5) * 64 + 40) * 3 + c] = 3e7f;
  SceneData d;
  Material m;
  m.base_color = Vec3(0.9f);
  m.metallic = 1;
  m.roughness = 0.05f;
  add_icosphere(d, Vec3(0), 1, 3, m);
  add_quad(d, Vec3(0, -1, 0), Vec3(0, 0, -5), Vec3(5, 0, 0), testing::diffuse(Vec3(0.7f)));
  auto scene = make_scene(std::move(d), std::make_unique<Environment>(img, 1.0f, 0.0f));
  JobSpec spec = make_spec(16, 16, Vec3(0, 0.5f, 4), Vec3(0, 0, 0), 40, 4.0f, 0.1f);
  expect_clean(render_small(*scene, spec), "hot pixel");
}

TEST(HardCases, NonFiniteEnvironmentTexelsAreDropped) {
  RgbImage img;
  img.width = 4;
  img.height = 2;
  img.rgb.assign(4 * 2 * 3, 1.0f);
  img.rgb[0] = std::nanf("");
  img.rgb[4] = INFINITY;
  img.rgb[8] = -3.0f;
  Environment env(img, 1.0f, 0.0f);
  for (int i = 0; i < 64; ++i) {
    EnvSample s = env.sample({(i % 8 + 0.5f) / 8, (i / 8 + 0.5f) / 8});
    EXPECT_TRUE(is_finite(s.radiance));
    EXPECT_TRUE(std::isfinite(s.pdf));
  }
}

// The brightest emission and environment a spec or scene may hold, seen
// through an open lens from a path that can hit the light directly: the
// reference's second moment (about kMaxRadiance^2 = 1e24 per sample) must
// come out finite, as must everything else.
TEST(HardCases, RadianceAtTheLimitKeepsEveryBufferFinite) {
  SceneData d = testing::small_room();
  add_quad(d, Vec3(0, 1, -0.5f), Vec3(0.2f, 0, 0), Vec3(0, 0.2f, 0),
           testing::emitter(Vec3(kMaxRadiance)));
  auto scene = make_scene(std::move(d), testing::constant_env(kMaxRadiance));
  JobSpec spec = make_spec(12, 12, Vec3(0, 1, 3), Vec3(0, 1, -0.5f), 50, 3.5f, 0.05f);
  spec.reference_error = 0.01f;  // the adaptive path: up to reference_max_spp samples
  spec.reference_max_spp = 256;
  FrameBuffers fb = render_small(*scene, spec);
  expect_clean(fb, "radiance at the limit");
  float brightest = 0;
  for (float v : fb.reference) brightest = std::max(brightest, v);
  EXPECT_GT(brightest, 1e10f);  // the light is in the picture
}

// focal_distance = 1e-38 is a valid positive number: the lens rays and the
// circle of confusion must stay finite (they used to overflow to Inf/NaN).
TEST(HardCases, TinyFocalDistanceKeepsEveryBufferFinite) {
  auto scene = make_scene(testing::small_room(), testing::constant_env(1.0f));
  for (float focal : {1e-38f, 1e-30f, 1e-7f, 3e38f}) {
    JobSpec spec = make_spec(12, 10, Vec3(0, 1, 3), Vec3(0, 1, 0), 50, focal, 0.05f);
    FrameBuffers fb = render_small(*scene, spec);
    expect_clean(fb, "tiny focal distance");
    EXPECT_EQ(fb.camera.focal_distance, focal);
    for (float c : fb.coc) EXPECT_GT(c, 0.0f);
  }
}

TEST(HardCases, EnvironmentMapTexelAboveTheLimitIsALoadErrorNamingTheFile) {
  const auto dir = std::filesystem::temp_directory_path() / "dofarm_hard_cases_env";
  std::filesystem::create_directories(dir);
  RgbImage img;
  img.width = 8;
  img.height = 4;
  img.rgb.assign(size_t(8) * 4 * 3, 0.5f);
  img.rgb[(size_t(2) * 8 + 5) * 3 + 1] = 1e30f;
  EnvironmentSpec env;
  env.map = dir / "hot.exr";
  write_rgb_exr(env.map, img);
  try {
    Environment::from_spec(env);
    FAIL() << "a texel of 1e30 was accepted";
  } catch (const RuntimeError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(env.map.string()), std::string::npos) << what;
    EXPECT_NE(what.find("texel (5, 2)"), std::string::npos) << what;
  }
  // Within the limit, but not times the intensity.
  img.rgb[(size_t(2) * 8 + 5) * 3 + 1] = 1e6f;
  std::filesystem::remove(env.map);
  write_rgb_exr(env.map, img);
  EXPECT_NO_THROW(Environment::from_spec(env));
  env.intensity = 1e7f;
  EXPECT_THROW(Environment::from_spec(env), RuntimeError);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace dofarm::render
