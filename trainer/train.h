// The training loop (thesis 4.3) and the run folder it resumes from.
//
// RUN/
//   config.toml          effective TrainConfig (resume refuses a model-incompatible one)
//   split.json           train/validation frame ranges per shard (dataset.h)
//   checkpoints/last.pt  model, Adam state, epoch, step, sample index, LR scale, best loss
//   checkpoints/best.pt  the same, for the lowest validation loss so far
//   loss.csv             one row per epoch: epoch,step,train_loss,val_loss,lr,skipped,seconds
//   events.log           resumes, skipped non-finite steps, rollbacks
//
// Adam(0.9, 0.99); learning rate per eq. 4.5 as implemented by
// learning_rate(); a non-finite loss or gradient skips the step, and
// max_bad_steps in a row roll the model and optimizer back to the last
// checkpoint with the learning rate scaled by rollback_lr_factor.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

#include "trainer/config.h"
#include "trainer/model.h"

namespace dofarm::trainer {

struct TrainOptions {
  std::filesystem::path data_dir, run_dir;
  TrainConfig config;
  // Fault injection for tests: may replace the loss of a step before backward.
  std::function<torch::Tensor(int64_t step, const torch::Tensor& loss)> loss_hook;
  // Stop (after saving) once this many steps are done in total; -1 = never.
  int64_t stop_at_step = -1;
};

struct TrainResult {
  int64_t steps = 0;      // total optimizer steps taken (skipped ones count)
  int epochs = 0;         // completed epochs
  double best_val = 0;    // lowest validation loss (train loss without validation)
  int skipped_steps = 0;  // this session
  int rollbacks = 0;      // this session
  bool resumed = false;
};

// Trains (or resumes) the run in options.run_dir. Throws SpecError when the run
// cannot be resumed with this config, RuntimeError on data or IO failure.
TrainResult train(const TrainOptions& options);

// Thesis eq. 4.5 as implemented: a linear warm-up over warmup_steps to lr,
// then exponential decay by lr_decay per epoch, never below lr_min.
double learning_rate(const OptimConfig& o, int64_t step, int epoch);

// The device the config asks for: CUDA when `auto` and available.
torch::Device pick_device(const std::string& device);

// A trained model from a run folder (checkpoints/best.pt, else last.pt), its
// config, on `device`, in eval mode.
struct LoadedRun {
  TrainConfig config;
  Denoiser model{nullptr};
  std::filesystem::path checkpoint;
};
LoadedRun load_run(const std::filesystem::path& run_dir, torch::Device device);

}  // namespace dofarm::trainer
