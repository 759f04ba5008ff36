// The scheduler's in-memory queue: packs become runnable through their
// pending-dependency counts, and the queue, kept in memory or rebuilt from the
// store after a restart, always says what JobStore::runnable_tasks says.
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <random>

#include "coordinator/scheduler.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

using testing::TempDir;
using testing::tiny_spec;

class RunQueueTest : public ::testing::Test {
 protected:
  RunQueueTest() : store_(dir_.path() / "state.db"), sched_(store_, clock_) {}
  std::string submit(const JobSpec& spec) {
    return sched_.submit("/jobs/a.toml", {}, "/out", spec);
  }
  Assignment take(const std::string& worker) { return testing::take(sched_, worker); }
  void done(const std::string& worker, const Assignment& a) { testing::done(sched_, worker, a); }
  bool runnable(int64_t task, const std::string& worker = "w1") {
    const std::vector<int64_t> r = sched_.runnable(worker);
    return std::find(r.begin(), r.end(), task) != r.end();
  }
  // The answer of the store's own query, the reference.
  std::vector<int64_t> sql_runnable(JobStore& store, const std::string& worker) {
    std::vector<int64_t> ids;
    for (const TaskRow& t : store.runnable_tasks(worker, clock_.now(), 1 << 20)) {
      ids.push_back(t.id);
    }
    return ids;
  }
  int64_t pack_of(const std::string& batch) {
    for (const TaskRow& t : store_.tasks(batch)) {
      if (t.kind == TaskKind::kPackShard) return t.id;
    }
    ADD_FAILURE() << "no pack";
    return 0;
  }

  TempDir dir_;
  FakeClock clock_;
  JobStore store_;
  Scheduler sched_;
};

TEST_F(RunQueueTest, PackBecomesRunnableExactlyWhenItsLastTileIsDone) {
  const std::string batch = submit(tiny_spec(1, 1, 2));  // 4 tiles, 1 pack
  const int64_t pack = pack_of(batch);
  for (const char* w : {"w1", "w2"}) sched_.worker_seen(w, "host", 4);
  std::vector<Assignment> tiles;
  for (int i = 0; i < 4; ++i) tiles.push_back(take(i % 2 ? "w2" : "w1"));
  EXPECT_TRUE(sched_.runnable("w1").empty());
  for (int i = 0; i < 3; ++i) {
    done(i % 2 ? "w2" : "w1", tiles[i]);
    EXPECT_FALSE(runnable(pack)) << "runnable after " << i + 1 << " of 4 tiles";
  }
  // The last tile fails back to pending: the pack still waits.
  ASSERT_EQ(sched_.fail("w2", tiles[3].task_id, tiles[3].attempt, "flaky").status,
            FailStatus::kRetry);
  EXPECT_FALSE(runnable(pack)) << "a tile that failed back to pending counted as done";
  clock_.advance(10);  // past the back-off
  EXPECT_EQ(sched_.runnable("w1"), std::vector<int64_t>{tiles[3].task_id});
  const Assignment again = take("w1");
  ASSERT_EQ(again.task_id, tiles[3].task_id);
  EXPECT_FALSE(runnable(pack));
  done("w1", again);
  EXPECT_EQ(sched_.runnable("w1"), std::vector<int64_t>{pack});
  // A duplicate completion must not count a tile twice: the pack is taken
  // once and nothing else becomes runnable.
  EXPECT_EQ(sched_.complete("w1", again.task_id, again.attempt, "/out/t.exr", "xxh64:00"),
            CompleteStatus::kDuplicate);
  EXPECT_EQ(take("w2").task_id, pack);
  EXPECT_TRUE(sched_.runnable("w1").empty());
}

TEST_F(RunQueueTest, InvalidatedTileTakesItsPackOutOfTheQueueUntilItIsDoneAgain) {
  const std::string batch = submit(tiny_spec(2, 2));  // 2 tiles, 1 pack
  const int64_t pack = pack_of(batch);
  sched_.worker_seen("w1", "host", 4);
  const Assignment t0 = take("w1");
  const Assignment t1 = take("w1");
  done("w1", t0);
  done("w1", t1);
  EXPECT_EQ(sched_.runnable("w1"), std::vector<int64_t>{pack});
  ASSERT_TRUE(sched_.invalidate(t0.task_id).ok);
  EXPECT_EQ(sched_.runnable("w1"), std::vector<int64_t>{t0.task_id});
  EXPECT_EQ(sched_.runnable("w1"), sql_runnable(store_, "w1"));
  const Assignment redo = take("w1");
  EXPECT_TRUE(sched_.runnable("w1").empty());
  done("w1", redo);
  EXPECT_EQ(sched_.runnable("w1"), std::vector<int64_t>{pack});
}

// A worker blocklisted for an older batch still gets the next batch's packs.
// The queue skips a blocked batch in one step, to the first key after it;
// that key's rest was zeros, and packs (frame -1) sort below it, so the skip
// landed past the next batch's packs: w1 saw b's tiles but never b's pack.
TEST(RunQueue, AWorkerBlocklistedForOneBatchStillGetsTheNextBatchsPack) {
  TempDir dir;
  FakeClock clock;
  SchedulerOptions o;
  o.blocklist_after = 2;
  JobStore store(dir.path() / "state.db");
  Scheduler s(store, clock, o);
  const std::string a = s.submit("/jobs/a.toml", {}, "/out/a", tiny_spec(6, 6));
  const std::string b = s.submit("/jobs/b.toml", {}, "/out/b", tiny_spec(1, 1));
  // w1 fails two of a's tiles: blocklisted for a.
  for (int i = 0; i < 2; ++i) {
    const Assignment t = testing::take(s, "w1");
    ASSERT_EQ(t.batch_id, a);
    EXPECT_TRUE(s.fail("w1", t.task_id, t.attempt, "boom").worker_blocklisted == (i == 1));
  }
  // w2 takes a's other tiles, then renders b's only tile: b's pack is runnable.
  for (;;) {
    const Assignment t = testing::take(s, "w2");
    if (t.task_id == 0) FAIL() << "b's tile never came";
    if (t.batch_id != b) continue;
    testing::done(s, "w2", t);
    break;
  }
  // Past the back-off, a's failed tiles run again (for others): the skip
  // over a is taken for w1.
  clock.advance(3600);
  std::vector<int64_t> sql;
  for (const TaskRow& t : store.runnable_tasks("w1", clock.now(), 1 << 20)) sql.push_back(t.id);
  EXPECT_EQ(s.runnable("w1"), sql);
  const std::optional<Assignment> next = s.assign("w1");
  ASSERT_TRUE(next.has_value());
  EXPECT_EQ(next->batch_id, b);
  EXPECT_EQ(next->kind, TaskKind::kPackShard);
}

// Batch priorities: a later batch of higher priority is served before an
// older one, equal priorities oldest first, a change reorders what is handed
// out next (leases held are kept), and the order survives a restart.
TEST_F(RunQueueTest, HigherPriorityBatchesAreServedFirstAndEqualOnesOldestFirst) {
  const std::string old_batch = sched_.submit("/jobs/a.toml", {}, "/out/a", tiny_spec(2, 2));
  clock_.advance(1);
  const std::string urgent =
      sched_.submit("/jobs/b.toml", {}, "/out/b", tiny_spec(2, 2), {}, std::nullopt, 80);
  EXPECT_EQ(store_.batch(old_batch)->priority, kDefaultPriority);
  EXPECT_EQ(store_.batch(urgent)->priority, 80);
  // Both batches' tiles are runnable; the urgent one's come first.
  Assignment a = take("w1");
  EXPECT_EQ(a.batch_id, urgent);
  EXPECT_EQ(sql_runnable(store_, "w1"), sched_.runnable("w1"));

  // Lowered below the old batch: the old batch's tiles come next, and the
  // lease already held stays.
  EXPECT_TRUE(sched_.set_priority(urgent, 10).ok);
  EXPECT_EQ(sql_runnable(store_, "w1"), sched_.runnable("w1"));
  EXPECT_EQ(take("w2").batch_id, old_batch);
  EXPECT_TRUE(sched_.heartbeat("w1", a.task_id, a.attempt)) << "the lease survives the change";

  // Equal priorities: the older batch first.
  EXPECT_TRUE(sched_.set_priority(urgent, kDefaultPriority).ok);
  EXPECT_EQ(take("w3").batch_id, old_batch);

  // Out of range, or no such batch: refused, nothing changed.
  EXPECT_FALSE(sched_.set_priority(urgent, kMaxPriority + 1).ok);
  EXPECT_FALSE(sched_.set_priority(urgent, -1).ok);
  EXPECT_FALSE(sched_.set_priority("b-00000000", 60).ok);
  EXPECT_EQ(store_.batch(urgent)->priority, kDefaultPriority);

  // Raised again; a restarted coordinator keeps the order (from the store).
  EXPECT_TRUE(sched_.set_priority(urgent, kMaxPriority).ok);
  const std::vector<int64_t> before = sched_.runnable("w4");
  ASSERT_FALSE(before.empty());
  EXPECT_EQ(store_.task(before.front())->batch_id, urgent);
  sched_.flush();
  JobStore reopened(dir_.path() / "state.db");
  Scheduler restarted(reopened, clock_);
  EXPECT_EQ(restarted.runnable("w4"), before);
  EXPECT_EQ(reopened.batch(urgent)->priority, kMaxPriority);
  // The change is an event of the batch.
  bool seen = false;
  for (const EventRow& e : reopened.events(urgent, 100)) seen |= e.kind == "priority";
  EXPECT_TRUE(seen);
}

// A seeded random walk through every operation (assign, complete, fail,
// release, heartbeat, lease expiry, invalidate, cancel, resume, priority
// changes, time passing)
// over three batches and four workers. After every step the queue in memory
// must list exactly the tasks the store's query lists, for every worker; and
// every 20 steps the coordinator "crashes" (a new store connection and
// scheduler on the same file, the old one never flushed) and the rebuilt
// queue must list them too.
TEST(RunQueue, QueueInMemoryAndRebuiltAfterARestartEqualTheStoresAnswer) {
  TempDir dir;
  FakeClock clock;
  SchedulerOptions o;
  o.max_task_failures = 2;  // reach failures for good and blocklists quickly
  o.blocklist_after = 2;
  std::vector<std::unique_ptr<JobStore>> stores;
  std::vector<std::unique_ptr<Scheduler>> scheds;  // old ones stay: a crash does not flush
  stores.push_back(std::make_unique<JobStore>(dir.path() / "state.db"));
  scheds.push_back(std::make_unique<Scheduler>(*stores.back(), clock, o));
  std::vector<std::string> batches;
  for (const JobSpec& spec : {tiny_spec(4, 2, 2), tiny_spec(3, 1), tiny_spec(2, 2)}) {
    batches.push_back(scheds.back()->submit("/jobs/a.toml", {}, "/out", spec));
  }
  const std::vector<std::string> workers = {"w1", "w2", "w3", "w4"};
  struct Held {
    std::string worker;
    int64_t task;
    int attempt;
  };
  std::vector<Held> held;
  std::vector<int64_t> done_tasks;
  std::mt19937 rng(7);
  auto pick = [&](size_t n) { return size_t(rng() % n); };
  auto check = [&](Scheduler& s, JobStore& store, const std::string& when) {
    for (const std::string& w : workers) {
      std::vector<int64_t> sql;
      for (const TaskRow& t : store.runnable_tasks(w, clock.now(), 1 << 20)) sql.push_back(t.id);
      ASSERT_EQ(s.runnable(w), sql) << w << " " << when;
    }
  };
  int failed_for_good = 0, blocklisted = 0, expired = 0, invalidated = 0, restarts = 0;
  int reprioritised = 0;
  std::mt19937 priorities(11);  // its own stream: the walk's draws stay as they were
  for (int step = 0; step < 400; ++step) {
    Scheduler& s = *scheds.back();
    if (step % 9 == 4) {
      // Batch priorities reorder the queue (ties: oldest batch first).
      static constexpr int kLevels[] = {kMinPriority, kDefaultPriority, kDefaultPriority + 1,
                                        kMaxPriority};
      reprioritised +=
          s.set_priority(batches[priorities() % batches.size()], kLevels[priorities() % 4]).ok;
    }
    const std::string& w = workers[pick(workers.size())];
    const int op = int(pick(100));
    if (op < 35) {
      if (std::optional<Assignment> a = s.assign(w)) held.push_back({w, a->task_id, a->attempt});
    } else if (op < 60 && !held.empty()) {
      const size_t i = pick(held.size());
      if (s.complete(held[i].worker, held[i].task, held[i].attempt, "/out/t.exr", "xxh64:00") ==
          CompleteStatus::kAccepted) {
        done_tasks.push_back(held[i].task);
      }
      held.erase(held.begin() + long(i));
    } else if (op < 70 && !held.empty()) {
      const size_t i = pick(held.size());
      const FailResult r = s.fail(held[i].worker, held[i].task, held[i].attempt, "boom");
      failed_for_good += r.status == FailStatus::kFailedForGood;
      blocklisted += r.worker_blocklisted;
      held.erase(held.begin() + long(i));
    } else if (op < 74 && !held.empty()) {
      const size_t i = pick(held.size());
      s.release(held[i].worker, held[i].task, held[i].attempt);
      held.erase(held.begin() + long(i));
    } else if (op < 82 && !held.empty()) {
      const Held& h = held[pick(held.size())];
      s.heartbeat(h.worker, h.task, h.attempt);
    } else if (op < 90) {
      clock.advance(double(pick(4)));
      for (const std::string& v : workers) s.worker_seen(v, "host", 4);
    } else if (op < 92) {
      clock.advance(31);  // every lease not renewed since ends
      for (const std::string& v : workers) s.worker_seen(v, "host", 4);
      expired += int(s.expire_leases().size());
    } else if (op < 96 && !done_tasks.empty()) {
      invalidated += s.invalidate(done_tasks[pick(done_tasks.size())]).ok;
    } else if (op < 98) {
      s.cancel(batches[pick(batches.size())]);
    } else {
      s.resume(batches[pick(batches.size())]);
    }
    check(s, *stores.back(), "after step " + std::to_string(step));
    if (::testing::Test::HasFatalFailure()) return;
    if (step % 20 == 19) {
      stores.push_back(std::make_unique<JobStore>(dir.path() / "state.db"));
      scheds.push_back(std::make_unique<Scheduler>(*stores.back(), clock, o));
      ++restarts;
      check(*scheds.back(), *stores.back(), "after restart " + std::to_string(restarts));
      if (::testing::Test::HasFatalFailure()) return;
    }
  }
  // The walk went through the states that matter.
  EXPECT_GT(failed_for_good, 0);
  EXPECT_GT(blocklisted, 0);
  EXPECT_GT(expired, 0);
  EXPECT_GT(invalidated, 0);
  EXPECT_GT(reprioritised, 0);
  EXPECT_EQ(restarts, 20);
}

}  // namespace
}  // namespace dofarm::coordinator
