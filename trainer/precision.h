// Reduced-precision compute for the denoiser's convolutions: bfloat16
// autocast on the CPU (oneDNN runs bf16 convolutions with AVX-512 BF16 /
// AMX where the CPU has them). Weights, optimiser state, the loss and
// everything outside the network stay float32; only the ops autocast lists
// as lower-precision-safe (convolutions, matrix products) run in bf16, and
// the network's output is turned back into float32 before anything reads it.
// Figures and the quality check: docs/trainer.md, "bfloat16 on the CPU".
#pragma once

#include <torch/torch.h>

#include <string>

#include "trainer/config.h"

namespace dofarm::trainer {

// "fp32" | "bf16"; anything else is a SpecError naming `key`.
Precision parse_precision(const std::string& name, const std::string& key);
const char* precision_name(Precision p);

// Whether this CPU runs bf16 convolutions in hardware (AVX-512 BF16 or
// AMX-BF16). Without, libtorch emulates them: on a Zen 3 EPYC (AVX2 only)
// 16x slower than fp32 per training step and 27x per denoised frame, with
// gradients at cosine 0.91 to fp32's (docs/trainer.md, "bfloat16 on the
// CPU"). The environment variable DOFARM_BF16_EMULATED=1 makes bf16 apply
// anyway (to measure that path).
bool cpu_runs_bf16_natively();
bool bf16_emulation_forced();
// Whether `p` changes anything on `device`: bf16 autocast is the CPU's only
// (on CUDA the network runs in float32), and only on a CPU that runs bf16
// natively or with DOFARM_BF16_EMULATED=1; elsewhere the caller says so once.
bool autocast_applies(Precision p, torch::Device device);
// Says once, naming `key`, that `p` is not applied on `device`.
void warn_if_not_applied(Precision p, torch::Device device, const std::string& key);

// Autocast on for this thread while the scope lives (autocast state is
// per thread: each StepRunner replica opens its own), restored after, and
// the cast-weight cache dropped so that no bf16 copy outlives a step (the
// weights change at every optimiser step). No-op where !autocast_applies.
class AutocastScope {
 public:
  AutocastScope(Precision p, torch::Device device);
  ~AutocastScope();
  AutocastScope(const AutocastScope&) = delete;
  AutocastScope& operator=(const AutocastScope&) = delete;

 private:
  bool active_ = false;
  bool was_enabled_ = false;
  at::ScalarType was_dtype_ = at::kBFloat16;
};

// The network's output of `forward()` run under AutocastScope(p, device),
// as float32 (what the loss, the scores and the remodulation read).
template <typename Forward>
torch::Tensor float_output(Precision p, torch::Device device, Forward&& forward) {
  torch::Tensor y;
  {
    AutocastScope autocast(p, device);
    y = forward();
  }
  return y.to(torch::kFloat);
}

}  // namespace dofarm::trainer
