#include "trainer/ceiling.h"

#include <cmath>
#include <cstdio>
#include <limits>

#include "trainer/metrics.h"

namespace dofarm::trainer {

namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string fixed(double v, int prec) {
  if (!std::isfinite(v)) return "–";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.*f", prec, v);
  return buf;
}
}  // namespace

std::vector<float> second_reference_half(const FrameBuffers& frame) {
  const size_t n = 3 * frame.plane();
  if (frame.reference_half.size() != n || frame.reference.size() != n) return {};
  std::vector<float> b(n);
  // R = (A + B) / 2 with A the first and B the second half's mean.
  for (size_t i = 0; i < n; ++i) b[i] = 2.0f * frame.reference[i] - frame.reference_half[i];
  return b;
}

namespace {
// score(A, B) on the display-encoded halves; NaN without reference_half.
template <class Score>
double on_encoded_halves(const FrameBuffers& frame, Score score) {
  const std::vector<float> b = second_reference_half(frame);
  if (b.empty()) return kNaN;
  const int w = frame.width, h = frame.height;
  const std::vector<float> da = display_encode({frame.reference_half.data(), 3, h, w});
  const std::vector<float> db = display_encode({b.data(), 3, h, w});
  return score(ImageView{da.data(), 3, h, w}, ImageView{db.data(), 3, h, w});
}
}  // namespace

double reference_ceiling_ssim(const FrameBuffers& frame) {
  return on_encoded_halves(frame, [](ImageView a, ImageView b) { return ssim(a, b); });
}

double exact_denoiser_ssim(const FrameBuffers& frame) {
  return on_encoded_halves(frame, ssim_of_truth_against_mean);
}

double ReferenceCeiling::add(const FrameBuffers& frame, const std::string& shard, int frame_index) {
  // Both figures from one encoding of the halves.
  double exact = kNaN;
  const double s = on_encoded_halves(frame, [&](ImageView a, ImageView b) {
    exact = ssim_of_truth_against_mean(a, b);
    return ssim(a, b);
  });
  if (!std::isfinite(s)) return s;
  if (ssim_.empty() || s < min()) {
    min_shard_ = shard;
    min_frame_ = frame_index;
  }
  ssim_.push_back(s);
  exact_.push_back(exact);
  return s;
}

// Means over the frames add() counted (those with a finite ceiling).
double ReferenceCeiling::mean() const { return finite_mean(ssim_); }

double ReferenceCeiling::exact_mean() const { return finite_mean(exact_); }

double ReferenceCeiling::min() const {
  if (ssim_.empty()) return kNaN;
  double m = ssim_[0];
  for (double s : ssim_) m = std::min(m, s);
  return m;
}

nlohmann::json ReferenceCeiling::to_json() const {
  auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
  nlohmann::json j = {
      {"method",
       "SSIM between the means of the first and the second half of the "
       "reference's samples (reference_half and 2*reference - reference_half), sRGB-encoded and "
       "clamped like the scores; a lower bound on the reference's own SSIM"},
      {"frames", frames()},
      {"mean_ssim", num(mean())},
      {"min_ssim", num(min())},
      {"exact_denoiser_mean_ssim", num(exact_mean())},
      {"exact_denoiser_method",
       "the SSIM of the noise-free image against the reference, estimated per window from the "
       "halves: contrast-structure (2 cov(A,B) + C2) / (2 cov(A,B) + var(A-B)/4 + C2)"}};
  if (frames() > 0) {
    j["min_shard"] = min_shard_;
    j["min_frame"] = min_frame_;
  }
  return j;
}

std::string ReferenceCeiling::markdown() const {
  if (frames() == 0)
    return "Reference ceiling: not measured (the shards have no `reference_half`).";
  return "Reference ceiling: SSIM " + fixed(mean(), 4) + " mean, " + fixed(min(), 4) +
         " worst frame (" + min_shard_ + " frame " + std::to_string(min_frame_) + "), over " +
         std::to_string(frames()) +
         " frames: SSIM between two independent half-sample references (the first and "
         "the second half of the samples) of the same frame. An exact denoiser (the noise-free "
         "image) would score about " + fixed(exact_mean(), 4) +
         " against these references (estimated from the halves): no denoiser can be judged "
         "above that.";
}

}  // namespace dofarm::trainer
