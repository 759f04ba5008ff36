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
// sample count would score at least as high against R. A denoiser scored
// against R can only be judged up to about this value.
#pragma once

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

// Over the frames of an evaluation: the mean and the worst frame.
class ReferenceCeiling {
 public:
  // Scores `frame` (identified by `shard` and `frame_index` in the report);
  // returns its SSIM (NaN: not counted).
  double add(const FrameBuffers& frame, const std::string& shard, int frame_index);
  int frames() const { return int(ssim_.size()); }
  double mean() const;  // NaN when no frame was scored
  double min() const;   // NaN when no frame was scored
  // {"method", "frames", "mean_ssim", "min_ssim", "min_shard", "min_frame"}.
  nlohmann::json to_json() const;
  // One paragraph for report.md (plain text, no HTML).
  std::string markdown() const;

 private:
  std::vector<double> ssim_;
  std::string min_shard_;
  int min_frame_ = -1;
};

}  // namespace dofarm::trainer
