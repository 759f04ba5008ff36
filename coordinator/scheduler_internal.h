// Shared by the scheduler's source files (scheduler.cpp: leases and
// completions; scheduler_failures.cpp: the failure policy;
// scheduler_operations.cpp: the operator's cancel, resume and invalidate).
// Not an interface: coordinator/scheduler.h is.
#pragma once

#include <algorithm>
#include <string>
#include <vector>

#include "coordinator/scheduler.h"

namespace dofarm::coordinator {

// Here, not in scheduler.cpp, so that every scheduler source can use it.
template <typename F>
auto Scheduler::guarded(F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (...) {
    // The transaction rolled back, so the memory may be ahead of the store:
    // load it again from the store, which is the record.
    try {
      rebuild();
    } catch (...) {
    }
    throw;
  }
}

namespace scheduler_internal {

using Transaction = JobStore::Transaction;

inline std::string describe(const TaskRow& t) { return describe_task(t); }

inline bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

}  // namespace scheduler_internal
}  // namespace dofarm::coordinator
