// Image quality metrics of the evaluation (thesis 5.1, table 5.1).
//
// Images are channel-first float arrays (C, H, W). SSIM and PSNR are taken on
// display values: linear radiance through the sRGB transfer curve, clamped to
// [0, 1] (display_encode()); relative MSE on the linear HDR values. Every
// metric takes an optional per-pixel mask (H*W bytes, non-zero = counted) so the
// evaluation can split in-focus (CoC < 1 px) from out-of-focus pixels.
//
// Plain C++ on purpose: an implementation independent of the one being
// trained, checked against scikit-image (tests/trainer/data/ssim_fixture.txt).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace dofarm::trainer {

struct ImageView {
  const float* data = nullptr;
  int channels = 0, height = 0, width = 0;
  size_t plane() const { return size_t(height) * width; }
};

// IEC 61966-2-1 sRGB encoding of a linear value, then clamped to [0, 1].
float srgb_encode_clamped(float linear);
std::vector<float> display_encode(ImageView linear);

// SSIM of Wang et al. 2004: 11x11 Gaussian window, sigma 1.5, K1 0.01,
// K2 0.03, data range 1, population (not sample) covariances, only windows that
// lie fully inside the image ("valid"), mean over channels. Equals
// skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
// use_sample_covariance=False, data_range=1). With a mask, the SSIM map is
// averaged over the valid pixels whose centre is masked in; NaN when none is.
double ssim(ImageView a, ImageView b, const uint8_t* mask = nullptr);
// ssim(a, b, masks[k]) for every k (null: no mask), with the windows'
// filtered means computed once for all of them: the same numbers, bit for
// bit, at the cost of one ssim() (the evaluation scores several regions).
std::vector<double> ssim_per_mask(ImageView a, ImageView b,
                                  const std::vector<const uint8_t*>& masks);
// What ssim_per_mask() divides, kept per square tile of `tile` pixels
// (tiles_x x tiles_y, row-major; a window counts in the tile of its
// centre): for mask m, sum[m][t] of the SSIM map (summed over channels) and
// count[m][t] of its values. The mask's SSIM is the sum of sum[m] over the
// sum of count[m], so scores of two images over the same tiles can be
// compared tile by tile (a paired bootstrap: bench/trainer/study_tables.py).
struct TiledSsim {
  int tile = 0, tiles_x = 0, tiles_y = 0;
  std::vector<std::vector<double>> sum;
  std::vector<std::vector<uint32_t>> count;
};
// ssim_per_mask(), and with `tiled` non-null its tiles' sums (tile >= 1).
std::vector<double> ssim_per_mask(ImageView a, ImageView b,
                                  const std::vector<const uint8_t*>& masks, int tile,
                                  TiledSsim* tiled);
// ssim() of the display encodings of two linear images.
double display_ssim(ImageView linear_a, ImageView linear_b);

// The SSIM that the noise-free image T would score against R = (a + b) / 2,
// estimated from two independent, unbiased estimates a and b of T (e.g. the
// two halves of a reference's samples), with ssim()'s window and constants.
// Per window: cov(T, R) = var(T) is estimated by cov(a, b), the variance R's
// noise adds to var(R) by var(a - b) / 4, so the contrast-structure term is
// (2 cov(a, b) + C2) / (2 cov(a, b) + var(a - b) / 4 + C2) (cov(a, b)
// clamped at 0), and the luminance term is taken from the means of a and b.
// This is the score an exact denoiser gets against R, the reference's own
// cap on every score; ssim(a, b) is lower, each half having twice R's noise.
double ssim_of_truth_against_mean(ImageView a, ImageView b);

// The mean of the finite values of v, e.g. per-frame scores where a frame
// without in-focus pixels has none; NaN when there are none.
double finite_mean(const std::vector<double>& v);

// Peak signal-to-noise ratio for data range 1, in dB, capped at kPsnrCap for
// identical images so that no infinity reaches a report. NaN for an empty mask.
inline constexpr double kPsnrCap = 100.0;
double psnr(ImageView a, ImageView b, const uint8_t* mask = nullptr);

// Relative MSE on linear HDR: mean over pixels and channels of
// (d - r)^2 / (r^2 + 0.01) (Rousselle et al. 2011's regularised form).
double relative_mse(ImageView denoised, ImageView reference, const uint8_t* mask = nullptr);

// Temporal flicker of consecutive frames t-1, t: the relative MSE of the
// frame-to-frame differences, after the temporal loss of Chaitanya et al.
// 2017 (eq. 4, which compares the temporal derivatives of output and
// reference). On linear HDR, mean over pixels and channels of
//   ((d_t - d_{t-1}) - (r_t - r_{t-1}))^2 / (m^2 + 0.01),  m = (r_t + r_{t-1}) / 2,
// so a change the reference also makes costs nothing, and a denoiser whose
// output wobbles on a still reference scores above 0 even when each frame
// alone is as close to it as a steady output's. `mask` (of frame t) as for
// relative_mse(); NaN for an empty mask.
double temporal_relative_mse(ImageView denoised_prev, ImageView denoised, ImageView reference_prev,
                             ImageView reference, const uint8_t* mask = nullptr);

}  // namespace dofarm::trainer
