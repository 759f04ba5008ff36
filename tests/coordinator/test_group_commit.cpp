// Group commit of heartbeats: a renewal reaches the store at the next flush,
// a renewal lost in a crash only shortens the lease, and a late flush never
// writes a renewal over a lease the worker no longer holds. Fake clock; a
// "crash" is a second store connection and scheduler on the same file while
// the first, never flushed, still holds its memory.
#include <gtest/gtest.h>

#include "coordinator/scheduler.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

using testing::TempDir;
using testing::tiny_spec;

class GroupCommitTest : public ::testing::Test {
 protected:
  GroupCommitTest() : store_(path()), sched_(store_, clock_, options()) {
    sched_.submit("/jobs/a.toml", {}, "/out", tiny_spec(2, 2));
    for (const char* w : {"w1", "w2"}) sched_.worker_seen(w, "host", 4);
  }
  static SchedulerOptions options() {
    SchedulerOptions o;
    o.lease_seconds = 30;
    o.heartbeat_flush_seconds = 1;
    return o;
  }
  std::filesystem::path path() const { return dir_.path() / "state.db"; }
  double stored_expiry(int64_t task) { return store_.task(task)->lease_expiry; }

  TempDir dir_;
  FakeClock clock_;
  JobStore store_;
  Scheduler sched_;
};

TEST_F(GroupCommitTest, RenewalIsWrittenAtTheNextFlushNotBefore) {
  const double t0 = clock_.now();
  const Assignment a = *sched_.assign("w1");
  EXPECT_EQ(stored_expiry(a.task_id), t0 + 30);  // the lease itself is written at once
  clock_.advance(20);
  ASSERT_TRUE(sched_.heartbeat("w1", a.task_id, a.attempt));
  sched_.flush_if_due();  // 20 s since the last flush: due
  EXPECT_EQ(stored_expiry(a.task_id), t0 + 50);
  clock_.advance(0.5);
  ASSERT_TRUE(sched_.heartbeat("w1", a.task_id, a.attempt));
  sched_.flush_if_due();  // 0.5 s: not due
  EXPECT_EQ(stored_expiry(a.task_id), t0 + 50);
  clock_.advance(0.5);
  sched_.flush_if_due();
  EXPECT_EQ(stored_expiry(a.task_id), t0 + 50.5);
}

TEST_F(GroupCommitTest, RenewalLostInACrashOnlyShortensTheLease) {
  const double t0 = clock_.now();
  const Assignment a = *sched_.assign("w1");
  sched_.flush();
  clock_.advance(20);
  ASSERT_TRUE(sched_.heartbeat("w1", a.task_id, a.attempt));  // t0 + 50, in memory only
  JobStore reopened(path());
  Scheduler restarted(reopened, clock_, options());
  clock_.set(t0 + 29);
  EXPECT_TRUE(restarted.expire_leases().empty());
  EXPECT_TRUE(restarted.heartbeat("w1", a.task_id, a.attempt)) << "the lease itself was lost";
  restarted.flush();
  clock_.set(t0 + 58);
  EXPECT_TRUE(restarted.expire_leases().empty()) << "the renewal after the restart was lost";
  clock_.set(t0 + 60);
  EXPECT_EQ(restarted.expire_leases(), std::vector<int64_t>{a.task_id});
}

TEST_F(GroupCommitTest, FlushedRenewalSurvivesARestart) {
  const double t0 = clock_.now();
  const Assignment a = *sched_.assign("w1");
  clock_.advance(20);
  ASSERT_TRUE(sched_.heartbeat("w1", a.task_id, a.attempt));
  clock_.advance(1);
  sched_.flush_if_due();
  JobStore reopened(path());
  Scheduler restarted(reopened, clock_, options());
  clock_.set(t0 + 45);
  EXPECT_TRUE(restarted.expire_leases().empty()) << "a flushed renewal was lost";
  clock_.set(t0 + 51);
  EXPECT_EQ(restarted.expire_leases(), std::vector<int64_t>{a.task_id});
}

TEST_F(GroupCommitTest, LateFlushNeverRenewsALeaseTheWorkerNoLongerHolds) {
  const Assignment a = *sched_.assign("w1");
  clock_.advance(20);
  ASSERT_TRUE(sched_.heartbeat("w1", a.task_id, a.attempt));  // not flushed yet
  ASSERT_TRUE(sched_.release("w1", a.task_id, a.attempt));
  const Assignment b = *sched_.assign("w2");
  ASSERT_EQ(b.task_id, a.task_id);
  sched_.flush();
  const TaskRow t = *store_.task(a.task_id);
  EXPECT_EQ(t.lease_worker, "w2");
  EXPECT_EQ(t.attempts, b.attempt);
  EXPECT_EQ(t.lease_expiry, b.lease_expiry);
  EXPECT_EQ(t.lease_expiry, clock_.now() + 30);
}

TEST_F(GroupCommitTest, StoreExtendsOnlyTheHoldersCurrentLeaseAndOnlyForward) {
  const Assignment a = *sched_.assign("w1");
  const double expiry = a.lease_expiry;
  EXPECT_FALSE(store_.extend_lease(a.task_id, a.attempt, "w2", expiry + 10));  // not the holder
  EXPECT_FALSE(
      store_.extend_lease(a.task_id, a.attempt + 1, "w1", expiry + 10));       // not this attempt
  EXPECT_FALSE(store_.extend_lease(a.task_id, a.attempt, "w1", expiry - 10));  // backwards
  EXPECT_EQ(stored_expiry(a.task_id), expiry);
  EXPECT_TRUE(store_.extend_lease(a.task_id, a.attempt, "w1", expiry + 10));
  EXPECT_EQ(stored_expiry(a.task_id), expiry + 10);
  ASSERT_EQ(sched_.complete("w1", a.task_id, a.attempt, "/out/t.exr", "xxh64:00"),
            CompleteStatus::kAccepted);
  EXPECT_FALSE(store_.extend_lease(a.task_id, a.attempt, "w1", expiry + 20));  // done
  EXPECT_EQ(stored_expiry(a.task_id), 0);
}

}  // namespace
}  // namespace dofarm::coordinator
