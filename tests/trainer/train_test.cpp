#include "trainer/train.h"

#include <ATen/Parallel.h>
#include <ATen/autocast_mode.h>
#include <gtest/gtest.h>
#include <spdlog/fmt/fmt.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "common/error.h"
#include "common/exr_io.h"
#include "tests/cpu_mask.h"
#include "tests/trainer/synthetic.h"
#include "tests/trainer/train_fixtures.h"
#include "trainer/eval.h"
#include "trainer/losses.h"
#include "trainer/precision.h"
#include "trainer/report.h"
#include "trainer/step_runner.h"

namespace dofarm::trainer {
namespace {

namespace fs = std::filesystem;
using namespace fixtures;

TEST(Train, ResumedRunTakesTheSameStepsAsAnUninterruptedOne) {
  fs::path a = fresh_dir("run_a"), b = fresh_dir("run_b");
  TrainOptions o{shared_data(), a, tiny_config()};
  TrainResult ra = train(o);
  EXPECT_EQ(ra.steps, 6);
  EXPECT_EQ(ra.epochs, 2);

  TrainOptions ob{shared_data(), b, tiny_config()};
  ob.stop_at_step = 4;  // interrupted in the middle of epoch 2
  EXPECT_EQ(train(ob).steps, 4);
  ob.stop_at_step = -1;
  TrainResult rb = train(ob);
  EXPECT_TRUE(rb.resumed);
  EXPECT_EQ(rb.steps, 6);
  fs::copy_file(a / "checkpoints/last.pt", a / "checkpoints/best.pt",
                fs::copy_options::overwrite_existing);
  fs::copy_file(b / "checkpoints/last.pt", b / "checkpoints/best.pt",
                fs::copy_options::overwrite_existing);
  torch::Tensor pa = flat_params(a), pb = flat_params(b);
  EXPECT_TRUE(torch::isfinite(pa).all().item<bool>());
  EXPECT_LT((pa - pb).abs().max().item<float>(), 1e-6f);

  std::ifstream csv(a / "loss.csv");
  std::string header, row;
  std::getline(csv, header);
  EXPECT_EQ(header,
            "epoch,step,train_loss,val_loss,lr,skipped,seconds,val_ssim,val_psnr,val_frame_ssim,"
            "val_tile_ssim");
  int rows = 0;
  while (std::getline(csv, row)) ++rows;
  EXPECT_EQ(rows, 2);
}

// A random batch of `sequences` x `frames` frames of side x side pixels, laid
// out as make_batch lays it out (channels-last frames).
Batch random_batch(const ModelConfig& mc, int64_t sequences, int64_t frames, int64_t side) {
  Batch b;
  b.input = torch::rand({sequences * frames, mc.input_channels(), side, side})
                .contiguous(torch::MemoryFormat::ChannelsLast)
                .view({sequences, frames, mc.input_channels(), side, side});
  b.target = torch::rand({sequences * frames, 3, side, side})
                 .contiguous(torch::MemoryFormat::ChannelsLast)
                 .view({sequences, frames, 3, side, side});
  return b;
}

// Every parameter's gradient, flattened into one vector.
torch::Tensor flat_grads(Denoiser& m) {
  std::vector<torch::Tensor> gs;
  for (const auto& p : m->parameters()) gs.push_back(p.grad().flatten().clone());
  return torch::cat(gs);
}

TEST(StepRunner, ReplicasGiveTheWholeBatchsLossAndGradient) {
  const int threads_before = at::get_num_threads();
  for (bool recurrent : {false, true}) {
    for (int replicas : {2, 3}) {
      ModelConfig mc;
      mc.recurrent = recurrent;
      mc.channels = {8, 12, 12, 16, 16};
      torch::manual_seed(11);
      Denoiser whole(mc), split(mc);
      {
        torch::NoGradGuard ng;
        auto a = whole->parameters(), b = split->parameters();
        for (size_t i = 0; i < a.size(); ++i) b[i].copy_(a[i]);
      }
      for (Denoiser* m : {&whole, &split})
        (*m)->set_memory_format(torch::MemoryFormat::ChannelsLast);
      // Batch of 5 sequences: unequal parts (2 + 3, or 1 + 2 + 2).
      Batch batch = random_batch(mc, 5, 3, 32);
      LossConfig lc;
      lc.temporal = 0.25f;  // a per-sequence term too
      torch::Tensor kernel = log_kernel(lc.log_sigma);

      StepOutcome w = compute_gradients(whole, batch, lc, kernel);
      torch::Tensor gw = flat_grads(whole);
      StepRunner runner(split, replicas);
      EXPECT_EQ(runner.replicas(), replicas);
      StepOutcome s1 = runner.run(batch, lc, kernel);
      torch::Tensor g1 = flat_grads(split);
      StepOutcome s2 = runner.run(batch, lc, kernel);
      torch::Tensor g2 = flat_grads(split);
      const std::string what =
          std::string(recurrent ? "recurrent" : "plain") + ", " + std::to_string(replicas);
      ASSERT_TRUE(w.finite && s1.finite && s2.finite) << what;
      EXPECT_NEAR(s1.loss, w.loss, 1e-6 * std::abs(w.loss)) << what;
      const double scale = gw.abs().max().item<double>();
      EXPECT_LT((g1 - gw).abs().max().item<double>() / scale, 1e-5) << what;
      // The combination order is fixed: the same step twice is bit-identical.
      EXPECT_EQ(s1.loss, s2.loss) << what;
      EXPECT_TRUE(torch::equal(g1, g2)) << what;

      // A non-finite loss in any part makes the whole step non-finite.
      StepOutcome bad = runner.run(batch, lc, kernel, [](const torch::Tensor& l) {
        return l * std::numeric_limits<float>::infinity();
      });
      EXPECT_FALSE(bad.finite) << what;
    }
  }
  EXPECT_EQ(at::get_num_threads(), threads_before);  // restored by ~StepRunner
}

// Gradient-norm clipping by hand: gradients (3) and (4, 0) have norm 5.
TEST(StepRunner, ClipGradientsScalesToTheBoundAndOnlyAbove) {
  auto params = [] {
    torch::Tensor a = torch::zeros({1}, torch::requires_grad()),
                  b = torch::zeros({2}, torch::requires_grad()),
                  c = torch::zeros({3}, torch::requires_grad());  // no gradient: ignored
    a.mutable_grad() = torch::tensor({3.0f});
    b.mutable_grad() = torch::tensor({4.0f, 0.0f});
    return std::vector<torch::Tensor>{a, b, c};
  };
  for (double bound : {0.0, 5.0, 10.0}) {
    std::vector<torch::Tensor> p = params();
    EXPECT_DOUBLE_EQ(clip_gradients(p, bound), 5.0) << bound;
    EXPECT_EQ(p[0].grad().item<float>(), 3.0f) << bound;  // untouched, bit for bit
    EXPECT_EQ(p[1].grad()[0].item<float>(), 4.0f) << bound;
  }
  std::vector<torch::Tensor> p = params();
  EXPECT_DOUBLE_EQ(clip_gradients(p, 1.0), 5.0);  // the norm before clipping
  EXPECT_NEAR(p[0].grad().item<float>(), 0.6f, 1e-7);
  EXPECT_NEAR(p[1].grad()[0].item<float>(), 0.8f, 1e-7);
  EXPECT_EQ(p[1].grad()[1].item<float>(), 0.0f);
  EXPECT_NEAR(clip_gradients(p, 0.0), 1.0, 1e-7);
  EXPECT_FALSE(p[2].grad().defined());
  EXPECT_DOUBLE_EQ(clip_gradients({torch::zeros({2})}, 1.0), 0.0);
}

TEST(StepRunner, ReplicaCountFollowsTheConfigDeviceThreadsAndBatch) {
  EXPECT_EQ(step_replicas(0, torch::kCPU, 2, 4), 2);   // auto, 2 threads
  EXPECT_EQ(step_replicas(0, torch::kCPU, 1, 4), 1);   // auto, 1 thread
  EXPECT_EQ(step_replicas(0, torch::kCPU, 16, 1), 1);  // never more than the batch
  EXPECT_EQ(step_replicas(3, torch::kCPU, 1, 4), 3);   // as configured
  EXPECT_EQ(step_replicas(8, torch::kCPU, 8, 4), 4);
  EXPECT_EQ(step_replicas(0, torch::Device(torch::kCUDA, 0), 16, 4), 1);  // CPU only
  // bf16: one model on all threads is faster (docs/trainer.md); as configured
  // otherwise. Where bf16 is not applied (no bf16 units) the step is fp32's.
  EXPECT_EQ(step_replicas(0, torch::kCPU, 2, 4, Precision::kBf16),
            autocast_applies(Precision::kBf16, torch::kCPU) ? 1 : 2);
  EXPECT_EQ(step_replicas(2, torch::kCPU, 2, 4, Precision::kBf16), 2);
}

// bfloat16 autocast (trainer/precision.h): the step's loss and gradient stay
// close to float32's, but are not float32's (autocast did act), the weights'
// gradients are float32 and finite, and the thread's autocast state is as
// before. Each replica thread runs under the same autocast: the split step
// equals its two parts computed one by one in bf16 at the replicas' thread
// count (a replica left in fp32 would differ at bf16's 3e-3 level).
// Where the CPU has no bf16 hardware, bf16 runs through libtorch's
// emulation, whose gradients are further from fp32's (cosine 0.91 on a Zen
// 3 EPYC against > 0.99 with AVX-512 BF16): the test forces it
// (DOFARM_BF16_EMULATED) and bounds it by what was measured there.
struct ForceBf16 {
  ForceBf16() { ::setenv("DOFARM_BF16_EMULATED", "1", 1); }
  ~ForceBf16() { ::unsetenv("DOFARM_BF16_EMULATED"); }
};

TEST(Precision, Bf16StepIsCloseToFp32InEveryReplica) {
  const ForceBf16 force;
  const int threads_before = at::get_num_threads();
  ModelConfig mc;
  mc.channels = {8, 12, 12, 16, 16};
  torch::manual_seed(5);
  Denoiser m(mc);
  m->set_memory_format(torch::MemoryFormat::ChannelsLast);
  Batch batch = random_batch(mc, 4, 3, 32);
  LossConfig lc;
  torch::Tensor kernel = log_kernel(lc.log_sigma);

  StepOutcome f = compute_gradients(m, batch, lc, kernel);
  torch::Tensor gf = flat_grads(m);
  StepOutcome b = compute_gradients(m, batch, lc, kernel, {}, Precision::kBf16);
  torch::Tensor gb = flat_grads(m);
  EXPECT_FALSE(at::autocast::is_cpu_enabled());
  ASSERT_TRUE(f.finite && b.finite);
  for (const auto& p : m->parameters()) EXPECT_EQ(p.grad().scalar_type(), torch::kFloat);
  EXPECT_NEAR(b.loss, f.loss, 0.02 * f.loss);
  const double cosine = (gf * gb).sum().item<double>() / (gf.norm() * gb.norm()).item<double>();
  EXPECT_GT(cosine, cpu_runs_bf16_natively() ? 0.99 : 0.85);
  EXPECT_GT((gf - gb).abs().max().item<double>(), 1e-4 * gf.abs().max().item<double>());

  // The split step against its parts, one by one at one thread each.
  auto part = [&](int64_t start) {
    Batch p;
    p.input = batch.input.narrow(0, start, 2);
    p.target = batch.target.narrow(0, start, 2);
    return p;
  };
  at::set_num_threads(1);
  compute_gradients(m, part(0), lc, kernel, {}, Precision::kBf16);
  torch::Tensor g0 = flat_grads(m);
  compute_gradients(m, part(2), lc, kernel, {}, Precision::kBf16);
  torch::Tensor g1 = flat_grads(m);
  at::set_num_threads(threads_before);
  torch::Tensor parts = 0.5 * g0 + 0.5 * g1;
  {
    StepRunner runner(m, 2, Precision::kBf16);
    ASSERT_TRUE(runner.run(batch, lc, kernel).finite);
  }
  torch::Tensor gs = flat_grads(m);
  const double scale = gs.abs().max().item<double>();
  EXPECT_LT((gs - parts).abs().max().item<double>() / scale, 1e-5);
  EXPECT_GT((gs - gf).abs().max().item<double>() / scale, 1e-4);
  EXPECT_EQ(at::get_num_threads(), threads_before);
}

TEST(Train, ResumeIsExactWithTheStepSplitAcrossReplicas) {
  fs::path a = fresh_dir("run_rep_a"), b = fresh_dir("run_rep_b");
  TrainConfig cfg = tiny_config();
  cfg.train.cpu_replicas = 2;
  TrainOptions o{shared_data(), a, cfg};
  EXPECT_EQ(train(o).steps, 6);
  TrainOptions ob{shared_data(), b, cfg};
  ob.stop_at_step = 2;
  train(ob);
  ob.stop_at_step = -1;
  EXPECT_TRUE(train(ob).resumed);
  for (const fs::path& r : {a, b})
    fs::copy_file(r / "checkpoints/last.pt", r / "checkpoints/best.pt",
                  fs::copy_options::overwrite_existing);
  torch::Tensor pa = flat_params(a), pb = flat_params(b);
  EXPECT_TRUE(torch::isfinite(pa).all().item<bool>());
  EXPECT_TRUE(torch::equal(pa, pb));
}

TEST(Train, NonFiniteLossIsSkippedThenRolledBackWithLowerLr) {
  fs::path run = fresh_dir("run_nan");
  TrainOptions o{shared_data(), run, tiny_config()};
  o.config.train.max_bad_steps = 2;
  o.loss_hook = [](int64_t step, const torch::Tensor& loss) {
    return step >= 1 && step <= 4 ? loss * std::numeric_limits<float>::quiet_NaN() : loss;
  };
  TrainResult r = train(o);
  EXPECT_EQ(r.skipped_steps, 4);
  EXPECT_EQ(r.rollbacks, 2);  // each rollback lowers the LR again
  EXPECT_TRUE(torch::isfinite(flat_params(run)).all().item<bool>());
  std::ifstream ev(run / "events.log");
  std::stringstream ss;
  ss << ev.rdbuf();
  EXPECT_NE(ss.str().find("rolled back"), std::string::npos) << ss.str();
  EXPECT_NE(ss.str().find("LR scale now 0.5"), std::string::npos) << ss.str();
  EXPECT_NE(ss.str().find("LR scale now 0.25"), std::string::npos) << ss.str();
  // The CSV holds only finite losses of the steps taken.
  std::ifstream csv(run / "loss.csv");
  std::string all((std::istreambuf_iterator<char>(csv)), std::istreambuf_iterator<char>());
  EXPECT_EQ(all.find("nan"), std::string::npos) << all;
}

// train.grad_clip: every step's norm before clipping is in steps.csv, the
// epochs' events count exactly the steps above the bound, and a bound no
// step reaches changes nothing, bit for bit.
TEST(Train, GradClipRecordsTheNormAndClipsOnlyAboveTheBound) {
  fs::path plain = fresh_dir("run_noclip");
  TrainOptions o{shared_data(), plain, tiny_config()};
  o.config.train.grad_clip = 0.0f;  // off (the default clips at 1)
  train(o);
  const StepCurve norms = read_steps_csv(plain / "steps.csv");
  ASSERT_EQ(norms.grad_norm.size(), 6u);
  for (double n : norms.grad_norm) EXPECT_TRUE(std::isfinite(n) && n > 0) << n;

  fs::path loose = fresh_dir("run_clip_loose");
  TrainOptions ol{shared_data(), loose, tiny_config()};
  ol.config.train.grad_clip = 1e9f;
  train(ol);
  EXPECT_TRUE(torch::equal(flat_params(plain), flat_params(loose)));

  // A bound between the smallest and the largest norm clips some steps.
  std::vector<double> sorted = norms.grad_norm;
  std::sort(sorted.begin(), sorted.end());
  ASSERT_LT(sorted.front(), sorted.back());
  const float bound = float(0.5 * (sorted.front() + sorted.back()));
  fs::path tight = fresh_dir("run_clip_tight");
  TrainOptions ot{shared_data(), tight, tiny_config()};
  ot.config.train.grad_clip = bound;
  train(ot);
  EXPECT_FALSE(torch::equal(flat_params(plain), flat_params(tight)));
  const StepCurve t = read_steps_csv(tight / "steps.csv");
  int above = 0;
  for (double n : t.grad_norm) above += n > bound;
  ASSERT_GT(above, 0);
  std::ifstream ev(tight / "events.log");
  const std::string events((std::istreambuf_iterator<char>(ev)), std::istreambuf_iterator<char>());
  int logged = 0;
  for (size_t at = events.find(" steps clipped"); at != std::string::npos;
       at = events.find(" steps clipped", at + 1)) {
    const size_t of = events.rfind(" of ", at), start = events.rfind(": ", of);
    logged += std::stoi(events.substr(start + 2, of - start - 2));
  }
  EXPECT_EQ(logged, above) << events;
}

// train.best_by = "frames": best.pt is the epoch whose whole validation
// frames scored best, its recorded score 1 - that SSIM, among the epochs
// whose whole frames did not fail (whole_frame_failure); without whole-frame
// validation the setting is refused.
TEST(Train, BestByFramesPicksTheEpochWithTheBestWholeFrames) {
  fs::path run = fresh_dir("run_best_frames");
  TrainOptions o{shared_data(), run, tiny_config()};
  o.config.data.val_fraction = 0.25f;
  o.config.train.epochs = 4;
  o.config.train.best_by = BestBy::kFrames;
  train(o);
  const LossCurve c = read_loss_csv(run / "loss.csv");
  ASSERT_EQ(c.val_frame_ssim.size(), 4u);
  int best = -1;
  for (int i = 0; i < 4; ++i)
    if (whole_frame_failure(c.val_frame_ssim[i], c.val_ssim[i], c.val_tile_ssim[i]) ==
            FrameFailure::kNone &&
        (best < 0 || c.val_frame_ssim[i] > c.val_frame_ssim[best]))
      best = i;
  if (best < 0) {  // every epoch of the tiny run failed on whole frames
    EXPECT_FALSE(fs::exists(run / "checkpoints" / "best.pt"));
  } else {
    const LoadedRun b = load_run(run, torch::kCPU, "best");
    EXPECT_EQ(b.state.epoch, int64_t(best) + 1);
    EXPECT_NEAR(b.state.best, 1.0 - c.val_frame_ssim[best], 1e-5);  // CSV: 6 digits
  }

  try {
    load_train_config("", {"train.best_by=\"frames\"", "train.val_frames=0"});
    ADD_FAILURE() << "best_by = frames without whole-frame validation was accepted";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find("train.best_by"), std::string::npos) << e.what();
  }
}

TEST(Train, IncompatibleConfigIsRefusedWithTheReason) {
  fs::path run = fresh_dir("run_incompatible");
  TrainOptions o{shared_data(), run, tiny_config()};
  o.config.train.epochs = 1;
  o.config.train.steps_per_epoch = 1;
  train(o);
  o.config.model.recurrent = true;
  try {
    train(o);
    FAIL() << "resumed with another model";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find("model.recurrent"), std::string::npos) << e.what();
  }
}

TEST(LearningRate, WarmUpThenDecay) {
  OptimConfig o;
  o.lr = 1e-3f;
  o.warmup_steps = 10;
  o.lr_decay = 0.5f;
  EXPECT_NEAR(learning_rate(o, 0, 0, 1), 1e-4, 1e-9);
  EXPECT_NEAR(learning_rate(o, 9, 0, 1), 1e-3, 1e-9);
  EXPECT_NEAR(learning_rate(o, 100, 2, 1), 2.5e-4, 1e-9);
  EXPECT_NEAR(learning_rate(o, 100, 100, 1), o.lr_min, 1e-12);
}

// The failure the trainer keeps out of best.pt (docs/results.md, "Where
// whole frames fail"): the failing run's 0.757 whole against 0.834 tiles,
// and its step-4000 0.307 against 0.80 crops.
TEST(WholeFrameFailure, ThresholdsAndNonFinite) {
  EXPECT_EQ(whole_frame_failure(0.757, 0.83, 0.834), FrameFailure::kBelowTiles);
  EXPECT_EQ(whole_frame_failure(0.307, 0.80, 0.49), FrameFailure::kBelowCrops);
  EXPECT_EQ(whole_frame_failure(NAN, 0.80, 0.80), FrameFailure::kNonFinite);
  EXPECT_EQ(whole_frame_failure(INFINITY, 0.80, 0.80), FrameFailure::kNonFinite);
  // Sound: whole frames a little above their tiles, or within 0.02 below.
  EXPECT_EQ(whole_frame_failure(0.855, 0.83, 0.847), FrameFailure::kNone);
  EXPECT_EQ(whole_frame_failure(0.830, 0.83, 0.849), FrameFailure::kNone);
  EXPECT_EQ(whole_frame_failure(0.828, 0.83, 0.849), FrameFailure::kBelowTiles);
  // Without tiles or crops to compare against, only the crops' or nothing.
  EXPECT_EQ(whole_frame_failure(0.5, NAN, NAN), FrameFailure::kNone);
  EXPECT_EQ(whole_frame_failure(0.5, 0.8, NAN), FrameFailure::kBelowCrops);
}

// train.ema's decay: (1 + t) / (10 + t) at step t + 1 until it reaches the
// setting, then the setting.
TEST(Ema, DecayWarmsUpThenHoldsTheSetting) {
  EXPECT_DOUBLE_EQ(ema_decay(0.999, 1), 0.1);
  EXPECT_DOUBLE_EQ(ema_decay(0.999, 2), 2.0 / 11.0);
  EXPECT_DOUBLE_EQ(ema_decay(0.999, 1000), 1000.0 / 1009.0);
  EXPECT_DOUBLE_EQ(ema_decay(0.999, 8992), 0.999);  // 8992 / 9001 = 0.99900...
  EXPECT_DOUBLE_EQ(ema_decay(0.999, 100000), 0.999);
  EXPECT_DOUBLE_EQ(ema_decay(0.5, 3), 0.25);
  EXPECT_DOUBLE_EQ(ema_decay(0.5, 9), 0.5);
  EXPECT_THROW(parse_train_config("", "t.toml", {"train.ema=1"}), SpecError);
  EXPECT_THROW(parse_train_config("", "t.toml", {"train.ema=-0.1"}), SpecError);
}

// The average the checkpoints keep is, to float rounding, the one computed
// here from every step's trained weights (step-*.pt); a run stopped and
// resumed keeps it bit for bit; --weights picks it or the trained weights.
TEST(Train, EmaIsTheAverageOfEveryStepsWeightsAndResumesExactly) {
  fs::path a = fresh_dir("run_ema_a"), b = fresh_dir("run_ema_b");
  TrainConfig cfg = tiny_config();
  cfg.train.ema = 0.6f;
  TrainOptions o{shared_data(), a, cfg};
  o.save_every = 1;
  EXPECT_EQ(train(o).steps, 6);

  // The initial weights: the trainer seeds, then builds the model.
  torch::manual_seed(cfg.train.seed);
  Denoiser init(cfg.model);
  std::vector<torch::Tensor> avg;
  for (const auto& p : init->parameters()) avg.push_back(p.detach().clone());
  for (int step = 1; step <= 6; ++step) {
    const fs::path ck = a / "checkpoints" / fmt::format("step-{:08d}.pt", step);
    LoadedRun r = load_run(a, torch::kCPU, ck.string(), Weights::kRaw);
    EXPECT_FALSE(r.averaged);
    const double d = ema_decay(cfg.train.ema, step);
    const auto w = r.model->parameters();
    ASSERT_EQ(w.size(), avg.size());
    for (size_t i = 0; i < avg.size(); ++i) avg[i].mul_(d).add_(w[i].detach(), 1.0 - d);
  }
  LoadedRun last = load_run(a, torch::kCPU, "last", Weights::kAveraged);
  EXPECT_TRUE(last.averaged);
  const auto got = last.model->parameters();
  double worst = 0, moved = 0;
  for (size_t i = 0; i < avg.size(); ++i) {
    worst = std::max(worst, (got[i] - avg[i]).abs().max().item<double>());
    moved = std::max(moved, (got[i] - init->parameters()[i]).abs().max().item<double>());
  }
  EXPECT_LT(worst, 1e-6);
  EXPECT_GT(moved, 1e-4);  // the average did move away from the initial weights
  // auto reads the average; raw the trained weights of the last step.
  EXPECT_TRUE(load_run(a, torch::kCPU, "last").averaged);
  LoadedRun raw = load_run(a, torch::kCPU, "last", Weights::kRaw);
  LoadedRun step6 =
      load_run(a, torch::kCPU, (a / "checkpoints" / "step-00000006.pt").string(), Weights::kRaw);
  EXPECT_TRUE(torch::equal(raw.model->parameters()[0], step6.model->parameters()[0]));
  EXPECT_FALSE(torch::equal(raw.model->parameters()[0], got[0]));

  TrainOptions ob{shared_data(), b, cfg};
  ob.stop_at_step = 4;
  train(ob);
  ob.stop_at_step = -1;
  EXPECT_TRUE(train(ob).resumed);
  for (Weights w : {Weights::kAveraged, Weights::kRaw}) {
    const auto pa = load_run(a, torch::kCPU, "last", w).model->parameters();
    const auto pb = load_run(b, torch::kCPU, "last", w).model->parameters();
    for (size_t i = 0; i < pa.size(); ++i) EXPECT_TRUE(torch::equal(pa[i], pb[i])) << i;
  }

  // A run without the average: auto reads the trained weights, averaged is
  // an error that names the key.
  fs::path c = fresh_dir("run_ema_off");
  TrainOptions oc{shared_data(), c, tiny_config()};
  oc.config.train.ema = 0.0f;
  oc.stop_at_step = 1;
  train(oc);
  EXPECT_FALSE(load_run(c, torch::kCPU, "last").averaged);
  try {
    load_run(c, torch::kCPU, "last", Weights::kAveraged);
    ADD_FAILURE() << "no error";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find("train.ema"), std::string::npos) << e.what();
  }
}

// Thesis eq. 4.5: 0.0001 * 1.25893^E for E <= 9, else 0.0001 * 10 / sqrt(E),
// E the passes over the training data done, from 0.
TEST(LearningRate, ThesisEq45) {
  EXPECT_DOUBLE_EQ(thesis_learning_rate(0), 1e-4);
  EXPECT_NEAR(thesis_learning_rate(9), 7.943e-4, 1e-7);  // 1e-3 / 10^(1/10)
  EXPECT_NEAR(thesis_learning_rate(10), 3.16228e-4, 1e-9);
  EXPECT_DOUBLE_EQ(thesis_learning_rate(16), 2.5e-4);
  // Through learning_rate(): E counts passes of 5 steps, whatever the epoch.
  OptimConfig o = apply_preset("thesis").train;
  EXPECT_DOUBLE_EQ(learning_rate(o, 0, 0, 5), 1e-4);
  EXPECT_DOUBLE_EQ(learning_rate(o, 4, 3, 5), 1e-4);
  EXPECT_NEAR(learning_rate(o, 5, 0, 5), 1.25893e-4, 1e-12);
  EXPECT_DOUBLE_EQ(learning_rate(o, 80, 0, 5), 2.5e-4);
}

}  // namespace
}  // namespace dofarm::trainer

namespace dofarm::trainer {
namespace {

// Validation SSIM and PSNR are recorded per epoch (the report plots them).
TEST(Train, LossCsvRecordsValidationSsimAndPsnr) {
  const LossCurve c = read_loss_csv(trained_run() / "loss.csv");
  ASSERT_EQ(c.val_ssim.size(), 6u);
  for (size_t i = 0; i < c.val_ssim.size(); ++i) {
    EXPECT_GT(c.val_ssim[i], 0.0) << i;
    EXPECT_LE(c.val_ssim[i], 1.0) << i;
    EXPECT_GT(c.val_psnr[i], 5.0) << i;
    EXPECT_LT(c.val_psnr[i], 100.0) << i;
  }
}

TEST(Denoise, ExrFrameGivesTheSameResultAsTheShardFrame) {
  FrameBuffers fb = testing::synthetic_frame(3, 48, 40, 2, 9);  // not a multiple of 32
  fs::path exr = fresh_dir("denoise") / "frame.exr";
  write_frame_exr(exr, fb);
  FrameDenoiser den(trained_run(), torch::kCPU);
  std::vector<float> direct = den.denoise(fb, 1);
  den.reset_sequence();
  std::vector<float> via_exr = den.denoise(read_frame_exr(exr).buffers, 1);
  ASSERT_EQ(direct.size(), size_t(3 * 48 * 40));
  EXPECT_EQ(direct, via_exr);
  for (float v : direct) ASSERT_TRUE(std::isfinite(v) && v >= 0.0f);
}

// bf16 is applied on the CPU only where the CPU runs it in hardware (or
// when forced): elsewhere asking for it gives fp32's gradients exactly.
TEST(Precision, Bf16IsNotAppliedWhereTheCpuOnlyEmulatesIt) {
  ASSERT_FALSE(bf16_emulation_forced());
  EXPECT_EQ(autocast_applies(Precision::kBf16, torch::kCPU), cpu_runs_bf16_natively());
  EXPECT_FALSE(autocast_applies(Precision::kFp32, torch::kCPU));
  EXPECT_FALSE(autocast_applies(Precision::kBf16, torch::Device(torch::kCUDA, 0)));
  {
    const ForceBf16 force;
    EXPECT_TRUE(autocast_applies(Precision::kBf16, torch::kCPU));
  }
  ModelConfig mc;
  mc.channels = {8, 8, 8, 8, 8};
  torch::manual_seed(3);
  Denoiser m(mc);
  Batch batch = random_batch(mc, 2, 3, 32);
  LossConfig lc;
  const torch::Tensor kernel = log_kernel(lc.log_sigma);
  compute_gradients(m, batch, lc, kernel);
  const torch::Tensor gf = flat_grads(m);
  compute_gradients(m, batch, lc, kernel, {}, Precision::kBf16);
  const torch::Tensor gb = flat_grads(m);
  EXPECT_EQ(torch::equal(gf, gb), !cpu_runs_bf16_natively());
}

TEST(Precision, Bf16DenoiseIsCloseToFp32AndFinite) {
  const ForceBf16 force;
  FrameBuffers fb = testing::synthetic_frame(3, 48, 40, 2, 9);
  FrameDenoiser exact(trained_run(), torch::kCPU);
  FrameDenoiser fast(trained_run(), torch::kCPU, "best", Precision::kBf16);
  std::vector<float> a = exact.denoise(fb, 1), b = fast.denoise(fb, 1);
  ASSERT_EQ(a.size(), b.size());
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_TRUE(std::isfinite(b[i]) && b[i] >= 0.0f);
    num += double(a[i] - b[i]) * (a[i] - b[i]);
    den += double(a[i]) * a[i];
  }
  EXPECT_GT(num, 0.0);               // bf16 did act
  EXPECT_LT(std::sqrt(num / den), 0.02);  // relative RMS difference
}

// The thesis preset end to end on the synthetic shard: an epoch is one pass
// over the training sequences (passes.json), each step's learning rate is
// eq. 4.5 of its pass, best.pt holds the epoch of the lowest training loss,
// and eval scores the validation frames and, in a second table, every frame.
TEST(Train, ThesisPresetPassesEq45BestByTrainingLossAndAllFrameEval) {
  fs::path dir = fresh_dir("thesis_run");
  TrainOptions o;
  o.data_dir = shared_data();
  o.run_dir = dir / "run";
  const TrainConfig thesis = apply_preset("thesis");
  o.config = load_train_config(
      "",
      {"model.channels=[8, 8, 8, 8, 8]", "data.crop=32", "data.sequence=3", "data.queue=4",
       "data.readers=1", "data.val_fraction=0.25", "train.epochs=3", "train.batch=2",
       "train.val_sequences=2", "train.device=cpu"},
      &thesis);
  TrainResult r = train(o);
  // 12 frames of 3-frame sequences, one of them validation: 3 training
  // sequences, 2 steps of 2 per pass.
  nlohmann::json passes = nlohmann::json::parse(std::ifstream(o.run_dir / "passes.json"));
  EXPECT_EQ(passes["training_sequences"], 3);
  EXPECT_EQ(r.steps, 6);
  const StepCurve steps = read_steps_csv(o.run_dir / "steps.csv");
  ASSERT_EQ(steps.lr.size(), 6u);
  for (size_t i = 0; i < 6; ++i)
    EXPECT_NEAR(steps.lr[i], thesis_learning_rate(int64_t(i) / 2), 1e-9) << i;
  const LossCurve epochs = read_loss_csv(o.run_dir / "loss.csv");
  ASSERT_EQ(epochs.train.size(), 3u);
  size_t best = 0;
  for (size_t i = 1; i < 3; ++i)
    if (epochs.train[i] < epochs.train[best]) best = i;
  LoadedRun b = load_run(o.run_dir, torch::kCPU, "best");
  EXPECT_EQ(b.state.epoch, int64_t(best) + 1);
  EXPECT_NEAR(b.state.best, epochs.train[best], 1e-5 * epochs.train[best]);  // CSV: 6 digits
  fs::path out = dir / "eval";
  EvalOptions e{o.run_dir, shared_data(), out, 0, 0, 0};
  EvalSummary s = evaluate(e);
  EXPECT_EQ(s.frames, 3);
  EXPECT_EQ(s.frames_all, 12);
  nlohmann::json j = nlohmann::json::parse(std::ifstream(out / "report.json"));
  EXPECT_EQ(j["summary"]["frames"], 3);
  EXPECT_EQ(j["all_frames"]["summary"]["frames"], 12);
  EXPECT_NEAR(j["all_frames"]["summary"]["denoised"]["all"]["ssim"].get<double>(), s.ssim_all,
              1e-12);
  std::ifstream md(out / "report.md");
  const std::string text((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("**All frames**"), std::string::npos);
  e.all_frames = false;
  e.out_dir = dir / "eval_val";
  EXPECT_EQ(evaluate(e).frames_all, 0);
}

int run_cli(const std::string& args) {
  std::string cmd = std::string(DOFARM_BINARY_DIR) + "/dofarm-train " + args + " >/dev/null 2>&1";
  int rc = std::system(cmd.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

TEST(Cli, ExitCodesSayWhatWentWrong) {
  if (!fs::exists(fs::path(DOFARM_BINARY_DIR) / "dofarm-train")) GTEST_SKIP() << "no binary";
  fs::path bad = fresh_dir("cli_bad_data"), run = fresh_dir("cli_run");
  std::ofstream(bad / "shard-00000.h5") << "not a shard";
  std::string data = shared_data().string();
  EXPECT_EQ(run_cli("train --data " + data + " --run " + run.string() + " --set train.epoch=1"),
            2);  // unknown key
  EXPECT_EQ(run_cli("train --data /nonexistent/dofarm --run " + run.string()), 2);
  EXPECT_EQ(run_cli("train --data " + bad.string() + " --run " + run.string()), 1);
  EXPECT_EQ(
      run_cli("export --run " + trained_run().string() + " --out " + (run / "model.pt").string()),
      0);
  EXPECT_TRUE(fs::exists(run / "model.pt"));
  // The weights alone, then scored through --checkpoint FILE.
  const std::string ckpt = (run / "weights.pt").string();
  EXPECT_EQ(run_cli("export --run " + trained_run().string() +
                    " --format checkpoint --checkpoint last --out " + ckpt),
            0);
  EXPECT_EQ(run_cli("export --run " + trained_run().string() + " --format onnx --out " + ckpt), 2);
  EXPECT_EQ(run_cli("eval --run " + trained_run().string() + " --data " + data + " --checkpoint " +
                    ckpt + " --images 0 --crops 0 --out " + (run / "eval").string()),
            0);
  EXPECT_TRUE(fs::exists(run / "eval" / "report.json"));
}

// The preset by its one name, as a user runs it: the run's config.toml holds
// the thesis's values (so a resume needs no --preset), --set applies over it,
// and an unknown name is bad input.
TEST(Cli, ThesisPresetByName) {
  if (!fs::exists(fs::path(DOFARM_BINARY_DIR) / "dofarm-train")) GTEST_SKIP() << "no binary";
  fs::path run = fresh_dir("cli_thesis") / "run";
  const std::string common = " --data " + shared_data().string() + " --run " + run.string() +
                             " --set 'model.channels=[8, 8, 8, 8, 8]' --set data.crop=32"
                             " --set data.sequence=3 --set data.readers=1 --set train.epochs=1"
                             " --set train.val_sequences=1 --set train.device=cpu";
  EXPECT_EQ(run_cli("train --preset thesys" + common), 2);
  ASSERT_EQ(run_cli("train --preset thesis" + common + " --set model.dof=false"), 0);
  const TrainConfig saved = load_train_config(run / "config.toml");
  TrainConfig want = apply_preset("thesis");
  std::erase(want.model.inputs, std::string("coc:thesis"));
  EXPECT_EQ(saved.model.inputs, want.model.inputs);
  EXPECT_EQ(saved.model.decoder, DecoderForm::kThesis);
  EXPECT_EQ(saved.loss.log_form, GradientLoss::kThesis);
  EXPECT_EQ(saved.train.schedule, Schedule::kThesis);
  EXPECT_EQ(saved.model.channels, (std::vector<int>{8, 8, 8, 8, 8}));
  EXPECT_TRUE(fs::exists(run / "passes.json"));
}

// The global --threads sets the intra-op threads of the command (and so the
// training step's replicas); without it OMP_NUM_THREADS counts where set,
// else every CPU the process may use: libtorch's own default found 1 core of
// this machine's 2, and every study run trained on one core.
TEST(Cli, ThreadsFollowTheOptionTheEnvironmentOrTheCpus) {
  if (!fs::exists(fs::path(DOFARM_BINARY_DIR) / "dofarm-train")) GTEST_SKIP() << "no binary";
  const fs::path dir = fresh_dir("cli_threads");
  int n = 0;
  auto train = [&](const std::string& env, const std::string& option) {
    const fs::path run = dir / ("run" + std::to_string(n++)), log = run.string() + ".log";
    const std::string cmd = env + " " + std::string(DOFARM_BINARY_DIR) + "/dofarm-train " + option +
                            " --log-level info train --data " + shared_data().string() + " --run " +
                            run.string() +
                            " --set 'model.channels=[8, 8, 8, 8, 8]' --set data.crop=32"
                            " --set data.sequence=3 --set data.readers=1 --set train.epochs=1"
                            " --set train.steps_per_epoch=2 --set train.val_sequences=1"
                            " --set train.device=cpu --set train.batch=2 >" +
                            log.string() + " 2>&1";
    EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
    std::ifstream in(log);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  };
  const std::string by_option = train("env -u OMP_NUM_THREADS", "--threads 2");
  EXPECT_NE(by_option.find("2 intra-op thread(s) (--threads)"), std::string::npos) << by_option;
  EXPECT_NE(by_option.find("split across 2 model replicas"), std::string::npos) << by_option;
  const std::string by_env = train("OMP_NUM_THREADS=1", "");
  EXPECT_NE(by_env.find("1 intra-op thread(s) (OMP_NUM_THREADS)"), std::string::npos) << by_env;
  EXPECT_EQ(by_env.find("model replicas"), std::string::npos) << by_env;
  const int cpus = dofarm::cpu_testing::CpuMask().count();
  ASSERT_GT(cpus, 0);
  const std::string by_cpus = train("env -u OMP_NUM_THREADS", "");
  EXPECT_NE(by_cpus.find(std::to_string(cpus) + " intra-op thread(s) (CPUs this process may use)"),
            std::string::npos)
      << by_cpus;
  EXPECT_EQ(run_cli("--threads -1 train --data " + shared_data().string() + " --run " +
                    (dir / "refused").string()),
            2);
  EXPECT_FALSE(fs::exists(dir / "refused"));
}

}  // namespace
}  // namespace dofarm::trainer
