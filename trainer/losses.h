// Training loss of thesis 4.3.4 (eq. 4.2-4.4) plus the RAE's temporal term.
//
//   L = w_l1 * L1(out, target) + w_log * L_g + w_t * L1(d/dt out, d/dt target)
//
//   L1: eq. 4.3, the mean absolute difference.
//   L_g, loss.log_form = "thesis": eq. 4.4, per frame
//        sum (LoG*out - LoG*target)^2 / sum (LoG*target)^2, mean over frames
//        (the sums run over the frame's channels and filtered pixels; the
//        denominator gets kLogFloor per element so a flat target crop stays
//        finite);
//   L_g, loss.log_form = "l1": the project's mean |LoG*out - LoG*target|.
//   The temporal term is Chaitanya 2017 eq. 4 (for the recurrent model).
//   With loss.focus_weight k > 0 (thesis 6.1, 6.3: "penalize areas in focus
//   harder for missing edges and detail", using the CoC buffer), the L1 term
//   and the gradient term weigh each pixel by focus_weights(): the L1 term
//   becomes mean(w |out - target|), the "l1" gradient term mean(w' |dLoG|)
//   and eq. 4.4's numerator sum w' (dLoG)^2, with w' the weights of the
//   LoG's valid region, renormalised to mean 1 there.
//
// LoG * x is the image filtered with a Laplacian of Gaussian: it responds to
// edges and fine detail, which L1 alone lets the network blur.
// The filter is applied 'valid' (no padding: no fake edges at the crop border)
// and its kernel sums to exactly zero, so flat images give exactly zero
// response and the loss is finite and zero for identical inputs.
#pragma once

#include <torch/torch.h>

#include "trainer/config.h"
#include "trainer/inputs.h"

namespace dofarm::trainer {

// Per element, added to eq. 4.4's denominator (of the unit-L1 kernel's
// responses): a real edge contributes ~1e-3, a flat crop 0.
inline constexpr double kLogFloor = 1e-8;

// The (2r+1)^2 LoG kernel, r = ceil(3 sigma), zero-mean, unit L1 norm.
torch::Tensor log_kernel(float sigma);

// Laplacian-of-Gaussian filtered images: [N, C, H, W] -> [N, C, H-2r, W-2r].
torch::Tensor log_filter(const torch::Tensor& x, const torch::Tensor& kernel);

// The network's output back to demodulated radiance (inverse of the
// radiance input's encoding), element-wise on a tensor.
torch::Tensor radiance_inverse(const torch::Tensor& y, RadianceSpace space);

// Per-pixel focus weights from the CoC in pixels, [N, 1, H, W] ->
// [N, 1, H, W]: w = 1 + k exp(-(coc / c0)^2), then divided by its mean over
// each frame, so a frame keeps its total weight (and a batch split across
// replicas the same gradient) and only the share of sharp pixels grows.
// A non-finite CoC counts as far out of focus (w = 1 before normalising).
torch::Tensor focus_weights(const torch::Tensor& coc, float k, float c0);

struct LossTerms {
  torch::Tensor total, l1, log, temporal;  // scalars
};

// out, target: [B, T, 3, H, W] in the network's (transformed) space; coc:
// [B, T, 1, H, W] in pixels, needed when cfg.focus_weight > 0.
LossTerms denoiser_loss(const torch::Tensor& out, const torch::Tensor& target,
                        const LossConfig& cfg, const torch::Tensor& kernel,
                        const torch::Tensor& coc = {});

}  // namespace dofarm::trainer
