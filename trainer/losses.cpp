#include "trainer/losses.h"

#include <cmath>

#include "common/error.h"

namespace dofarm::trainer {

torch::Tensor log_kernel(float sigma) {
  const int r = int(std::ceil(3.0f * sigma));
  const int n = 2 * r + 1;
  torch::Tensor k = torch::empty({n, n}, torch::kFloat64);
  auto a = k.accessor<double, 2>();
  const double s2 = double(sigma) * sigma;
  for (int y = -r; y <= r; ++y)
    for (int x = -r; x <= r; ++x) {
      double q = (x * x + y * y) / (2.0 * s2);
      // Laplacian of the Gaussian (thesis 4.3.4), up to the constant factor
      // that the normalisation below removes.
      a[y + r][x + r] = (q - 1.0) * std::exp(-q);
    }
  k -= k.mean();       // truncation leaves a small DC response: remove it
  k /= k.abs().sum();  // scale-free: the loss weight alone sets its strength
  return k.to(torch::kFloat32);
}

torch::Tensor radiance_inverse(const torch::Tensor& y, RadianceSpace space) {
  return space == RadianceSpace::kLog1p ? torch::expm1(y.clamp_min(0)) : y.clamp_min(0);
}

torch::Tensor log_filter(const torch::Tensor& x, const torch::Tensor& kernel) {
  const int64_t c = x.size(1);
  torch::Tensor w = kernel.to(x.options())
                        .unsqueeze(0)
                        .unsqueeze(0)
                        .expand({c, 1, kernel.size(0), kernel.size(1)});
  namespace F = torch::nn::functional;
  return F::conv2d(x, w, F::Conv2dFuncOptions().groups(c));  // depthwise, 'valid'
}

LossTerms denoiser_loss(const torch::Tensor& out, const torch::Tensor& target,
                        const LossConfig& cfg, const torch::Tensor& kernel) {
  DOFARM_CHECK_EQ(out.dim(), int64_t(5));
  DOFARM_CHECK(out.sizes() == target.sizes());
  const auto s = out.sizes();
  torch::Tensor o = out.reshape({s[0] * s[1], s[2], s[3], s[4]});
  torch::Tensor t = target.reshape({s[0] * s[1], s[2], s[3], s[4]});
  LossTerms l;
  l.l1 = (o - t).abs().mean();  // eq. 4.3, the spatial term of eq. 4.2
  if (s[3] > kernel.size(0) && s[4] > kernel.size(1)) {
    const torch::Tensor lo = log_filter(o, kernel), lt = log_filter(t, kernel);
    if (cfg.log_form == GradientLoss::kThesis) {
      // Thesis eq. 4.4, one ratio per frame. The kernel's scale cancels.
      const torch::Tensor num = (lo - lt).square().sum({1, 2, 3});
      const double floor = kLogFloor * double(lt[0].numel());
      l.log = (num / (lt.square().sum({1, 2, 3}) + floor)).mean();
    } else {
      l.log = (lo - lt).abs().mean();
    }
  } else
    l.log = torch::zeros({}, out.options());
  if (cfg.temporal > 0 && s[1] > 1) {
    // Chaitanya 2017 eq. 4: L1 between frame-to-frame differences, which
    // penalises flicker the per-frame terms cannot see.
    torch::Tensor dout = out.narrow(1, 1, s[1] - 1) - out.narrow(1, 0, s[1] - 1);
    torch::Tensor dtgt = target.narrow(1, 1, s[1] - 1) - target.narrow(1, 0, s[1] - 1);
    l.temporal = (dout - dtgt).abs().mean();
  } else {
    l.temporal = torch::zeros({}, out.options());
  }
  l.total = cfg.l1 * l.l1 + cfg.log * l.log + cfg.temporal * l.temporal;
  return l;
}

}  // namespace dofarm::trainer
