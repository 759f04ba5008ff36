// The calling thread's CPU affinity mask, narrowed for a test: the default
// thread counts follow it (common/cpus.h), and a child process forked while
// it is narrowed inherits it.
#pragma once

#include <sched.h>

namespace dofarm::cpu_testing {

class CpuMask {
 public:
  CpuMask() {
    CPU_ZERO(&saved_);
    ok_ = sched_getaffinity(0, sizeof(saved_), &saved_) == 0;
  }
  ~CpuMask() { restore(); }
  CpuMask(const CpuMask&) = delete;
  CpuMask& operator=(const CpuMask&) = delete;

  // The CPUs of the mask it was made with (0 when it could not be read).
  int count() const { return ok_ ? CPU_COUNT(&saved_) : 0; }
  // Narrows the calling thread to the first CPU of that mask.
  bool narrow_to_one() {
    if (!ok_) return false;
    int first = 0;
    while (!CPU_ISSET(first, &saved_)) ++first;
    cpu_set_t one;
    CPU_ZERO(&one);
    CPU_SET(first, &one);
    narrowed_ = sched_setaffinity(0, sizeof(one), &one) == 0;
    return narrowed_;
  }
  // Back to the mask it was made with (also on destruction).
  bool restore() {
    if (!narrowed_) return true;
    narrowed_ = sched_setaffinity(0, sizeof(saved_), &saved_) != 0;
    return !narrowed_;
  }

 private:
  cpu_set_t saved_;
  bool ok_ = false, narrowed_ = false;
};

}  // namespace dofarm::cpu_testing
