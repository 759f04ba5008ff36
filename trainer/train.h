// The training loop (thesis 4.3) and the run folder it resumes from.
//
// RUN/ (docs/trainer.md, "Run folder")
//   config.toml          effective TrainConfig (resume starts from it)
//   split.json           train/validation frame ranges per shard (dataset.h)
//   checkpoints/         last.pt, best.pt, step-*.pt (run_folder.h)
//   loss.csv             one row per epoch: ...,val_ssim,val_psnr
//   steps.csv            one row per step: step,loss,lr
//   passes.json          training sequences per pass (eq. 4.5's E; epochs of
//                        train.steps_per_epoch = 0)
//   events.log           new run, resumes, stops, skipped non-finite steps, rollbacks
// With train.ema > 0 the checkpoints also hold the weights' moving average,
// which validation, best.pt and everything that loads a run use.
// Batches: batches.h; the step itself: step_runner.h.
//
// Adam(0.9, 0.99); learning rate by learning_rate(); a non-finite loss or gradient skips the step,
// and max_bad_steps in a row roll the model and optimizer back to the last checkpoint with the
// learning rate scaled by rollback_lr_factor.
#pragma once

#include <torch/torch.h>

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <future>
#include <memory>
#include <string>
#include <vector>

#include "trainer/augment.h"
#include "trainer/batches.h"
#include "trainer/config.h"
#include "trainer/model.h"
#include "trainer/run_folder.h"
#include "trainer/step_runner.h"

namespace dofarm::trainer {

struct TrainOptions {
  std::filesystem::path data_dir, run_dir;
  TrainConfig config;
  // Fault injection for tests: may replace the loss of a step before backward.
  std::function<torch::Tensor(int64_t step, const torch::Tensor& loss)> loss_hook = {};
  // Stop (after saving) once this many steps are done in total; -1 = never.
  int64_t stop_at_step = -1;
  // Set asynchronously (a signal handler): the current step finishes, last.pt
  // is written and train() returns with TrainResult::stopped.
  const std::atomic<bool>* stop = nullptr;
  // Every this many steps write last.pt and keep a copy as
  // checkpoints/step-NNNNNNNN.pt; 0 = only at the end of each epoch.
  int64_t save_every = 0;
};

struct TrainResult {
  int64_t steps = 0;      // total optimizer steps taken (skipped ones count)
  int epochs = 0;         // completed epochs
  double best_val = 0;    // lowest validation loss (train loss without validation)
  int skipped_steps = 0;  // this session
  int rollbacks = 0;      // this session
  bool resumed = false;
  bool stopped = false;  // by TrainOptions::stop, with last.pt written
};

// Makes glibc's malloc keep freed blocks up to 32 MiB in the heap instead of
// returning them to the kernel: a training step frees and reallocates some
// 200 MB of activations, which otherwise come back as fresh zeroed pages
// (about 45 000 page faults, 5-7% of a CPU step). train() calls it; RSS then
// stays at its peak.
void keep_freed_memory();

// Trains (or resumes) the run in options.run_dir. Throws SpecError when the run
// cannot be resumed with this config, RuntimeError on data or IO failure (a
// missing last.pt beside a loss.csv with epochs in it is one). A run folder
// that this call created is removed again when it fails before writing any
// progress, so that a corrected retry starts clean.
TrainResult train(const TrainOptions& options);

// The learning rate of optimizer step `step` (0-based) in epoch `epoch`:
//   train.schedule = "thesis": thesis eq. 4.5 with E = step / steps_per_pass,
//     the passes over the training sequences completed;
//   "warmup_decay": a linear warm-up over warmup_steps to lr, then
//     exponential decay by lr_decay per epoch, never below lr_min.
double learning_rate(const OptimConfig& o, int64_t step, int epoch, int64_t steps_per_pass);
// Thesis eq. 4.5: 1e-4 * 1.25893^E for E <= 9, else 1e-3 / sqrt(E).
double thesis_learning_rate(int64_t pass);

// The moving average's decay after optimizer step `step` (1-based: the
// number of steps taken) with train.ema = `ema`: min(ema, (1 + t) / (10 + t))
// with t = step - 1 (the warm-up of TensorFlow's ExponentialMovingAverage
// with num_updates), so the first update keeps 1/10 of the initial weights
// and the average follows the trained weights closely while they move fast.
double ema_decay(double ema, int64_t step);
// avg <- d * avg + (1 - d) * w, parameter by parameter (float32 throughout).
void update_average(Denoiser& average, Denoiser& model, double d);

// Whether an epoch's whole validation frames show that its weights fail on
// whole frames (docs/results.md, "Where whole frames fail"): their SSIM is
// not finite, or more than 0.2 below the validation crops' (`crops`), or
// more than 0.02 below the same frames denoised as crop-sized tiles
// (`tiles`; NaN `crops` or `tiles`: not compared). The trainer logs such
// an epoch, and it never becomes best.pt.
enum class FrameFailure { kNone, kNonFinite, kBelowCrops, kBelowTiles };
FrameFailure whole_frame_failure(double frames, double crops, double tiles);

}  // namespace dofarm::trainer
