#include "worker/render/simd.h"

#include <atomic>

namespace dofarm::render {

namespace {
std::atomic<bool> g_allowed{true};
}  // namespace

bool simd_available() {
#ifdef DOFARM_HAVE_AVX2_KERNELS
  static const bool yes = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") != 0;
  }();
  return yes;
#else
  return false;
#endif
}

void allow_simd(bool allowed) { g_allowed.store(allowed, std::memory_order_relaxed); }

bool use_simd() { return simd_available() && g_allowed.load(std::memory_order_relaxed); }

}  // namespace dofarm::render
