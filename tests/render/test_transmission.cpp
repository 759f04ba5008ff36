// Refraction through real geometry: a ray meets a glass slab, enters it
// (the hit knows it is on the front side), bends by Snell's law, leaves it
// through the back face (the hit knows it is inside) and continues parallel
// to where it came from, displaced by the slab's known offset.
#include <gtest/gtest.h>

#include <cmath>

#include "tests/render/render_fixtures.h"
#include "worker/render/bsdf.h"
#include "worker/render/integrator.h"

namespace dofarm::render {
namespace {

// The refracted direction, drawn with a lobe number past Fresnel's share.
Vec3 refract_through(const SurfaceHit& hit, Vec3 d) {
  const Bsdf bsdf(hit.ns, hit.ng, hit.base_color, hit.metallic, hit.roughness, hit.ior,
                  {hit.specular, hit.specular_color}, {hit.transmission, hit.front});
  const BsdfSample s = bsdf.sample(-d, 0.999f, Vec2(0.5f, 0.5f));
  EXPECT_TRUE(s.valid && s.is_delta);
  return s.wi;
}

TEST(Transmission, RayCrossesASlabAsSnellSays) {
  SceneData d;
  const float thickness = 0.5f;
  add_box(d, Vec3(-5, -5, -thickness), Vec3(5, 5, 0), testing::glass(0.0f));
  auto scene = testing::make_scene(std::move(d), testing::constant_env(1.0f));

  for (double theta_deg : {0.0, 20.0, 45.0, 70.0}) {
    SCOPED_TRACE(theta_deg);
    const double theta = theta_deg * kPi / 180.0;
    const Vec3 dir(float(std::sin(theta)), 0.0f, float(-std::cos(theta)));
    const Ray in{dir * -3.0f, dir};  // meets the slab's top at the origin
    SurfaceHit a;
    ASSERT_TRUE(scene->intersect(in, &a));
    EXPECT_TRUE(a.front);
    EXPECT_NEAR(a.p.z, 0.0f, 1e-5f);
    const Vec3 inside = refract_through(a, dir);
    const double theta_t = std::asin(std::sin(theta) / 1.5);
    EXPECT_NEAR(inside.x, std::sin(theta_t), 1e-5);
    EXPECT_NEAR(inside.z, -std::cos(theta_t), 1e-5);

    SurfaceHit b;
    ASSERT_TRUE(scene->intersect({scene->offset_origin(a, inside), inside}, &b));
    EXPECT_FALSE(b.front);
    EXPECT_NEAR(b.p.z, -thickness, 1e-5f);
    EXPECT_NEAR(b.p.x - a.p.x, thickness * std::tan(theta_t), 1e-4);
    const Vec3 out = refract_through(b, inside);
    EXPECT_NEAR(out.x, dir.x, 1e-5f);
    EXPECT_NEAR(out.z, dir.z, 1e-5f);
    // The lateral shift of a slab: t sin(theta - theta_t) / cos(theta_t),
    // measured perpendicular to the ray.
    const Vec3 straight = a.p + dir * float(thickness / std::cos(theta));
    const Vec3 off = b.p - straight;
    const double shift = std::sqrt(double(dot(off, off)) - std::pow(double(dot(off, dir)), 2));
    EXPECT_NEAR(shift, thickness * std::sin(theta - theta_t) / std::cos(theta_t), 1e-4);
  }
}

// From inside, beyond the critical angle (41.8 degrees for IOR 1.5), the
// surface reflects everything: the refraction number draws a reflection.
TEST(Transmission, TotalInternalReflectionFromInside) {
  SceneData d;
  add_box(d, Vec3(-5, -5, -1), Vec3(5, 5, 0), testing::glass(0.0f));
  auto scene = testing::make_scene(std::move(d), testing::constant_env(1.0f));
  for (double theta_deg : {30.0, 41.0, 42.5, 60.0}) {
    SCOPED_TRACE(theta_deg);
    const double theta = theta_deg * kPi / 180.0;
    const Vec3 dir(float(std::sin(theta)), 0.0f, float(std::cos(theta)));  // upwards, inside
    SurfaceHit hit;
    ASSERT_TRUE(scene->intersect({Vec3(0, 0, -0.5f), dir}, &hit));
    EXPECT_FALSE(hit.front);
    const Vec3 wi = refract_through(hit, dir);
    if (theta_deg > 41.81) {
      EXPECT_NEAR(wi.z, -dir.z, 1e-6f);  // mirrored back down
    } else {
      EXPECT_GT(wi.z, 0.0f);  // out through the top
      EXPECT_NEAR(wi.x, 1.5 * std::sin(theta), 1e-5);
    }
  }
}

// KHR_materials_volume (Beer-Lambert): light that crosses a clear IOR-1
// slab of thickness T absorbing sigma = -ln(c) / d leaves with c^(T / d) of
// its radiance, per channel, exactly; the same slab without absorption
// passes everything.
TEST(Transmission, AbsorbingSlabPassesColourToTheThicknessOverDistance) {
  for (bool absorbing : {true, false}) {
    SCOPED_TRACE(absorbing);
    SceneData d;
    Material m = testing::glass(0.0f, Vec3(1), /*ior=*/1.0f);
    const Vec3 c(0.5f, 0.25f, 1.0f);
    const float distance = 2.0f, thickness = 0.5f;
    if (absorbing) m.attenuation = Vec3(-std::log(c.x), -std::log(c.y), -std::log(c.z)) / distance;
    add_box(d, Vec3(-5, -5, -thickness), Vec3(5, 5, 0), m);
    auto scene = testing::make_scene(std::move(d), testing::constant_env(1.0f));
    IntegratorSettings settings;
    for (int i = 0; i < 8; ++i) {
      PixelSampler sampler(SamplerKind::kSobol, 3, 0, i, 0, Stream::kTest);
      sampler.start_sample(0);
      const Vec3 dir = normalize(Vec3(0.1f * i, 0.0f, -1.0f));
      const Vec3 L = trace_path(*scene, {dir * -3.0f, dir}, sampler, settings);
      const float path = thickness / -dir.z;  // the length inside the slab
      for (int k = 0; k < 3; ++k)
        EXPECT_NEAR(L[k], absorbing ? std::pow(c[k], path / distance) : 1.0f, 1e-5f)
            << "channel " << k << " ray " << i;
    }
  }
}

}  // namespace
}  // namespace dofarm::render
