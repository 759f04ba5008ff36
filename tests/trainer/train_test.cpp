#include "trainer/train.h"

#include <ATen/Parallel.h>
#include <ATen/autocast_mode.h>
#include <gtest/gtest.h>
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
#include "common/shard.h"
#include "tests/trainer/synthetic.h"
#include "trainer/eval.h"
#include "trainer/losses.h"
#include "trainer/metrics.h"
#include "trainer/precision.h"
#include "trainer/report.h"
#include "trainer/step_runner.h"

namespace dofarm::trainer {
namespace {

namespace fs = std::filesystem;

fs::path fresh_dir(const std::string& name) { return testing::scratch_dir(name); }

// A tiny but complete configuration: 8-channel model, 32x32 crops, 3 frames.
TrainConfig tiny_config() {
  TrainConfig c = load_train_config(
      "", {"model.channels=[8, 8, 8, 8, 8]", "data.crop=32", "data.sequence=3", "data.queue=4",
           "data.readers=1", "train.epochs=2", "train.steps_per_epoch=3", "train.batch=2",
           "train.warmup_steps=2", "train.val_sequences=2", "train.device=cpu"});
  return c;
}

fs::path shared_data() {
  static fs::path d = [] {
    fs::path p = fresh_dir("train_data");
    testing::write_synthetic_shard(p / "shard-00000.h5", 12, 64, 64, 3, 5);
    return p;
  }();
  return d;
}

torch::Tensor flat_params(const fs::path& run) {
  LoadedRun r = load_run(run, torch::kCPU);
  std::vector<torch::Tensor> ps;
  for (const auto& p : r.model->parameters()) ps.push_back(p.detach().flatten());
  return torch::cat(ps);
}

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
            "epoch,step,train_loss,val_loss,lr,skipped,seconds,val_ssim,val_psnr,val_frame_ssim");
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
  // bf16: one model on all threads is faster (docs/trainer.md); as configured otherwise.
  EXPECT_EQ(step_replicas(0, torch::kCPU, 2, 4, Precision::kBf16), 1);
  EXPECT_EQ(step_replicas(2, torch::kCPU, 2, 4, Precision::kBf16), 2);
}

// bfloat16 autocast (trainer/precision.h): the step's loss and gradient stay
// close to float32's, but are not float32's (autocast did act), the weights'
// gradients are float32 and finite, and the thread's autocast state is as
// before. Each replica thread runs under the same autocast: the split step
// equals its two parts computed one by one in bf16 at the replicas' thread
// count (a replica left in fp32 would differ at bf16's 3e-3 level).
TEST(Precision, Bf16StepIsCloseToFp32InEveryReplica) {
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
  EXPECT_GT(cosine, 0.99);
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
// frames scored best, its recorded score 1 - that SSIM; without whole-frame
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
  size_t best = 0;
  for (size_t i = 1; i < 4; ++i)
    if (c.val_frame_ssim[i] > c.val_frame_ssim[best]) best = i;
  const LoadedRun b = load_run(run, torch::kCPU, "best");
  EXPECT_EQ(b.state.epoch, int64_t(best) + 1);
  EXPECT_NEAR(b.state.best, 1.0 - c.val_frame_ssim[best], 1e-5);  // CSV: 6 digits

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

fs::path trained_run() {
  static fs::path run = [] {
    fs::path r = fresh_dir("run_eval");
    TrainOptions o{shared_data(), r, tiny_config()};
    o.config.data.sequence = 3;  // 12 frames: 9 to train, 3 to validate
    o.config.data.val_fraction = 0.25f;
    o.config.train.epochs = 6;
    o.config.train.steps_per_epoch = 5;
    train(o);
    return r;
  }();
  return run;
}

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

TEST(Eval, ReportHasEveryFrameAndBeatsTheNoisyInput) {
  fs::path out = fresh_dir("eval_report");
  EvalOptions e{trained_run(), shared_data(), out, 0, 1, 0};
  EvalSummary s = evaluate(e);
  EXPECT_EQ(s.frames, 3);
  for (const char* f : {"report.md", "report.json", "report.html", "loss.svg", "steps.svg",
                        "lr.svg", "frame-000.png"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  EXPECT_FALSE(fs::exists(out / "frame-001.png"));  // max_images = 1
  std::ifstream in(out / "report.json");
  nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["frames"].size(), 3u);
  double noisy = j["summary"]["noisy"]["all"]["ssim"],
         den = j["summary"]["denoised"]["all"]["ssim"];
  EXPECT_GT(den, noisy);
  EXPECT_TRUE(std::isfinite(s.psnr));
  EXPECT_GT(s.ms, 0.0);
  // Synthetic references are converged (reference_half == reference): the
  // ceiling is exactly 1 on every frame (trainer/ceiling.h).
  EXPECT_EQ(j["reference_ceiling"]["frames"], 3);
  EXPECT_DOUBLE_EQ(j["reference_ceiling"]["mean_ssim"].get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(j["frames"][0]["reference_ceiling_ssim"].get<double>(), 1.0);
  // Flicker: none for a sequence's first frame, then per pair of frames; the
  // noisy input (fresh noise every frame) flickers more than the output.
  EXPECT_TRUE(j["frames"][0]["denoised"]["all"]["flicker"].is_null());
  EXPECT_TRUE(j["frames"][1]["denoised"]["all"]["flicker"].is_number());
  const double fl_noisy = j["summary"]["noisy"]["all"]["flicker"],
               fl_den = j["summary"]["denoised"]["all"]["flicker"];
  EXPECT_GT(fl_noisy, fl_den);
  EXPECT_NEAR(s.flicker, fl_den, 1e-12);
  EXPECT_TRUE(j["denoise_ms_at_size"].is_null());  // not asked for
}

// Full-frame validation (train.val_frames): each epoch's val_frame_ssim is
// in (0, 1], and full_frame_ssim over all validation frames equals what eval
// scores on them with the same weights.
TEST(Eval, FullFrameValidationScoresAsEvalDoes) {
  const LossCurve c = read_loss_csv(trained_run() / "loss.csv");
  ASSERT_EQ(c.val_frame_ssim.size(), 6u);
  for (double v : c.val_frame_ssim) EXPECT_TRUE(v > 0 && v <= 1) << v;

  LoadedRun run = load_run(trained_run(), torch::kCPU, "last");
  run.model->eval();
  const std::vector<ShardSplit> splits = load_split_file(trained_run());
  int frames = 0;
  for (const ShardSplit& s : splits) frames += s.val_end - s.val_begin;
  ASSERT_EQ(frames, 3);
  // The last epoch's figure: the default 2 frames, to the CSV's 6 digits.
  EXPECT_NEAR(full_frame_ssim(run.model, run.config, torch::kCPU, shared_data(), splits, 2),
              c.val_frame_ssim.back(), 1e-5);
  const double whole =
      full_frame_ssim(run.model, run.config, torch::kCPU, shared_data(), splits, frames);
  fs::path out = fresh_dir("eval_whole");
  EvalOptions e{trained_run(), shared_data(), out, 0, 0, 0, "last"};
  e.all_frames = false;
  EXPECT_NEAR(evaluate(e).ssim, whole, 1e-9);
  EXPECT_TRUE(
      std::isnan(full_frame_ssim(run.model, run.config, torch::kCPU, shared_data(), {}, 2)));
}

// Scores by circle of confusion (kFocusRegions): each region's score is the
// metric over exactly its pixels, the shares add up, and a band without
// pixels has no score. The synthetic CoC runs from 0 to 8 px.
TEST(Eval, ScoresEveryBandOfTheCircleOfConfusion) {
  fs::path out = fresh_dir("eval_bands");
  EvalOptions e{trained_run(), shared_data(), out, 0, 0, 0};
  evaluate(e);
  std::ifstream in(out / "report.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  const nlohmann::json& share = j["summary"]["pixel_share"];
  EXPECT_DOUBLE_EQ(share["all"].get<double>(), 1.0);
  EXPECT_NEAR(share["in_focus"].get<double>() + share["out_of_focus"].get<double>(), 1.0, 1e-12);
  EXPECT_NEAR(share["coc_1_4"].get<double>() + share["coc_4_16"].get<double>() +
                  share["coc_16_up"].get<double>(),
              share["out_of_focus"].get<double>(), 1e-12);
  EXPECT_GT(share["coc_1_4"].get<double>(), 0.2);
  EXPECT_GT(share["coc_4_16"].get<double>(), 0.2);
  EXPECT_EQ(share["coc_16_up"].get<double>(), 0.0);
  EXPECT_TRUE(j["summary"]["denoised"]["coc_16_up"]["ssim"].is_null());
  EXPECT_TRUE(j["frames"][0]["noisy"]["coc_16_up"]["ssim"].is_null());
  // Frame 0's noisy input over the 4-16 px band, scored here independently.
  const nlohmann::json& row = j["frames"][0];
  ShardReader reader(shared_data() / row["shard"].get<std::string>());
  const FrameBuffers fb = reader.read_frame(row["frame"].get<int>() - reader.info().frame_start);
  const size_t n = fb.plane();
  std::vector<uint8_t> band(n);
  for (size_t p = 0; p < n; ++p) band[p] = fb.coc[p] >= 4.0f && fb.coc[p] < 16.0f;
  const std::vector<float> noisy(fb.noisy.begin(), fb.noisy.begin() + 3 * n);
  const std::vector<float> a = display_encode({noisy.data(), 3, fb.height, fb.width}),
                           b = display_encode({fb.reference.data(), 3, fb.height, fb.width});
  const double want =
      ssim({a.data(), 3, fb.height, fb.width}, {b.data(), 3, fb.height, fb.width}, band.data());
  EXPECT_NEAR(row["noisy"]["coc_4_16"]["ssim"].get<double>(), want, 1e-12);
  EXPECT_NE(row["noisy"]["coc_4_16"]["ssim"].get<double>(),
            row["noisy"]["coc_1_4"]["ssim"].get<double>());
  std::ifstream md_in(out / "report.md");
  const std::string md((std::istreambuf_iterator<char>(md_in)), std::istreambuf_iterator<char>());
  EXPECT_NE(md.find("By circle of confusion"), std::string::npos);
  EXPECT_NE(md.find("| coc_4_16 | 4–16 |"), std::string::npos);
}

// The CoC probe (--coc-override): a model with a CoC input denoises
// differently when fed a false CoC, while the noisy row and the regions
// (from the frame's own CoC) stay; a model without the input is unmoved,
// to the last bit.
TEST(Eval, CocOverrideMovesOnlyAModelThatReadsTheCoc) {
  auto scores = [](const fs::path& run, const char* name, float coc) {
    fs::path out = fresh_dir(name);
    EvalOptions e{run, shared_data(), out, 0, 0, 0};
    e.all_frames = false;
    e.coc_override = coc;
    evaluate(e);
    std::ifstream in(out / "report.json");
    return nlohmann::json::parse(in);
  };
  const nlohmann::json own = scores(trained_run(), "probe_own", NAN),
                       zero = scores(trained_run(), "probe_zero", 0.0f);
  EXPECT_TRUE(own["coc_override"].is_null());
  EXPECT_EQ(zero["coc_override"].get<double>(), 0.0);
  EXPECT_EQ(zero["summary"]["noisy"], own["summary"]["noisy"]);
  EXPECT_EQ(zero["summary"]["pixel_share"], own["summary"]["pixel_share"]);
  EXPECT_NE(zero["summary"]["denoised"]["out_of_focus"]["ssim"].get<double>(),
            own["summary"]["denoised"]["out_of_focus"]["ssim"].get<double>());

  fs::path nococ = fresh_dir("run_nococ");
  TrainOptions o{shared_data(), nococ, tiny_config()};
  std::erase(o.config.model.inputs, std::string("coc:log"));
  o.config.train.epochs = 1;
  o.config.train.steps_per_epoch = 2;
  train(o);
  const nlohmann::json a = scores(nococ, "probe_nococ_own", NAN),
                       b = scores(nococ, "probe_nococ_big", 50.0f);
  EXPECT_EQ(a["summary"]["denoised"], b["summary"]["denoised"]);

  // The command refuses a CoC that is not a finite number of pixels >= 0
  // (NaN would silently mean "no probe"), before writing anything.
  const fs::path refused = fresh_dir("probe_refused") / "report";
  for (const char* bad : {"nan", "inf", "-1"}) {
    const std::string cmd = std::string(DOFARM_TRAIN_EXE) + " eval --run " +
                            trained_run().string() + " --data " + shared_data().string() +
                            " --out " + refused.string() + " --coc-override " + bad +
                            " >/dev/null 2>&1";
    const int rc = std::system(cmd.c_str());
    EXPECT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 2) << bad;
    EXPECT_FALSE(fs::exists(refused)) << bad;
  }
}

// Crops where the lens matters (report.h): on a CoC map with one sharp
// square and one blurred square, the windows found are those squares.
TEST(Crops, WindowsOfTheSmallestAndLargestCircleOfConfusion) {
  const int w = 40, h = 24;
  std::vector<float> coc(size_t(w) * h, 1.5f);  // neither sharp nor "out of focus"
  for (int y = 4; y < 12; ++y)
    for (int x = 6; x < 14; ++x) coc[size_t(y) * w + x] = 0.0f;
  for (int y = 14; y < 22; ++y)
    for (int x = 30; x < 38; ++x) coc[size_t(y) * w + x] = 20.0f;
  FocusCrops c = choose_focus_crops(coc, w, h, 8);  // stride 2: both squares on the grid
  ASSERT_TRUE(c.in_focus.found && c.out_of_focus.found);
  EXPECT_EQ(c.in_focus.x, 6);
  EXPECT_EQ(c.in_focus.y, 4);
  EXPECT_DOUBLE_EQ(c.in_focus.mean_coc, 0.0);
  EXPECT_EQ(c.out_of_focus.x, 30);
  EXPECT_EQ(c.out_of_focus.y, 14);
  EXPECT_DOUBLE_EQ(c.out_of_focus.mean_coc, 20.0);
  // A frame that is all pinhole has no out-of-focus window, an all-blurred
  // one no in-focus window.
  EXPECT_FALSE(choose_focus_crops(std::vector<float>(size_t(w) * h, 0.0f), w, h, 8)
                   .out_of_focus.found);
  EXPECT_FALSE(
      choose_focus_crops(std::vector<float>(size_t(w) * h, 9.0f), w, h, 8).in_focus.found);

  // The crop PNG holds the window's pixels, sRGB-encoded, each drawn 2 x 2.
  std::vector<float> img(size_t(3) * w * h);
  for (size_t i = 0; i < img.size(); ++i) img[i] = float(i % 97) / 96.0f;
  const std::string png = crop_png_bytes(img, w, h, c.out_of_focus, 2);
  RgbImage back = decode_rgb_image(png.data(), png.size(), "crop", /*srgb=*/false);
  ASSERT_EQ(back.width, 16);
  ASSERT_EQ(back.height, 16);
  const size_t n = size_t(w) * h;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x)
      for (int ch = 0; ch < 3; ++ch) {
        const size_t p = size_t(14 + y / 2) * w + size_t(30 + x / 2);
        ASSERT_NEAR(back.rgb[(size_t(y) * 16 + x) * 3 + ch],
                    std::round(srgb_encode_clamped(img[ch * n + p]) * 255.0f) / 255.0f, 1e-6)
            << x << "," << y;
      }
}

// eval --crops: the same windows for any run on the same data (chosen from
// the data's CoC), written as PNGs and listed in report.json and report.md.
TEST(Eval, WritesCropsChosenByTheCircleOfConfusion) {
  fs::path out = fresh_dir("eval_crops");
  EvalOptions e{trained_run(), shared_data(), out, 0, 0, 0};
  e.all_frames = false;
  e.crops = 2;
  e.crop_side = 8;
  evaluate(e);
  nlohmann::json j = nlohmann::json::parse(std::ifstream(out / "report.json"));
  ASSERT_FALSE(j["crops"].empty());
  std::set<int> frames;
  for (const auto& c : j["crops"]) {
    frames.insert(c["index"].get<int>());
    for (const char* kind : {"noisy", "denoised", "reference"})
      EXPECT_TRUE(fs::exists(out / c[kind].get<std::string>())) << c.dump();
    const bool sharp = c["region"] == "in_focus";
    EXPECT_TRUE(sharp ? c["mean_coc_px"] < 1.0 : c["mean_coc_px"] >= 2.0) << c.dump();
    EXPECT_EQ(c["side"], 8);
  }
  EXPECT_EQ(frames.size(), 2u);  // e.crops frames
  std::ifstream md(out / "report.md");
  std::string text((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find(j["crops"][0]["denoised"].get<std::string>()), std::string::npos);
}

// Which frames the crops show: the most blurred, every shard's best before
// any shard's second, the most blurred shard first; ties keep their order.
TEST(Eval, CropsShowTheMostBlurredFramesSpreadOverShards) {
  using Picks = std::vector<std::pair<size_t, size_t>>;
  const std::vector<std::vector<double>> blur = {{3.0, 2.9, 1.0}, {40.0, 39.0}, {}, {12.0}};
  EXPECT_EQ(spread_by_blur(blur, 2), (Picks{{1, 0}, {3, 0}}));
  EXPECT_EQ(spread_by_blur(blur, 4), (Picks{{1, 0}, {3, 0}, {0, 0}, {1, 1}}));
  EXPECT_EQ(spread_by_blur(blur, 9), (Picks{{1, 0}, {3, 0}, {0, 0}, {1, 1}, {0, 1}, {0, 2}}));
  EXPECT_EQ(spread_by_blur({{5.0}, {5.0}}, 2), (Picks{{0, 0}, {1, 0}}));
  EXPECT_TRUE(spread_by_blur(blur, 0).empty());
  EXPECT_TRUE(spread_by_blur({}, 3).empty());
}

// `eval --time-size` times a frame of a size the data does not have: the
// first validation frame repeated periodically.
// crop_frame: the window's pixels in every buffer (per-version planes too),
// the camera kept; a window outside the frame is refused.
TEST(Eval, CropFrameTakesTheWindowOfEveryBuffer) {
  const FrameBuffers f = testing::synthetic_frame(3, 16, 12, 2, 9);
  const FrameBuffers c = crop_frame(f, 5, 4, 6, 3);
  ASSERT_EQ(c.width, 6);
  ASSERT_EQ(c.height, 3);
  EXPECT_EQ(c.camera.focal_distance, f.camera.focal_distance);
  const size_t n = f.plane(), m = c.plane();
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 6; ++x) {
      const size_t s = size_t(4 + y) * 16 + size_t(5 + x), d = size_t(y) * 6 + size_t(x);
      EXPECT_EQ(c.coc[d], f.coc[s]);
      EXPECT_EQ(c.reference[2 * m + d], f.reference[2 * n + s]);
      EXPECT_EQ(c.noisy[5 * m + d], f.noisy[5 * n + s]);  // version 1, blue
    }
  EXPECT_THROW(crop_frame(f, 12, 0, 6, 3), SpecError);
  EXPECT_THROW(crop_frame(f, -1, 0, 6, 3), SpecError);
}

TEST(Eval, TimesTheDenoiseAtARequestedSize) {
  const FrameBuffers f = testing::synthetic_frame(1, 5, 3, 2, 4);
  const FrameBuffers t = tile_frame(f, 12, 7);
  ASSERT_EQ(t.width, 12);
  ASSERT_EQ(t.versions, 2);
  for (int y = 0; y < 7; ++y)
    for (int x = 0; x < 12; ++x) {
      ASSERT_EQ(t.coc[size_t(y) * 12 + x], f.coc[size_t(y % 3) * 5 + x % 5]);
      // Version 1's blue plane.
      ASSERT_EQ(t.noisy[(3 + 2) * 84 + size_t(y) * 12 + x],
                f.noisy[(3 + 2) * 15 + size_t(y % 3) * 5 + x % 5]);
    }
  fs::path out = fresh_dir("eval_time");
  EvalOptions e{trained_run(), shared_data(), out, 1, 0, 0};
  e.all_frames = false;
  e.time_side = 96;
  e.time_reps = 2;
  EvalSummary s = evaluate(e);
  EXPECT_GT(s.ms_at_size, 0.0);
  nlohmann::json j = nlohmann::json::parse(std::ifstream(out / "report.json"));
  EXPECT_EQ(j["denoise_ms_at_size"]["side"], 96);
  EXPECT_EQ(j["denoise_ms_at_size"]["reps"], 2);
  EXPECT_DOUBLE_EQ(j["denoise_ms_at_size"]["ms"].get<double>(), s.ms_at_size);
}

// The page as a reader sees it: opened by a real browser (Debian's
// chromium, headless), its script run, its plots and images decoded, its
// numbers those of report.json.
TEST(Eval, ReportPageLoadsInABrowserWithItsPlotsAndNumbers) {
  const char* browsers[] = {"/usr/bin/chromium", "/usr/bin/chromium-browser"};
  std::string browser;
  for (const char* b : browsers)
    if (fs::exists(b)) browser = b;
  if (browser.empty()) GTEST_SKIP() << "no chromium (scripts/install-deps.sh installs it)";
  fs::path out = fresh_dir("eval_html");
  EvalOptions e{trained_run(), shared_data(), out, 0, 2, 0};
  evaluate(e);
  const fs::path dom = out / "dom.html";
  const std::string cmd = browser +
                          " --headless --no-sandbox --disable-gpu --disable-dev-shm-usage "
                          "--no-first-run --user-data-dir=" + (out / "profile").string() +
                          " --virtual-time-budget=5000 --dump-dom file://" +
                          (out / "report.html").string() + " > " + dom.string() + " 2>/dev/null";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  std::ifstream in(dom);
  const std::string page((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // The script ran: 5 plots + the error scale; both strips decoded.
  EXPECT_NE(page.find("data-svgs=\"6\""), std::string::npos) << page.substr(0, 2000);
  EXPECT_NE(page.find("data-images=\"2\""), std::string::npos);
  // Plots with axis titles, tick values and legends.
  for (const char* text : {"Loss per epoch", ">epoch<", ">optimizer step<", "learning rate",
                           "class=\"ytick\"", "class=\"xtick\"", ">validation<",
                           ">training (mean over the epoch)<", ">noisy (1 spp)<", ">error ×4<",
                           "Validation SSIM per epoch", "PSNR (dB)",
                           "mean |denoised - reference| per pixel"})
    EXPECT_NE(page.find(text), std::string::npos) << text;
  // The numbers are report.json's.
  std::ifstream js(out / "report.json");
  nlohmann::json j = nlohmann::json::parse(js);
  char ssim[32];
  std::snprintf(ssim, sizeof ssim, "<td>%.4f</td>",
                j["summary"]["denoised"]["all"]["ssim"].get<double>());
  EXPECT_NE(page.find(ssim), std::string::npos) << ssim;
  EXPECT_NE(page.find(j["checkpoint"]["file"].get<std::string>()), std::string::npos);
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

TEST(Precision, Bf16DenoiseIsCloseToFp32AndFinite) {
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

}  // namespace
}  // namespace dofarm::trainer
