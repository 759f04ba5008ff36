// The reference ceiling: how well the reference itself is converged, as the
// score an exact denoiser could not beat (issue 13, item 2).
//
// The renderer stores, besides the reference R (mean of n samples), the mean
// A of the first half of its samples (`reference_half`,
// worker/render/render_job.cpp). B = 2R - A is the mean of the second half, so
// A and B are two estimates of the pixel from disjoint samples, n/2 each,
// with R = (A + B) / 2.
// SSIM(A, B), with the evaluation's own SSIM and display encoding
// (metrics.h), is a conservative measure of the ceiling: each half carries
// twice the variance of R, so an independent second reference at the full
// sample count would score at least as high against R.
// It is not the cap on a denoiser's score: an exact denoiser outputs the
// noise-free image T, and SSIM(T, R) is higher still (R's noise only, not two
// halves' noise). That cap is estimated from the same halves by
// ssim_of_truth_against_mean (metrics.h) and reported beside the ceiling as
// the "exact-denoiser score". Measured on the session-sized Cornell study
// (references of at most 512 samples): halves 0.734, exact denoiser 0.900,
// and the project's default network scored 0.827, well above the halves'
// figure (docs/results.md).
#pragma once

#include <cmath>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common/image.h"

namespace dofarm::trainer {

// B = 2 * reference - reference_half (3, H, W), the second half. Empty when
// the frame has no reference_half.
std::vector<float> second_reference_half(const FrameBuffers& frame);

// SSIM between the two halves (display-encoded, as metrics.h). NaN when the
// frame has no reference_half or is smaller than the SSIM window.
double reference_ceiling_ssim(const FrameBuffers& frame);

// The SSIM an exact denoiser (the noise-free image) would score against the
// reference, estimated from the halves (ssim_of_truth_against_mean on the
// display-encoded halves). NaN as reference_ceiling_ssim.
double exact_denoiser_ssim(const FrameBuffers& frame);

// Over the frames of an evaluation: the mean and the worst frame.
class ReferenceCeiling {
 public:
  // Scores `frame` (identified by `shard` and `frame_index` in the report);
  // returns its SSIM (NaN: not counted).
  double add(const FrameBuffers& frame, const std::string& shard, int frame_index);
  int frames() const { return int(ssim_.size()); }
  double mean() const;  // NaN when no frame was scored
  double min() const;   // NaN when no frame was scored
  double exact_mean() const;  // mean exact_denoiser_ssim; NaN when no frame was scored
  // exact_denoiser_ssim of the frame add() last counted.
  double last_exact() const { return exact_.empty() ? std::nan("") : exact_.back(); }
  // {"method", "frames", "mean_ssim", "min_ssim", "min_shard", "min_frame",
  //  "exact_denoiser_mean_ssim"}.
  nlohmann::json to_json() const;
  // One paragraph for report.md (plain text, no HTML).
  std::string markdown() const;

 private:
  std::vector<double> ssim_;
  std::vector<double> exact_;  // exact_denoiser_ssim of the same frames
  std::string min_shard_;
  int min_frame_ = -1;
};

}  // namespace dofarm::trainer
