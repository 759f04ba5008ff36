// Thin lens, circle of confusion and the auxiliary buffers against their
// analytic values.
#include <gtest/gtest.h>

#include <cmath>

#include "tests/render/render_fixtures.h"
#include "worker/render/camera.h"

namespace dofarm::render {
namespace {

using testing::make_scene;
using testing::make_spec;

// A wall facing the camera at view depth `dist` (camera at z = dist, looking
// down -z at the plane z = 0), lit by a constant environment.
std::unique_ptr<Scene> wall_scene() {
  SceneData d;
  Material m = testing::diffuse(Vec3(0.5f));
  m.roughness = 0.625f;
  add_quad(d, Vec3(0, 0, 0), Vec3(50, 0, 0), Vec3(0, 50, 0), m);
  return make_scene(std::move(d), testing::constant_env(1.0f));
}

// The thin-lens CoC diameter in pixels, derived independently: the cone
// from the lens disk (diameter 2A) through the point at depth z meets the
// focal plane S in a disk of diameter 2A|z - S|/z; the focal plane spans
// 2 S tan(fov/2) scene units over H pixels.
double analytic_coc(double A, double S, double z, double fov_deg, int H) {
  double world = 2.0 * A * std::fabs(z - S) / z;
  double pixels_per_unit = H / (2.0 * S * std::tan(fov_deg * M_PI / 360.0));
  return world * pixels_per_unit;
}

TEST(ThinLens, ApertureZeroIsThePinholeBitForBit) {
  auto scene = make_scene(testing::small_room());
  // Focal distance is meaningless for a pinhole: any value, same bytes.
  JobSpec a = make_spec(24, 16, Vec3(0, 1, 3), Vec3(0, 1, 0), 45, /*focal=*/2.0f, 0.0f);
  JobSpec b = make_spec(24, 16, Vec3(0, 1, 3), Vec3(0, 1, 0), 45, /*focal=*/7.5f, 0.0f);
  FrameBuffers fa = render_frame(*scene, a, 0), fb = render_frame(*scene, b, 0);
  EXPECT_TRUE(testing::same_bytes(fa, fb));
  for (float c : fa.coc) EXPECT_EQ(c, 0.0f);

  // And each lens ray at aperture 0 is the pinhole ray, whatever the lens sample.
  Camera cam(camera_for_frame(a, scene->data(), 0), 24, 16);
  for (float u : {0.0f, 0.3f, 0.99f}) {
    Ray r = cam.generate_ray({5.25f, 7.5f}, {u, 1 - u});
    Ray p = cam.pinhole_ray({5.25f, 7.5f});
    EXPECT_EQ(std::memcmp(&r, &p, sizeof(Ray)), 0);
  }
}

TEST(ThinLens, LensRaysConvergeOnTheFocalPlane) {
  JobSpec s = make_spec(32, 32, Vec3(0, 0, 5), Vec3(0, 0, 0), 40, /*focal=*/5.0f, 0.3f);
  SceneData empty;
  Camera cam(camera_for_frame(s, empty, 0), 32, 32);
  Ray pin = cam.pinhole_ray({10.5f, 20.5f});
  Vec3 target = pin.o + pin.d * (5.0f / -pin.d.z);  // pinhole ray at view depth 5
  for (float u : {0.1f, 0.5f, 0.9f}) {
    Ray r = cam.generate_ray({10.5f, 20.5f}, {u, 0.7f});
    EXPECT_GT(length(r.o - pin.o), 0.0f);
    Vec3 at = r.o + r.d * ((r.o.z - 0.0f) / -r.d.z);  // where it crosses z = 0
    EXPECT_NEAR(at.x, target.x, 1e-4);
    EXPECT_NEAR(at.y, target.y, 1e-4);
  }
}

TEST(ThinLens, CocIsZeroOnTheFocalPlaneAndAnalyticElsewhere) {
  auto scene = wall_scene();
  for (float dist : {2.0f, 5.0f, 12.0f}) {
    const float S = 5.0f, A = 0.1f, fov = 30.0f;
    const int W = 20, H = 16;
    JobSpec spec = make_spec(W, H, Vec3(0, 0, dist), Vec3(0, 0, 0), fov, S, A);
    FrameBuffers fb = render_frame(*scene, spec, 0);
    for (size_t i = 0; i < fb.plane(); ++i) {
      EXPECT_NEAR(fb.depth[i], dist, 1e-4 * dist);
      double expect = analytic_coc(A, S, dist, fov, H);
      EXPECT_NEAR(fb.coc[i], expect, 1e-4 * std::max(1.0, expect)) << "distance " << dist;
      if (dist == S) {
        EXPECT_LT(fb.coc[i], 1e-3f);
      }
    }
  }
}

TEST(ThinLens, CocOfEscapingRaysIsTheLimitAtInfinity) {
  SceneData d;
  add_quad(d, Vec3(0, 0, -100), Vec3(1, 0, 0), Vec3(0, 1, 0), testing::diffuse(Vec3(0.5f)));
  auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
  JobSpec spec = make_spec(8, 8, Vec3(0, 0, 0), Vec3(0, 0, -1), 20, 2.0f, 0.05f);
  FrameBuffers fb = render_frame(*scene, spec, 0, Rect{0, 0, 2, 2});
  double limit = 0.05 * 8 / (2.0 * std::tan(10.0 * M_PI / 180.0));
  for (size_t i = 0; i < fb.plane(); ++i) {
    EXPECT_EQ(fb.depth[i], 0.0f);
    EXPECT_NEAR(fb.coc[i], limit, 1e-4);
  }
}

TEST(AuxBuffers, PlaneAtKnownDistanceGivesDepthNormalRoughness) {
  auto scene = wall_scene();
  JobSpec spec = make_spec(16, 12, Vec3(0, 0, 3.5f), Vec3(0, 0, 0), 50);
  FrameBuffers fb = render_frame(*scene, spec, 0);
  const size_t P = fb.plane();
  for (size_t i = 0; i < P; ++i) {
    EXPECT_NEAR(fb.depth[i], 3.5f, 1e-5);
    EXPECT_NEAR(fb.normal[i], 0.0f, 1e-6);          // view-space x
    EXPECT_NEAR(fb.normal[P + i], 0.0f, 1e-6);      // y
    EXPECT_NEAR(fb.normal[2 * P + i], 1.0f, 1e-6);  // z: towards the camera
    EXPECT_EQ(fb.roughness[i], 0.625f);
    EXPECT_NEAR(fb.albedo_ref[i], 0.5f, 1e-6);
  }
}

TEST(AuxBuffers, NormalsHaveUnitLengthAndFaceTheCamera) {
  auto scene = make_scene(testing::small_room());
  // From inside the room, looking at the back wall: every pixel hits.
  JobSpec spec = make_spec(24, 24, Vec3(0.3f, 1.2f, 0.9f), Vec3(0, 0.8f, 0), 60);
  FrameBuffers fb = render_frame(*scene, spec, 0);
  const size_t P = fb.plane();
  for (size_t i = 0; i < P; ++i) {
    ASSERT_GT(fb.depth[i], 0.0f);
    Vec3 n(fb.normal[i], fb.normal[P + i], fb.normal[2 * P + i]);
    EXPECT_NEAR(length(n), 1.0f, 1e-5);
  }
}

TEST(CameraKeys, InterpolateLinearlyAndSlerpRotation) {
  JobSpec s = make_spec(8, 8, Vec3(0, 0, 5), Vec3(0, 0, 0), 30, 2.0f, 0.0f);
  s.frame_end = 10;
  CameraKey k = s.camera_keys[0];
  k.frame = 10;
  k.position = Vec3(10, 0, 5);
  k.look_at = Vec3(10, 0, 0);
  k.fov_deg = 50;
  k.focal_distance = 4;
  k.aperture = 0.2f;
  s.camera_keys.push_back(k);
  SceneData none;
  CameraState mid = camera_for_frame(s, none, 5);
  EXPECT_FLOAT_EQ(mid.position[0], 5.0f);
  EXPECT_FLOAT_EQ(mid.fov_deg, 40.0f);
  EXPECT_FLOAT_EQ(mid.focal_distance, 3.0f);
  EXPECT_FLOAT_EQ(mid.aperture, 0.1f);
  EXPECT_NEAR(mid.rotation[0], 1.0f, 1e-6);  // both keys look down -z
  CameraState after = camera_for_frame(s, none, 10);
  EXPECT_FLOAT_EQ(after.position[0], 10.0f);
}

}  // namespace
}  // namespace dofarm::render
