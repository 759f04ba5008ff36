#include "trainer/metrics.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "common/error.h"

namespace dofarm::trainer {

float srgb_encode_clamped(float v) {
  if (!(v > 0.0f)) return 0.0f;  // negatives and NaN display as black
  float e = v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
  return std::min(e, 1.0f);
}

std::vector<float> display_encode(ImageView img) {
  size_t n = size_t(img.channels) * img.plane();
  std::vector<float> out(n);
  for (size_t i = 0; i < n; ++i) out[i] = srgb_encode_clamped(img.data[i]);
  return out;
}

namespace {

void check_same_shape(ImageView a, ImageView b) {
  DOFARM_CHECK_EQ(a.channels, b.channels);
  DOFARM_CHECK_EQ(a.height, b.height);
  DOFARM_CHECK_EQ(a.width, b.width);
}

// The mean over the pixels `mask` keeps (all when null) and every channel of
// term(i), i the element's index in a planar image of `shape`'s size; NaN
// when the mask keeps none.
template <class Term>
double masked_mean(ImageView shape, const uint8_t* mask, Term term) {
  double sum = 0;
  size_t count = 0;
  for (int c = 0; c < shape.channels; ++c)
    for (size_t p = 0; p < shape.plane(); ++p) {
      if (mask && !mask[p]) continue;
      sum += term(c * shape.plane() + p);
      ++count;
    }
  return count ? sum / double(count) : std::numeric_limits<double>::quiet_NaN();
}

constexpr int kRadius = 5;  // 11x11 window: scipy's truncate 3.5 * sigma 1.5, rounded

// Normalised 1-D Gaussian, sigma 1.5 (Wang 2004, section III-C).
std::array<double, 2 * kRadius + 1> gaussian_window() {
  std::array<double, 2 * kRadius + 1> w{};
  double sum = 0;
  for (int i = -kRadius; i <= kRadius; ++i) sum += w[i + kRadius] = std::exp(-i * i / 4.5);
  for (double& v : w) v /= sum;
  return w;
}

// Gaussian-filtered `src` (H, W) on the valid region only: out is
// (H - 2r) x (W - 2r). Separable: rows, then columns.
std::vector<double> filter_valid(const std::vector<double>& src, int h, int w) {
  static const auto g = gaussian_window();
  int vw = w - 2 * kRadius, vh = h - 2 * kRadius;
  std::vector<double> rows(size_t(h) * vw);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < vw; ++x) {
      double s = 0;
      for (int k = 0; k <= 2 * kRadius; ++k) s += g[k] * src[size_t(y) * w + x + k];
      rows[size_t(y) * vw + x] = s;
    }
  std::vector<double> out(size_t(vh) * vw);
  for (int y = 0; y < vh; ++y)
    for (int x = 0; x < vw; ++x) {
      double s = 0;
      for (int k = 0; k <= 2 * kRadius; ++k) s += g[k] * rows[size_t(y + k) * vw + x];
      out[size_t(y) * vw + x] = s;
    }
  return out;
}

}  // namespace

namespace {

constexpr double kC1 = 0.01 * 0.01, kC2 = 0.03 * 0.03;  // SSIM's (K L)^2 with L = 1

// For each mask (null: every window), the mean over channels and valid
// windows whose centre the mask keeps of term(mx, my, vx, vy, cxy): the
// Gaussian-weighted means, variances and covariance of a and b in the
// window, filtered once for all masks. NaN where no window counts. With
// `tiled`, also the sums and counts per tile of `tile` pixels.
template <class Term>
std::vector<double> mean_over_windows(ImageView a, ImageView b,
                                      const std::vector<const uint8_t*>& masks, Term term,
                                      int tile = 0, TiledSsim* tiled = nullptr) {
  check_same_shape(a, b);
  const int h = a.height, w = a.width;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (tiled) {
    DOFARM_CHECK(tile >= 1);
    tiled->tile = tile;
    tiled->tiles_x = (w + tile - 1) / tile;
    tiled->tiles_y = (h + tile - 1) / tile;
    const size_t n = size_t(tiled->tiles_x) * tiled->tiles_y;
    tiled->sum.assign(masks.size(), std::vector<double>(n, 0.0));
    tiled->count.assign(masks.size(), std::vector<uint32_t>(n, 0));
  }
  if (h <= 2 * kRadius || w <= 2 * kRadius) return std::vector<double>(masks.size(), nan);
  const int vh = h - 2 * kRadius, vw = w - 2 * kRadius;
  std::vector<double> total(masks.size(), 0.0);
  std::vector<size_t> count(masks.size(), 0);
  std::vector<double> x(size_t(h) * w), y(x.size()), xx(x.size()), yy(x.size()), xy(x.size());
  for (int c = 0; c < a.channels; ++c) {
    const float* pa = a.data + size_t(c) * a.plane();
    const float* pb = b.data + size_t(c) * b.plane();
    for (size_t i = 0; i < x.size(); ++i) {
      x[i] = pa[i];
      y[i] = pb[i];
      xx[i] = x[i] * x[i];
      yy[i] = y[i] * y[i];
      xy[i] = x[i] * y[i];
    }
    auto mx = filter_valid(x, h, w), my = filter_valid(y, h, w);
    auto mxx = filter_valid(xx, h, w), myy = filter_valid(yy, h, w), mxy = filter_valid(xy, h, w);
    for (int j = 0; j < vh; ++j)
      for (int i = 0; i < vw; ++i) {
        const size_t centre = size_t(j + kRadius) * w + i + kRadius;
        const size_t k = size_t(j) * vw + i;
        double value = 0;
        bool computed = false;  // for the first mask that keeps the window
        for (size_t m = 0; m < masks.size(); ++m) {
          if (masks[m] && !masks[m][centre]) continue;
          if (!computed) {
            double vx = mxx[k] - mx[k] * mx[k], vy = myy[k] - my[k] * my[k];
            double cxy = mxy[k] - mx[k] * my[k];
            value = term(mx[k], my[k], vx, vy, cxy);
            computed = true;
          }
          total[m] += value;
          ++count[m];
          if (tiled) {
            const size_t t = size_t((j + kRadius) / tile) * tiled->tiles_x + (i + kRadius) / tile;
            tiled->sum[m][t] += value;
            ++tiled->count[m][t];
          }
        }
      }
  }
  std::vector<double> out(masks.size());
  for (size_t m = 0; m < masks.size(); ++m) out[m] = count[m] ? total[m] / double(count[m]) : nan;
  return out;
}

}  // namespace

std::vector<double> ssim_per_mask(ImageView a, ImageView b,
                                  const std::vector<const uint8_t*>& masks, int tile,
                                  TiledSsim* tiled) {
  return mean_over_windows(
      a, b, masks,
      [](double mx, double my, double vx, double vy, double cxy) {
        return (2 * mx * my + kC1) * (2 * cxy + kC2) /
               ((mx * mx + my * my + kC1) * (vx + vy + kC2));
      },
      tile, tiled);
}

std::vector<double> ssim_per_mask(ImageView a, ImageView b,
                                  const std::vector<const uint8_t*>& masks) {
  return ssim_per_mask(a, b, masks, 0, nullptr);
}

double ssim(ImageView a, ImageView b, const uint8_t* mask) {
  return ssim_per_mask(a, b, {mask})[0];
}

double display_ssim(ImageView linear_a, ImageView linear_b) {
  const std::vector<float> a = display_encode(linear_a), b = display_encode(linear_b);
  return ssim({a.data(), linear_a.channels, linear_a.height, linear_a.width},
              {b.data(), linear_b.channels, linear_b.height, linear_b.width});
}

double ssim_of_truth_against_mean(ImageView a, ImageView b) {
  return mean_over_windows(
      a, b, {nullptr}, [](double mx, double my, double vx, double vy, double cxy) {
        const double cov = std::max(0.0, cxy);
        const double noise = std::max(0.0, vx + vy - 2 * cxy) / 4.0;  // var(a - b) / 4
        return (2 * mx * my + kC1) / (mx * mx + my * my + kC1) * (2 * cov + kC2) /
               (2 * cov + noise + kC2);
      })[0];
}

double finite_mean(const std::vector<double>& v) {
  double s = 0;
  int n = 0;
  for (double x : v)
    if (std::isfinite(x)) s += x, ++n;
  return n ? s / n : std::numeric_limits<double>::quiet_NaN();
}

double psnr(ImageView a, ImageView b, const uint8_t* mask) {
  check_same_shape(a, b);
  const double mse = masked_mean(a, mask, [&](size_t i) {
    const double d = double(a.data[i]) - b.data[i];
    return d * d;
  });
  if (std::isnan(mse)) return mse;  // an empty mask
  if (mse <= std::pow(10.0, -kPsnrCap / 10.0)) return kPsnrCap;
  return -10.0 * std::log10(mse);
}

double relative_mse(ImageView d, ImageView r, const uint8_t* mask) {
  check_same_shape(d, r);
  return masked_mean(d, mask, [&](size_t i) {
    const double ref = r.data[i], diff = double(d.data[i]) - ref;
    return diff * diff / (ref * ref + 0.01);
  });
}

double temporal_relative_mse(ImageView dp, ImageView d, ImageView rp, ImageView r,
                             const uint8_t* mask) {
  check_same_shape(d, r);
  check_same_shape(dp, d);
  check_same_shape(rp, r);
  return masked_mean(d, mask, [&](size_t i) {
    const double dd = double(d.data[i]) - dp.data[i], dr = double(r.data[i]) - rp.data[i];
    const double m = 0.5 * (double(r.data[i]) + rp.data[i]);
    return (dd - dr) * (dd - dr) / (m * m + 0.01);
  });
}

}  // namespace dofarm::trainer
