// What an operator sees (issue 14, "Status as operators know it"): workers
// with their liveness, counts and current tile; the task table with errors
// and reproduce commands; the events of a batch in time order; all of it as
// the bounded JSON of the wire. A fake clock on a real store.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include "common/messages.h"
#include "common/protocol.h"
#include "coordinator/scheduler.h"
#include "coordinator/server.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

using testing::TempDir;
using testing::tiny_spec;

class OperatorViewTest : public ::testing::Test {
 protected:
  static SchedulerOptions options() { return testing::failure_policy_options(0); }
  OperatorViewTest() : store_(dir_.path() / "state.db") { reopen(); }
  void reopen() {
    sched_.reset();
    sched_ = std::make_unique<Scheduler>(store_, clock_, options());
  }
  Assignment take(const std::string& worker) { return testing::take(*sched_, worker); }
  const WorkerStatus& worker(const StatusReport& r, const std::string& id) {
    for (const WorkerStatus& w : r.workers)
      if (w.worker.id == id) return w;
    ADD_FAILURE() << "no worker " << id;
    static WorkerStatus none;
    return none;
  }

  TempDir dir_;
  FakeClock clock_;
  JobStore store_;
  std::unique_ptr<Scheduler> sched_;
};

// The rule (docs/farm.md "Worker liveness"): live while heard from within one
// lease length, lost after, left once it said goodbye; the same rule decides
// who is eligible for tasks.
TEST_F(OperatorViewTest, WorkerIsLiveForOneLeaseOfSilenceThenLostAndLeftWhenItSaysSo) {
  sched_->worker_seen("w1", "node-01.farm", 8);
  sched_->worker_seen("w2", "node-02.farm", 8);
  clock_.advance(30);  // exactly one lease: still live
  StatusReport r = sched_->status();
  EXPECT_EQ(worker(r, "w1").state, Liveness::kLive);
  EXPECT_TRUE(worker(r, "w1").live);
  EXPECT_EQ(worker(r, "w1").worker.host, "node-01.farm");
  clock_.advance(0.5);
  sched_->worker_seen("w2", "node-02.farm", 8);
  r = sched_->status();
  EXPECT_EQ(worker(r, "w1").state, Liveness::kLost);
  EXPECT_FALSE(worker(r, "w1").live);
  EXPECT_EQ(worker(r, "w2").state, Liveness::kLive);
  const protocol::Json j = status_to_json(r);
  for (const auto& w : j.at("workers")) {
    EXPECT_EQ(w.at("state"), w.at("worker") == "w1" ? "lost" : "live") << w.dump();
    EXPECT_EQ(w.at("live"), w.at("worker") == "w2") << w.dump();
  }
  sched_->worker_left("w2");
  EXPECT_EQ(worker(sched_->status(), "w2").state, Liveness::kLeft);
  // A lost worker is no longer eligible: with nobody live, a submitted batch
  // would stall, and w1 is back the moment it asks again.
  sched_->worker_seen("w1", "node-01.farm", 8);
  EXPECT_EQ(worker(sched_->status(), "w1").state, Liveness::kLive);
}

TEST_F(OperatorViewTest, WorkersShowTheirCurrentTileAndCountsThatSurviveARestart) {
  const std::string batch = sched_->submit("/jobs/a.toml", {}, "/out", tiny_spec(3, 3, 2));
  sched_->worker_seen("w1", "h1", 2);
  sched_->worker_seen("w2", "h2", 2);
  for (int i = 0; i < 3; ++i) testing::done(*sched_, "w1", take("w1"));
  const Assignment failing = take("w1");
  sched_->fail("w1", failing.task_id, failing.attempt, "out of memory");
  const Assignment held = take("w2");
  StatusReport r = sched_->status();
  const WorkerStatus& w2 = worker(r, "w2");
  ASSERT_EQ(w2.current.size(), 1u);
  EXPECT_EQ(w2.current[0].task_id, held.task_id);
  EXPECT_EQ(w2.current[0].batch_id, batch);
  EXPECT_EQ(w2.current[0].frame, held.frame);
  EXPECT_EQ(w2.current[0].rect.x, held.rect.x);
  EXPECT_EQ(w2.current[0].rect.w, held.rect.w);
  EXPECT_EQ(worker(r, "w1").counts.done, 3);
  EXPECT_EQ(worker(r, "w1").counts.failed, 1);
  EXPECT_EQ(w2.counts.done, 0);
  reopen();  // the counts come back from the attempts table
  r = sched_->status();
  EXPECT_EQ(worker(r, "w1").counts.done, 3);
  EXPECT_EQ(worker(r, "w1").counts.failed, 1);
  const protocol::Json j = status_to_json(r);
  protocol::encode("status_reply", j);  // valid against its definition
  for (const auto& w : j.at("workers")) {
    if (w.at("worker") != "w2") continue;
    EXPECT_EQ(w.at("current").at(0).at("task"), held.task_id);
    EXPECT_EQ(w.at("current").at(0).at("frame"), held.frame);
    EXPECT_EQ(w.at("host"), "h2");
    EXPECT_EQ(w.at("heartbeat_age"), 0.0);
  }
}

TEST_F(OperatorViewTest, TaskListFiltersByStateAndShowsWorkerAttemptsErrorAndReproduce) {
  const std::string batch = sched_->submit("/jobs/a.toml", {"seed=3"}, "/out", tiny_spec(2, 2, 2));
  sched_->worker_seen("w1", "h1", 2);
  const Assignment a = take("w1");
  ASSERT_EQ(sched_->fail("w1", a.task_id, a.attempt, "cannot open scene.bin").status,
            FailStatus::kRetry);
  const Assignment b = take("w1");
  testing::done(*sched_, "w1", b);
  const Assignment c = take("w1");  // leased

  StatusQuery q;
  q.batch = batch;
  q.tasks = true;
  StatusReport all = sched_->status(q);
  ASSERT_EQ(all.batches.size(), 1u);
  const BatchStatus& st = all.batches[0];
  EXPECT_EQ(int(st.tasks.size()), st.tasks_total);  // 8 tiles and a pack
  EXPECT_EQ(st.tasks_total, 9);
  for (const TaskStatus& t : st.tasks) {
    if (t.task_id == a.task_id) {
      EXPECT_EQ(t.state, TaskState::kPending);  // waiting out its back-off
      EXPECT_EQ(t.worker, "w1");
      EXPECT_EQ(t.attempts, 1);
      EXPECT_EQ(t.error, "cannot open scene.bin");
      EXPECT_EQ(t.reproduce, "dofarm render /jobs/a.toml --frame " + std::to_string(a.frame) +
                                 " --tile " + std::to_string(a.rect.x) + "," +
                                 std::to_string(a.rect.y) + ",16,16 --out repro.exr --set seed=3");
    } else if (t.task_id == b.task_id) {
      EXPECT_EQ(t.state, TaskState::kDone);
      EXPECT_EQ(t.worker, "w1");
    } else if (t.task_id == c.task_id) {
      EXPECT_EQ(t.state, TaskState::kLeased);
      EXPECT_EQ(t.worker, "w1");
    } else {
      EXPECT_TRUE(t.worker.empty()) << t.task_id;
      EXPECT_EQ(t.attempts, 0);
    }
    if (t.kind == TaskKind::kPackShard) {
      EXPECT_TRUE(t.reproduce.empty());
    }
  }
  q.state = TaskState::kLeased;
  StatusReport leased = sched_->status(q);
  ASSERT_EQ(leased.batches[0].tasks.size(), 1u);
  EXPECT_EQ(leased.batches[0].tasks[0].task_id, c.task_id);
  q.state = TaskState::kPending;
  q.task_limit = 2;
  StatusReport pending = sched_->status(q);
  EXPECT_EQ(pending.batches[0].tasks.size(), 2u);
  EXPECT_EQ(pending.batches[0].tasks_omitted, 7 - 2);  // 9 - done - leased
  const protocol::Json j = status_to_json(pending);
  protocol::encode("status_reply", j);
  EXPECT_EQ(j.at("batches").at(0).at("tasks").size(), 2u);
  EXPECT_EQ(j.at("batches").at(0).at("tasks_omitted"), 5);
  // Without the question there is no task list on the wire.
  EXPECT_FALSE(status_to_json(sched_->status(batch)).at("batches").at(0).contains("tasks"));
}

TEST_F(OperatorViewTest, EventsAreTimeOrderedLeasesRetriesFailuresBlocklistingAndExpiries) {
  const std::string batch = sched_->submit("/jobs/a.toml", {}, "/out", tiny_spec(2, 2, 2));
  sched_->worker_seen("w1", "h1", 2);
  sched_->worker_seen("w2", "h2", 2);
  clock_.advance(1);
  const Assignment a = take("w1");
  clock_.advance(1);
  sched_->fail("w1", a.task_id, a.attempt, "first error");
  clock_.advance(1);
  const Assignment b = take("w1");
  clock_.advance(1);
  // Blocklists w1 (two failed tasks); w2 is left to retry both.
  EXPECT_TRUE(sched_->fail("w1", b.task_id, b.attempt, "second error").worker_blocklisted);
  clock_.advance(1);
  const Assignment c = take("w2");
  clock_.advance(31);  // w2 silent beyond its lease
  sched_->expire_leases();

  const std::vector<EventRow> ev = sched_->events(batch, 100);
  std::vector<std::string> kinds;
  for (const EventRow& e : ev) kinds.push_back(e.kind);
  EXPECT_EQ(kinds, (std::vector<std::string>{"submitted", "lease", "retry", "lease", "blocklisted",
                                             "retry", "lease", "expired"}));
  for (size_t i = 1; i < ev.size(); ++i) EXPECT_LE(ev[i - 1].time, ev[i].time);
  EXPECT_EQ(ev[1].task, a.task_id);
  EXPECT_EQ(ev[1].worker, "w1");
  EXPECT_NE(ev[2].text.find("first error"), std::string::npos) << ev[2].text;
  EXPECT_EQ(ev[2].level, "warn");
  EXPECT_EQ(ev[4].worker, "w1");
  EXPECT_NE(ev[4].text.find("blocklisted"), std::string::npos) << ev[4].text;
  EXPECT_NE(ev[4].text.find("second error"), std::string::npos) << "the reason: " << ev[4].text;
  EXPECT_EQ(ev[6].worker, "w2");
  EXPECT_EQ(ev[7].task, c.task_id);
  EXPECT_EQ(ev[7].worker, "w2");
  // The newest N, still oldest first.
  const std::vector<EventRow> last = sched_->events(batch, 3);
  ASSERT_EQ(last.size(), 3u);
  EXPECT_EQ(last[0].kind, "retry");
  EXPECT_EQ(last[2].kind, "expired");
  const protocol::Json j = events_to_json(batch, last, true);
  protocol::encode("events_reply", j);
  EXPECT_EQ(j.at("events").size(), 3u);
  EXPECT_EQ(j.at("older"), true);
  EXPECT_EQ(j.at("events").at(2).at("kind"), "expired");
}

// One `events` reply stays below the message limit whatever the store holds.
TEST_F(OperatorViewTest, EventsReplyIsBoundedAndKeepsTheNewest) {
  std::vector<EventRow> many;
  for (int i = 0; i < 2000; ++i)
    many.push_back({i + 1, 1.7e9 + i, "b-00000001", "warn",
                    std::string(4000, 'x') + std::to_string(i), "retry", i + 1, "w1"});
  const protocol::Json j = events_to_json("b-00000001", many, false);
  const std::string wire = protocol::encode("events_reply", j);
  EXPECT_LT(wire.size(), protocol::kMaxMessageBytes);
  const size_t listed = j.at("events").size();
  EXPECT_GT(listed, 100u);
  EXPECT_EQ(j.at("events_omitted").get<size_t>(), 2000 - listed);
  EXPECT_EQ(j.at("events").back().at("task"), 2000);  // the newest is kept
}

TEST_F(OperatorViewTest, TaskListOfAHugeBatchIsBounded) {
  const std::string batch = sched_->submit("/jobs/" + std::string(3000, 'd') + ".toml", {}, "/out",
                                           tiny_spec(40, 1, 20));  // 16000 tiles, 40 packs
  StatusQuery q;
  q.batch = batch;
  q.tasks = true;
  q.task_limit = 10000;
  const protocol::Json j = status_to_json(sched_->status(q));
  const std::string wire = protocol::encode("status_reply", j);
  EXPECT_LT(wire.size(), protocol::kMaxMessageBytes);
  const auto& b = j.at("batches").at(0);
  EXPECT_GT(b.at("tasks").size(), 50u);
  EXPECT_EQ(b.at("tasks").size() + b.at("tasks_omitted").get<size_t>(), 16040u);
}

// A store written before events had kinds opens, keeps its events, and
// records the new ones with theirs.
TEST(JobStoreMigration, StoreWithoutEventKindsGainsThemInPlace) {
  TempDir dir;
  const auto path = dir.path() / "old.db";
  {
    JobStore store(path);
    store.add_event(100, "b-0123abcd", "info", "an old event");
  }
  {
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
    for (const char* sql :
         {"ALTER TABLE events DROP COLUMN kind", "ALTER TABLE events DROP COLUMN task",
          "ALTER TABLE events DROP COLUMN worker", "DROP INDEX attempts_by_start"})
      ASSERT_EQ(sqlite3_exec(db, sql, nullptr, nullptr, nullptr), SQLITE_OK) << sql;
    sqlite3_close(db);
  }
  JobStore store(path);
  store.add_event({0, 101, "b-0123abcd", "warn", "a new one", "retry", 7, "w1"});
  const std::vector<EventRow> ev = store.events("b-0123abcd", 10);
  ASSERT_EQ(ev.size(), 2u);
  EXPECT_EQ(ev[0].kind, "retry");
  EXPECT_EQ(ev[0].task, 7);
  EXPECT_EQ(ev[0].worker, "w1");
  EXPECT_EQ(ev[1].text, "an old event");
  EXPECT_EQ(ev[1].kind, "");
}

// A store written before batch priorities opens with every batch at the
// default priority, so its batches are served as before (oldest first), and
// a priority set afterwards is kept.
TEST(JobStoreMigration, StoreWithoutPrioritiesGainsThemInPlace) {
  TempDir dir;
  const auto path = dir.path() / "old.db";
  FakeClock clock;
  std::string first, second;
  {
    JobStore store(path);
    Scheduler s(store, clock);
    first = s.submit("/jobs/a.toml", {}, "/out/a", testing::tiny_spec(1, 1));
    clock.advance(1);
    second = s.submit("/jobs/b.toml", {}, "/out/b", testing::tiny_spec(1, 1), {}, std::nullopt, 90);
    s.flush();
  }
  {
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
    const char* sql = "ALTER TABLE batches DROP COLUMN priority";
    ASSERT_EQ(sqlite3_exec(db, sql, nullptr, nullptr, nullptr), SQLITE_OK) << sql;
    sqlite3_close(db);
  }
  JobStore store(path);
  EXPECT_EQ(store.batch(first)->priority, kDefaultPriority);
  EXPECT_EQ(store.batch(second)->priority, kDefaultPriority);
  Scheduler s(store, clock);
  std::optional<Assignment> a = s.assign("w1");
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(a->batch_id, first) << "equal priorities: the older batch first";
  EXPECT_TRUE(s.set_priority(second, 70).ok);
  EXPECT_EQ(JobStore(path).batch(second)->priority, 70);
}

}  // namespace
}  // namespace dofarm::coordinator
