// Piecewise-constant distributions and the environment light's sampling:
// every sampler delivers the density its pdf claims, and the guide-table
// search finds the cell of a plain CDF inversion.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "chi2.h"
#include "tests/render/same_bits.h"
#include "worker/render/bsdf.h"
#include "worker/render/distribution.h"
#include "worker/render/environment.h"
#include "worker/render/simd.h"

namespace dofarm::render {
namespace {

// Weights with what breaks searches: zero runs at both ends and inside, one
// heavy cell, a size that is not a power of two.
std::vector<std::vector<float>> awkward_weights() {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  std::vector<float> random(1000);
  for (float& w : random) w = uni(rng) < 0.3f ? 0.0f : uni(rng);
  std::vector<float> peaked(513, 1e-3f);
  peaked[200] = 1e4f;
  return {{1.0f},
          {0.0f, 0.0f, 2.0f, 0.0f, 1.0f, 0.0f, 0.0f},
          {3.0f, 0.0f, 0.0f, 0.0f, 0.0f, 1.0f},
          {0.0f, 0.0f, 0.0f},  // all zero: uniform
          random,
          peaked};
}

// The discrete pmf is the probability that sample_discrete() picks the cell:
// on a fine uniform grid of u the share of each cell equals its pmf to the
// grid step, the cell never decreases with u (inversion, which keeps
// stratified points stratified), and a zero cell is never picked.
TEST(Distribution1D, DiscreteSamplesFollowThePmfAndAreMonotone) {
  constexpr int kGrid = 1 << 20;
  for (const auto& w : awkward_weights()) {
    Distribution1D dist(w);
    std::vector<double> count(w.size(), 0.0);
    size_t last = 0;
    for (int k = 0; k < kGrid; ++k) {
      const float u = float(k) / float(kGrid);
      float pmf, remapped;
      const size_t i = dist.sample_discrete(u, &pmf, &remapped);
      ASSERT_LT(i, w.size());
      ASSERT_GE(i, last) << "u = " << u;
      ASSERT_GT(pmf, 0.0f) << "picked a zero cell " << i << " at u = " << u;
      ASSERT_EQ(pmf, dist.pmf(i));
      ASSERT_GE(remapped, 0.0f);
      ASSERT_LT(remapped, 1.0f);
      last = i;
      count[i] += 1;
    }
    double pmf_sum = 0;
    for (size_t i = 0; i < w.size(); ++i) {
      EXPECT_NEAR(count[i] / kGrid, dist.pmf(i), 2.0 / kGrid) << "cell " << i << " of " << w.size();
      pmf_sum += dist.pmf(i);
    }
    EXPECT_NEAR(pmf_sum, 1.0, 1e-6);
  }
}

// The guide table must land where a binary search of the CDF lands, also
// exactly on cell boundaries and at the ends of [0, 1).
TEST(Distribution1D, GuideTableFindsTheCellOfABinarySearch) {
  for (const auto& w : awkward_weights()) {
    Distribution1D dist(w);
    // The CDF as the pmfs give it; a boundary u = cdf[i] belongs to the first
    // non-empty cell at or after i.
    std::vector<double> cdf(w.size() + 1, 0.0);
    for (size_t i = 0; i < w.size(); ++i) cdf[i + 1] = cdf[i] + dist.pmf(i);
    std::vector<float> us = {0.0f, 0x1.fffffep-1f, 0.5f, 0.25f, 0.75f};
    for (size_t i = 0; i <= w.size(); ++i) {
      float c = float(cdf[i]);
      for (float v : {c, std::nextafter(c, 0.0f), std::nextafter(c, 1.0f)})
        if (v >= 0.0f && v < 1.0f) us.push_back(v);
    }
    for (float u : us) {
      const size_t i = dist.sample_discrete(u, nullptr);
      const float x = dist.sample_continuous(u, nullptr);
      EXPECT_GT(dist.pmf(i), 0.0f) << "u = " << u;
      // Within the cell's own [start, end), up to the float rounding of the
      // pmf sums above.
      EXPECT_GE(double(u), cdf[i] - 1e-6) << "u = " << u << ", cell " << i;
      EXPECT_LE(double(u), cdf[i + 1] + 1e-6) << "u = " << u << ", cell " << i;
      EXPECT_GE(x, float(i) / float(w.size()) - 1e-6f);
      EXPECT_LE(x, float(i + 1) / float(w.size()) + 1e-6f);
    }
  }
}

// Continuous samples: a histogram over bins finer than the cells against the
// integral of pdf() over each bin (piecewise constant, so exact per bin).
TEST(Distribution1D, ContinuousSamplesFollowThePdf) {
  std::vector<float> w = {0.0f, 1.0f, 4.0f, 0.0f, 0.5f, 2.0f, 0.0f};
  Distribution1D dist(w);
  constexpr int kBinsPerCell = 8, kSamples = 400000;
  const int bins = int(w.size()) * kBinsPerCell;
  std::vector<double> observed(bins, 0.0);
  std::mt19937_64 rng(11);
  for (int s = 0; s < kSamples; ++s) {
    const float u = float(rng() >> 40) * 0x1p-24f;
    float pdf;
    const float x = dist.sample_continuous(u, &pdf);
    ASSERT_GE(x, 0.0f);
    ASSERT_LT(x, 1.0f);
    ASSERT_FLOAT_EQ(pdf, dist.pdf(x));
    observed[std::min(bins - 1, int(x * float(bins)))] += 1;
  }
  double stat = 0, integral = 0;
  int dof = -1;
  for (int b = 0; b < bins; ++b) {
    const double mass = dist.pdf((float(b) + 0.5f) / float(bins)) / bins;
    integral += mass;
    if (mass == 0) {
      EXPECT_EQ(observed[b], 0) << "bin " << b << " has no density but got samples";
      continue;
    }
    const double e = mass * kSamples;
    stat += (observed[b] - e) * (observed[b] - e) / e;
    ++dof;
  }
  EXPECT_NEAR(integral, 1.0, 1e-6);
  EXPECT_GT(test::chi2_p_value(stat, dof), 1e-4) << "chi2 = " << stat << ", dof = " << dof;
}

// Over the unit square: sample() delivers pdf() (chi-square over the cells),
// the pdf it reports is pdf() at the sample, and pdf() integrates to 1.
TEST(Distribution2D, SamplesFollowThePdf) {
  constexpr int nu = 12, nv = 7, kSamples = 400000;
  std::vector<float> w(nu * nv);
  std::mt19937 gen(5);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (float& x : w) x = uni(gen) < 0.2f ? 0.0f : uni(gen) * uni(gen);
  Distribution2D dist(w, nu, nv);
  std::vector<double> observed(nu * nv, 0.0);
  std::mt19937_64 rng(17);
  auto uniform = [&] { return float(rng() >> 40) * 0x1p-24f; };
  for (int s = 0; s < kSamples; ++s) {
    Vec2 u(uniform(), uniform());
    float pdf;
    Vec2 p = dist.sample(u, &pdf);
    ASSERT_GT(pdf, 0.0f);
    ASSERT_FLOAT_EQ(pdf, dist.pdf(p));
    const int x = std::min(nu - 1, int(p.x * nu)), y = std::min(nv - 1, int(p.y * nv));
    observed[y * nu + x] += 1;
  }
  double stat = 0, integral = 0;
  int dof = -1;
  for (int y = 0; y < nv; ++y)
    for (int x = 0; x < nu; ++x) {
      const double mass = dist.pdf(Vec2((x + 0.5f) / nu, (y + 0.5f) / nv)) / (nu * nv);
      integral += mass;
      if (mass == 0) {
        EXPECT_EQ(observed[y * nu + x], 0) << "cell " << x << "," << y;
        continue;
      }
      const double e = mass * kSamples, o = observed[y * nu + x];
      stat += (o - e) * (o - e) / e;
      ++dof;
    }
  EXPECT_NEAR(integral, 1.0, 1e-5);
  EXPECT_GT(test::chi2_p_value(stat, dof), 1e-4) << "chi2 = " << stat << ", dof = " << dof;
}

// The compact 2D table (the environment map's block table) as a 1D
// distribution (one row): every cell is picked with its pmf on a fine grid
// of u, the cell never decreases with u, zero cells are never picked, the
// pmf is weight / total to float precision, and the boundaries are exact: u
// at a cell's start picks that cell, the float below it an earlier one. Rows
// of 256 cells (one summary line, full) and of 5000 (a summary of 20 lines)
// are among the sizes.
TEST(CompactDistribution2D, OneRowFollowsThePmfWithExactBoundaries) {
  auto sets = awkward_weights();
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (int n : {16, 17, 256, 5000}) {
    std::vector<float> w(static_cast<size_t>(n));
    for (float& x : w) x = uni(rng) < 0.25f ? 0.0f : uni(rng) * uni(rng);
    w[size_t(n) - 1] = 0.0f;  // trailing zero cells
    sets.push_back(w);
  }
  constexpr int kGrid = 1 << 20;
  for (const auto& wf : sets) {
    const std::vector<double> w(wf.begin(), wf.end());
    const int n = int(w.size());
    const CompactDistribution2D dist(w, n, 1);
    double total = 0;
    for (double x : w) total += x;
    std::vector<double> count(w.size(), 0.0);
    size_t last = 0;
    for (int k = 0; k < kGrid; ++k) {
      Vec2 r;
      const size_t i = dist.sample_discrete(Vec2(float(k) / float(kGrid), 0.5f), &r);
      ASSERT_LT(i, w.size());
      ASSERT_GE(i, last) << "u = " << float(k) / float(kGrid);
      ASSERT_GT(dist.pmf(i), 0.0) << "picked a zero cell " << i;
      ASSERT_GE(r.x, 0.0f);
      ASSERT_LT(r.x, 1.0f);
      last = i;
      count[i] += 1;
    }
    double pmf_sum = 0, start = 0;
    for (int i = 0; i < n; ++i) {
      const double p = dist.pmf(size_t(i));
      EXPECT_NEAR(count[i] / kGrid, p, 1.0 / kGrid + 1e-12) << "cell " << i << " of " << n;
      const double want = total > 0 ? w[i] / total : 1.0 / n;
      EXPECT_NEAR(p, want, 1e-6 * want + 1.2e-7) << "cell " << i << " of " << n;
      // Partial sums of the exact float differences are the float starts.
      if (p > 0) {
        const float s = float(start);
        Vec2 r;
        EXPECT_EQ(dist.sample_discrete(Vec2(s, 0.5f), &r), size_t(i)) << "start of " << i;
        EXPECT_EQ(r.x, 0.0f);
        if (s > 0) {
          const size_t below = dist.sample_discrete(Vec2(std::nextafter(s, 0.0f), 0.5f), &r);
          EXPECT_LT(below, size_t(i)) << "below the start of " << i;
          EXPECT_GT(dist.pmf(below), 0.0);
        }
      }
      start += p;
      pmf_sum += p;
    }
    EXPECT_NEAR(pmf_sum, 1.0, 1e-12);
    // Outside [0, 1) clamps: the first and the last cell with weight.
    Vec2 r;
    EXPECT_EQ(dist.sample_discrete(Vec2(-1.0f, 0.5f), &r), dist.sample_discrete(Vec2(0.0f, 0.5f), &r));
    EXPECT_EQ(dist.sample_discrete(Vec2(1.0f, 0.5f), &r),
              dist.sample_discrete(Vec2(0x1.fffffep-1f, 0.5f), &r));
  }
}

// Rows then columns: on a grid of u the number of points in a cell is the
// number of rows of the grid in the row's interval times the columns in the
// column's interval, so it is pmf * N up to the edges of the two intervals;
// the pmf is the cell's weight over the total.
TEST(CompactDistribution2D, RowsThenColumnsFollowThePmf) {
  constexpr int nu = 37, nv = 300, kX = 1 << 11, kY = 1 << 12;
  std::vector<double> w(size_t(nu) * nv);
  std::mt19937 gen(21);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (double& x : w) x = uni(gen) < 0.2 ? 0.0 : uni(gen) * uni(gen);
  for (int x = 0; x < nu; ++x) w[size_t(7) * nu + x] = 0.0;  // an empty row
  w[size_t(150) * nu + 36] = 50.0;                            // a sun at a row's end
  double total = 0;
  for (double x : w) total += x;
  const CompactDistribution2D dist(w, nu, nv);
  std::vector<double> count(w.size(), 0.0);
  for (int j = 0; j < kY; ++j)
    for (int i = 0; i < kX; ++i) {
      Vec2 r;
      const size_t c = dist.sample_discrete(Vec2((i + 0.5f) / kX, (j + 0.5f) / kY), &r);
      ASSERT_LT(c, w.size());
      ASSERT_GT(w[c], 0.0) << "cell " << c;
      ASSERT_TRUE(r.x >= 0.0f && r.x < 1.0f && r.y >= 0.0f && r.y < 1.0f);
      count[c] += 1;
    }
  double pmf_sum = 0;
  for (size_t c = 0; c < w.size(); ++c) {
    const double p = dist.pmf(c);
    pmf_sum += p;
    // Row and column probabilities each come from two float starts, so each
    // is within 2^-24 of its exact value: p = pr pc is within 2^-24 (pr + pc).
    const size_t row = c / nu;
    double row_w = 0;
    for (int x = 0; x < nu; ++x) row_w += w[row * nu + size_t(x)];
    if (row_w > 0) {
      EXPECT_NEAR(p, w[c] / total, 0x1p-24 * (row_w / total + w[c] / row_w) + 1e-15)
          << "cell " << c;
    }
    // Rows of the grid in the row's interval: kY * pmf_row +- 1; likewise
    // columns. pmf_row from the row's cells.
    double row_p = 0;
    for (int x = 0; x < nu; ++x) row_p += dist.pmf(row * nu + size_t(x));
    if (row_p <= 0) continue;
    const double a = kY * row_p, b = kX * p / row_p;
    EXPECT_LE(std::fabs(count[c] - a * b), a + b + 1) << "cell " << c;
  }
  EXPECT_NEAR(pmf_sum, 1.0, 1e-9);
}

// A w x h map whose texel (x, y) has the radiance rgb(x, y).
template <class Rgb>
RgbImage map_of(int w, int h, Rgb rgb) {
  RgbImage img;
  img.width = w;
  img.height = h;
  img.rgb.resize(size_t(w) * h * 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const Vec3 v = rgb(x, y);
      float* t = &img.rgb[(size_t(y) * w + x) * 3];
      t[0] = v.x;
      t[1] = v.y;
      t[2] = v.z;
    }
  return img;
}

RgbImage sky_with_a_sun() {
  RgbImage img;
  img.width = 32;
  img.height = 16;
  img.rgb.assign(size_t(32) * 16 * 3, 0.0f);
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 32; ++x)
      for (int c = 0; c < 3; ++c) img.rgb[(size_t(y) * 32 + x) * 3 + c] = 0.1f + 0.05f * (x % 5);
  for (int y = 12; y < 16; ++y)  // a black ground: no samples may go there
    for (int x = 0; x < 32; ++x)
      for (int c = 0; c < 3; ++c) img.rgb[(size_t(y) * 32 + x) * 3 + c] = 0.0f;
  for (int c = 0; c < 3; ++c) img.rgb[(size_t(3) * 32 + 20) * 3 + c] = 200.0f;
  return img;
}

// The environment's sampled directions pass a chi-square test against the
// solid-angle density pdf() claims, which integrates to 1 over the sphere.
void expect_samples_follow_pdf(const Environment& env, test::SphereCells cells, int samples) {
  test::Chi2Options opt;
  opt.cells = cells;
  opt.samples = samples;
  auto sample = [&](Vec2 u) -> std::optional<Vec3> {
    EnvSample s = env.sample(u);
    if (!(s.pdf > 0)) return std::nullopt;
    return s.wi;
  };
  auto pdf = [&](Vec3 d) { return env.pdf(d); };
  test::Chi2Result r = test::chi2_test(sample, pdf, opt);
  EXPECT_NEAR(r.pdf_integral, 1.0, 2e-3) << r.summary();
  EXPECT_GT(r.p_value, 1e-4) << r.summary();
  EXPECT_EQ(r.outside_support, 0) << r.summary();
}

// The environment's directions have the solid-angle density pdf() claims,
// which integrates to 1 over the sphere; the two-output eval() agrees with
// eval() and pdf(); a sample's radiance and pdf are those of its direction.
TEST(Environment, SamplesFollowThePdfOverTheSphere) {
  const Environment env(sky_with_a_sun(), 1.0f, 30.0f);
  expect_samples_follow_pdf(env, test::SphereCells{Vec3(0, 1, 0), 0.0, 24, 48}, 300000);

  std::mt19937_64 rng(23);
  auto uniform = [&] { return float(rng() >> 40) * 0x1p-24f; };
  for (int i = 0; i < 2000; ++i) {
    EnvSample s = env.sample(Vec2(uniform(), uniform()));
    ASSERT_GT(s.pdf, 0.0f);
    float p;
    Vec3 le = env.eval(s.wi, &p);
    EXPECT_NEAR(p, s.pdf, 2e-3f * s.pdf);
    EXPECT_EQ(le.x, env.eval(s.wi).x);
    EXPECT_EQ(p, env.pdf(s.wi));
    EXPECT_NEAR(s.radiance.x, le.x, 1e-6f);
  }
}

// A map whose size is not a multiple of the 4x4 blocks (the last blocks
// overhang the edge), with zero rows and columns inside blocks, a sun and a
// black ground: the blocked tables must still give every texel exactly the
// probability weight / total that one table over all texels gives, and never
// sample past the edge.
RgbImage awkward_sky() {
  RgbImage img;
  img.width = 30;
  img.height = 15;
  img.rgb.assign(size_t(30) * 15 * 3, 0.0f);
  for (int y = 0; y < 11; ++y)
    for (int x = 0; x < 30; ++x) {
      if (x % 7 == 3 || y == 5) continue;  // zero columns and a zero row
      for (int c = 0; c < 3; ++c) img.rgb[(size_t(y) * 30 + x) * 3 + c] = 0.05f + 0.1f * (x % 3);
    }
  for (int c = 0; c < 3; ++c) img.rgb[(size_t(2) * 30 + 29) * 3 + c] = 300.0f;  // at the edge
  return img;
}

TEST(Environment, BlockedTablesGiveEachTexelItsWeightOverTheTotal) {
  const RgbImage img = awkward_sky();
  const Environment env(img, 1.0f, 0.0f);
  const int w = img.width, h = img.height;
  std::vector<double> weight(size_t(w) * h);
  double total = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float* t = &img.rgb[(size_t(y) * w + x) * 3];
      const double wt =
          double(luminance(Vec3(t[0], t[1], t[2]))) * std::sin(kPi * (y + 0.5f) / float(h));
      weight[size_t(y) * w + x] = wt;
      total += wt;
    }
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      // The direction through the texel's centre (the map's convention,
      // environment.h: phi = atan2(d.x, -d.z), u = phi / 2pi + 1/2).
      const float theta = kPi * (y + 0.5f) / float(h);
      const float phi = kTwoPi * ((x + 0.5f) / float(w) - 0.5f);
      const Vec3 d(std::sin(theta) * std::sin(phi), std::cos(theta),
                   -std::sin(theta) * std::cos(phi));
      // pdf over the unit square = probability * w * h.
      const double pdf_uv = double(env.pdf(d)) * 2.0 * kPi * kPi * std::sin(theta);
      const double want = weight[size_t(y) * w + x] / total * w * h;
      EXPECT_NEAR(pdf_uv, want, 1e-4 * want + 1e-9) << "texel " << x << ", " << y;
    }
}

// Direction to texel (environment.h's mapping, evaluated without libm's
// atan2): every direction lands in the texel that the mapping computed in
// double with std::atan2 gives, unless it lies within 1e-4 of a texel's
// width of a texel edge (float rounding may go either way there). Each
// texel's radiance names it: (x + 1, y + 1, 1).
TEST(Environment, EveryDirectionFindsItsTexel) {
  constexpr int w = 96, h = 48;
  const RgbImage img =
      map_of(w, h, [](int x, int y) { return Vec3(float(x + 1), float(y + 1), 1); });
  const double rotation = 30.0 * M_PI / 180.0;
  const Environment env(img, 1.0f, 30.0f);
  std::mt19937_64 rng(31);
  std::normal_distribution<double> normal;
  int checked = 0;
  for (int i = 0; i < 200000; ++i) {
    double d[3] = {normal(rng), normal(rng), normal(rng)};
    if (i < 8) {  // the axes and octant edges too
      d[0] = (i & 1) ? 0.0 : (i & 2 ? -1.0 : 1.0);
      d[1] = (i & 4) ? 1.0 : 0.0;
      d[2] = (i & 1) ? 1.0 : 0.0;
    }
    const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    const Vec3 dir(float(d[0] / len), float(d[1] / len), float(d[2] / len));
    const double theta = std::atan2(std::hypot(double(dir.x), double(dir.z)), double(dir.y));
    double u = (std::atan2(double(dir.x), -double(dir.z)) - rotation) / (2 * M_PI) + 0.5;
    u -= std::floor(u);
    const double fx = u * w, fy = theta / M_PI * h;
    auto near_edge = [](double f) { return std::fabs(f - std::round(f)) < 1e-4; };
    if (near_edge(fx) || near_edge(fy)) continue;
    const int x = std::min(w - 1, int(fx)), y = std::min(h - 1, int(fy));
    const Vec3 le = env.eval(dir);
    ASSERT_EQ(le.x, float(x + 1)) << dir.x << " " << dir.y << " " << dir.z;
    ASSERT_EQ(le.y, float(y + 1)) << dir.x << " " << dir.y << " " << dir.z;
    float p;
    EXPECT_EQ(env.eval(env.locate(dir), dir, &p).x, le.x);
    EXPECT_EQ(p, env.pdf(dir));
    ++checked;
  }
  EXPECT_GT(checked, 199000);
}

// Environment::locate of a batch (AVX2 lanes where the CPU has them) finds
// each direction's texel as locate() of it alone, with and without AVX2, for
// every batch size and for more than eight directions; directions on the
// axes, the poles, the seam behind the map and both signs of zero included.
TEST(Environment, BatchedLocateIsTheSingleLocate) {
  const RgbImage img = map_of(96, 48, [](int, int) { return Vec3(1.0f); });
  SimdRestore restore;
  std::mt19937_64 rng(37);
  std::normal_distribution<float> normal;
  std::vector<Vec3> dirs = {{0, 1, 0},      {0, -1, 0},      {-0.0f, 1, -0.0f}, {1, 0, 0},
                            {-1, 0, 0},     {0, 0, 1},       {0, 0, -1},        {-0.0f, 0, 1},
                            {1e-30f, 0, 1}, {-1e-30f, 0, 1}, {0.6f, 0, 0.8f},   {0, 0.6f, -0.8f}};
  while (dirs.size() < 77 * 60)
    dirs.push_back(normalize(Vec3(normal(rng), normal(rng), normal(rng))));
  for (float rotation : {0.0f, 30.0f, -250.0f}) {
    const Environment env(img, 1.0f, rotation);
    for (bool simd : {true, false}) {
      allow_simd(simd);
      int differ = 0;
      size_t i = 0;
      for (int n : {8, 1, 3, 8, 5, 13, 2, 7, 8, 16, 6})
        for (int rep = 0; rep < 60 && i + size_t(n) <= dirs.size(); ++rep, i += size_t(n)) {
          Environment::Located got[16];
          env.locate(&dirs[i], n, got);
          for (int k = 0; k < n; ++k)
            differ += got[k].texel != env.locate(dirs[i + size_t(k)]).texel;
        }
      EXPECT_EQ(i, dirs.size());
      EXPECT_EQ(differ, 0) << "rotation " << rotation << (simd ? ", AVX2" : ", scalar");
    }
  }
  // A constant environment has no texels.
  const Environment constant(Vec3(0.5f));
  Environment::Located got[3];
  constant.locate(dirs.data(), 3, got);
  for (const Environment::Located& l : got) EXPECT_EQ(l.texel, nullptr);
}

// Environment::sample of several choices (a batch's light samples, AVX2
// lanes where the CPU has them) gives each choice's sample(choice) bit for
// bit, with and without AVX2: a map with black texels and rows (samples of
// pdf 0 among the others), a width that is no multiple of the blocks,
// numbers at 0 and just below 1, every batch size.
TEST(Environment, BatchedSamplesAreTheSingleSamples) {
  const RgbImage img = map_of(90, 45, [](int x, int y) {
    const float v = (y % 7 == 3 || (x + y) % 5 == 0) ? 0.0f : 0.1f + float((x * 13 + y * 7) % 17);
    return Vec3(v, 0.5f * v, 1.0f);
  });
  SimdRestore restore;
  std::mt19937_64 rng(59);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (float rotation : {0.0f, 75.0f}) {
    const Environment env(img, 1.0f, rotation);
    std::vector<Environment::Choice> choices;
    for (float a : {0.0f, 0x1.fffffep-1f, 0.5f})
      for (float b : {0.0f, 0x1.fffffep-1f, 0.25f}) choices.push_back(env.choose(Vec2(a, b)));
    while (choices.size() < 77 * 40) choices.push_back(env.choose(Vec2(uni(rng), uni(rng))));
    for (bool simd : {true, false}) {
      allow_simd(simd);
      int differ = 0, zero = 0;
      size_t i = 0;
      for (int n : {8, 1, 3, 8, 5, 13, 2, 7, 8, 16, 6})
        for (int rep = 0; rep < 40 && i + size_t(n) <= choices.size(); ++rep, i += size_t(n)) {
          EnvSample got[16];
          env.sample(&choices[i], n, got);
          for (int k = 0; k < n; ++k) {
            const EnvSample want = env.sample(choices[i + size_t(k)]);
            zero += !(want.pdf > 0);
            differ +=
                !(test::same_bits(got[k].pdf, want.pdf) && test::same_bits(got[k].wi, want.wi) &&
                  test::same_bits(got[k].radiance, want.radiance));
          }
        }
      EXPECT_EQ(i, choices.size());
      EXPECT_EQ(differ, 0) << "rotation " << rotation << (simd ? ", AVX2" : ", scalar");
      RecordProperty("samples_of_pdf_0", zero);
    }
  }
}

// choose(u, n) makes choose(u)'s choice, and marks it below exactly when
// its block lies wholly below the plane of n: every sample of a marked
// choice points below n (so a BSDF that rejects directions below its
// geometric normal returns 0 for it), and every sample further below than
// the bound on a block's angular radius allows is marked. Maps with blocks
// past their edge (90 x 45) and whole ones (256 x 128), turned and not;
// batched (AVX2) and single samples.
TEST(Environment, ChoicesBelowASurfaceHaveEverySampleBelowIt) {
  SimdRestore restore;
  std::mt19937_64 rng(61);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  auto unit_vector = [&] {
    const float z = 1.0f - 2.0f * uni(rng), phi = kTwoPi * uni(rng);
    const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
    return Vec3(r * std::cos(phi), z, r * std::sin(phi));
  };
  for (int size : {90, 256})
    for (float rotation : {0.0f, 75.0f}) {
      const int w = size, h = size / 2;
      const RgbImage img = map_of(w, h, [](int x, int y) {
        const float v = (x + 2 * y) % 9 == 0 ? 0.0f : 0.2f + float((x * 7 + y * 3) % 11);
        return Vec3(v, 0.5f * v, 1.0f);
      });
      const Environment env(img, 1.0f, rotation);
      // The bound the marking may not be looser than: twice a block's
      // angular radius (its centre within one radius of the sample, and
      // the plane within one more), plus the margin, plus slack.
      const float radius = 0.5f * (kPi * 4.0f / float(h) + kTwoPi * 4.0f / float(w));
      const float sure_cos = -std::sin(2.0f * radius + 2e-3f);
      // A white diffuse BSDF and a rough dielectric with n as geometric normal.
      int marked = 0, unmarked_far = 0, above = 0, lit = 0, total = 0;
      std::vector<Environment::Choice> batch;
      std::vector<Vec3> normals;
      for (int i = 0; i < 20000; ++i) {
        const Vec3 n = unit_vector();
        const Vec2 u(uni(rng), uni(rng));
        const Environment::Choice plain = env.choose(u);
        const Environment::Choice c = env.choose(u, n);
        ASSERT_EQ(c.block, plain.block);
        ASSERT_TRUE(test::same_bits(c.r.x, plain.r.x) && test::same_bits(c.r.y, plain.r.y));
        EXPECT_FALSE(plain.below);
        EXPECT_FALSE(env.choose(u, n * 2.0f).below);  // not a unit normal: never marked
        batch.push_back(c);
        normals.push_back(n);
      }
      for (bool simd : {true, false}) {
        allow_simd(simd);
        std::vector<EnvSample> got(batch.size());
        for (size_t i = 0; i < batch.size(); i += 8)
          env.sample(&batch[i], int(std::min<size_t>(8, batch.size() - i)), &got[i]);
        for (size_t i = 0; i < batch.size(); ++i) {
          const EnvSample& s = got[i];
          if (!(s.pdf > 0)) continue;
          ++total;
          const Vec3& n = normals[i];
          const float cos_n = dot(s.wi, n);
          if (batch[i].below) {
            ++marked;
            above += !(cos_n < 0.0f);
            const Vec3 ns = normalize(n + unit_vector() * 0.2f);
            for (float metallic : {0.0f, 1.0f}) {
              const Bsdf bsdf(dot(ns, n) > 0 ? ns : n, n, Vec3(1.0f), metallic, 0.5f, 1.5f);
              ASSERT_TRUE(bsdf.in_lanes());
              float pdf = -1;
              const Vec3 f = bsdf.evaluate(normalize(n + unit_vector() * 0.5f), s.wi, &pdf);
              lit += max_component(f) > 0 || pdf != 0;
            }
          } else {
            unmarked_far += cos_n < sure_cos;
          }
        }
      }
      SCOPED_TRACE(testing::Message() << w << " x " << h << ", rotation " << rotation);
      EXPECT_EQ(above, 0);
      EXPECT_EQ(lit, 0);
      EXPECT_EQ(unmarked_far, 0);
      // Random normals see about half of the sky: a good share is marked.
      EXPECT_GT(marked, total / 4);
    }
}

TEST(Environment, SamplesFollowThePdfOnAMapNotMadeOfWholeBlocks) {
  const Environment env(awkward_sky(), 1.0f, 0.0f);
  expect_samples_follow_pdf(env, test::SphereCells{Vec3(0, 1, 0), 0.0, 15, 30}, 200000);
  // Every sample is a texel of the map with that texel's radiance and pdf.
  for (int i = 0; i < 64; ++i)
    for (int j = 0; j < 64; ++j) {
      EnvSample s = env.sample(Vec2((i + 0.5f) / 64, (j + 0.5f) / 64));
      if (!(s.pdf > 0)) continue;
      float p;
      const Vec3 le = env.eval(s.wi, &p);
      EXPECT_NEAR(p, s.pdf, 1e-3f * s.pdf);
      EXPECT_EQ(le.x, s.radiance.x);
    }
}

}  // namespace
}  // namespace dofarm::render
