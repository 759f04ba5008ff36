// Training loss of thesis 4.3 (eq. 4.2-4.4) plus the RAE's temporal term.
//
//   L = w_l1 * L1(out, target) + w_log * L1(LoG * out, LoG * target)
//       + w_t * L1(d/dt out, d/dt target)          (recurrent model only)
//
// LoG * x is the image filtered with a Laplacian of Gaussian (eq. 4.3): it
// responds to edges and fine detail, which L1 alone lets the network blur.
// The filter is applied 'valid' (no padding: no fake edges at the crop border)
// and its kernel sums to exactly zero, so flat images give exactly zero
// response and the loss is finite and zero for identical inputs.
#pragma once

#include <torch/torch.h>

#include "trainer/config.h"

namespace dofarm::trainer {

// The (2r+1)^2 LoG kernel, r = ceil(3 sigma), zero-mean, unit L1 norm.
torch::Tensor log_kernel(float sigma);

// Laplacian-of-Gaussian filtered images: [N, C, H, W] -> [N, C, H-2r, W-2r].
torch::Tensor log_filter(const torch::Tensor& x, const torch::Tensor& kernel);

struct LossTerms {
  torch::Tensor total, l1, log, temporal;  // scalars
};

// out, target: [B, T, 3, H, W] in the network's (transformed) space.
LossTerms denoiser_loss(const torch::Tensor& out, const torch::Tensor& target,
                        const LossConfig& cfg, const torch::Tensor& kernel);

}  // namespace dofarm::trainer
