#include "trainer/precision.h"

#include <ATen/autocast_mode.h>
#include <spdlog/spdlog.h>

#include <cstdlib>
#include <string>

#include "common/error.h"

namespace dofarm::trainer {

Precision parse_precision(const std::string& name, const std::string& key) {
  return value_of(precision_names(), name, key);
}

const char* precision_name(Precision p) {
  for (const auto& [n, q] : precision_names())
    if (q == p) return n.c_str();
  return "?";
}

bool cpu_runs_bf16_natively() {
  static const bool native =
      __builtin_cpu_supports("avx512bf16") || __builtin_cpu_supports("amx-bf16");
  return native;
}

bool bf16_emulation_forced() {
  const char* v = std::getenv("DOFARM_BF16_EMULATED");
  return v && std::string(v) == "1";
}

bool autocast_applies(Precision p, torch::Device device) {
  return p == Precision::kBf16 && device.is_cpu() &&
         (cpu_runs_bf16_natively() || bf16_emulation_forced());
}

void warn_if_not_applied(Precision p, torch::Device device, const std::string& key) {
  if (p == Precision::kFp32 || autocast_applies(p, device)) return;
  if (device.is_cpu())
    spdlog::warn(
        "{} = {} is not applied: this CPU has neither AVX-512 BF16 nor AMX, and libtorch's "
        "emulated bf16 ran 16x slower than fp32 per training step, with gradients at cosine "
        "0.91 to fp32's (docs/trainer.md, \"bfloat16 on the CPU\"); the network runs in fp32 "
        "(DOFARM_BF16_EMULATED=1 forces bf16)",
        key, precision_name(p));
  else
    spdlog::warn("{} = {} applies on the CPU only; on {} the network runs in fp32", key,
                 precision_name(p), device.str());
}

AutocastScope::AutocastScope(Precision p, torch::Device device) {
  if (!autocast_applies(p, device)) return;
  active_ = true;
  was_enabled_ = at::autocast::is_cpu_enabled();
  was_dtype_ = at::autocast::get_autocast_cpu_dtype();
  at::autocast::set_autocast_cpu_dtype(at::kBFloat16);
  at::autocast::set_cpu_enabled(true);
}

AutocastScope::~AutocastScope() {
  if (!active_) return;
  at::autocast::set_cpu_enabled(was_enabled_);
  at::autocast::set_autocast_cpu_dtype(was_dtype_);
  if (!was_enabled_) at::autocast::clear_cache();
}

}  // namespace dofarm::trainer
