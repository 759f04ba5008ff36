// One training step's forward, loss and backward, on one model or split
// across model replicas (thesis 4.3 loss; the optimizer step is the caller's).
#pragma once

#include <torch/torch.h>

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "trainer/batches.h"
#include "trainer/config.h"
#include "trainer/model.h"

namespace dofarm::trainer {

// Forward, loss and backward of one batch, gradients set afresh (not
// accumulated). Returns the loss and whether it and every gradient are
// finite; the caller applies the step only then. `hook` (tests) may replace
// the loss before backward.
struct StepOutcome {
  double loss = 0;
  bool finite = false;
};
// `precision`: the network's forward (and so its backward) under that
// autocast (trainer/precision.h); the loss is computed in float32.
StepOutcome compute_gradients(Denoiser& model, const Batch& batch, const LossConfig& loss,
                              const torch::Tensor& kernel,
                              const std::function<torch::Tensor(const torch::Tensor&)>& hook = {},
                              Precision precision = Precision::kFp32);

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
  StepRunner(Denoiser model, int replicas, Precision precision = Precision::kFp32);
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
  Precision precision_;
};

// The global L2 norm of the gradients of `params` (all of them as one
// vector, accumulated in double) and, when max_norm > 0 and the norm exceeds
// it, the gradients scaled by max_norm / norm so that their norm becomes
// max_norm (gradient-norm clipping, Pascanu et al. 2013, sec. 3.2). Below
// the bound, or with max_norm = 0, the gradients are untouched, bit for bit.
// Returns the norm before clipping (0 without gradients). Not libtorch's
// clip_grad_norm_: that one sums in float, scales by max_norm / (norm +
// 1e-6) (never exactly to the bound) and rescales every step, clipped or
// not.
double clip_gradients(const std::vector<torch::Tensor>& params, double max_norm);

// Replicas for train.cpu_replicas = `configured` (0 = auto, see OptimConfig)
// on `device` with `threads` intra-op threads at `precision`; never more
// than `batch`.
int step_replicas(int configured, torch::Device device, int threads, int batch,
                  Precision precision = Precision::kFp32);

// The process's intra-op thread count, and where it came from. `requested` >
// 0 is taken as is; 0 takes OMP_NUM_THREADS when it is set to a positive
// count, else the CPUs this process may run on (sched_getaffinity: under
// Slurm, the job's allocation). libtorch's own default is the number of
// physical cores its cpuinfo finds, which on some virtual machines is 1 of 2
// (seen on the 2-core build machine: every training step ran on one core).
struct IntraOpThreads {
  int threads = 1;
  std::string source;  // "--threads", "OMP_NUM_THREADS" or "CPUs this process may use"
};
IntraOpThreads choose_intra_op_threads(int requested);

}  // namespace dofarm::trainer
