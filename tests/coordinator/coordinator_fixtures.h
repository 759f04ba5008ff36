// Shared by the coordinator tests: a temporary state folder and small specs.
#pragma once

#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <optional>
#include <string>

#include <gtest/gtest.h>

#include "common/jobspec.h"
#include "coordinator/scheduler.h"

namespace dofarm::coordinator::testing {

class TempDir {
 public:
  TempDir() {
    static std::atomic<int> counter{0};
    path_ = std::filesystem::temp_directory_path() /
            ("dofarm_coordinator_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// `frames` frames of one whole-image tile each, `per_shard` frames a shard.
inline JobSpec tiny_spec(int frames, int per_shard, int tiles_per_side = 1) {
  JobSpec spec;
  spec.width = 16 * tiles_per_side;
  spec.height = 16 * tiles_per_side;
  spec.tile = 16;
  spec.frame_start = 0;
  spec.frame_end = frames - 1;
  spec.per_shard = per_shard;
  return spec;
}

// The scheduler options of the failure-policy tests (test_failure_policy,
// test_operator_view): a 30 s lease, a first retry after 2 s, failure for
// good at the third failure, a blocklist after two failed tasks of a batch,
// and `stall_timeout` seconds without an eligible worker to fail a batch
// (0: never).
inline SchedulerOptions failure_policy_options(double stall_timeout) {
  SchedulerOptions o;
  o.lease_seconds = 30;
  o.backoff_base = 2;
  o.max_task_failures = 3;
  o.blocklist_after = 2;
  o.stall_timeout = stall_timeout;
  return o;
}

// The next task for `worker`; a test failure (and an empty assignment) when
// there is none.
inline Assignment take(Scheduler& sched, const std::string& worker) {
  std::optional<Assignment> a = sched.assign(worker);
  EXPECT_TRUE(a.has_value()) << worker << " got nothing";
  return a.value_or(Assignment{});
}

// Completes `a` as `worker`, which must be accepted.
inline void done(Scheduler& sched, const std::string& worker, const Assignment& a) {
  ASSERT_EQ(sched.complete(worker, a.task_id, a.attempt, "/out/t.exr", "xxh64:00"),
            CompleteStatus::kAccepted);
}

}  // namespace dofarm::coordinator::testing
