#include "trainer/precision.h"

#include <ATen/autocast_mode.h>

#include "common/error.h"

namespace dofarm::trainer {

Precision parse_precision(const std::string& name, const std::string& key) {
  if (name == "fp32") return Precision::kFp32;
  if (name == "bf16") return Precision::kBf16;
  throw SpecError(FileLoc{}, key, "expected fp32 or bf16, got \"" + name + "\"");
}

const char* precision_name(Precision p) { return p == Precision::kBf16 ? "bf16" : "fp32"; }

bool autocast_applies(Precision p, torch::Device device) {
  return p == Precision::kBf16 && device.is_cpu();
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
