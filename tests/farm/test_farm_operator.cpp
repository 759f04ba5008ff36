// Issue 14, "Status as operators know it", with the real executable, real
// workers, ZeroMQ on loopback and the SQLite job store: a failing tile shows
// its error and reproduce command in `status --tasks` and in `events`; a
// killed worker stops being live after one lease; a second coordinator on
// the same state folder or port says who is in the way; `status --watch`
// prints plain blocks when its output is not a terminal.
#include <gtest/gtest.h>
#include <unistd.h>

#include "common/staging.h"
#include "coordinator/job_store.h"
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

using coordinator::AttemptRow;
using coordinator::EventRow;
using coordinator::JobStore;
using coordinator::TaskRow;

std::string first_line(const std::string& s) { return s.substr(0, s.find('\n')); }

size_t count_of(const std::string& haystack, const std::string& needle) {
  size_t n = 0;
  for (size_t p = haystack.find(needle); p != std::string::npos; p = haystack.find(needle, p + 1))
    ++n;
  return n;
}

// This host's name as workers send it (docs/protocol.md: the `host` field).
std::string this_host() {
  char host[256] = {};
  gethostname(host, sizeof(host) - 1);
  std::string out = host;
  for (char& c : out)
    if (!std::isalnum(static_cast<unsigned char>(c)) && !std::strchr("._:@+-", c)) c = '_';
  return out;
}

// Batch priorities from the command line: a batch submitted later with
// `--priority 80` is rendered before an older one at the default 50 by the
// one worker (every attempt of its tasks starts before any of the other's);
// `status` shows each batch's priority; `dofarm priority` changes it and
// refuses what it cannot do (a value outside 0..100: exit 2 from the CLI's
// own check; a batch the coordinator does not have: an error naming it).
TEST(FarmOperator, HigherPriorityBatchIsRenderedFirstAndPriorityCanBeChanged) {
  TempDir tmp;
  TinyJob j;
  j.frame_end = 1;
  j.per_shard = 1;
  const fs::path spec = write_job(tmp.path(), "job.toml", j);
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 30);
  const std::string ep = coord.endpoint();
  CliResult a =
      run_cli(tmp.path(), "submit_a",
              {"submit", spec.string(), "--coordinator", ep, "--out", (tmp / "A").string()});
  ASSERT_EQ(a.status, 0) << a.err;
  CliResult b = run_cli(tmp.path(), "submit_b",
                        {"submit", spec.string(), "--coordinator", ep, "--out",
                         (tmp / "B").string(), "--priority", "80"});
  ASSERT_EQ(b.status, 0) << b.err;
  const std::string older = first_line(a.out), urgent = first_line(b.out);

  const Json st = farm_status(ep);
  EXPECT_EQ(batch_of(st, older).at("priority"), 50) << st.dump(2);
  EXPECT_EQ(batch_of(st, urgent).at("priority"), 80) << st.dump(2);
  CliResult table = run_cli(tmp.path(), "status", {"status", "--coordinator", ep});
  EXPECT_NE(table.out.find(urgent + "  running  priority 80"), std::string::npos) << table.out;

  CliResult too_high =
      run_cli(tmp.path(), "too_high", {"priority", older, "101", "--coordinator", ep});
  EXPECT_EQ(too_high.status, 2) << too_high.err;
  CliResult unknown =
      run_cli(tmp.path(), "unknown", {"priority", "b-00000000", "60", "--coordinator", ep});
  EXPECT_NE(unknown.status, 0);
  EXPECT_NE(unknown.err.find("no batch b-00000000"), std::string::npos) << unknown.err;
  CliResult same = run_cli(tmp.path(), "same", {"priority", urgent, "90", "--coordinator", ep});
  ASSERT_EQ(same.status, 0) << same.err;
  EXPECT_NE(same.out.find("priority 80 -> 90"), std::string::npos) << same.out;

  Child w = start_worker(tmp.path(), ep, "w1");
  ASSERT_TRUE(poll_until("both batches done", [&] {
    return batch_state(ep, older) == "done" && batch_state(ep, urgent) == "done";
  })) << coord.child().describe();
  JobStore store(tmp / "state" / "dofarm.sqlite");
  double urgent_last = 0, older_first = 1e300;
  for (const auto& [batch, start_of] : {std::pair{urgent, true}, std::pair{older, false}})
    for (const TaskRow& t : store.tasks(batch))
      for (const AttemptRow& at : store.attempts(t.id)) {
        if (start_of)
          urgent_last = std::max(urgent_last, at.started);
        else
          older_first = std::min(older_first, at.started);
      }
  EXPECT_LE(urgent_last, older_first) << "the urgent batch's tasks all started first";
  bool event = false;
  for (const EventRow& e : store.events(urgent, 100)) event |= e.kind == "priority";
  EXPECT_TRUE(event);
}

// One tile of frame 1 cannot be staged (a folder stands at its staged file's
// name), so that tile fails on both workers and fails for good, with the
// rename's error; every other tile renders.
TEST(FarmOperator, FailingTileShowsItsErrorAndReproduceInTaskListAndEvents) {
  TempDir tmp;
  const fs::path spec = write_job(tmp.path(), "job.toml", TinyJob{});
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 5);
  const std::string ep = coord.endpoint();
  const fs::path out = tmp / "out";
  CliResult sub = run_cli(tmp.path(), "submit",
                          {"submit", spec.string(), "--coordinator", ep, "--out", out.string()});
  ASSERT_EQ(sub.status, 0) << sub.err;
  const std::string batch = first_line(sub.out);
  const Rect bad_rect{16, 16, 16, 8};
  const fs::path blocked = staged_tile_path(out, batch, 1, bad_rect);
  fs::create_directories(blocked);

  Child w1 = start_worker(tmp.path(), ep, "w1");
  Child w2 = start_worker(tmp.path(), ep, "w2");
  ASSERT_TRUE(poll_until("the batch to end", [&] { return batch_state(ep, batch) != "running"; }))
      << coord.child().describe();
  EXPECT_EQ(batch_state(ep, batch), "failed");

  // The task list, failed tasks only: the tile (its error names the file)
  // with its reproduce command, and the pack of its shard that needed it.
  CliResult js =
      run_cli(tmp.path(), "tasks_json",
              {"status", batch, "--tasks", "--state", "failed", "--coordinator", ep, "--json"});
  ASSERT_EQ(js.status, 0) << js.err;
  const Json b = batch_of(Json::parse(js.out), batch);
  ASSERT_EQ(b.at("tasks").size(), 2u) << b.dump(2);
  int64_t tile_task = 0;
  for (const Json& t : b.at("tasks")) {
    EXPECT_EQ(t.at("state"), "failed");
    if (t.at("kind") == "pack_shard") {
      EXPECT_EQ(t.at("shard"), 0);
      EXPECT_NE(t.at("error").get<std::string>().find("which failed"), std::string::npos) << t;
      continue;
    }
    tile_task = t.at("task");
    EXPECT_EQ(t.at("frame"), 1);
    EXPECT_EQ(t.at("rect"), Json({16, 16, 16, 8}));
    EXPECT_EQ(t.at("attempts"), 2);  // once on each worker
    EXPECT_TRUE(t.at("worker") == "w1" || t.at("worker") == "w2") << t;
    EXPECT_NE(t.at("error").get<std::string>().find(blocked.filename().string()), std::string::npos)
        << t;
    const std::string repro = t.at("reproduce");
    EXPECT_EQ(repro.rfind("dofarm render ", 0), 0u) << repro;
    EXPECT_NE(repro.find("--frame 1 --tile 16,16,16,8"), std::string::npos) << repro;
  }
  ASSERT_GT(tile_task, 0) << b.dump(2);
  EXPECT_EQ(b.at("tasks_omitted"), 0);

  CliResult table = run_cli(tmp.path(), "tasks_table",
                            {"status", batch, "--tasks", "--state", "failed", "--coordinator", ep});
  ASSERT_EQ(table.status, 0) << table.err;
  EXPECT_NE(table.out.find("TASK"), std::string::npos) << table.out;
  EXPECT_NE(table.out.find("16,16,16,8"), std::string::npos) << table.out;
  EXPECT_NE(table.out.find("error: "), std::string::npos) << table.out;
  EXPECT_NE(table.out.find("reproduce: dofarm render"), std::string::npos) << table.out;
  // Done tasks are not failed ones: the filter holds.
  CliResult done =
      run_cli(tmp.path(), "tasks_done",
              {"status", batch, "--tasks", "--state", "done", "--coordinator", ep, "--json"});
  ASSERT_EQ(done.status, 0) << done.err;
  const Json d = batch_of(Json::parse(done.out), batch);
  EXPECT_EQ(d.at("tasks").size(), size_t(d.at("tasks_done").get<int>()));
  for (const Json& t : d.at("tasks")) EXPECT_EQ(t.at("state"), "done");

  // The events: leases, the first failure (a retry) and the final one, with
  // the error's text, in time order.
  CliResult ev = run_cli(tmp.path(), "events_json",
                         {"events", batch, "--coordinator", ep, "--json", "--limit", "1000"});
  ASSERT_EQ(ev.status, 0) << ev.err;
  const Json events = Json::parse(ev.out).at("events");
  std::vector<std::string> tile_kinds;
  double last_time = 0;
  for (const Json& e : events) {
    EXPECT_GE(e.at("time").get<double>(), last_time) << e;
    last_time = e.at("time");
    if (e.at("task") == tile_task) tile_kinds.push_back(e.at("kind"));
    if (e.at("task") == tile_task && e.at("kind") != "lease") {
      EXPECT_NE(e.at("text").get<std::string>().find(blocked.filename().string()),
                std::string::npos)
          << e;
    }
  }
  EXPECT_EQ(tile_kinds, (std::vector<std::string>{"lease", "retry", "lease", "failed"}))
      << events.dump(1);
  CliResult lines = run_cli(tmp.path(), "events", {"events", batch, "--coordinator", ep});
  ASSERT_EQ(lines.status, 0) << lines.err;
  EXPECT_NE(lines.out.find("retry"), std::string::npos) << lines.out;
  EXPECT_NE(lines.out.find("failed for good"), std::string::npos) << lines.out;
  EXPECT_NE(lines.out.find("leased to w"), std::string::npos) << lines.out;
  // An unknown batch is bad input, like status.
  CliResult nope = run_cli(tmp.path(), "events_nope", {"events", "b-nope", "--coordinator", ep});
  EXPECT_EQ(nope.status, 2) << nope.out << nope.err;
  EXPECT_NE(nope.err.find("dofarm: error:"), std::string::npos) << nope.err;

  // The coordinator logged the failures at warning level.
  const std::string log = coord.child().err();
  EXPECT_NE(log.find("[warning]"), std::string::npos) << log;
  EXPECT_NE(log.find("failed for good"), std::string::npos) << log;
}

// docs/farm.md "Worker liveness": live while heard from within one lease;
// a worker killed with SIGKILL says no goodbye and is shown lost once a
// lease has passed in silence.
TEST(FarmOperator, KilledWorkerIsShownLostAfterOneLeaseOfSilence) {
  TempDir tmp;
  const double lease = 2;
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", lease);
  const std::string ep = coord.endpoint();
  Child w = start_worker(tmp.path(), ep, "w1");
  auto entry = [&]() -> Json {
    const Json st = farm_status(ep);  // kept: a range-for over a temporary's member dangles
    for (const Json& e : st.at("workers"))
      if (e.at("worker") == "w1") return e;
    return nullptr;
  };
  ASSERT_TRUE(poll_until("w1 to be live", [&] {
    Json e = entry();
    return !e.is_null() && e.at("state") == "live";
  }));
  EXPECT_EQ(entry().at("host"), this_host());
  w.kill9();
  // Every observation follows the rule exactly, until it is lost.
  int observations = 0;
  ASSERT_TRUE(poll_until("w1 to be shown lost", [&] {
    const Json e = entry();
    ++observations;
    const double age = e.at("heartbeat_age");
    EXPECT_EQ(e.at("state"), age <= lease ? "live" : "lost") << e;
    EXPECT_EQ(e.at("live"), age <= lease) << e;
    return e.at("state") == "lost";
  }));
  EXPECT_GT(observations, 1);
  CliResult table = run_cli(tmp.path(), "status", {"status", "--coordinator", ep});
  ASSERT_EQ(table.status, 0) << table.err;
  EXPECT_NE(table.out.find("workers: 0 live, 1 lost"), std::string::npos) << table.out;
  EXPECT_NE(table.out.find("lost"), std::string::npos) << table.out;
}

TEST(FarmOperator, SecondCoordinatorOnTheSameStateRefusesAndNamesTheHolder) {
  TempDir tmp;
  CoordinatorProcess first(tmp.path(), "first", tmp / "state", 5);
  CliResult second = run_cli(
      tmp.path(), "second",
      {"coordinator", "--listen", "tcp://127.0.0.1:*", "--state", (tmp / "state").string()}, 30);
  EXPECT_EQ(second.status, 1) << second.out << second.err;
  EXPECT_EQ(second.out, "");  // never said it listens
  EXPECT_NE(second.err.find("dofarm: error: another coordinator (pid " +
                            std::to_string(first.child().pid()) + ")"),
            std::string::npos)
      << second.err;
  EXPECT_NE(second.err.find((tmp / "state").string()), std::string::npos) << second.err;
  // The first one is unharmed, and once it is gone the folder is free again
  // (the kernel drops the lock of a killed process).
  EXPECT_NO_THROW(farm_status(first.endpoint()));
  first.child().kill9();
  CoordinatorProcess third(tmp.path(), "third", tmp / "state", 5);
  EXPECT_NO_THROW(farm_status(third.endpoint()));
}

TEST(FarmOperator, SecondCoordinatorOnABusyPortNamesTheEndpoint) {
  TempDir tmp;
  CoordinatorProcess first(tmp.path(), "first", tmp / "state1", 5);
  CliResult second = run_cli(
      tmp.path(), "second",
      {"coordinator", "--listen", first.endpoint(), "--state", (tmp / "state2").string()}, 30);
  EXPECT_EQ(second.status, 1) << second.out << second.err;
  EXPECT_NE(second.err.find("cannot listen on " + first.endpoint() + ": Address already in use"),
            std::string::npos)
      << second.err;
}

// Not a terminal (a file here): plain blocks, one per refresh, no escape
// codes, until the batch ends; and Ctrl-C ends a watch with exit 0.
TEST(FarmOperator, WatchPrintsPlainBlocksOnANonTerminalUntilTheBatchEnds) {
  TempDir tmp;
  TinyJob job;
  job.frame_end = 1;
  const fs::path spec = write_job(tmp.path(), "job.toml", job);
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 5);
  const std::string ep = coord.endpoint();
  CliResult sub =
      run_cli(tmp.path(), "submit",
              {"submit", spec.string(), "--coordinator", ep, "--out", (tmp / "out").string()});
  ASSERT_EQ(sub.status, 0) << sub.err;
  const std::string batch = first_line(sub.out);
  Child watch({"status", batch, "--coordinator", ep, "--watch", "0.2"}, tmp / "watch.out",
              tmp / "watch.err");
  ASSERT_TRUE(
      poll_until("a first block", [&] { return watch.out().find("ETA") != std::string::npos; }));
  Child w = start_worker(tmp.path(), ep, "w1");
  const std::optional<int> rc = watch.wait();
  ASSERT_EQ(rc, 0) << watch.describe();
  const std::string text = watch.out();
  EXPECT_EQ(text.find('\x1b'), std::string::npos) << "no escape codes in a file";
  EXPECT_GE(count_of(text, "every 0.2 s"), 2u) << text;
  EXPECT_EQ(count_of(text, "every 0.2 s"), count_of(text, batch + "  ")) << text;
  // The last block is the final state.
  const std::string last = text.substr(text.rfind("every 0.2 s"));
  EXPECT_NE(last.find(batch + "  done"), std::string::npos) << last;

  // Without a batch a watch runs until Ctrl-C, which ends it with exit 0.
  Child forever({"status", "--coordinator", ep, "--watch", "0.2"}, tmp / "forever.out",
                tmp / "forever.err");
  ASSERT_TRUE(
      poll_until("two blocks", [&] { return count_of(forever.out(), "every 0.2 s") >= 2; }));
  forever.signal(SIGINT);
  EXPECT_EQ(forever.wait(30), 0) << forever.describe();
}

}  // namespace
}  // namespace dofarm::farm_testing
