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

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <future>
#include <memory>
#include <string>
#include <vector>

#include "trainer/augment.h"
#include "trainer/config.h"
#include "trainer/model.h"
#include "trainer/run_folder.h"

namespace dofarm::trainer {

class SequenceStream;

// One batch on the device: input [B, T, C, S, S] and target [B, T, 3, S, S],
// each frame in `format` (with ChannelsLast the [B*T, C, S, S] view the
// model takes is NHWC without a copy).
struct Batch {
  torch::Tensor input, target;
  uint64_t next_index = 0;  // the stream's next sample after this batch
};
Batch make_batch(const std::vector<Sample>& samples, torch::Device device,
                 torch::MemoryFormat format);

// Assembles the next batch on a background thread while the caller trains on
// the current one, so the step never waits for data (the stream's readers
// make the samples; this takes them in index order and lays them out).
// Single consumer; the stream must outlive it.
class BatchPrefetcher {
 public:
  BatchPrefetcher(SequenceStream& stream, int batch, torch::Device device,
                  torch::MemoryFormat format);
  ~BatchPrefetcher();  // waits for the batch in flight
  BatchPrefetcher(const BatchPrefetcher&) = delete;
  BatchPrefetcher& operator=(const BatchPrefetcher&) = delete;

  // The next batch (rethrows a stream failure); starts on the one after.
  Batch next();
  // Seconds next() has spent waiting for a batch that was not ready yet.
  double waited_seconds() const { return waited_; }

 private:
  Batch assemble();
  SequenceStream& stream_;
  int batch_;
  torch::Device device_;
  torch::MemoryFormat format_;
  std::future<Batch> pending_;
  double waited_ = 0;
};

// Forward, loss and backward of one batch, gradients set afresh (not
// accumulated). Returns the loss and whether it and every gradient are
// finite; the caller applies the step only then. `hook` (tests) may replace
// the loss before backward.
struct StepOutcome {
  double loss = 0;
  bool finite = false;
};
StepOutcome compute_gradients(Denoiser& model, const Batch& batch, const LossConfig& loss,
                              const torch::Tensor& kernel,
                              const std::function<torch::Tensor(const torch::Tensor&)>& hook = {});

// Runs training steps, on the CPU split across model replicas (data
// parallelism inside one process): the batch's sequences are divided into
// `replicas` contiguous parts, part 0 runs on `model` in the calling thread,
// part k on replica k (a copy of the model made before each step) in its own
// thread, each with intra-op threads / replicas threads of its own. The
// gradients are then combined in replica order, g = sum_k (n_k / n) g_k, which
// is the gradient of the whole batch's mean loss (every loss term is a mean
// over equal-sized sequences), up to float summation order; the order is
// fixed, so a run stays deterministic. On 2 cores oneDNN's convolutions run
// faster as two 1-thread halves than as one 2-thread whole (no per-layer
// barrier, each half in its own cache), and so do the element-wise layers
// (figures in docs/trainer.md). With replicas = 1 this is compute_gradients.
// The hook, if any, is applied to each part's loss.
class StepRunner {
 public:
  // Takes the process's intra-op threads down to threads / replicas for its
  // lifetime (restored by the destructor); replicas <= batch.
  StepRunner(Denoiser model, int replicas);
  ~StepRunner();
  StepRunner(const StepRunner&) = delete;
  StepRunner& operator=(const StepRunner&) = delete;

  int replicas() const { return int(copies_.size()) + 1; }
  // Gradients of `batch` left in the model's parameters, as compute_gradients.
  StepOutcome run(const Batch& batch, const LossConfig& loss, const torch::Tensor& kernel,
                  const std::function<torch::Tensor(const torch::Tensor&)>& hook = {});

 private:
  struct Worker;
  Denoiser model_;
  std::vector<Denoiser> copies_;
  std::vector<std::unique_ptr<Worker>> workers_;
  int saved_threads_ = 0;
};

// Replicas for train.cpu_replicas = `configured` (0 = auto, see OptimConfig)
// on `device` with `threads` intra-op threads; never more than `batch`.
int step_replicas(int configured, torch::Device device, int threads, int batch);

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

// Thesis eq. 4.5 as implemented: a linear warm-up over warmup_steps to lr,
// then exponential decay by lr_decay per epoch, never below lr_min.
double learning_rate(const OptimConfig& o, int64_t step, int epoch);

}  // namespace dofarm::trainer
