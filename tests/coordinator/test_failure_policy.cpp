// Issue 10, defect 10: fail, don't hang. A task that failed on every worker
// that could take it fails for good, and a batch with no eligible worker for
// stall_timeout fails with that reason, instead of running forever. Driven by
// a fake clock on a real store.
#include <gtest/gtest.h>

#include "coordinator/scheduler.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

using testing::TempDir;
using testing::tiny_spec;

class FailurePolicyTest : public ::testing::Test {
 protected:
  static SchedulerOptions options() { return testing::failure_policy_options(60); }
  FailurePolicyTest() : store_(dir_.path() / "state.db") { reopen(options()); }
  void reopen(SchedulerOptions o) {
    sched_.reset();
    sched_ = std::make_unique<Scheduler>(store_, clock_, o);
  }
  std::string submit(const JobSpec& spec) {
    return sched_->submit("/jobs/a.toml", {}, "/out", spec);
  }
  void hello(std::initializer_list<const char*> workers) {
    for (const char* w : workers) sched_->worker_seen(w, "host", 4);
  }
  Assignment take(const std::string& worker) { return testing::take(*sched_, worker); }
  BatchStatus status(const std::string& batch) { return sched_->status(batch).batches.at(0); }

  TempDir dir_;
  FakeClock clock_;
  JobStore store_;
  std::unique_ptr<Scheduler> sched_;
};

TEST_F(FailurePolicyTest, TaskFailedOnBothWorkersOfATwoWorkerFarmFailsForGood) {
  // Three failures are needed when three workers could try; with two, the
  // second one's failure is final (it used to wait for a third).
  const std::string batch = submit(tiny_spec(1, 1));
  hello({"w1", "w2"});
  const Assignment a = take("w1");
  EXPECT_EQ(sched_->fail("w1", a.task_id, a.attempt, "scene: not glTF").status, FailStatus::kRetry);
  clock_.advance(3);
  hello({"w1", "w2"});
  const Assignment b = take("w2");
  ASSERT_EQ(b.task_id, a.task_id);
  EXPECT_EQ(sched_->fail("w2", b.task_id, b.attempt, "scene: not glTF").status,
            FailStatus::kFailedForGood);
  const BatchStatus st = status(batch);
  EXPECT_EQ(st.batch.state, BatchState::kFailed);
  EXPECT_EQ(st.tasks_failed, 2);  // the tile and its pack
  EXPECT_NE(st.reason.find("scene: not glTF"), std::string::npos) << st.reason;
}

TEST_F(FailurePolicyTest, ALoneWorkerStillRetriesUpToTheLimit) {
  submit(tiny_spec(1, 1));
  hello({"w1"});
  for (int i = 1; i <= 3; ++i) {
    const Assignment a = take("w1");
    const FailStatus s = sched_->fail("w1", a.task_id, a.attempt, "flaky NFS").status;
    EXPECT_EQ(s, i < 3 ? FailStatus::kRetry : FailStatus::kFailedForGood) << "failure " << i;
    clock_.advance(10);
    hello({"w1"});
  }
}

TEST_F(FailurePolicyTest, BlocklistedWorkersTasksFailForGoodAndTheBatchFailsAfterTheStallTimeout) {
  const std::string batch = submit(tiny_spec(4, 4));  // four tiles, one pack
  hello({"w1"});
  const Assignment t1 = take("w1");
  EXPECT_EQ(sched_->fail("w1", t1.task_id, t1.attempt, "broken scene").status,
            FailStatus::kRetry);  // a lone worker may retry
  const Assignment t2 = take("w1");
  ASSERT_NE(t2.task_id, t1.task_id);
  const FailResult r = sched_->fail("w1", t2.task_id, t2.attempt, "broken scene");
  EXPECT_TRUE(r.worker_blocklisted);
  // Nobody is left to retry either task: both fail for good now.
  EXPECT_EQ(r.status, FailStatus::kFailedForGood);
  EXPECT_EQ(store_.task(t1.task_id)->state, TaskState::kFailed);
  EXPECT_EQ(store_.task(t1.task_id)->last_error, "broken scene");

  // The two tiles nobody tried wait for a worker, but not forever.
  EXPECT_TRUE(sched_->fail_stalled_batches().empty());  // the clock starts
  clock_.advance(30);
  hello({"w1"});  // live, but blocklisted: not eligible
  EXPECT_TRUE(sched_->fail_stalled_batches().empty());
  BatchStatus st = status(batch);
  EXPECT_EQ(st.batch.state, BatchState::kRunning);
  ASSERT_TRUE(st.stalled_seconds.has_value());
  EXPECT_DOUBLE_EQ(*st.stalled_seconds, 30);
  clock_.advance(31);
  EXPECT_EQ(sched_->fail_stalled_batches(), std::vector<std::string>{batch});
  st = status(batch);
  EXPECT_EQ(st.batch.state, BatchState::kFailed);
  EXPECT_EQ(st.tasks_failed, st.tasks_total);
  EXPECT_NE(st.reason.find("no eligible worker for 61 s"), std::string::npos) << st.reason;
  EXPECT_NE(st.reason.find("blocklisted: w1"), std::string::npos) << st.reason;
  EXPECT_FALSE(st.stalled_seconds.has_value());
  EXPECT_EQ(sched_->running_batches(), 0u);
  // The stored record says the same after a restart.
  reopen(options());
  EXPECT_EQ(status(batch).reason, st.reason);
}

TEST_F(FailurePolicyTest, StallClockStopsWhileAnEligibleWorkerIsLiveOrALeaseIsHeld) {
  const std::string batch = submit(tiny_spec(2, 2));
  EXPECT_TRUE(sched_->fail_stalled_batches().empty());  // nobody seen: the clock starts
  clock_.advance(50);
  hello({"w1"});
  const Assignment a = take("w1");
  EXPECT_TRUE(sched_->fail_stalled_batches().empty());
  EXPECT_FALSE(status(batch).stalled_seconds.has_value());
  // w1 goes quiet, but its lease keeps the batch from stalling until it expires.
  clock_.advance(25);
  EXPECT_TRUE(sched_->heartbeat("w1", a.task_id, a.attempt));
  clock_.advance(50);  // w1 last seen 50 s ago: lost (one lease), but it holds a lease
  EXPECT_TRUE(sched_->fail_stalled_batches().empty());
  clock_.advance(20);  // lease expired; w1 not live (70 s)
  EXPECT_FALSE(sched_->expire_leases().empty());
  EXPECT_TRUE(sched_->fail_stalled_batches().empty());  // the clock starts again
  clock_.advance(59);
  EXPECT_TRUE(sched_->fail_stalled_batches().empty());
  EXPECT_EQ(status(batch).batch.state, BatchState::kRunning);
  clock_.advance(2);
  EXPECT_EQ(sched_->fail_stalled_batches(), std::vector<std::string>{batch});
  EXPECT_NE(status(batch).reason.find("no live worker"), std::string::npos);
}

TEST_F(FailurePolicyTest, ZeroStallTimeoutNeverFailsABatch) {
  SchedulerOptions o = options();
  o.stall_timeout = 0;
  reopen(o);
  const std::string batch = submit(tiny_spec(1, 1));
  for (int i = 0; i < 5; ++i) {
    EXPECT_TRUE(sched_->fail_stalled_batches().empty());
    clock_.advance(1e6);
  }
  EXPECT_EQ(status(batch).batch.state, BatchState::kRunning);
}

}  // namespace
}  // namespace dofarm::coordinator
