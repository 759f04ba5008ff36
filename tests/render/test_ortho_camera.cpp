// Orthographic cameras (glTF camera.orthographic, Blender's Orthographic
// type): parallel rays from the film rectangle, the thin lens as Cycles has
// it (on the near clipping plane, Focus Distance counted from there), the
// CoC of that lens, the film fitted to the image as Blender fits it, and
// Cycles' f-number for such a camera.
#include <gtest/gtest.h>

#include <cfloat>
#include <cmath>

#include "tests/render/render_fixtures.h"
#include "worker/render/camera.h"
#include "worker/render/render_job.h"

namespace dofarm::render {
namespace {

using testing::make_scene;
using testing::make_spec;

// A camera at (1, 2, 3) looking at (4, 0, -2): no axis of the world lines
// up with the camera's.
CameraState ortho_state(float height, float focal = 1, float aperture = 0) {
  CameraState s = testing::posed_camera(Vec3(1, 2, 3), Vec3(4, 0, -2));
  s.fov_deg = 0;
  s.ortho_height = height;
  s.focal_distance = focal;
  s.aperture = aperture;
  return s;
}

Vec3 camera_position(const CameraState& s) { return {s.position[0], s.position[1], s.position[2]}; }

// Pinhole rays: one direction, the camera's -z, each from its film point
// on the near plane: a 40 x 20 image of a view 2 high spans x in [-2, 2]
// and y in [-1, 1], 0.1 per pixel, and the ray ends on the far plane.
TEST(OrthoCamera, PinholeRaysAreParallelAndLeaveTheFilmOnTheNearPlane) {
  const CameraState s = ortho_state(2.0f);
  const Camera cam(s, 40, 20, CameraClip{0.5f, 8.0f});
  const Vec3 axis = normalize(Vec3(4, 0, -2) - Vec3(1, 2, 3));
  struct Case {
    Vec2 film;
    float x, y;  // camera space
  };
  for (const Case& c : {Case{{0, 0}, -2.0f, 1.0f}, Case{{40, 20}, 2.0f, -1.0f},
                        Case{{20, 10}, 0.0f, 0.0f}, Case{{5.5f, 12.25f}, -1.45f, -0.225f}}) {
    const Ray r = cam.pinhole_ray(c.film);
    EXPECT_NEAR(r.d.x, axis.x, 1e-6f);
    EXPECT_NEAR(r.d.y, axis.y, 1e-6f);
    EXPECT_NEAR(r.d.z, axis.z, 1e-6f);
    const Vec3 o = cam.to_view(r.o - camera_position(s));
    EXPECT_NEAR(o.x, c.x, 1e-5f);
    EXPECT_NEAR(o.y, c.y, 1e-5f);
    EXPECT_NEAR(o.z, -0.5f, 1e-5f);  // the near plane
    EXPECT_EQ(r.t_min, 0.0f);
    EXPECT_NEAR(cam.view_depth(r.o + r.d * r.t_max), 8.0f, 1e-5f);
    // Without planes: from the camera's own plane, unbounded.
    const Ray open = Camera(s, 40, 20).pinhole_ray(c.film);
    EXPECT_NEAR(cam.view_depth(open.o), 0.0f, 1e-5f);
    EXPECT_TRUE(std::isinf(open.t_max));
  }
}

// Through the lens: every ray of a film point meets the film point's place
// on the focal plane, focal_distance beyond the near plane, and at another
// depth the rays spread over a disk whose diameter in pixels is coc_pixels.
TEST(OrthoCamera, LensRaysMeetOnTheFocalPlaneAndSpreadOverTheCoc) {
  const float near = 0.5f, S = 4.0f, A = 0.3f, h = 2.0f;
  const int W = 40, H = 20;
  const CameraState s = ortho_state(h, S, A);
  const Camera cam(s, W, H, CameraClip{near, 100.0f});
  const Vec2 film(13.5f, 6.25f);
  const Ray pin = cam.pinhole_ray(film);
  auto at_depth = [&](const Ray& r, float depth) {
    const Vec3 o = cam.to_view(r.o - camera_position(s)), d = cam.to_view(r.d);
    return o + d * ((-depth - o.z) / d.z);  // camera space, z = -depth
  };
  const Vec3 focus = at_depth(pin, near + S);
  const float z = 7.0f;
  const Vec3 centre = at_depth(pin, z);
  float widest = 0;
  for (int i = 0; i <= 16; ++i) {
    for (int j = 0; j <= 16; ++j) {
      const Vec2 u(std::min(i / 16.0f, 0.9999999f), std::min(j / 16.0f, 0.9999999f));
      const Ray r = cam.generate_ray(film, u);
      EXPECT_NEAR(cam.view_depth(r.o), near, 1e-5f);  // the lens lies on the near plane
      const Vec3 f = at_depth(r, near + S);
      EXPECT_NEAR(f.x, focus.x, 1e-5f);
      EXPECT_NEAR(f.y, focus.y, 1e-5f);
      const Vec3 p = at_depth(r, z);
      widest = std::max(widest, std::hypot(p.x - centre.x, p.y - centre.y));
    }
  }
  // The disk's radius A |z - (near + S)| / S, in pixels of h / H units.
  const double radius = A * std::fabs(z - (near + S)) / S;
  EXPECT_NEAR(widest, radius, 1e-4);
  EXPECT_NEAR(cam.coc_pixels(z), 2 * radius * H / h, 1e-4);
  EXPECT_NEAR(cam.coc_pixels(near + S), 0.0f, 1e-5f);
  // The same in front of the focal plane, and unlike a perspective lens,
  // the same at every image position (no 1 / z).
  EXPECT_NEAR(cam.coc_pixels(near + S - 1.0f), 2 * A * 1.0 / S * H / h, 1e-4);
}

// An escaping ray has no depth, and an orthographic lens blurs without
// bound with depth: its CoC is the far plane's, or float's largest (never
// Inf) without one.
TEST(OrthoCamera, EscapingRaysGetTheFarPlanesCoc) {
  const CameraState s = ortho_state(2.0f, 4.0f, 0.3f);
  const Camera far(s, 40, 20, CameraClip{0.5f, 30.0f});
  EXPECT_EQ(far.coc_pixels(0.0f), far.coc_pixels(30.0f));
  EXPECT_NEAR(far.coc_pixels(0.0f), 2 * 0.3 * (29.5 - 4.0) / 4.0 * 20 / 2.0, 1e-3);
  const Camera open(s, 40, 20);
  EXPECT_EQ(open.coc_pixels(0.0f), FLT_MAX);
  // Extreme values the spec accepts stay finite.
  CameraState extreme = ortho_state(1e-30f, 1e-38f, 1e30f);
  EXPECT_TRUE(std::isfinite(Camera(extreme, 8, 8).coc_pixels(5.0f)));
  const Ray r = Camera(extreme, 8, 8).generate_ray({1, 1}, {0.9f, 0.2f});
  EXPECT_TRUE(is_finite(r.o) && is_finite(r.d));
  EXPECT_NEAR(length(r.d), 1.0f, 1e-5f);
}

// Cycles makes an orthographic camera's aperture radius 1 / (2 N), in
// scene units; a focal length does not enter.
TEST(OrthoCamera, FstopGivesOneOverTwoN) {
  CameraKey k;
  k.fstop = 0.8f;
  EXPECT_FLOAT_EQ(lens_radius(k, 0.0f, 64, 32, true), 0.625f);
  k.focal_length_mm = 50.0f;
  EXPECT_FLOAT_EQ(lens_radius(k, 0.0f, 64, 32, true), 0.625f);
  EXPECT_FLOAT_EQ(lens_radius(k, 40.0f, 64, 32, false), 0.03125f);  // 50 mm / (2 N)
}

// Blender's sensor fit auto for an orthographic camera: its scale spans the
// longer side of the image. A film of xmag 2, ymag 1 (Blender's scale 4 on
// a 2:1 render) shows 4 x 2 at 2:1, 4 x 4 in a square image and 2 x 4 in a
// portrait one.
TEST(OrthoCamera, FilmFitsTheImageAsBlendersAutoFit) {
  EXPECT_FLOAT_EQ(fitted_ortho_height(1.0f, 2.0f, 64, 32), 2.0f);
  EXPECT_FLOAT_EQ(fitted_ortho_height(1.0f, 2.0f, 64, 64), 4.0f);
  EXPECT_FLOAT_EQ(fitted_ortho_height(1.0f, 2.0f, 32, 64), 4.0f);
  EXPECT_FLOAT_EQ(fitted_ortho_height(1.0f, 0.5f, 64, 64), 2.0f);    // portrait film
  EXPECT_FLOAT_EQ(fitted_ortho_height(1.0f, 0.0f, 64, 16), 2.0f);    // no aspect: ymag
  EXPECT_FLOAT_EQ(fitted_ortho_height(1.0f, 2.0f, 641, 321), 2.0f);  // rounding: a match
  // The warning says what it crops in Blender's words.
  const std::string why = describe_aspect_mismatch(2.0f, 64, 64, true);
  EXPECT_NE(why.find("the Orthographic Scale spans the longer side"), std::string::npos) << why;
  EXPECT_NE(why.find("200% of the camera's height"), std::string::npos) << why;
  // A scene camera key with ymag makes an orthographic frame.
  SceneData d;
  d.source = "ortho.gltf";
  CameraTrackKey key;
  key.yfov_deg = 0;
  key.ymag = 1.0f;
  key.aspect = 2.0f;
  d.camera_track.push_back(key);
  JobSpec spec = make_spec(64, 64, Vec3(0, 0, 0), Vec3(0, 0, -1));
  spec.camera_from_scene = true;
  spec.camera_keys.clear();
  const CameraState cs = camera_for_frame(spec, d, 0);
  EXPECT_TRUE(cs.orthographic());
  EXPECT_FLOAT_EQ(cs.ortho_height, 4.0f);
  EXPECT_EQ(cs.fov_deg, 0.0f);
}

// A frame through an orthographic scene camera: two walls side by side,
// their edge at x = 0.55, seen from 2 and from 6 units: in a 40 px image 4
// units wide the edge crosses pixel column 25 whatever the depth (column 24
// sees only the left wall, 26 only the right), and depth and CoC are the
// same in every pixel.
TEST(OrthoCamera, AFrameShowsTheViewsRectangleWithItsDepthAndCoc) {
  for (const float dist : {2.0f, 6.0f}) {
    SceneData d = testing::walls_side_by_side();
    CameraTrackKey key;
    key.position = Vec3(0, 0, dist);
    key.yfov_deg = 0;
    key.ymag = 1.0f;
    key.aspect = 2.0f;
    d.camera_track.push_back(key);
    auto scene = make_scene(std::move(d), testing::constant_env(1.0f));
    JobSpec spec = make_spec(40, 20, Vec3(0, 0, 0), Vec3(0, 0, -1), 40, 3.0f, 0.2f);
    spec.camera_from_scene = true;
    const FrameBuffers fb = render_frame(*scene, spec, 0);
    EXPECT_EQ(fb.camera.ortho_height, 2.0f);
    const float coc = 2 * 0.2f * std::fabs(dist - 3.0f) / 3.0f * 20 / 2.0f;
    for (size_t i = 0; i < fb.plane(); ++i) {
      ASSERT_NEAR(fb.depth[i], dist, 1e-4f);
      ASSERT_NEAR(fb.coc[i], coc, 1e-3f);
    }
    // Through a pinhole, each version's albedo is that of its ray's wall.
    JobSpec pin = spec;
    pin.camera_keys[0].aperture = 0;
    const FrameBuffers p = render_frame(*scene, pin, 0);
    for (int y = 0; y < 20; ++y) {
      EXPECT_NEAR(p.albedo[size_t(y) * 40 + 24], 0.2f, 1e-6f) << "row " << y;
      EXPECT_NEAR(p.albedo[size_t(y) * 40 + 26], 0.8f, 1e-6f) << "row " << y;
    }
  }
}

}  // namespace
}  // namespace dofarm::render
