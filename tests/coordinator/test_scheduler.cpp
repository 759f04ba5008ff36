// Scheduler: the failure policy of DESIGN.md "The farm", driven by a fake
// clock (no sleeping) on a real store in a temporary folder.
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>

#include "coordinator/scheduler.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

using testing::TempDir;
using testing::tiny_spec;

class SchedulerTest : public ::testing::Test {
 protected:
  SchedulerTest() : store_(dir_.path() / "state.db"), sched_(store_, clock_, options()) {}
  static SchedulerOptions options() {
    SchedulerOptions o;
    o.lease_seconds = 30;
    o.backoff_base = 2;
    o.backoff_max = 300;
    return o;
  }
  std::string submit(const JobSpec& spec) {
    return sched_.submit("/jobs/a.toml", {"image.width=16"}, "/out", spec);
  }
  // Registers live workers so the "another worker could take it" rule sees them.
  void hello(std::initializer_list<const char*> workers) {
    for (const char* w : workers) sched_.worker_seen(w, "host", 4);
  }
  Assignment take(const std::string& worker) { return testing::take(sched_, worker); }
  void done(const std::string& worker, const Assignment& a) { testing::done(sched_, worker, a); }
  BatchStatus status(const std::string& batch) { return sched_.status(batch).batches.at(0); }

  TempDir dir_;
  FakeClock clock_;
  JobStore store_;
  Scheduler sched_;
};

TEST_F(SchedulerTest, ExpiredLeaseIsRequeuedWithoutCountingAFailure) {
  submit(tiny_spec(1, 1));
  hello({"w1", "w2"});
  const Assignment a = take("w1");
  clock_.advance(29);
  EXPECT_TRUE(sched_.heartbeat("w1", a.task_id, a.attempt));  // lease now ends at +59
  clock_.advance(29);
  EXPECT_TRUE(sched_.expire_leases().empty());
  clock_.advance(31);
  EXPECT_EQ(sched_.expire_leases(), std::vector<int64_t>{a.task_id});
  EXPECT_FALSE(sched_.heartbeat("w1", a.task_id, a.attempt));
  // No back-off and no failure: the same worker may take it again at once.
  const Assignment again = take("w1");
  EXPECT_EQ(again.task_id, a.task_id);
  EXPECT_EQ(again.attempt, a.attempt + 1);
  EXPECT_EQ(store_.failure_count(a.task_id, 0), 0);
  EXPECT_EQ(store_.attempts(a.task_id)[0].outcome, AttemptOutcome::kExpired);
}

TEST_F(SchedulerTest, LateResultAfterReassignmentIsIgnored) {
  submit(tiny_spec(1, 1));
  hello({"w1", "w2"});
  const Assignment a1 = take("w1");
  clock_.advance(31);
  const Assignment a2 = take("w2");  // assign expires w1's lease first
  ASSERT_EQ(a2.task_id, a1.task_id);
  EXPECT_EQ(sched_.complete("w1", a1.task_id, a1.attempt, "/out/late.exr", "xxh64:01"),
            CompleteStatus::kStale);
  EXPECT_EQ(store_.task(a1.task_id)->state, TaskState::kLeased);
  EXPECT_EQ(sched_.fail("w1", a1.task_id, a1.attempt, "boom").status, FailStatus::kStale);
  EXPECT_EQ(store_.failure_count(a1.task_id, 0), 0);
  done("w2", a2);
  EXPECT_EQ(store_.task(a1.task_id)->staged_path, "/out/t.exr");
}

TEST_F(SchedulerTest, DuplicateCompletionIsHarmless) {
  const std::string batch = submit(tiny_spec(1, 1));
  hello({"w1"});
  const Assignment tile = take("w1");
  done("w1", tile);
  EXPECT_EQ(sched_.complete("w1", tile.task_id, tile.attempt, "/out/other.exr", "xxh64:02"),
            CompleteStatus::kDuplicate);
  EXPECT_EQ(store_.task(tile.task_id)->staged_path, "/out/t.exr");
  EXPECT_EQ(sched_.complete("w1", 9999, 1, "", ""), CompleteStatus::kUnknownTask);
  const Assignment pack = take("w1");
  done("w1", pack);
  EXPECT_EQ(sched_.complete("w1", pack.task_id, pack.attempt, "/out/s.h5", "xxh64:03"),
            CompleteStatus::kDuplicate);
  EXPECT_EQ(status(batch).batch.state, BatchState::kDone);
}

TEST_F(SchedulerTest, AWorkerNeverGetsATaskItFailedWhileAnotherWorkerCouldTakeIt) {
  submit(tiny_spec(2, 2));  // two tiles, then a pack
  hello({"w1", "w2"});
  const Assignment a = take("w1");
  ASSERT_EQ(sched_.fail("w1", a.task_id, a.attempt, "bad tile").status, FailStatus::kRetry);
  clock_.advance(1000);  // long past any back-off
  hello({"w2"});
  const Assignment next = take("w1");
  EXPECT_NE(next.task_id, a.task_id) << "w1 got back the task it failed";
  done("w1", next);
  EXPECT_FALSE(sched_.assign("w1").has_value()) << "only the failed tile is left";
  EXPECT_EQ(take("w2").task_id, a.task_id);
}

TEST_F(SchedulerTest, ALoneWorkerRetriesItsFailedTaskAfterTheBackOff) {
  submit(tiny_spec(1, 1));
  hello({"w1"});
  const Assignment a = take("w1");
  sched_.fail("w1", a.task_id, a.attempt, "flaky");
  clock_.advance(2.5);
  EXPECT_EQ(take("w1").task_id, a.task_id);
}

TEST_F(SchedulerTest, BackOffIsRespectedAndDoubles) {
  submit(tiny_spec(1, 1));
  hello({"w1"});
  Assignment a = take("w1");
  FailResult r = sched_.fail("w1", a.task_id, a.attempt, "e1");
  EXPECT_EQ(r.retry_at, clock_.now() + 2);
  clock_.advance(1.9);
  EXPECT_FALSE(sched_.assign("w1").has_value());
  clock_.advance(0.2);
  a = take("w1");
  r = sched_.fail("w1", a.task_id, a.attempt, "e2");
  EXPECT_EQ(r.status, FailStatus::kRetry);
  EXPECT_EQ(r.retry_at, clock_.now() + 4);
  clock_.advance(3.9);
  EXPECT_FALSE(sched_.assign("w1").has_value());
  clock_.advance(0.2);
  EXPECT_TRUE(sched_.assign("w1").has_value());
}

TEST_F(SchedulerTest, FailsForGoodAfterThreeDistinctWorkersAndTheBatchStillEnds) {
  const std::string batch = submit(tiny_spec(2, 1));  // shard 0: frame 0; shard 1: frame 1
  hello({"w1", "w2", "w3"});
  const Assignment bad = take("w1");
  ASSERT_EQ(bad.frame, 0);
  EXPECT_EQ(sched_.fail("w1", bad.task_id, bad.attempt, "NaN in tile").status, FailStatus::kRetry);
  // Frame 1's tile and pack go to w1 meanwhile: it keeps working on others.
  const Assignment good = take("w1");
  ASSERT_EQ(good.frame, 1);
  done("w1", good);
  const Assignment pack1 = take("w1");
  ASSERT_EQ(pack1.kind, TaskKind::kPackShard);
  done("w1", pack1);
  clock_.advance(10);
  hello({"w2", "w3"});
  for (const char* w : {"w2", "w3"}) {
    const Assignment a = take(w);
    ASSERT_EQ(a.task_id, bad.task_id);
    const FailResult r = sched_.fail(w, a.task_id, a.attempt, std::string("NaN in tile on ") + w);
    EXPECT_EQ(r.status, w == std::string("w3") ? FailStatus::kFailedForGood : FailStatus::kRetry);
    clock_.advance(10);
    hello({"w1", "w2", "w3"});
  }
  EXPECT_EQ(store_.failed_workers(bad.task_id, 0), (std::vector<std::string>{"w1", "w2", "w3"}));
  const BatchStatus st = status(batch);
  EXPECT_EQ(st.batch.state, BatchState::kFailed);
  EXPECT_EQ(st.tasks_failed, 2);  // the tile and the pack that needed it
  EXPECT_EQ(st.tasks_done, 2);
  EXPECT_EQ(st.frames_packed, 1);
  ASSERT_EQ(st.failed.size(), 2u);
  EXPECT_EQ(st.failed[0].error, "NaN in tile on w3");
  EXPECT_EQ(st.failed[0].reproduce,
            "dofarm render /jobs/a.toml --frame 0 --tile 0,0,16,16 --out repro.exr "
            "--set image.width=16");
  EXPECT_EQ(st.failed[1].kind, TaskKind::kPackShard);
  EXPECT_NE(st.failed[1].error.find("NaN in tile on w3"), std::string::npos);
}

TEST_F(SchedulerTest, WorkerFailingThreeTasksOfABatchIsBlocklistedForIt) {
  const std::string batch = submit(tiny_spec(4, 4));
  const std::string other = submit(tiny_spec(1, 1));
  hello({"w1"});
  for (int i = 0; i < 3; ++i) {
    const Assignment a = take("w1");
    ASSERT_EQ(a.batch_id, batch);
    const FailResult r = sched_.fail("w1", a.task_id, a.attempt, "driver crash");
    EXPECT_EQ(r.worker_blocklisted, i == 2);
  }
  clock_.advance(1000);
  hello({"w1"});
  const Assignment a = take("w1");
  EXPECT_EQ(a.batch_id, other) << "a blocklisted worker still got a task of the batch";
  EXPECT_EQ(status(batch).blocklisted, std::vector<std::string>{"w1"});
}

TEST_F(SchedulerTest, ReleaseIsNotAFailure) {
  submit(tiny_spec(1, 1));
  hello({"w1", "w2"});
  const Assignment a = take("w1");
  EXPECT_TRUE(sched_.release("w1", a.task_id, a.attempt));
  EXPECT_FALSE(sched_.release("w1", a.task_id, a.attempt));  // no longer held
  EXPECT_EQ(store_.failure_count(a.task_id, 0), 0);
  // Neither back-off nor exclusion: the same worker may take it at once.
  EXPECT_EQ(take("w1").task_id, a.task_id);
}

TEST_F(SchedulerTest, PackRunsOnlyAfterAllItsTilesAndListsThem) {
  submit(tiny_spec(2, 2, 2));  // 2 frames x 4 tiles, one shard
  hello({"w1"});
  std::vector<Assignment> tiles;
  for (int i = 0; i < 8; ++i) {
    tiles.push_back(take("w1"));
    ASSERT_EQ(tiles.back().kind, TaskKind::kRenderTile);
  }
  EXPECT_EQ(tiles.front().frame, 0);  // earlier frames first
  EXPECT_EQ(tiles.back().frame, 1);
  for (int i = 0; i < 7; ++i) done("w1", tiles[i]);
  EXPECT_FALSE(sched_.assign("w1").has_value()) << "pack assigned with a tile still leased";
  done("w1", tiles[7]);
  const Assignment pack = take("w1");
  EXPECT_EQ(pack.kind, TaskKind::kPackShard);
  EXPECT_EQ(pack.shard_range.frame_start, 0);
  EXPECT_EQ(pack.shard_range.frame_end, 1);
  EXPECT_EQ(pack.shard_range.file, "shard-00000.h5");
  ASSERT_EQ(pack.inputs.size(), 8u);
  EXPECT_EQ(pack.inputs[0].frame, 0);
  EXPECT_EQ(pack.inputs[7].frame, 1);
  EXPECT_EQ(pack.inputs[7].staged_path, "/out/t.exr");
}

TEST_F(SchedulerTest, CancelRevokesLeasesAndResumeGoesOn) {
  const std::string batch = submit(tiny_spec(2, 2));
  hello({"w1"});
  const Assignment a = take("w1");
  EXPECT_TRUE(sched_.cancel(batch).ok);
  EXPECT_FALSE(sched_.cancel(batch).ok);  // already cancelled
  EXPECT_FALSE(sched_.heartbeat("w1", a.task_id, a.attempt));
  EXPECT_EQ(sched_.complete("w1", a.task_id, a.attempt, "/x", "xxh64:00"), CompleteStatus::kStale);
  EXPECT_FALSE(sched_.assign("w1").has_value());
  EXPECT_EQ(status(batch).batch.state, BatchState::kCancelled);
  EXPECT_FALSE(sched_.resume("b-nosuch0").ok);
  EXPECT_TRUE(sched_.resume(batch).ok);
  for (int i = 0; i < 3; ++i) done("w1", take("w1"));
  EXPECT_EQ(status(batch).batch.state, BatchState::kDone);
}

TEST_F(SchedulerTest, ResumeGivesFailedTasksAFreshCount) {
  SchedulerOptions o = options();
  o.max_task_failures = 1;
  Scheduler strict(store_, clock_, o);
  const std::string batch = strict.submit("/jobs/a.toml", {}, "/out", tiny_spec(1, 1));
  strict.worker_seen("w1", "host", 4);
  const Assignment a = *strict.assign("w1");
  ASSERT_EQ(strict.fail("w1", a.task_id, a.attempt, "bad").status, FailStatus::kFailedForGood);
  EXPECT_EQ(strict.status(batch).batches[0].batch.state, BatchState::kFailed);
  ASSERT_TRUE(strict.resume(batch).ok);
  EXPECT_EQ(strict.status(batch).batches[0].batch.state, BatchState::kRunning);
  const Assignment again = *strict.assign("w1");
  EXPECT_EQ(again.task_id, a.task_id);
  EXPECT_GT(again.attempt, a.attempt);  // attempt numbers never repeat
}

TEST_F(SchedulerTest, StatusCountsFramesRateAndEta) {
  const std::string batch = submit(tiny_spec(4, 2));  // shards {0,1}, {2,3}
  hello({"w1", "w2"});
  const double t0 = clock_.now();
  clock_.advance(60);
  done("w1", take("w1"));  // frame 0
  clock_.advance(60);
  done("w1", take("w1"));                // frame 1
  const Assignment leased = take("w2");  // frame 2, still running
  BatchStatus st = status(batch);
  EXPECT_EQ(st.tasks_total, 6);
  EXPECT_EQ(st.tasks_done, 2);
  EXPECT_EQ(st.tasks_leased, 1);
  EXPECT_EQ(st.tasks_pending, 3);
  EXPECT_EQ(st.frames_total, 4);
  EXPECT_EQ(st.frames_rendered, 2);
  EXPECT_EQ(st.frames_packed, 0);
  // 2 frames in the 120 s since submission: 60 frames/hour, 2 left: 120 s.
  EXPECT_DOUBLE_EQ(clock_.now() - t0, 120);
  EXPECT_DOUBLE_EQ(st.frames_per_hour, 60);
  ASSERT_TRUE(st.eta_seconds.has_value());
  EXPECT_DOUBLE_EQ(*st.eta_seconds, 120);
  const StatusReport all = sched_.status();
  ASSERT_EQ(all.workers.size(), 2u);
  EXPECT_EQ(all.workers[1].leased_tasks, std::vector<int64_t>{leased.task_id});
  EXPECT_TRUE(all.workers[0].live);
  // Past the window the rate only counts recent frames: none, so no ETA.
  clock_.advance(601);
  sched_.heartbeat("w2", leased.task_id, leased.attempt);
  st = status(batch);
  EXPECT_EQ(st.frames_per_hour, 0);
  EXPECT_FALSE(st.eta_seconds.has_value());
  EXPECT_FALSE(sched_.status().workers[0].live);  // w1 unseen for 601 s > one lease
}

TEST_F(SchedulerTest, InvalidatedStagedTileIsRenderedAgainBeforeThePack) {
  const std::string batch = submit(tiny_spec(2, 2));
  hello({"w1"});
  const Assignment t0 = take("w1");
  const Assignment t1 = take("w1");
  done("w1", t0);
  done("w1", t1);
  const std::vector<StagedTile> staged = sched_.staged_tiles_to_verify(batch);
  ASSERT_EQ(staged.size(), 2u);
  EXPECT_EQ(staged[0].staged_path, "/out/t.exr");
  EXPECT_EQ(staged[0].checksum, "xxh64:00");
  // The caller found t1's staged file corrupt.
  ASSERT_TRUE(sched_.invalidate(t1.task_id).ok);
  EXPECT_FALSE(sched_.invalidate(t1.task_id).ok);  // not done any more
  EXPECT_EQ(sched_.staged_tiles_to_verify(batch).size(), 1u);
  const Assignment redo = take("w1");
  EXPECT_EQ(redo.task_id, t1.task_id) << "the pack ran with a tile missing";
  EXPECT_FALSE(sched_.assign("w1").has_value());
  done("w1", redo);
  const Assignment pack = take("w1");
  EXPECT_EQ(pack.kind, TaskKind::kPackShard);
  done("w1", pack);
  EXPECT_TRUE(sched_.staged_tiles_to_verify(batch).empty());  // packed: nothing to verify
  EXPECT_EQ(status(batch).batch.state, BatchState::kDone);
}

TEST_F(SchedulerTest, ARestartedCoordinatorGoesOnWithTheLeasesItHad) {
  const std::string batch = submit(tiny_spec(1, 1));
  hello({"w1"});
  const Assignment a = take("w1");
  {
    // A second coordinator process on the same state folder, after a kill.
    JobStore reopened(dir_.path() / "state.db");
    Scheduler restarted(reopened, clock_, options());
    clock_.advance(10);
    EXPECT_TRUE(restarted.expire_leases().empty());  // the lease still runs
    EXPECT_TRUE(restarted.heartbeat("w1", a.task_id, a.attempt));
    EXPECT_EQ(restarted.complete("w1", a.task_id, a.attempt, "/out/t.exr", "xxh64:00"),
              CompleteStatus::kAccepted);
  }
  EXPECT_EQ(store_.task(a.task_id)->state, TaskState::kDone);
  EXPECT_EQ(status(batch).tasks_done, 1);
}

}  // namespace
}  // namespace dofarm::coordinator
