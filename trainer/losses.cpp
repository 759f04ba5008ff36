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

torch::Tensor focus_weights(const torch::Tensor& coc, float k, float c0) {
  DOFARM_CHECK_EQ(coc.dim(), int64_t(4));
  DOFARM_CHECK(c0 > 0.0f);
  // NaN and +-Inf -> 1e30 px: exp(-(c/c0)^2) = 0, no extra weight.
  const torch::Tensor c = coc.nan_to_num(1e30, 1e30, 1e30) / c0;
  const torch::Tensor w = 1.0 + k * torch::exp(-c.square());
  return w / w.mean({1, 2, 3}, /*keepdim=*/true);  // mean >= 1: never divides by 0
}

LossTerms denoiser_loss(const torch::Tensor& out, const torch::Tensor& target,
                        const LossConfig& cfg, const torch::Tensor& kernel,
                        const torch::Tensor& coc) {
  DOFARM_CHECK_EQ(out.dim(), int64_t(5));
  DOFARM_CHECK(out.sizes() == target.sizes());
  const auto s = out.sizes();
  torch::Tensor o = out.reshape({s[0] * s[1], s[2], s[3], s[4]});
  torch::Tensor t = target.reshape({s[0] * s[1], s[2], s[3], s[4]});
  // Focus weights (thesis 6.3), [B*T, 1, H, W]; undefined = unweighted.
  torch::Tensor w;
  if (cfg.focus_weight > 0) {
    DOFARM_CHECK(coc.defined());
    DOFARM_CHECK_EQ(coc.numel(), s[0] * s[1] * s[3] * s[4]);
    w = focus_weights(coc.reshape({s[0] * s[1], 1, s[3], s[4]}).to(out.dtype()), cfg.focus_weight,
                      cfg.focus_coc_px);
  }
  LossTerms l;
  // eq. 4.3, the spatial term of eq. 4.2
  l.l1 = w.defined() ? ((o - t).abs() * w).mean() : (o - t).abs().mean();
  if (s[3] > kernel.size(0) && s[4] > kernel.size(1)) {
    const torch::Tensor lo = log_filter(o, kernel), lt = log_filter(t, kernel);
    torch::Tensor wv;  // the weights of the LoG's valid region, mean 1 per frame
    if (w.defined()) {
      const int64_t r = kernel.size(0) / 2;
      wv = w.narrow(2, r, lo.size(2)).narrow(3, r, lo.size(3));
      wv = wv / wv.mean({1, 2, 3}, /*keepdim=*/true);
    }
    if (cfg.log_form == GradientLoss::kThesis) {
      // Thesis eq. 4.4, one ratio per frame. The kernel's scale cancels.
      const torch::Tensor sq = (lo - lt).square();
      const torch::Tensor num = (wv.defined() ? sq * wv : sq).sum({1, 2, 3});
      const double floor = kLogFloor * double(lt[0].numel());
      l.log = (num / (lt.square().sum({1, 2, 3}) + floor)).mean();
    } else {
      const torch::Tensor a = (lo - lt).abs();
      l.log = (wv.defined() ? a * wv : a).mean();
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
