// Processes dying under the farm: kill -9 of a worker and of the
// coordinator mid-batch, SIGTERM of a worker mid-task. Real processes, real
// signals, real ZeroMQ on loopback, the real job store.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <regex>

#include "coordinator/job_store.h"
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

using coordinator::AttemptOutcome;
using coordinator::JobStore;

// 16 tiles of about a third of a second each on one thread: long enough to
// be caught mid-task, short enough for two busy cores.
TinyJob slow_job() {
  TinyJob j;
  j.reference_spp = 1024;
  return j;
}

std::string submit(const TempDir& tmp, const std::string& endpoint, const fs::path& job,
                   const fs::path& out) {
  CliResult r = run_cli(tmp.path(), "submit",
                        {"submit", job.string(), "--coordinator", endpoint, "--out", out.string()});
  EXPECT_EQ(r.status, 0) << r.out << r.err;
  std::string batch = r.out.substr(0, r.out.find('\n'));
  EXPECT_TRUE(std::regex_match(batch, std::regex("b-[0-9a-f]{8}"))) << r.out;
  return batch;
}

std::string outcome_list(const std::vector<coordinator::AttemptRow>& attempts) {
  std::string s;
  for (const auto& a : attempts)
    s += " " + a.worker + ":" + (a.outcome ? to_string(*a.outcome) : "running");
  return s;
}

TEST(FarmFaults, KilledWorkersTaskIsRequeuedAndNoFrameIsLostOrDuplicated) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", slow_job());
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 2);
  const std::string ep = coord.endpoint();
  const std::string batch = submit(tmp, ep, job, tmp / "out");
  ASSERT_FALSE(batch.empty());

  std::map<std::string, Child> workers;
  workers["w1"] = start_worker(tmp.path(), ep, "w1");
  workers["w2"] = start_worker(tmp.path(), ep, "w2");

  std::string victim;
  int64_t task = 0;
  ASSERT_TRUE(poll_until("a worker holding a task", [&] {
    Json st = farm_status(ep, batch);
    for (const auto& [id, child] : workers) {
      auto leases = leases_of(st, id);
      if (!leases.empty()) {
        victim = id;
        task = leases.front();
        return true;
      }
    }
    return false;
  }));
  workers[victim].kill9();

  ASSERT_TRUE(poll_until("the batch to be done", [&] { return batch_state(ep, batch) == "done"; }))
      << coord.child().describe();
  CliResult st = run_cli(tmp.path(), "status", {"status", batch, "--coordinator", ep, "--json"});
  ASSERT_EQ(st.status, 0) << st.err;
  Json b = batch_of(Json::parse(st.out), batch);
  ASSERT_FALSE(b.is_null()) << st.out;
  EXPECT_EQ(b.at("state"), "done");
  EXPECT_EQ(b.at("frames_packed"), 4);
  EXPECT_EQ(b.at("tasks_failed"), 0);
  EXPECT_TRUE(shards_match_render(tmp / "out", job));

  coord.child().kill9();  // the store survives it (see the next test)
  // The dead worker's lease expired (not a failure) and someone else did it.
  JobStore store(tmp / "state" / "dofarm.sqlite");
  auto attempts = store.attempts(task);
  ASSERT_GE(attempts.size(), 2u) << outcome_list(attempts);
  EXPECT_EQ(attempts.front().worker, victim);
  EXPECT_EQ(attempts.front().outcome, AttemptOutcome::kExpired) << outcome_list(attempts);
  EXPECT_EQ(attempts.back().outcome, AttemptOutcome::kDone) << outcome_list(attempts);
  EXPECT_NE(attempts.back().worker, victim);
}

TEST(FarmFaults, KilledCoordinatorRestartsOnItsStateAndTheBatchCompletes) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", slow_job());
  const fs::path state = tmp / "state";
  std::string batch;
  int done_before = 0;
  {
    CoordinatorProcess coord(tmp.path(), "coordinator1", state, 2);
    const std::string ep = coord.endpoint();
    batch = submit(tmp, ep, job, tmp / "out");
    ASSERT_FALSE(batch.empty());
    Child w1 = start_worker(tmp.path(), ep, "w1");
    Child w2 = start_worker(tmp.path(), ep, "w2");
    ASSERT_TRUE(poll_until("a task done while the batch still runs", [&] {
      Json b = batch_of(farm_status(ep, batch), batch);
      done_before = b.at("tasks_done").get<int>();
      return done_before >= 1 && b.at("state") == "running" &&
             done_before + 2 < b.at("tasks_total").get<int>();
    }));
    coord.child().kill9();
    w1.kill9();
    w2.kill9();
  }

  CoordinatorProcess coord(tmp.path(), "coordinator2", state, 2);
  const std::string ep = coord.endpoint();
  Json b = batch_of(farm_status(ep, batch), batch);
  ASSERT_FALSE(b.is_null()) << "the batch is gone after the restart";
  EXPECT_EQ(b.at("state"), "running");
  EXPECT_GE(b.at("tasks_done").get<int>(), done_before) << "done tasks were lost";

  // The batch is still running: resume may say so; both answers are fine.
  CliResult r = run_cli(tmp.path(), "resume", {"resume", batch, "--coordinator", ep});
  EXPECT_TRUE(r.status == 0 || r.status == 2) << r.status << r.out << r.err;

  Child w3 = start_worker(tmp.path(), ep, "w3");
  Child w4 = start_worker(tmp.path(), ep, "w4");
  ASSERT_TRUE(poll_until("the batch to be done", [&] { return batch_state(ep, batch) == "done"; }))
      << coord.child().describe();
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

TEST(FarmFaults, SigtermedWorkerReleasesItsTaskAndExitsZero) {
  TempDir tmp;
  TinyJob j;  // one 64x64 tile of several seconds: SIGTERM lands mid-render
  j.width = 64;
  j.height = 64;
  j.tile = 64;
  j.frame_end = 0;
  j.per_shard = 1;
  j.reference_spp = 1024;
  const fs::path job = write_job(tmp.path(), "job.toml", j);
  // A long lease: only a release, never an expiry, can free the task here.
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 600);
  const std::string ep = coord.endpoint();
  const std::string batch = submit(tmp, ep, job, tmp / "out");
  ASSERT_FALSE(batch.empty());

  Child w1 = start_worker(tmp.path(), ep, "w1");
  int64_t task = 0;
  ASSERT_TRUE(poll_until("w1 rendering a task", [&] {
    auto leases = leases_of(farm_status(ep), "w1");
    if (leases.empty()) return false;
    task = leases.front();
    return w1.err().find("task " + std::to_string(task) + ": frame") != std::string::npos;
  })) << w1.describe();
  w1.signal(SIGTERM);

  ASSERT_TRUE(poll_until("w1 to hold no task", [&] {
    return leases_of(farm_status(ep), "w1").empty();
  })) << w1.describe();
  std::optional<int> exit = w1.wait();
  ASSERT_TRUE(exit.has_value()) << "the worker did not exit: " << w1.describe();
  EXPECT_EQ(*exit, 0) << w1.describe();

  Json b = batch_of(farm_status(ep, batch), batch);
  EXPECT_EQ(b.at("state"), "running");
  EXPECT_EQ(b.at("tasks_leased"), 0);
  EXPECT_EQ(b.at("tasks_pending"), b.at("tasks_total"));

  coord.child().kill9();
  JobStore store(tmp / "state" / "dofarm.sqlite");
  auto attempts = store.attempts(task);
  ASSERT_EQ(attempts.size(), 1u) << outcome_list(attempts);
  EXPECT_EQ(attempts[0].worker, "w1");
  EXPECT_EQ(attempts[0].outcome, AttemptOutcome::kReleased) << outcome_list(attempts);
  auto row = store.task(task);
  ASSERT_TRUE(row.has_value());
  EXPECT_EQ(row->state, coordinator::TaskState::kPending);
}

// The local workers of a `dofarm run` that died without stopping them are
// ours to clean up.
void kill_orphaned_local_workers(pid_t run_pid) {
  for (pid_t pid : local_worker_pids(run_pid)) ::kill(pid, SIGKILL);
}

// `dofarm coordinator` stops cleanly on SIGTERM/SIGINT (exit 0). Where the
// signal lands (in the ZeroMQ poll or between polls) is chance, so several
// coordinators are stopped.
TEST(FarmFaults, SigtermedCoordinatorStopsWithExitZero) {
  TempDir tmp;
  std::vector<std::unique_ptr<CoordinatorProcess>> coords;
  for (int i = 0; i < 8; ++i)
    coords.push_back(std::make_unique<CoordinatorProcess>(
        tmp.path(), "coordinator" + std::to_string(i), tmp / ("state" + std::to_string(i)), 2));
  for (auto& c : coords) ASSERT_NO_THROW(farm_status(c->endpoint()));  // serving
  for (auto& c : coords) c->child().signal(SIGTERM);
  for (auto& c : coords) {
    std::optional<int> exit = c->child().wait();
    ASSERT_TRUE(exit.has_value()) << c->child().describe();
    EXPECT_EQ(*exit, 0) << c->child().describe();
  }
}

// `dofarm run` told to stop passes SIGTERM on to its workers, which hand
// their tasks back, and exits once they are gone.
TEST(FarmFaults, SigtermedRunHandsItsTasksBackAndStopsItsWorkers) {
  TempDir tmp;
  TinyJob j;
  j.width = 64;
  j.height = 64;
  j.tile = 64;
  j.frame_end = 0;
  j.per_shard = 1;
  j.reference_spp = 1024;
  const fs::path job = write_job(tmp.path(), "job.toml", j);
  Child run({"run", job.string(), "--out", (tmp / "out").string(), "--workers", "1", "--threads",
             "1", "--lease", "600"},
            tmp / "run.out", tmp / "run.err");
  const fs::path db = tmp / "out" / ".dofarm-state" / "dofarm.sqlite";
  int64_t task = 0;
  ASSERT_TRUE(poll_until("the local worker holding the render task", [&] {
    if (!run.running() || !fs::exists(db)) return false;
    try {
      JobStore store(db);
      for (const auto& b : store.batches())
        for (const auto& t : store.leased_tasks(b.id)) task = t.id;
    } catch (const std::exception&) {
      return false;  // the schema is being created
    }
    return task != 0;
  })) << run.describe();
  run.signal(SIGTERM);
  std::optional<int> exit = run.wait();
  ASSERT_TRUE(exit.has_value()) << run.describe();
  EXPECT_EQ(*exit, 1) << "the batch is not done: a runtime failure\n" << run.describe();
  JobStore store(db);
  // The worker's release may still be on its way when a broken `run` died.
  EXPECT_TRUE(poll_until(
      "the attempt to be released",
      [&] {
        auto attempts = store.attempts(task);
        return !attempts.empty() && attempts.back().outcome == AttemptOutcome::kReleased;
      },
      15))
      << outcome_list(store.attempts(task)) << "\n"
      << run.describe();
  EXPECT_NE(run.out().find(": running, 0/1 frames"), std::string::npos) << run.describe();
  kill_orphaned_local_workers(run.pid());
}

}  // namespace
}  // namespace dofarm::farm_testing
