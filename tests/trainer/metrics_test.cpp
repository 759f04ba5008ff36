#include "trainer/metrics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

namespace dofarm::trainer {
namespace {

constexpr int kH = 48, kW = 40, kC = 3;

// The deterministic inputs described in data/ssim_fixture.txt (integer
// arithmetic only, so C++ and numpy produce the same float32 values).
struct Fixture {
  std::vector<float> a, b, d;
  Fixture() : a(kC * kH * kW), b(a.size()), d(a.size()) {
    for (int c = 0; c < kC; ++c)
      for (int y = 0; y < kH; ++y)
        for (int x = 0; x < kW; ++x) {
          size_t i = (size_t(c) * kH + y) * kW + x;
          double av = ((x * 7 + y * 3 + c * 50 + (x * y) % 13) % 256) / 255.0;
          uint64_t n =
              (uint64_t(x) * 1103515245u + uint64_t(y) * 12345u + uint64_t(c) * 2654435761u) %
              (uint64_t(1) << 31);
          double noise = (double(n % 201) - 100.0) / 1000.0;
          a[i] = float(av);
          b[i] = float(std::clamp(double(a[i]) + noise, 0.0, 1.0));
          d[i] = float(std::clamp(double(a[i]) * 0.5 + 0.25, 0.0, 1.0));
        }
  }
  ImageView view(const std::vector<float>& v) const { return {v.data(), kC, kH, kW}; }
};

std::map<std::string, double> load_reference_values() {
  std::ifstream in(std::string(DOFARM_SOURCE_DIR) + "/tests/trainer/data/ssim_fixture.txt");
  EXPECT_TRUE(in.good());
  std::map<std::string, double> out;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    std::string name;
    double v;
    ls >> name >> v;
    out[name] = v;
  }
  return out;
}

TEST(Ssim, EqualsScikitImageWithin1e6) {
  auto ref = load_reference_values();
  ASSERT_EQ(ref.size(), 3u);
  Fixture f;
  EXPECT_NEAR(ssim(f.view(f.a), f.view(f.b)), ref["noisy"], 1e-6);
  EXPECT_NEAR(ssim(f.view(f.a), f.view(f.d)), ref["contrast"], 1e-6);
  EXPECT_NEAR(ssim(f.view(f.a), f.view(f.a)), ref["same"], 1e-12);
}

TEST(Ssim, MaskSelectsPixelsAndEmptyMaskIsNaN) {
  Fixture f;
  std::vector<uint8_t> all(kH * kW, 1), none(kH * kW, 0);
  EXPECT_DOUBLE_EQ(ssim(f.view(f.a), f.view(f.b), all.data()), ssim(f.view(f.a), f.view(f.b)));
  EXPECT_TRUE(std::isnan(ssim(f.view(f.a), f.view(f.b), none.data())));
  // The halves of a mask average back to the whole (equal valid counts).
  std::vector<uint8_t> left(kH * kW, 0), right(kH * kW, 0);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) (x < kW / 2 ? left : right)[y * kW + x] = 1;
  double l = ssim(f.view(f.a), f.view(f.b), left.data());
  double r = ssim(f.view(f.a), f.view(f.b), right.data());
  EXPECT_NEAR(0.5 * (l + r), ssim(f.view(f.a), f.view(f.b)), 1e-12);
  EXPECT_NE(l, r);
}

// Several masks in one pass give each mask's own SSIM, bit for bit, and NaN
// for an empty one, whatever the order and overlap of the masks.
TEST(Ssim, PerMaskEqualsOneCallPerMask) {
  Fixture f;
  std::vector<uint8_t> left(kH * kW, 0), ring(kH * kW, 0), none(kH * kW, 0);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      left[y * kW + x] = x < kW / 2;
      ring[y * kW + x] = (x + y) % 3 == 0;
    }
  const std::vector<const uint8_t*> masks = {ring.data(), nullptr, none.data(), left.data()};
  const std::vector<double> s = ssim_per_mask(f.view(f.a), f.view(f.b), masks);
  ASSERT_EQ(s.size(), 4u);
  EXPECT_EQ(s[0], ssim(f.view(f.a), f.view(f.b), ring.data()));
  EXPECT_EQ(s[1], ssim(f.view(f.a), f.view(f.b)));
  EXPECT_TRUE(std::isnan(s[2]));
  EXPECT_EQ(s[3], ssim(f.view(f.a), f.view(f.b), left.data()));
  EXPECT_NE(s[0], s[3]);
}

// Per tile (report.json's denoised_tiles): each tile's sum over its count
// is the SSIM of a mask that keeps the tile's pixels and the region's, and
// the tiles add up to the region's SSIM; tiles that do not divide the image
// are cut at its edges.
TEST(Ssim, TilesAddUpToTheMaskAndEachIsItsOwnMask) {
  Fixture f;
  std::vector<uint8_t> left(kH * kW, 0);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) left[y * kW + x] = x < kW / 2;
  const std::vector<const uint8_t*> masks = {nullptr, left.data()};
  const int tile = 7;
  TiledSsim t;
  const std::vector<double> s = ssim_per_mask(f.view(f.a), f.view(f.b), masks, tile, &t);
  EXPECT_EQ(s, ssim_per_mask(f.view(f.a), f.view(f.b), masks));  // bit for bit
  ASSERT_EQ(t.tiles_x, (kW + tile - 1) / tile);
  ASSERT_EQ(t.tiles_y, (kH + tile - 1) / tile);
  ASSERT_EQ(t.sum.size(), 2u);
  for (size_t m = 0; m < masks.size(); ++m) {
    double total = 0, count = 0;
    for (size_t i = 0; i < t.sum[m].size(); ++i) total += t.sum[m][i], count += t.count[m][i];
    EXPECT_NEAR(total / count, s[m], 1e-12);
  }
  int checked = 0;
  for (int ty = 0; ty < t.tiles_y; ++ty)
    for (int tx = 0; tx < t.tiles_x; ++tx) {
      std::vector<uint8_t> in_tile(kH * kW, 0);
      for (int y = ty * tile; y < std::min(kH, (ty + 1) * tile); ++y)
        for (int x = tx * tile; x < std::min(kW, (tx + 1) * tile); ++x)
          in_tile[y * kW + x] = left[y * kW + x];
      const size_t i = size_t(ty) * t.tiles_x + tx;
      const double own = ssim(f.view(f.a), f.view(f.b), in_tile.data());
      if (t.count[1][i] == 0) {
        EXPECT_TRUE(std::isnan(own));  // no window centre of the region there
        continue;
      }
      // Three channels: the count is per channel value.
      EXPECT_NEAR(t.sum[1][i] / t.count[1][i], own, 1e-12) << tx << "," << ty;
      ++checked;
    }
  EXPECT_GT(checked, 2);
}

TEST(Psnr, KnownValueAndCapForIdenticalImages) {
  std::vector<float> a(3 * 4 * 4, 0.5f), b(a.size(), 0.6f);
  ImageView va{a.data(), 3, 4, 4}, vb{b.data(), 3, 4, 4};
  EXPECT_NEAR(psnr(va, vb), 20.0, 1e-4);  // mse 0.01
  EXPECT_EQ(psnr(va, va), kPsnrCap);
}

TEST(RelativeMse, MatchesDefinition) {
  std::vector<float> r = {0.0f, 1.0f, 10.0f}, d = {0.1f, 1.5f, 10.0f};
  ImageView vr{r.data(), 1, 1, 3}, vd{d.data(), 1, 1, 3};
  double expect = (0.01 / 0.01 + 0.25 / 1.01 + 0.0) / 3.0;
  EXPECT_NEAR(relative_mse(vd, vr), expect, 1e-6);
  uint8_t mask[3] = {0, 1, 0};
  EXPECT_NEAR(relative_mse(vd, vr, mask), 0.25 / 1.01, 1e-6);
}

TEST(DisplayEncode, SrgbCurveAndClamp) {
  EXPECT_FLOAT_EQ(srgb_encode_clamped(0.0f), 0.0f);
  EXPECT_FLOAT_EQ(srgb_encode_clamped(-1.0f), 0.0f);
  EXPECT_FLOAT_EQ(srgb_encode_clamped(NAN), 0.0f);
  EXPECT_FLOAT_EQ(srgb_encode_clamped(1.0f), 1.0f);
  EXPECT_FLOAT_EQ(srgb_encode_clamped(7.0f), 1.0f);
  EXPECT_NEAR(srgb_encode_clamped(0.18f), 0.4613f, 1e-4);    // middle grey
  EXPECT_NEAR(srgb_encode_clamped(0.002f), 0.02584f, 1e-6);  // linear toe
}

// Flicker (temporal_relative_mse) on a known two-pixel sequence, values by
// hand: pixel 0 of a still reference (1) is denoised as 1.1, 0.9 (wobbling)
// or 1.1, 1.1 (steady); pixel 1 is exact (0). Each frame alone is equally
// wrong either way (|error| 0.1), so only the flicker tells them apart.
TEST(Metrics, FlickerScoresAWobblingOutputAboveASteadyOneOnAStillReference) {
  const std::vector<float> ref = {1.0f, 0.0f};
  const std::vector<float> up = {1.1f, 0.0f}, down = {0.9f, 0.0f};
  auto v = [](const std::vector<float>& x) { return ImageView{x.data(), 1, 1, 2}; };
  // Per-frame relative MSE is the same for both outputs: 0.01 / 1.01 / 2.
  EXPECT_NEAR(relative_mse(v(up), v(ref)), 0.01 / 1.01 / 2, 1e-7);
  EXPECT_NEAR(relative_mse(v(down), v(ref)), 0.01 / 1.01 / 2, 1e-7);
  // Wobbling: pixel 0 changes by -0.2 where the reference does not:
  // (0.2^2 / (1^2 + 0.01) + 0) / 2.
  const double wobble = temporal_relative_mse(v(up), v(down), v(ref), v(ref));
  EXPECT_NEAR(wobble, 0.04 / 1.01 / 2, 1e-7);
  EXPECT_EQ(temporal_relative_mse(v(up), v(up), v(ref), v(ref)), 0.0);  // steady
  // In-focus / out-of-focus split: only pixel 0 counted, or only pixel 1.
  const uint8_t first[2] = {1, 0}, second[2] = {0, 1}, none[2] = {0, 0};
  EXPECT_NEAR(temporal_relative_mse(v(up), v(down), v(ref), v(ref), first), 0.04 / 1.01, 1e-7);
  EXPECT_EQ(temporal_relative_mse(v(up), v(down), v(ref), v(ref), second), 0.0);
  EXPECT_TRUE(std::isnan(temporal_relative_mse(v(up), v(down), v(ref), v(ref), none)));
}

// A change the reference makes costs nothing when the output makes it too,
// and a frozen output is charged for it, relative to the mean brightness
// m = (1 + 2) / 2: 1^2 / (1.5^2 + 0.01) on pixel 0.
TEST(Metrics, FlickerChargesOnlyTheDifferenceFromTheReferencesChange) {
  const std::vector<float> r0 = {1.0f, 0.0f}, r1 = {2.0f, 0.0f};
  const std::vector<float> d0 = {1.1f, 0.0f}, d1 = {2.1f, 0.0f};
  auto v = [](const std::vector<float>& x) { return ImageView{x.data(), 1, 1, 2}; };
  EXPECT_NEAR(temporal_relative_mse(v(d0), v(d1), v(r0), v(r1)), 0.0, 1e-12);
  EXPECT_NEAR(temporal_relative_mse(v(r0), v(r0), v(r0), v(r1)), 1.0 / 2.26 / 2, 1e-7);
}

}  // namespace
}  // namespace dofarm::trainer
