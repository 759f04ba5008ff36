// Thin lens, circle of confusion and the auxiliary buffers against their
// analytic values.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

#include "common/error.h"
#include "tests/render/render_fixtures.h"
#include "tests/render/same_bits.h"
#include "worker/render/camera.h"
#include "worker/render/render_job.h"
#include "worker/render/simd.h"

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

// ---------------------------------------------------------------------------
// The scene camera's shape

// A glTF camera track of one key at the origin looking down -z.
SceneData scene_camera(float yfov_deg, float aspect) {
  SceneData d;
  d.source = "camera.gltf";
  CameraTrackKey k;
  k.yfov_deg = yfov_deg;
  k.aspect = aspect;
  d.camera_track.push_back(k);
  return d;
}

JobSpec from_scene_spec(int w, int h) {
  JobSpec s = make_spec(w, h, Vec3(0, 0, 0), Vec3(0, 0, -1));
  s.camera_from_scene = true;
  s.camera_keys.clear();
  return s;
}

// Half-angle (degrees) between the axis and the pinhole ray through the
// middle of the image's left edge / top edge.
double half_angle_x(const CameraState& c, int w, int h) {
  Ray r = Camera(c, w, h).pinhole_ray({0.0f, 0.5f * h});
  return std::atan2(std::fabs(r.d.x), -r.d.z) * 180.0 / M_PI;
}
double half_angle_y(const CameraState& c, int w, int h) {
  Ray r = Camera(c, w, h).pinhole_ray({0.5f * w, 0.0f});
  return std::atan2(std::fabs(r.d.y), -r.d.z) * 180.0 / M_PI;
}

// Blender's default sensor fit (auto): the camera's angle spans the longer
// side of any image it renders. A 16:9 camera exported with yfov Y has the
// angle 2 atan(tan(Y/2) 16/9) (Blender's glTF exporter, gather_cameras).
TEST(SceneCamera, FieldOfViewSpansTheLongerSideAsBlendersAutoFit) {
  const double yfov = 40, a = 16.0 / 9.0;
  const double angle = 2 * std::atan(std::tan(yfov * M_PI / 360) * a) * 180 / M_PI;
  const SceneData d = scene_camera(float(yfov), float(a));
  struct Case {
    int w, h;
    double half_x, half_y;  // expected, degrees
  };
  auto atan_deg = [](double t) { return std::atan(t) * 180 / M_PI; };
  const double t_angle = std::tan(angle * M_PI / 360);
  for (const Case& c :
       {Case{512, 288, angle / 2, yfov / 2},  // the camera's own shape
        Case{512, 512, angle / 2, angle / 2}, Case{512, 256, angle / 2, atan_deg(t_angle / 2)},
        Case{288, 512, atan_deg(t_angle * 288 / 512), angle / 2}}) {
    SCOPED_TRACE(::testing::Message() << c.w << "x" << c.h);
    const JobSpec spec = from_scene_spec(c.w, c.h);
    const CameraState cam = camera_for_frame(spec, d, 0);
    EXPECT_NEAR(half_angle_x(cam, c.w, c.h), c.half_x, 1e-3);
    EXPECT_NEAR(half_angle_y(cam, c.w, c.h), c.half_y, 1e-3);
  }
  // Without an aspect ratio in the file, yfov is vertical for any image (glTF).
  const SceneData no_aspect = scene_camera(float(yfov), 0.0f);
  EXPECT_FLOAT_EQ(camera_for_frame(from_scene_spec(512, 512), no_aspect, 0).fov_deg, 40.0f);
  // The job spec's own cameras keep their vertical fov whatever the image.
  JobSpec keyed = make_spec(512, 256, Vec3(0, 0, 0), Vec3(0, 0, -1), 30);
  EXPECT_NEAR(half_angle_y(camera_for_frame(keyed, d, 0), 512, 256), 15.0, 1e-3);
}

// Known answers from Blender 3.4.1 itself: a 50 mm lens on a 36 mm sensor
// (sensor fit auto), Camera.view_frame() half-angles in degrees at each
// render size. The glTF the exporter writes for the 1920x1080 render holds
// yfov = 2 atan(tan(angle/2) / (16/9)) and aspectRatio 16/9.
TEST(SceneCamera, MatchesBlendersViewFrameAtEveryImageSize) {
  const double angle = 2 * std::atan(18.0 / 50.0);
  const double a = 1920.0 / 1080.0;
  const SceneData d =
      scene_camera(float(2 * std::atan(std::tan(angle / 2) / a) * 180 / M_PI), float(a));
  struct Blender {
    int w, h;
    double half_x, half_y;
  };
  for (const Blender& b :
       {Blender{1920, 1080, 19.7989, 11.4476}, Blender{512, 512, 19.7989, 19.7989},
        Blender{1024, 512, 19.7989, 10.2040}, Blender{288, 512, 11.4476, 19.7989}}) {
    SCOPED_TRACE(::testing::Message() << b.w << "x" << b.h);
    const CameraState cam = camera_for_frame(from_scene_spec(b.w, b.h), d, 0);
    EXPECT_NEAR(half_angle_x(cam, b.w, b.h), b.half_x, 1e-4);
    EXPECT_NEAR(half_angle_y(cam, b.w, b.h), b.half_y, 1e-4);
  }
}

TEST(SceneCamera, DefaultImageSizeFollowsTheAspectRatio) {
  auto size = [](float a, int w, int h) {
    ImageSize s = image_size_for_aspect(a, w, h);
    return std::make_pair(s.width, s.height);
  };
  const float wide = 16.0f / 9.0f;
  EXPECT_EQ(size(wide, 0, 0), std::make_pair(512, 288));
  EXPECT_EQ(size(0.5f, 0, 0), std::make_pair(256, 512));
  EXPECT_EQ(size(1.0f, 0, 0), std::make_pair(512, 512));
  EXPECT_EQ(size(wide, 1920, 0), std::make_pair(1920, 1080));
  EXPECT_EQ(size(wide, 0, 1080), std::make_pair(1920, 1080));
  EXPECT_EQ(size(wide, 640, 640), std::make_pair(640, 640));  // both given: kept
  EXPECT_EQ(size(0.0f, 0, 0), std::make_pair(512, 512));      // no aspect in the file
  EXPECT_EQ(size(1000.0f, 0, 0), std::make_pair(512, 1));     // never 0 pixels
}

TEST(SceneCamera, MismatchSaysWhatTheImageCropsOrAdds) {
  const float wide = 16.0f / 9.0f;
  EXPECT_EQ(describe_aspect_mismatch(wide, 512, 288), "");
  EXPECT_EQ(describe_aspect_mismatch(wide, 1920, 1080), "");
  EXPECT_EQ(describe_aspect_mismatch(1.5f, 512, 341), "");  // rounding is no crop
  EXPECT_EQ(describe_aspect_mismatch(0.0f, 512, 512), "");  // nothing to compare with
  const std::string square = describe_aspect_mismatch(wide, 512, 512);
  EXPECT_NE(square.find("is 16:9 but the image is 512x512 (1:1)"), std::string::npos) << square;
  EXPECT_NE(square.find("the camera's full width and 178% of the camera's height"),
            std::string::npos)
      << square;
  const std::string two_to_one = describe_aspect_mismatch(wide, 1024, 512);
  EXPECT_NE(two_to_one.find("the middle 89% of the camera's height"), std::string::npos)
      << two_to_one;
  const std::string portrait = describe_aspect_mismatch(wide, 288, 512);
  EXPECT_NE(portrait.find("the middle 56% of the camera's width"), std::string::npos) << portrait;
}

TEST(SceneCamera, FromSceneWithoutACameraIsAnErrorAtTheKey) {
  JobSpec spec = from_scene_spec(8, 8);
  spec.key_locations["camera.from_scene"] = FileLoc{"job.toml", 4, 14};
  SceneData none;
  try {
    camera_for_frame(spec, none, 0);
    FAIL() << "rendered from the origin";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "camera.from_scene");
    EXPECT_EQ(e.loc().str(), "job.toml:4:14");
  }
}

// Clipping planes (CameraClip): a camera ray's [t_min, t_max] spans view
// depths near to far exactly, through the pinhole and through any lens
// point, where the pinhole's plane distance along a tilted ray differs
// from the lens ray's.
TEST(CameraClipping, CameraRaysSpanTheViewDepthsBetweenThePlanes) {
  CameraState s = testing::posed_camera(Vec3(1, 2, 3), Vec3(4, 0, -2));
  s.fov_deg = 60;
  s.focal_distance = 3;
  s.aperture = 0.4f;
  const Camera clipped(s, 64, 48, CameraClip{2.0f, 7.0f});
  const Camera open(s, 64, 48);
  for (Vec2 film : {Vec2(0.5f, 0.5f), Vec2(32, 24), Vec2(63.5f, 47.5f), Vec2(3, 40)}) {
    for (Vec2 lens : {Vec2(0.5f, 0.5f), Vec2(0.05f, 0.9f), Vec2(0.99f, 0.01f)}) {
      for (const Ray& r : {clipped.generate_ray(film, lens), clipped.pinhole_ray(film)}) {
        EXPECT_NEAR(clipped.view_depth(r.o + r.d * r.t_min), 2.0f, 1e-4f);
        EXPECT_NEAR(clipped.view_depth(r.o + r.d * r.t_max), 7.0f, 1e-4f);
      }
      // The same rays otherwise, and unclipped without planes.
      const Ray a = clipped.generate_ray(film, lens), b = open.generate_ray(film, lens);
      EXPECT_EQ(a.o.x, b.o.x);
      EXPECT_EQ(a.d.y, b.d.y);
      EXPECT_EQ(b.t_min, 0.0f);
      EXPECT_TRUE(std::isinf(b.t_max));
    }
  }
}

// ---------------------------------------------------------------------------
// Lens keys

TEST(Lens, FstopGivesFocalLengthOverTwoN) {
  CameraKey k;
  k.fstop = 2.0f;
  k.focal_length_mm = 50.0f;
  EXPECT_FLOAT_EQ(lens_radius(k, 40.0f, 512, 512), 0.0125f);  // 50 mm / (2 * 2), in metres
  // No focal length: Blender's 50 mm lens on its 36 mm sensor has the angle
  // 2 atan(18 / 50) across the image's longer side.
  k.focal_length_mm = 0;
  const float angle = float(2 * std::atan(18.0 / 50.0) * 180 / M_PI);
  EXPECT_NEAR(lens_radius(k, angle, 512, 512), 0.0125f, 1e-6);
  const float vfov_wide = float(2 * std::atan(18.0 / 50.0 * 288 / 512) * 180 / M_PI);
  EXPECT_NEAR(lens_radius(k, vfov_wide, 512, 288), 0.0125f, 1e-6);
  const float vfov_tall = angle;  // portrait: the longer side is vertical
  EXPECT_NEAR(lens_radius(k, vfov_tall, 288, 512), 0.0125f, 1e-6);
  k.sensor_width_mm = 24;  // a smaller sensor at the same angle: a shorter lens
  EXPECT_NEAR(lens_radius(k, angle, 512, 512), 0.0125f * 24 / 36, 1e-6);
  CameraKey radius;
  radius.aperture = 0.3f;
  EXPECT_EQ(lens_radius(radius, 40.0f, 64, 64), 0.3f);
}

TEST(Lens, FstopKeyRendersLikeTheEquivalentAperture) {
  auto scene = make_scene(testing::small_room());
  JobSpec a = make_spec(16, 12, Vec3(0, 1, 3), Vec3(0, 1, 0), 45, 2.5f, 0.0125f);
  JobSpec b = a;
  b.camera_keys[0].aperture = 0;
  b.camera_keys[0].fstop = 2;
  b.camera_keys[0].focal_length_mm = 50;
  FrameBuffers fa = render_frame(*scene, a, 0), fb = render_frame(*scene, b, 0);
  EXPECT_EQ(fb.camera.aperture, 0.0125f);
  EXPECT_TRUE(testing::same_bytes(fa, fb));
}

// ---------------------------------------------------------------------------
// Focus

TEST(Focus, PointGivesItsViewDepthEveryFrame) {
  // The camera moves from z = 5 to z = 9 looking down -z; the point stays.
  JobSpec s = make_spec(8, 8, Vec3(0, 0, 5), Vec3(0, 0, 0), 40, 1.0f, 0.1f);
  s.frame_end = 4;
  s.camera_keys[0].focus = FocusMode::kPoint;
  s.camera_keys[0].focus_point = Vec3(1.5f, -0.5f, 2.0f);
  CameraKey k = s.camera_keys[0];
  k.frame = 4;
  k.position = Vec3(0, 0, 9);
  k.look_at = Vec3(0, 0, 4);
  s.camera_keys.push_back(k);
  SceneData none;
  for (int f = 0; f <= 4; ++f) {
    EXPECT_NEAR(camera_for_frame(s, none, f).focal_distance, 3.0f + float(f), 1e-5) << f;
  }
}

TEST(Focus, PointBehindTheCameraIsAnErrorNamingTheKeyAndFrame) {
  JobSpec s = make_spec(8, 8, Vec3(0, 0, 5), Vec3(0, 0, 0), 40, 1.0f, 0.1f);
  s.camera_keys[0].focus = FocusMode::kPoint;
  s.camera_keys[0].focus_point = Vec3(0, 0, 6);
  s.key_locations["camera.key.0.focus_point"] = FileLoc{"job.toml", 9, 15};
  SceneData none;
  try {
    camera_for_frame(s, none, 0);
    FAIL() << "accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "camera.key.0.focus_point");
    EXPECT_EQ(e.loc().str(), "job.toml:9:15");
    EXPECT_NE(e.message().find("frame 0"), std::string::npos) << e.what();
  }
}

TEST(Focus, AutoFocusesOnTheSurfaceAtTheImageCentre) {
  auto scene = wall_scene();
  for (float dist : {1.5f, 4.0f}) {
    JobSpec spec = make_spec(9, 7, Vec3(0.3f, -0.2f, dist), Vec3(0.3f, -0.2f, 0), 30, 1.0f, 0.1f);
    spec.camera_keys[0].focus = FocusMode::kAuto;
    FrameBuffers fb = render_frame(*scene, spec, 0);
    // What the frame records is what the lens and the coc buffer used: the
    // wall is in focus everywhere.
    EXPECT_NEAR(fb.camera.focal_distance, dist, 1e-5 * dist);
    for (float c : fb.coc) EXPECT_LT(c, 1e-3f);
  }
  // Looking away from the wall: nothing to focus on is an error.
  JobSpec away = make_spec(8, 8, Vec3(0, 0, 3), Vec3(0, 0, 6), 30, 1.0f, 0.1f);
  away.camera_keys[0].focus = FocusMode::kAuto;
  try {
    frame_camera(*scene, away, 0);
    FAIL() << "accepted";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "camera.key.0.focus");
    EXPECT_NE(e.message().find("hits nothing"), std::string::npos) << e.what();
  }
}

TEST(Focus, FocusPointRecordedInTheFrameIsTheOneTheCocUses) {
  auto scene = wall_scene();
  const float dist = 6, S = 2.5f, A = 0.1f, fov = 30;
  const int W = 10, H = 8;
  JobSpec spec = make_spec(W, H, Vec3(0, 0, dist), Vec3(0, 0, 0), fov, 1.0f, A);
  spec.camera_keys[0].focus = FocusMode::kPoint;
  spec.camera_keys[0].focus_point = Vec3(4, -3, dist - S);  // off-axis, depth S
  FrameBuffers fb = render_frame(*scene, spec, 0);
  EXPECT_NEAR(fb.camera.focal_distance, S, 1e-5);
  for (float c : fb.coc) EXPECT_NEAR(c, analytic_coc(A, S, dist, fov, H), 1e-3);
}

// Camera::generate_rays (a packet's camera rays at once, in AVX2 lanes
// where the CPU has them) gives generate_ray()'s rays bit for bit: origin,
// direction and clipping range, for turned cameras with and without
// clipping planes, lens points at the disk's centre, on its diagonals and
// axes, and focal distances whose direction under- or overflows a float
// (generate_ray()'s double fallback, redone lane by lane).
TEST(Camera, BatchedRaysAreTheSingleRays) {
  SimdRestore restore;
  auto same_ray = [&](const Ray& a, const Ray& b) {
    return test::same_bits(a.o, b.o) && test::same_bits(a.d, b.d) &&
           test::same_bits(a.t_min, b.t_min) && test::same_bits(a.t_max, b.t_max);
  };
  std::vector<Vec2> lens = {{0.5f, 0.5f},  {0.0f, 0.0f}, {0.9f, 0.9f},    {0.1f, 0.9f},
                            {0.5f, 0.0f},  {0.0f, 0.5f}, {0.99f, 0.5f},   {0.5f, 0.25f},
                            {0.75f, 0.5f}, {0.3f, 0.7f}, {0.999f, 0.001f}};
  std::vector<Vec2> film = {{0.0f, 0.0f}, {320.0f, 180.0f}, {639.99f, 359.99f}, {17.25f, 301.5f}};
  uint32_t h = 12345;
  for (int i = 0; i < 40; ++i) {  // and scattered points
    auto next = [&h] {
      h = h * 1664525u + 1013904223u;
      return float(h >> 8) * 0x1p-24f;
    };
    lens.push_back({next(), next()});
    film.push_back({next() * 640.0f, next() * 360.0f});
  }
  struct Case {
    const char* name;
    float focal, aperture;
    CameraClip clip;
  };
  const Case cases[] = {{"plain", 3.4f, 0.08f, {}},
                        {"near and far", 9.0f, 0.03f, {0.1f, 100.0f}},
                        {"near only", 2.0f, 0.5f, {0.5f, std::numeric_limits<float>::infinity()}},
                        {"far only", 4.0f, 0.2f, {0.0f, 7.0f}},
                        {"focus 1e-38", 1e-38f, 1e-30f, {}},
                        {"focus 3e38", 3e38f, 0.1f, {0.1f, 1e30f}}};
  std::vector<bool> modes = {false};
  if (simd_available()) modes.push_back(true);
  for (bool simd : modes) {
    allow_simd(simd);
    for (const Case& c : cases) {
      for (const CameraState& pose :
           {CameraState{}, testing::posed_camera(Vec3(1, 2, 3), Vec3(4, 0, -2)),
            testing::posed_camera(Vec3(-5, 1, 0.5f), Vec3(0, 1.5f, 0))}) {
        CameraState state = pose;
        state.fov_deg = 39.6f;
        state.focal_distance = c.focal;
        state.aperture = c.aperture;
        const Camera camera(state, 640, 360, c.clip);
        for (size_t start = 0; start < lens.size(); start += 3) {
          for (int n = 1; n <= 8; ++n) {
            Vec2 f[8], l[8];
            for (int k = 0; k < n; ++k) {
              f[k] = film[(start + size_t(k)) % film.size()];
              l[k] = lens[(start + size_t(k)) % lens.size()];
            }
            Ray batch[8];
            camera.generate_rays(f, l, n, batch);
            for (int k = 0; k < n; ++k)
              ASSERT_TRUE(same_ray(batch[k], camera.generate_ray(f[k], l[k])))
                  << c.name << ", simd " << simd << ", film (" << f[k].x << ", " << f[k].y
                  << "), lens (" << l[k].x << ", " << l[k].y << ")";
          }
        }
      }
    }
  }
}

}  // namespace
}  // namespace dofarm::render
