// Solid-angle sampling of triangle lights (worker/render/spherical_triangle.h)
// against known answers: the solid angle of an octant and of a square
// (4 asin(s^2 / (s^2 + d^2)) for a square of half-side s at distance d on its
// axis), directions that all hit the triangle and are uniform over its solid
// angle (chi-square over 16 sub-triangles), and, through Scene, MIS pdfs that
// match the samples, a light that does not light itself, and NEE irradiance under a light a few millimetres away
// against Lambert's exact polygon formula, with a bounded weight.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <vector>

#include "tests/render/render_fixtures.h"
#include "worker/render/integrator.h"
#include "worker/render/shapes.h"
#include "worker/render/spherical_triangle.h"

namespace dofarm::render {
namespace {

using testing::make_scene;

struct Tri {
  Vec3 a, b, c;
};

// Whether the ray from o along d crosses the triangle (Moller-Trumbore in
// double, with a small tolerance at the edges for the float direction).
bool hits(Vec3 o, Vec3 d, const Tri& t) {
  auto sub = [](Vec3 x, Vec3 y) {
    return std::array<double, 3>{double(x.x) - y.x, double(x.y) - y.y, double(x.z) - y.z};
  };
  auto crs = [](const std::array<double, 3>& x, const std::array<double, 3>& y) {
    return std::array<double, 3>{x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2],
                                 x[0] * y[1] - x[1] * y[0]};
  };
  auto dt = [](const std::array<double, 3>& x, const std::array<double, 3>& y) {
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
  };
  const std::array<double, 3> dd{d.x, d.y, d.z};
  const auto e1 = sub(t.b, t.a), e2 = sub(t.c, t.a), s = sub(o, t.a);
  const auto p = crs(dd, e2);
  const double det = dt(e1, p);
  if (std::fabs(det) < 1e-300) return false;
  const double u = dt(s, p) / det;
  const auto q = crs(s, e1);
  const double v = dt(dd, q) / det, dist = dt(e2, q) / det;
  const double tol = 2e-4;  // float directions to a small, distant triangle
  return u >= -tol && v >= -tol && u + v <= 1 + tol && dist > 0;
}

// The triangle cut into 4^levels congruent parts by its edge midpoints.
void subdivide(const Tri& t, int levels, std::vector<Tri>* out) {
  if (levels == 0) {
    out->push_back(t);
    return;
  }
  const Vec3 ab = (t.a + t.b) * 0.5f, bc = (t.b + t.c) * 0.5f, ca = (t.c + t.a) * 0.5f;
  subdivide({t.a, ab, ca}, levels - 1, out);
  subdivide({ab, t.b, bc}, levels - 1, out);
  subdivide({ca, bc, t.c}, levels - 1, out);
  subdivide({ab, bc, ca}, levels - 1, out);
}

TEST(SphericalTriangle, SolidAngleOfKnownShapes) {
  // One octant of the sphere.
  EXPECT_NEAR(spherical_triangle_solid_angle(Vec3(0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)),
              M_PI / 2, 1e-6);
  // Winding and distance along the rays to the vertices do not matter.
  EXPECT_NEAR(spherical_triangle_solid_angle(Vec3(0), Vec3(0, 0, 3), Vec3(0, 2, 0), Vec3(5, 0, 0)),
              M_PI / 2, 1e-6);
  // A square of half-side s at distance d on its axis, as two triangles.
  for (double d : {1e-3, 0.05, 1.0, 40.0}) {
    const float s = 0.5f, z = float(d);
    const Vec3 p00(-s, -s, z), p10(s, -s, z), p11(s, s, z), p01(-s, s, z);
    const double omega = spherical_triangle_solid_angle(Vec3(0), p00, p10, p11) +
                         spherical_triangle_solid_angle(Vec3(0), p00, p11, p01);
    const double want = 4 * std::asin(double(s) * s / (double(s) * s + d * d));
    EXPECT_NEAR(omega, want, 1e-6 * want) << "d " << d;
  }
  // Seen edge-on, or degenerate: 0.
  EXPECT_EQ(spherical_triangle_solid_angle(Vec3(0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(1, 1, 0)),
            0.0);
  EXPECT_EQ(spherical_triangle_solid_angle(Vec3(0), Vec3(1, 0, 1), Vec3(2, 0, 2), Vec3(3, 0, 3)),
            0.0);
}

TEST(SphericalTriangle, SamplesHitTheTriangleUniformlyInSolidAngle) {
  const std::vector<Tri> cases = {
      {Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)},                  // an octant, seen from near
      {Vec3(0, 0, 1), Vec3(0, 1, 0), Vec3(1, 0, 0)},                  // the other winding
      {Vec3(-2, -1, 0.1f), Vec3(3, -0.5f, 0.12f), Vec3(0, 2, 0.08f)},  // large and close, obtuse
      {Vec3(-4, 0, 0.3f), Vec3(4, 0.2f, 0.3f), Vec3(0, 0.1f, 0.6f)},  // a sliver
      {Vec3(9, 10, 8), Vec3(9.02f, 10, 8), Vec3(9, 10.03f, 8.01f)},   // small and far
      // Seen at grazing angles: a light 2 mm and 0.1 mm above the plane
      // of the point, beside it (a ceiling next to a ceiling light).
      {Vec3(-0.5f, 0.002f, -0.5f), Vec3(0.5f, 0.002f, -0.5f), Vec3(0.5f, 0.002f, 0.5f)},
      {Vec3(-0.5f, 1e-4f, -0.5f), Vec3(0.5f, 1e-4f, 0.5f), Vec3(-0.5f, 1e-4f, 0.5f)},
  };
  std::mt19937 rng(12345);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (size_t k = 0; k < cases.size(); ++k) {
    const Tri& t = cases[k];
    const Vec3 from = k < 5 ? Vec3(0.1f, -0.2f, 0.05f) : Vec3(0.8f, 0.0f, 0.1f);
    const double omega = spherical_triangle_solid_angle(from, t.a, t.b, t.c);
    ASSERT_GT(omega, 0) << "case " << k;
    std::vector<Tri> parts;
    subdivide(t, 2, &parts);  // 16 cells
    std::vector<double> expected(parts.size());
    double sum = 0;
    for (size_t i = 0; i < parts.size(); ++i) {
      expected[i] = spherical_triangle_solid_angle(from, parts[i].a, parts[i].b, parts[i].c);
      sum += expected[i];
    }
    EXPECT_NEAR(sum, omega, 1e-4 * omega) << "case " << k;  // float midpoints
    const int n = 40000;
    std::vector<int> count(parts.size(), 0);
    int misses = 0;
    for (int s = 0; s < n; ++s) {
      Vec3 dir;
      ASSERT_TRUE(sample_spherical_triangle(from, t.a, t.b, t.c, omega, Vec2(uni(rng), uni(rng)),
                                            &dir));
      ASSERT_NEAR(length(dir), 1.0f, 1e-5f);
      if (!hits(from, dir, t)) {
        ++misses;
        continue;
      }
      // The cell it lands in (cells share edges: the first that claims it).
      for (size_t i = 0; i < parts.size(); ++i)
        if (hits(from, dir, parts[i])) {
          ++count[i];
          break;
        }
    }
    EXPECT_EQ(misses, 0) << "case " << k;
    double chi2 = 0;
    for (size_t i = 0; i < parts.size(); ++i) {
      const double e = n * expected[i] / omega;
      chi2 += (count[i] - e) * (count[i] - e) / e;
    }
    EXPECT_LT(chi2, 37.7) << "case " << k;  // chi-square, 15 degrees of freedom, p = 0.001
  }
}

TEST(SphericalTriangle, CornersOfTheUnitSquareMapToTheVertices) {
  // Arvo's map: u1 = 0 collapses onto the arc from B to A, u2 = 0 gives B,
  // u1 = 1, u2 = 1 gives C.
  const Vec3 from(0), a(1, 0, 0), b(0, 1, 0), c(0, 0, 1);
  const double omega = spherical_triangle_solid_angle(from, a, b, c);
  Vec3 d;
  ASSERT_TRUE(sample_spherical_triangle(from, a, b, c, omega, Vec2(0.3f, 0.0f), &d));
  EXPECT_NEAR(d.y, 1.0f, 1e-5f);
  ASSERT_TRUE(sample_spherical_triangle(from, a, b, c, omega, Vec2(0.0f, 1.0f), &d));
  EXPECT_NEAR(d.x, 1.0f, 1e-5f);
  ASSERT_TRUE(sample_spherical_triangle(from, a, b, c, omega, Vec2(1.0f, 1.0f), &d));
  EXPECT_NEAR(d.z, 1.0f, 1e-5f);
}

// Irradiance at the origin (normal +y) from a Lambertian polygon of radiance
// 1, by Lambert's formula: E = 1/2 sum_i beta_i (n . g_i), beta_i the angle
// the edge v_i v_i+1 subtends and g_i the unit normal of the plane through
// the origin and that edge (oriented so that the sum is positive).
double polygon_irradiance(const std::vector<Vec3>& v) {
  double e = 0;
  for (size_t i = 0; i < v.size(); ++i) {
    const Vec3 a = normalize(v[i]), b = normalize(v[(i + 1) % v.size()]);
    const double beta = std::acos(std::clamp(double(dot(a, b)), -1.0, 1.0));
    const Vec3 g = normalize(cross(a, b));
    e += beta * g.y;
  }
  return 0.5 * std::fabs(e);
}

TEST(SphericalTriangle, NeeUnderACloseLightMatchesLambertsFormulaWithBoundedWeights) {
  // A 1 x 1 light 5 mm above a receiver at the origin, off-centre; then the
  // same light seen from far to the side (area sampling there).
  for (Vec3 from : {Vec3(0.2f, 0, 0.1f), Vec3(0.49f, 0, 0.3f), Vec3(0.3f, -3.0f, 0.2f)}) {
    SceneData d;
    d.source = "light.gltf";
    const float h = 0.005f;
    const Vec3 p0(-0.5f, h, -0.5f), p1(0.5f, h, -0.5f), p2(0.5f, h, 0.5f), p3(-0.5f, h, 0.5f);
    add_quad(d, p0, p1, p2, p3, testing::emitter(Vec3(1)));
    auto scene = make_scene(std::move(d));
    const double want = polygon_irradiance({p0 - from, p1 - from, p2 - from, p3 - from});
    const int n = 20000;
    double sum = 0, sum2 = 0, largest = 0;
    for (int s = 0; s < n; ++s) {
      const float u = (s + 0.5f) / n;
      LightSample ls;
      // A scrambled second and third coordinate (golden-ratio sequences).
      const Vec2 uv(float(std::fmod(0.5 + s * 0.6180339887, 1.0)),
                    float(std::fmod(0.25 + s * 0.7548776662, 1.0)));
      double w = 0;
      if (scene->sample_light(from, u, uv, &ls) && ls.wi.y > 0) {
        w = ls.radiance.x * ls.wi.y / ls.pdf;
        // The pdf MIS would use for a BSDF ray that found the same point.
        SurfaceHit hit;
        ASSERT_TRUE(scene->intersect({from, ls.wi}, &hit));
        EXPECT_NEAR(hit.t, ls.distance, 1e-4f * ls.distance + 1e-6f);
        EXPECT_NEAR(scene->light_pdf(from, hit), ls.pdf, 1e-3f * ls.pdf);

      }
      sum += w;
      sum2 += w * w;
      largest = std::max(largest, w);
    }
    const double mean = sum / n, sd = std::sqrt(std::max(0.0, sum2 / n - mean * mean));
    EXPECT_NEAR(mean, want, 4 * sd / std::sqrt(double(n)) + 1e-6) << "from " << from.x;
    // By area, the weight cos A / (pmf r^2) reaches A / (pmf h^2) = 4e4
    // under the light (relative deviation above 10); by solid angle it is
    // cos Omega / pmf <= 2 pi / 0.5 (each triangle is selected by power, with
    // probability 1/2, whatever share of the solid angle it has).
    if (from.y > -0.1f) {
      EXPECT_LT(largest, 4 * M_PI) << "from " << from.x;
      EXPECT_LT(sd, 2 * mean) << "from " << from.x;
    }
  }
}

TEST(SphericalTriangle, TexturedLightGivesTheRadianceOfTheSampledPoint) {
  // An emission texture varying along the light (4 x 1 texels, bilinear):
  // NEE's estimate of the irradiance at a point must equal an independent
  // one, cosine-weighted directions traced to the light, whose hits read
  // the texture through Scene::intersect; near the light (solid angle,
  // where the sampled point's texture coordinates come from its
  // barycentrics) and far from it (area). Then again with the texture
  // read through a mirrored TEXCOORD_1 (both sides must read that set).
  for (auto [from, set] :
       {std::pair{Vec3(0.1f, 0, 0.05f), 0}, std::pair{Vec3(0.3f, -2.5f, 0.2f), 0},
        std::pair{Vec3(0.1f, 0, 0.05f), 1}, std::pair{Vec3(0.3f, -2.5f, 0.2f), 1}}) {
    SCOPED_TRACE(set);
    SceneData d;
    d.source = "light.gltf";
    Texture t;
    t.width = 4;
    t.height = 1;
    t.rgb = {0.2f, 0.2f, 0.2f, 1, 1, 1, 3, 3, 3, 0.5f, 0.5f, 0.5f};
    d.textures.push_back(t);
    Material m = testing::emitter(Vec3(1));
    m.emission_tex.index = 0;
    add_quad(d, Vec3(-0.5f, 0.02f, -0.5f), Vec3(0.5f, 0.02f, -0.5f), Vec3(0.5f, 0.02f, 0.5f),
             Vec3(-0.5f, 0.02f, 0.5f), m);
    if (set == 1) {
      d.uvs1 = d.uvs;
      for (Vec2& uv : d.uvs1) uv.x = 1.0f - uv.x;
      d.materials.back().emission_tex.uv.set = 1;
    }
    auto scene = make_scene(std::move(d));
    const int n = 200000;
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> uni(0.0f, 1.0f);
    double nee = 0, nee2 = 0, cosine = 0, cosine2 = 0;
    for (int s = 0; s < n; ++s) {
      LightSample ls;
      double w = 0;
      if (scene->sample_light(from, uni(rng), Vec2(uni(rng), uni(rng)), &ls) && ls.wi.y > 0)
        w = ls.radiance.x * ls.wi.y / ls.pdf;
      nee += w;
      nee2 += w * w;
      // Cosine-weighted about +y: E = pi * E[L].
      const float r = std::sqrt(uni(rng)), phi = 2 * kPi * uni(rng);
      const Vec3 dir(r * std::cos(phi), std::sqrt(std::max(0.0f, 1 - r * r)), r * std::sin(phi));
      SurfaceHit hit;
      const double c = scene->intersect({from, dir}, &hit) ? M_PI * hit.emission.x : 0.0;
      cosine += c;
      cosine2 += c * c;
    }
    const double mn = nee / n, mc = cosine / n;
    const double se = std::sqrt((nee2 / n - mn * mn) / n + (cosine2 / n - mc * mc) / n);
    EXPECT_GT(mn, 0.0);
    EXPECT_NEAR(mn, mc, 4 * se) << "from y " << from.y;
    EXPECT_LT(se, 0.02 * mc) << "from y " << from.y;  // enough power to see a wrong texel
  }
}

TEST(SphericalTriangle, ALightDoesNotLightItself) {
  // A tilted emitter with a white Lambertian base, alone in the scene: every
  // path that reaches it must return its emission exactly, since nothing can
  // reflect light back onto it. A hit point rounded to just behind the
  // light's plane sees its own triangles as a whole hemisphere by solid
  // angle; sampling them then added about 4% to the light (found as a +3.5%
  // bias of the whole Cornell box against Blender Cycles).
  SceneData d;
  d.source = "light.gltf";
  Material m = testing::diffuse(Vec3(0.8f), 1.0f);
  m.emission = Vec3(1);
  add_quad(d, Vec3(0.13f, 1.97f, -0.07f), Vec3(0.61f, 0.13f, 0.05f), Vec3(0.02f, 0.11f, 0.53f), m);
  auto scene = make_scene(std::move(d));
  const JobSpec spec = testing::make_spec(8, 8, Vec3(0, 0, 3), Vec3(0), 40.0f);
  IntegratorSettings settings;
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> uni(-1.0f, 1.0f);
  int paths = 0;
  double worst = 0;
  for (int i = 0; i < 4000; ++i) {
    const Vec3 target = Vec3(0.13f, 1.97f, -0.07f) + Vec3(0.61f, 0.13f, 0.05f) * uni(rng) +
                        Vec3(0.02f, 0.11f, 0.53f) * uni(rng);
    const Vec3 origin(uni(rng), 0.5f * uni(rng), uni(rng));
    PixelSampler sampler(spec.sampler, spec.seed, 0, i % 64, i / 64, Stream::kTest);
    sampler.start_sample(0);
    const Vec3 l = trace_path(*scene, {origin, normalize(target - origin)}, sampler, settings);
    worst = std::max(worst, double(std::fabs(l.x - 1.0f)));
    ++paths;
  }
  EXPECT_EQ(paths, 4000);
  EXPECT_LT(worst, 1e-5) << "a path gained light from the light itself";
}

}  // namespace
}  // namespace dofarm::render
