#include "trainer/precision.h"

#include <ATen/autocast_mode.h>
#include <spdlog/spdlog.h>

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

bool autocast_applies(Precision p, torch::Device device) {
  return p == Precision::kBf16 && device.is_cpu();
}

void warn_if_not_applied(Precision p, torch::Device device, const std::string& key) {
  if (p != Precision::kFp32 && !autocast_applies(p, device))
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
