#include "trainer/model.h"

#include <gtest/gtest.h>
#include <torch/script.h>
#include <torch/torch.h>
#include <unistd.h>

#include <filesystem>

#include "trainer/losses.h"

namespace dofarm::trainer {
namespace {

ModelConfig tiny(bool recurrent = false, bool dof = true) {
  ModelConfig m;
  m.dof = dof;
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

TEST(Denoiser, TorchScriptExportComputesTheSame) {
  for (bool recurrent : {false, true}) {
    torch::manual_seed(3);
    Denoiser m(tiny(recurrent));
    auto path =
        std::filesystem::temp_directory_path() /
        ("dofarm_export_" + std::to_string(::getpid()) + "_" + std::to_string(recurrent) + ".pt");
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
