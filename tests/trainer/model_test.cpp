#include "trainer/model.h"

#include <gtest/gtest.h>
#include <torch/script.h>
#include <torch/torch.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <tuple>

#include "common/error.h"
#include "trainer/config.h"
#include "trainer/losses.h"

namespace dofarm::trainer {
namespace {

ModelConfig tiny(bool recurrent = false) {
  ModelConfig m;
  m.recurrent = recurrent;
  m.channels = {8, 8, 8, 8, 8};
  return m;
}

TEST(LogLoss, ZeroForIdenticalAndFiniteOnFlatCrops) {
  torch::manual_seed(0);
  LossConfig cfg;
  torch::Tensor k = log_kernel(cfg.log_sigma);
  EXPECT_NEAR(k.sum().item<float>(), 0.0f, 1e-6f);
  torch::Tensor x = torch::rand({2, 3, 3, 32, 32});
  EXPECT_EQ(denoiser_loss(x, x, cfg, k).total.item<float>(), 0.0f);

  // Flat crops: constant output against constant target, gradients finite.
  torch::Tensor flat_out = torch::full({1, 2, 3, 32, 32}, 0.3f).requires_grad_(true);
  torch::Tensor flat_tgt = torch::full({1, 2, 3, 32, 32}, 0.7f);
  LossTerms l = denoiser_loss(flat_out, flat_tgt, cfg, k);
  EXPECT_NEAR(l.log.item<float>(), 0.0f, 1e-6f);  // no edges, no LoG response
  EXPECT_NEAR(l.total.item<float>(), 0.8f * 0.4f, 1e-5f);
  l.total.backward();
  EXPECT_TRUE(torch::isfinite(flat_out.grad()).all().item<bool>());
  // And a flat image against itself: exactly zero, finite gradient.
  torch::Tensor same = torch::zeros({1, 1, 3, 32, 32}).requires_grad_(true);
  LossTerms z = denoiser_loss(same, torch::zeros({1, 1, 3, 32, 32}), cfg, k);
  EXPECT_EQ(z.total.item<float>(), 0.0f);
  z.total.backward();
  EXPECT_TRUE(torch::isfinite(same.grad()).all().item<bool>());
}

// Thesis eq. 4.4 against the same sums taken by direct convolution loops
// with a kernel built here: L_g = sum (LoG P - LoG T)^2 / sum (LoG T)^2 per
// frame, mean over frames; L = 0.8 L1 + 0.2 L_g (eq. 4.2, 4.3).
TEST(LogLoss, ThesisEq44EqualsDirectSums) {
  torch::manual_seed(4);
  const int h = 11, w = 10, frames = 2;
  const float sigma = 0.5f;  // radius ceil(1.5) = 2: a 5x5 kernel, 7x6 valid outputs
  torch::Tensor p = torch::rand({1, frames, 3, h, w}, torch::kFloat64);
  torch::Tensor t = torch::rand({1, frames, 3, h, w}, torch::kFloat64);
  // The LoG up to scale (which eq. 4.4 cancels): (q - 1) e^-q, q = r^2 / 2 sigma^2,
  // made zero-sum.
  const int r = 2, kn = 2 * r + 1;
  double k[kn][kn], mean = 0;
  for (int y = 0; y < kn; ++y)
    for (int x = 0; x < kn; ++x) {
      const double q = ((x - r) * (x - r) + (y - r) * (y - r)) / (2.0 * sigma * sigma);
      k[y][x] = (q - 1.0) * std::exp(-q);
      mean += k[y][x] / (kn * kn);
    }
  for (auto& row : k)
    for (double& v : row) v -= mean;
  auto pa = p.accessor<double, 5>(), ta = t.accessor<double, 5>();
  double lg = 0, l1 = 0;
  for (int f = 0; f < frames; ++f) {
    double num = 0, den = 0;
    for (int c = 0; c < 3; ++c)
      for (int y = 0; y + kn <= h; ++y)
        for (int x = 0; x + kn <= w; ++x) {
          double lp = 0, lt = 0;
          for (int i = 0; i < kn; ++i)
            for (int j = 0; j < kn; ++j) {
              lp += k[i][j] * pa[0][f][c][y + i][x + j];
              lt += k[i][j] * ta[0][f][c][y + i][x + j];
            }
          num += (lp - lt) * (lp - lt);
          den += lt * lt;
        }
    lg += num / den / frames;
    for (int c = 0; c < 3; ++c)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
          l1 += std::abs(pa[0][f][c][y][x] - ta[0][f][c][y][x]) / (frames * 3 * h * w);
  }
  LossConfig cfg = apply_preset("thesis").loss;
  LossTerms got =
      denoiser_loss(p.to(torch::kFloat32), t.to(torch::kFloat32), cfg, log_kernel(sigma));
  EXPECT_NEAR(got.log.item<double>(), lg, 1e-5 * lg);
  EXPECT_NEAR(got.l1.item<double>(), l1, 1e-6);
  EXPECT_NEAR(got.total.item<double>(), 0.8 * l1 + 0.2 * lg, 1e-5 * (0.8 * l1 + 0.2 * lg));
  // The project's form is another number on the same data (|.| mean of a
  // unit-L1 kernel's responses), so the switch does something.
  cfg.log_form = GradientLoss::kL1;
  EXPECT_GT(
      std::abs(denoiser_loss(p.to(torch::kFloat32), t.to(torch::kFloat32), cfg, log_kernel(sigma))
                   .log.item<double>() -
               lg),
      0.1 * lg);
  // A flat target (no LoG response at all) stays finite, and identical
  // images give exactly 0.
  cfg.log_form = GradientLoss::kThesis;
  torch::Tensor flat = torch::full({1, 1, 3, 16, 16}, 0.5f);
  torch::Tensor edge = flat.clone();
  edge.narrow(4, 8, 8).fill_(1.0f);
  EXPECT_TRUE(std::isfinite(denoiser_loss(edge, flat, cfg, log_kernel(1.0f)).total.item<float>()));
  EXPECT_EQ(denoiser_loss(edge, edge, cfg, log_kernel(1.0f)).log.item<float>(), 0.0f);
}

TEST(LogLoss, SeesBlurThatL1BarelySees) {
  // A sharp edge against the same edge blurred: the LoG term is a larger
  // share of the error than of the image, which is why eq. 4.2 adds it.
  torch::Tensor sharp = torch::zeros({1, 1, 3, 32, 32});
  sharp.narrow(4, 16, 16).fill_(1.0f);
  torch::Tensor blurred = torch::avg_pool2d(sharp.reshape({1, 3, 32, 32}), 3, 1, 1, false, true)
                              .reshape({1, 1, 3, 32, 32});
  LossConfig cfg;
  LossTerms l = denoiser_loss(blurred, sharp, cfg, log_kernel(cfg.log_sigma));
  EXPECT_GT(l.log.item<float>(), 0.0f);
  EXPECT_GT(l.l1.item<float>(), 0.0f);
}

TEST(LogLoss, TemporalTermPenalisesFlickerOnly) {
  LossConfig cfg;
  cfg.temporal = 1.0f;
  torch::Tensor tgt = torch::rand({1, 4, 3, 32, 32});
  torch::Tensor shifted = tgt + 0.1f;  // constant bias: no flicker
  EXPECT_NEAR(denoiser_loss(shifted, tgt, cfg, log_kernel(1.0f)).temporal.item<float>(), 0.0f,
              1e-6f);
  torch::Tensor flicker = tgt.clone();
  flicker.select(1, 2).add_(0.1f);
  EXPECT_GT(denoiser_loss(flicker, tgt, cfg, log_kernel(1.0f)).temporal.item<float>(), 0.05f);
}

// Focus weights (thesis 6.3) by hand: k = 3, c0 = 1 px. Frame 0 has CoCs
// 0, 1, NaN and 100 px: raw weights 4, 1 + 3/e, 1, 1 (NaN = far out of
// focus), divided by their mean; frame 1 is all sharp: uniform weights 1.
TEST(FocusLoss, WeightsFollowTheCocAndAverageOnePerFrame) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  torch::Tensor coc =
      torch::tensor({0.0f, 1.0f, nan, 100.0f, 0.0f, 0.0f, 0.0f, 0.0f}).reshape({2, 1, 2, 2});
  torch::Tensor w = focus_weights(coc, 3.0f, 1.0f);
  const double raw[4] = {4.0, 1.0 + 3.0 / std::exp(1.0), 1.0, 1.0};
  const double mean = (raw[0] + raw[1] + raw[2] + raw[3]) / 4.0;
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(w[0][0][i / 2][i % 2].item<float>(), raw[i] / mean, 1e-6) << i;
    EXPECT_FLOAT_EQ(w[1][0][i / 2][i % 2].item<float>(), 1.0f) << i;
  }
  EXPECT_TRUE(torch::isfinite(w).all().item<bool>());
  // c0 scales the CoC: at c0 = 2 a 2 px CoC gets what 1 px got at c0 = 1.
  torch::Tensor w2 = focus_weights(coc * 2.0f, 3.0f, 2.0f);
  EXPECT_TRUE(torch::allclose(w2, w, 1e-6, 1e-6));
}

// The L1 term with focus weights, by hand: one pixel of four is wrong by 1
// in every channel. Sharp (CoC 0) among out-of-focus pixels (CoC 10), its
// weight is 4 / (7/4) = 16/7, so L1 = 3 * 16/7 / 12 = 4/7 against 1/4
// unweighted; when every pixel is as sharp, or k = 0, it is the plain L1.
TEST(FocusLoss, L1WeighsTheErrorOfSharpPixelsMore) {
  torch::Tensor tgt = torch::zeros({1, 1, 3, 2, 2});
  torch::Tensor out = tgt.clone();
  out.index_put_({0, 0, torch::indexing::Slice(), 0, 0}, 1.0f);
  torch::Tensor coc = torch::tensor({0.0f, 10.0f, 10.0f, 10.0f}).reshape({1, 1, 1, 2, 2});
  LossConfig cfg;
  cfg.focus_weight = 3.0f;
  cfg.focus_coc_px = 1.0f;
  const torch::Tensor k = log_kernel(1.0f);  // larger than the image: no gradient term
  EXPECT_NEAR(denoiser_loss(out, tgt, cfg, k, coc).l1.item<float>(), 4.0f / 7.0f, 1e-6);
  EXPECT_NEAR(denoiser_loss(out, tgt, cfg, k, torch::zeros_like(coc)).l1.item<float>(), 0.25f,
              1e-7);
  // The error where it is out of focus instead: weight 1 / (7/4) = 4/7.
  torch::Tensor moved = torch::tensor({10.0f, 0.0f, 10.0f, 10.0f}).reshape({1, 1, 1, 2, 2});
  EXPECT_NEAR(denoiser_loss(out, tgt, cfg, k, moved).l1.item<float>(), 0.25f * 4.0f / 7.0f, 1e-6);
  cfg.focus_weight = 0.0f;
  EXPECT_NEAR(denoiser_loss(out, tgt, cfg, k, coc).l1.item<float>(), 0.25f, 1e-7);
}

// The gradient term, both forms, is weighted too, and stays finite and 0 for
// identical images with any CoC (NaN included).
TEST(FocusLoss, GradientTermIsWeightedAndNanSafe) {
  torch::manual_seed(3);
  torch::Tensor tgt = torch::rand({1, 2, 3, 24, 24});
  torch::Tensor out = tgt + 0.1f * torch::randn({1, 2, 3, 24, 24});
  torch::Tensor coc = torch::full({1, 2, 1, 24, 24}, 20.0f);
  // Sharp where the error is: the left half.
  coc.index_put_({torch::indexing::Slice(), torch::indexing::Slice(), 0, torch::indexing::Slice(),
                  torch::indexing::Slice(0, 12)},
                 0.0f);
  torch::Tensor err_left = tgt.clone();
  err_left.index_put_({"...", torch::indexing::Slice(0, 12)},
                      out.index({"...", torch::indexing::Slice(0, 12)}));
  for (GradientLoss form : {GradientLoss::kL1, GradientLoss::kThesis}) {
    LossConfig cfg;
    cfg.log_form = form;
    const torch::Tensor k = log_kernel(1.0f);
    const float plain = denoiser_loss(err_left, tgt, cfg, k, coc).log.item<float>();
    cfg.focus_weight = 4.0f;
    const float weighted = denoiser_loss(err_left, tgt, cfg, k, coc).log.item<float>();
    EXPECT_GT(weighted, 1.25f * plain) << int(form);  // about 5/3 where the error is
    torch::Tensor bad = coc.clone();
    bad.index_put_({0, 0, 0, 5, 5}, std::numeric_limits<float>::quiet_NaN());
    EXPECT_TRUE(std::isfinite(denoiser_loss(err_left, tgt, cfg, k, bad).total.item<float>()));
    EXPECT_EQ(denoiser_loss(tgt, tgt, cfg, k, bad).total.item<float>(), 0.0f);
  }
}

TEST(Denoiser, ThesisWidthsAndShapes) {
  ModelConfig full;  // thesis defaults with the CoC input
  Denoiser m(full);
  torch::NoGradGuard ng;
  torch::Tensor y = m->forward(torch::rand({1, 2, 12, 64, 64}));
  EXPECT_EQ(y.sizes(), (std::vector<int64_t>{1, 2, 3, 64, 64}));
  Denoiser r(tiny(true));
  EXPECT_GT(parameter_count(*r), parameter_count(*Denoiser(tiny(false))));
  EXPECT_EQ(r->forward(torch::rand({2, 3, 12, 32, 64})).sizes(),
            (std::vector<int64_t>{2, 3, 3, 32, 64}));
}

// Thesis 4.3.1 with the widths of its DOF network (36, 48, 64, 85, 113):
// three convolutions per encoder block and in the bottleneck (which keeps
// the channel count), decoder blocks of two that take twice the next
// level's width and give it, the last one giving the 3 output channels; no
// output convolution. Every convolution 3x3 with a bias.
TEST(Denoiser, ThesisPresetLayerStructure) {
  const ModelConfig cfg = apply_preset("thesis").model;
  Denoiser m(cfg);
  const std::vector<std::tuple<std::string, int, int>> want = {
      {"e0_0", 12, 36},  {"e0_1", 36, 36},   {"e0_2", 36, 36},   {"e1_0", 36, 48},
      {"e1_1", 48, 48},  {"e1_2", 48, 48},   {"e2_0", 48, 64},   {"e2_1", 64, 64},
      {"e2_2", 64, 64},  {"e3_0", 64, 85},   {"e3_1", 85, 85},   {"e3_2", 85, 85},
      {"e4_0", 85, 113}, {"e4_1", 113, 113}, {"e4_2", 113, 113}, {"m_0", 113, 113},
      {"m_1", 113, 113}, {"m_2", 113, 113},  {"d4_0", 226, 113}, {"d4_1", 113, 85},
      {"d3_0", 170, 85}, {"d3_1", 85, 64},   {"d2_0", 128, 64},  {"d2_1", 64, 48},
      {"d1_0", 96, 48},  {"d1_1", 48, 36},   {"d0_0", 72, 36},   {"d0_1", 36, 3}};
  auto params = m->named_parameters();
  int64_t count = 0;
  for (const auto& [name, in, out] : want) {
    ASSERT_TRUE(params.contains(name + ".weight")) << name;
    EXPECT_EQ(params[name + ".weight"].sizes(), (std::vector<int64_t>{out, in, 3, 3})) << name;
    count += int64_t(9) * in * out + out;
  }
  EXPECT_EQ(params.size(), 2 * want.size());  // nothing else: no "out" convolution
  EXPECT_EQ(parameter_count(*m), count);
  // The no-CoC baseline of the thesis: 11 inputs, widths 32 ... 101.
  ModelConfig no_coc = cfg;
  std::erase(no_coc.inputs, std::string("coc:thesis"));
  Denoiser b(no_coc);
  EXPECT_EQ(b->named_parameters()["e0_0.weight"].sizes(), (std::vector<int64_t>{32, 11, 3, 3}));
  EXPECT_EQ(b->named_parameters()["m_2.weight"].sizes(), (std::vector<int64_t>{101, 101, 3, 3}));
  torch::NoGradGuard ng;
  EXPECT_EQ(b->forward(torch::rand({1, 2, 11, 32, 32})).sizes(),
            (std::vector<int64_t>{1, 2, 3, 32, 32}));
}

// The last decoder block has no activation (thesis fig. 4.3), in training
// and in the export: with every weight 0, d0_0's bias -1 and d0_1 passing
// channel 0 through with bias -0.5, the output is exactly -1.5 (a LeakyReLU
// anywhere in the block would give -0.6 or -0.06).
TEST(Denoiser, ThesisLastBlockIsLinear) {
  ModelConfig cfg = apply_preset("thesis").model;
  cfg.channels = {8, 8, 8, 8, 8};
  Denoiser m(cfg);
  {
    torch::NoGradGuard ng;
    for (auto& p : m->parameters()) p.zero_();
    auto params = m->named_parameters();
    params["d0_0.bias"].fill_(-1.0f);
    params["d0_1.weight"][0][0][1][1] = 1.0f;
    params["d0_1.bias"].fill_(-0.5f);
  }
  torch::NoGradGuard ng;
  torch::Tensor x = torch::rand({1, 12, 32, 32});
  std::vector<torch::Tensor> none;
  torch::Tensor y = m->forward_frame(x, none);
  EXPECT_TRUE(y.select(1, 0).eq(-1.5f).all().item<bool>()) << y.select(1, 0).max();
  EXPECT_TRUE(y.select(1, 1).eq(-0.5f).all().item<bool>());
  auto path = std::filesystem::temp_directory_path() /
              ("dofarm_export_thesis_" + std::to_string(::getpid()) + ".pt");
  m->export_torchscript(path);
  torch::Tensor s = torch::jit::load(path.string()).forward({x}).toTensor();
  std::filesystem::remove(path);
  EXPECT_TRUE(s.equal(y));
}

// The taps (crop_vs_frame --taps) are the encoder levels' outputs and the
// bottleneck's, at 1, 1/2, ... 1/32 of the frame, and change nothing.
TEST(Denoiser, TapsRecordEveryLevelAndChangeNothing) {
  torch::manual_seed(3);
  Denoiser m(tiny(false));
  torch::NoGradGuard ng;
  torch::Tensor x = torch::rand({1, 12, 64, 96});
  std::vector<torch::Tensor> none, taps;
  const torch::Tensor plain = m->forward_frame(x, none);
  m->set_taps(&taps);
  const torch::Tensor tapped = m->forward_frame(x, none);
  m->set_taps(nullptr);
  EXPECT_TRUE(tapped.equal(plain));
  ASSERT_EQ(int(taps.size()), kLevels + 1);
  for (int l = 0; l <= kLevels; ++l) {
    EXPECT_EQ(taps[l].size(2), 64 >> l) << l;
    EXPECT_EQ(taps[l].size(3), 96 >> l) << l;
  }
  m->forward_frame(x, none);  // after set_taps(nullptr): nothing more recorded
  EXPECT_EQ(int(taps.size()), kLevels + 1);
}

TEST(Denoiser, RecurrentOutputDependsOnEarlierFrames) {
  torch::manual_seed(1);
  Denoiser m(tiny(true));
  torch::NoGradGuard ng;
  torch::Tensor seq = torch::rand({1, 3, 12, 32, 32});
  torch::Tensor other = seq.clone();
  other.select(1, 0).uniform_();  // change only frame 0
  torch::Tensor a = m->forward(seq), b = m->forward(other);
  EXPECT_GT((a.select(1, 2) - b.select(1, 2)).abs().max().item<float>(), 0.0f);
  Denoiser plain(tiny(false));
  torch::Tensor c = plain->forward(seq), d = plain->forward(other);
  EXPECT_EQ((c.select(1, 2) - d.select(1, 2)).abs().max().item<float>(), 0.0f);
}

TEST(Denoiser, OverfitsOneBatch) {
  torch::manual_seed(2);
  Denoiser m(tiny(false));
  // Smooth inputs, like images (bilinear upsampling of 8x8 noise).
  namespace F = torch::nn::functional;
  torch::Tensor x =
      F::interpolate(torch::rand({4, 12, 8, 8}), F::InterpolateFuncOptions()
                                                     .size(std::vector<int64_t>{32, 32})
                                                     .mode(torch::kBilinear)
                                                     .align_corners(false))
          .reshape({2, 2, 12, 32, 32});
  // A denoising-like map the network can represent: target from the input colour.
  torch::Tensor target = 0.5f + 0.5f * x.narrow(2, 0, 3);
  LossConfig cfg;
  torch::Tensor k = log_kernel(cfg.log_sigma);
  torch::optim::Adam opt(m->parameters(), torch::optim::AdamOptions(3e-3).betas({0.9, 0.99}));
  float first = 0, last = 0;
  for (int step = 0; step < 300; ++step) {
    opt.zero_grad();
    torch::Tensor loss = denoiser_loss(m->forward(x), target, cfg, k).total;
    loss.backward();
    opt.step();
    if (step == 0) first = loss.item<float>();
    last = loss.item<float>();
  }
  EXPECT_LE(last * 10.0f, first) << "first " << first << " last " << last;
}

// A constant image stays constant through every layer when the border is
// its nearest value repeated (convolution, pooling and upsampling of a
// constant are constant), so the output is the same at every pixel, at any
// size: no pixel can tell how far it lies from a border. With zeros the
// border pixels differ, which is what a network trained on small crops can
// come to lean on (docs/results.md, "Where whole frames fail").
TEST(Denoiser, ReplicatePaddingGivesNoPixelItsDistanceToTheBorder) {
  torch::NoGradGuard ng;
  const torch::Tensor x = torch::full({1, 12, 64, 96}, 0.37f);
  for (PaddingMode mode : {PaddingMode::kZeros, PaddingMode::kReplicate}) {
    torch::manual_seed(5);
    ModelConfig cfg = tiny();
    cfg.padding = mode;
    Denoiser m(cfg);
    std::vector<torch::Tensor> none;
    const torch::Tensor y = m->forward_frame(x, none);
    // Per channel: the spread over pixels against the channel's size.
    const torch::Tensor flat = y.reshape({3, -1});
    const float spread = (flat.amax(1) - flat.amin(1)).max().item<float>();
    const float scale = flat.abs().mean().item<float>() + 1e-3f;
    if (mode == PaddingMode::kReplicate)
      EXPECT_LT(spread, 1e-4f * scale) << "replicate: the output varies over a constant input";
    else
      EXPECT_GT(spread, 1e-2f * scale) << "zeros: the border should show";
  }
}

// model.replicate_from: the levels above it pad with zeros, the rest
// replicate. With the same weights, every encoder level shallower than it
// matches the zero-padded network exactly and the first one at it differs;
// at 0 the whole network is the replicate-padded one.
TEST(Denoiser, ReplicateFromPadsOnlyTheDeepLevels) {
  torch::NoGradGuard ng;
  torch::manual_seed(9);
  const torch::Tensor x = torch::rand({1, 12, 64, 64});
  auto taps_of = [&](PaddingMode mode, int from) {
    torch::manual_seed(5);  // the same initial weights whatever the padding
    ModelConfig cfg = tiny();
    cfg.padding = mode;
    cfg.replicate_from = from;
    Denoiser m(cfg);
    std::vector<torch::Tensor> taps, none;
    m->set_taps(&taps);
    taps.push_back(m->forward_frame(x, none));
    return taps;  // encoder levels 0..4, the bottleneck, then the output
  };
  const auto zeros = taps_of(PaddingMode::kZeros, 0), all = taps_of(PaddingMode::kReplicate, 0);
  for (int from : {1, 3, 4, 5}) {
    const auto t = taps_of(PaddingMode::kReplicate, from);
    ASSERT_EQ(t.size(), zeros.size());
    for (int level = 0; level < from; ++level)
      EXPECT_TRUE(torch::equal(t[level], zeros[level])) << "from " << from << " level " << level;
    EXPECT_FALSE(torch::allclose(t[from], zeros[from])) << "from " << from;
    EXPECT_FALSE(torch::allclose(t.back(), zeros.back())) << "from " << from;
  }
  const auto t0 = taps_of(PaddingMode::kReplicate, 0);
  for (size_t i = 0; i < t0.size(); ++i) EXPECT_TRUE(torch::equal(t0[i], all[i])) << i;
  EXPECT_FALSE(torch::allclose(all[0], zeros[0]));
  EXPECT_THROW(parse_train_config("", "t.toml", {"model.replicate_from=6"}), SpecError);
  EXPECT_EQ(parse_train_config("", "t.toml", {"model.replicate_from=4"}).model.replicate_from, 4);
}

// replicate_pad1 against ATen's replication_pad2d: the same values and the
// same gradient for a random upstream gradient, in both memory layouts.
TEST(Denoiser, ReplicatePad1EqualsReplicationPad2d) {
  for (bool channels_last : {false, true}) {
    torch::manual_seed(11);
    torch::Tensor x = torch::randn({2, 5, 6, 7});
    if (channels_last) x = x.contiguous(torch::MemoryFormat::ChannelsLast);
    const torch::Tensor a = x.clone().requires_grad_(true), b = x.clone().requires_grad_(true);
    const torch::Tensor ya = replicate_pad1(a), yb = torch::replication_pad2d(b, {1, 1, 1, 1});
    ASSERT_EQ(ya.sizes(), yb.sizes());
    EXPECT_TRUE(torch::equal(ya, yb));
    const torch::Tensor g = torch::randn(ya.sizes());
    ya.backward(g);
    yb.backward(g);
    EXPECT_LT((a.grad() - b.grad()).abs().max().item<float>(), 1e-5f);
    // The corner pixel gathers four padded values' gradients and its own.
    EXPECT_GT((a.grad() - g.narrow(2, 1, 6).narrow(3, 1, 7)).abs().max().item<float>(), 0.1f);
  }
}

TEST(Denoiser, TorchScriptExportComputesTheSame) {
  for (int variant = 0; variant < 4; ++variant) {
    const bool recurrent = variant == 1;
    torch::manual_seed(3);
    ModelConfig cfg = tiny(recurrent);
    if (variant >= 2) cfg.padding = PaddingMode::kReplicate;
    if (variant == 3) cfg.replicate_from = 4;  // zeros above 1/16, replicate below
    Denoiser m(cfg);
    auto path =
        std::filesystem::temp_directory_path() /
        ("dofarm_export_" + std::to_string(::getpid()) + "_" + std::to_string(variant) + ".pt");
    m->export_torchscript(path);
    torch::jit::Module loaded = torch::jit::load(path.string());
    torch::NoGradGuard ng;
    torch::Tensor x0 = torch::rand({1, 12, 32, 64}), x1 = torch::rand({1, 12, 32, 64});
    std::vector<torch::Tensor> state;
    torch::Tensor y0 = m->forward_frame(x0, state);
    torch::Tensor y1 = m->forward_frame(x1, state);
    if (!recurrent) {
      torch::Tensor s = loaded.forward({x0}).toTensor();
      EXPECT_LT((s - y0).abs().max().item<float>(), 1e-5f);
    } else {
      std::vector<torch::jit::IValue> in{x0};
      for (int i = 0; i < kLevels; ++i) in.push_back(torch::zeros({1, 8, 32 >> i, 64 >> i}));
      auto out = loaded.forward(in).toTuple();
      EXPECT_LT((out->elements()[0].toTensor() - y0).abs().max().item<float>(), 1e-5f);
      std::vector<torch::jit::IValue> in1{x1};
      for (int i = 1; i <= kLevels; ++i) in1.push_back(out->elements()[i]);
      auto out1 = loaded.forward(in1).toTuple();
      EXPECT_LT((out1->elements()[0].toTensor() - y1).abs().max().item<float>(), 1e-5f);
    }
    std::filesystem::remove(path);
  }
}

TEST(Denoiser, PadToMultipleReplicatesEdges) {
  torch::Tensor x = torch::arange(2 * 3 * 33 * 40, torch::kFloat32).reshape({2, 3, 33, 40});
  torch::Tensor p = pad_to_multiple(x);
  EXPECT_EQ(p.sizes(), (std::vector<int64_t>{2, 3, 64, 64}));
  EXPECT_TRUE(p.narrow(2, 0, 33).narrow(3, 0, 40).equal(x));
  EXPECT_TRUE(p.select(2, 63).equal(p.select(2, 32)));
}

// Channels-last (NHWC) activations and weights change the speed on the CPU,
// not the values: outputs, loss and every gradient match the NCHW model up to
// float summation order.
TEST(Denoiser, ChannelsLastComputesTheSameOutputLossAndGradients) {
  for (bool recurrent : {false, true}) {
    ModelConfig cfg = tiny(recurrent);
    cfg.channels = {12, 16, 16, 20, 24};
    torch::manual_seed(3);
    Denoiser nchw(cfg);
    Denoiser nhwc(cfg);
    {
      torch::NoGradGuard ng;
      auto a = nchw->parameters(), b = nhwc->parameters();
      for (size_t i = 0; i < a.size(); ++i) b[i].copy_(a[i]);
    }
    nhwc->set_memory_format(torch::MemoryFormat::ChannelsLast);
    ASSERT_TRUE(
        nhwc->named_parameters()["e0_0.weight"].is_contiguous(torch::MemoryFormat::ChannelsLast));
    torch::Tensor x = torch::rand({2, 3, cfg.input_channels(), 64, 64});
    torch::Tensor t = torch::rand({2, 3, 3, 64, 64});
    LossConfig lc;
    lc.temporal = 0.1f;
    torch::Tensor k = log_kernel(lc.log_sigma);
    torch::Tensor la = denoiser_loss(nchw->forward(x), t, lc, k).total;
    torch::Tensor ya = nchw->forward(x);
    torch::Tensor yb = nhwc->forward(x);
    torch::Tensor lb = denoiser_loss(nhwc->forward(x), t, lc, k).total;
    EXPECT_TRUE(torch::allclose(ya, yb, 1e-4, 1e-5)) << (ya - yb).abs().max().item<float>();
    EXPECT_NEAR(la.item<float>(), lb.item<float>(), 1e-5f * std::abs(la.item<float>()));
    la.backward();
    lb.backward();
    auto ga = nchw->named_parameters(), gb = nhwc->named_parameters();
    for (const auto& p : ga) {
      torch::Tensor g1 = p.value().grad(), g2 = gb[p.key()].grad();
      ASSERT_TRUE(g1.defined() && g2.defined()) << p.key();
      EXPECT_TRUE(torch::isfinite(g2).all().item<bool>()) << p.key();
      double scale = g1.abs().max().item<double>() + 1e-12;
      EXPECT_LT((g1 - g2).abs().max().item<double>() / scale, 1e-4)
          << p.key() << " recurrent " << recurrent;
    }
  }
}

}  // namespace
}  // namespace dofarm::trainer
