// What the farm's commands print, checked without a terminal: the progress
// line says what it counts and never "done" for failed work, `status` and
// the progress bar give an ETA in one format, and `status --watch` redraws
// on a terminal and prints plain blocks elsewhere.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdio>
#include <sstream>

#include "common/progress.h"
#include "farm/status_view.h"

namespace dofarm::farm {
namespace {

std::string read_all(std::FILE* f) {
  std::rewind(f);
  std::string s;
  char buf[4096];
  for (size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) s.append(buf, n);
  return s;
}

size_t count_of(const std::string& haystack, const std::string& needle) {
  size_t n = 0;
  for (size_t p = haystack.find(needle); p != std::string::npos; p = haystack.find(needle, p + 1))
    ++n;
  return n;
}

Json batch_entry(const std::string& state, Json eta) {
  return {{"batch", "b-0000abcd"},   {"state", state},          {"spec_path", "/jobs/a.toml"},
          {"out_dir", "/out"},       {"created", 1.7e9},        {"tasks_total", 10},
          {"tasks_done", 4},         {"tasks_failed", 0},       {"tasks_leased", 1},
          {"tasks_pending", 5},      {"frames_total", 4},       {"frames_rendered", 1},
          {"frames_packed", 0},      {"frames_per_hour", 60.0}, {"eta_seconds", eta},
          {"failed", Json::array()}, {"failed_omitted", 0},     {"blocklisted", Json::array()},
          {"blocklisted_omitted", 0}};
}

TEST(ProgressLine, SaysWhatItCounts) {
  EXPECT_EQ(format_progress("batch b-1", 21, 50, 10, 0, "tasks"),
            "batch b-1  42% 21/50 tasks ETA 14s");
  EXPECT_EQ(format_progress("frame 3", 1, 4, 1, 4, "blocks"),
            "frame 3 [=>  ]  25% 1/4 blocks ETA 3s");
}

TEST(ProgressLine, FailedWorkNeverEndsDone) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  double t = 0;
  ProgressOptions o;
  o.mode = ProgressOptions::Mode::kBar;
  o.clock = [&] { return t; };
  o.bar_out = f;
  {
    Progress p("batch b-1", 3, "tasks", o);
    t = 6;
    p.advance(3);  // every task ended, one of them failed
    p.fail("1 of them failed");
  }
  const std::string text = read_all(f);
  EXPECT_NE(text.find("3/3 tasks"), std::string::npos) << text;
  EXPECT_NE(text.find("failed after 6s: 1 of them failed"), std::string::npos) << text;
  EXPECT_EQ(text.find("done"), std::string::npos) << text;
  std::fclose(f);

  f = std::tmpfile();
  o.bar_out = f;
  t = 0;
  {
    Progress p("batch b-2", 2, "tasks", o);
    t = 65;
    p.advance(2);
  }  // finish() by the destructor
  EXPECT_NE(read_all(f).find("2/2 tasks ETA 0s done in 1m05s"), std::string::npos) << read_all(f);
  std::fclose(f);
}

// A batch resumed at 153/1542 tasks logged "ETA 47s" in its first seconds:
// the 153 tasks of earlier runs counted as this run's rate. Only the tasks
// done since the run began count.
TEST(ProgressLine, AResumedRunsEtaCountsOnlyItsOwnWork) {
  // 100 done before, 10 since, in 20 s: 90 to go at 0.5 a second.
  EXPECT_EQ(format_progress("batch b-1", 110, 200, 20, 0, "tasks", 100),
            "batch b-1  55% 110/200 tasks ETA 3m00s");
  EXPECT_EQ(estimate_eta(100, 200, 20, 100), -1);  // nothing done yet in this run
  EXPECT_EQ(estimate_eta(200, 200, 20, 200), 0);   // nothing left

  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  double t = 0;
  ProgressOptions o;
  o.mode = ProgressOptions::Mode::kBar;
  o.bar_interval_s = 0;
  o.clock = [&] { return t; };
  o.bar_out = f;
  {
    Progress p("batch b-1", 1542, "tasks", o);
    p.resume_from(153);
    t = 1;
    p.advance(0);
    EXPECT_EQ(p.done(), 153);
    t = 100;
    p.advance(1);  // one task in 100 s: 1388 left take 138800 s
    EXPECT_EQ(p.done(), 154);
  }
  const std::string text = read_all(f);
  EXPECT_NE(text.find("153/1542 tasks ETA ?"), std::string::npos) << text;
  EXPECT_NE(text.find("154/1542 tasks ETA 38h33m"), std::string::npos) << text;
  std::fclose(f);
}

// One duration format: `status` prints the coordinator's eta_seconds as the
// progress bar prints its own estimate.
TEST(StatusText, EtaHasTheProgressBarsFormat) {
  const Json st = {{"now", 1.7e9},
                   {"batches", Json::array({batch_entry("running", 185.0)})},
                   {"batches_omitted", 0},
                   {"workers", Json::array()},
                   {"workers_omitted", 0}};
  const std::string text = format_status(st);
  EXPECT_NE(text.find("ETA " + format_duration(185)), std::string::npos) << text;
  EXPECT_EQ(format_duration(185), "3m05s");
  // 1 of 4 done after 61.67 s: 185 s to go, said the same way by the bar.
  EXPECT_NE(format_progress("x", 1, 4, 185.0 / 3, 0, "frames").find("ETA 3m05s"),
            std::string::npos);
  Json unknown = st;
  unknown["batches"][0]["eta_seconds"] = nullptr;
  EXPECT_NE(format_status(unknown).find("ETA -"), std::string::npos);
}

TEST(StatusText, WorkersShowHostStateAgeCountsAndTheirTile) {
  Json live = {{"worker", "w1"},
               {"host", "node-01"},
               {"threads", 8},
               {"last_seen", 1.7e9},
               {"live", true},
               {"tasks", {12}},
               {"state", "live"},
               {"heartbeat_age", 1.2},
               {"tasks_done", 40},
               {"tasks_failed", 2},
               {"current", Json::array({{{"task", 12},
                                         {"batch", "b-0000abcd"},
                                         {"kind", "render_tile"},
                                         {"frame", 3},
                                         {"rect", {0, 16, 16, 8}},
                                         {"shard", 1}}})}};
  Json lost = {{"worker", "w2"},          {"host", "node-02"},       {"threads", 8},
               {"last_seen", 1.7e9 - 95}, {"live", false},           {"tasks", Json::array()},
               {"state", "lost"},         {"heartbeat_age", 95.0},   {"tasks_done", 7},
               {"tasks_failed", 0},       {"current", Json::array()}};
  Json left = lost;
  left["worker"] = "w3";
  left["state"] = "left";
  const Json st = {{"now", 1.7e9},
                   {"batches", Json::array()},
                   {"batches_omitted", 0},
                   {"workers", {live, lost, left}},
                   {"workers_omitted", 0}};
  const std::string text = format_status(st);
  EXPECT_NE(text.find("workers: 1 live, 1 lost, 1 left"), std::string::npos) << text;
  EXPECT_NE(text.find("node-01"), std::string::npos) << text;
  EXPECT_NE(text.find("b-0000abcd frame 3 tile 0,16,16,8"), std::string::npos) << text;
  EXPECT_NE(text.find("1m35s ago"), std::string::npos) << text;
  EXPECT_EQ(text.find("w3"), std::string::npos) << "workers that left are counted, not listed";
  // A reply of an older coordinator (no state, no counts) still prints.
  Json old = live;
  for (const char* k : {"state", "heartbeat_age", "tasks_done", "tasks_failed", "current"})
    old.erase(k);
  const std::string before =
      format_status({{"now", 1.7e9 + 3}, {"batches", Json::array()}, {"workers", {old}}});
  EXPECT_NE(before.find("workers: 1 live, 0 lost"), std::string::npos) << before;
  EXPECT_NE(before.find("3s ago"), std::string::npos) << before;
}

TEST(StatusWatch, RedrawsOnATerminalAndPrintsBlocksElsewhereUntilTheBatchEnds) {
  for (bool terminal : {false, true}) {
    int calls = 0;
    auto fetch = [&] {
      ++calls;
      return Json{{"now", 1.7e9},
                  {"batches", Json::array({batch_entry(calls < 3 ? "running" : "done", nullptr)})},
                  {"workers", Json::array()}};
    };
    std::ostringstream out;
    std::atomic<bool> stop{false};
    std::vector<double> sleeps;
    WatchOptions o;
    o.interval_seconds = 5;
    o.terminal = terminal;
    o.batch = "b-0000abcd";
    watch(fetch, o, out, stop, [&](double s) { sleeps.push_back(s); });
    EXPECT_EQ(calls, 3);
    EXPECT_EQ(sleeps, (std::vector<double>{5, 5}));
    const std::string text = out.str();
    EXPECT_EQ(count_of(text, "every 5 s"), 3u) << text;
    EXPECT_EQ(count_of(text, "\x1b[H\x1b[2J"), terminal ? 3u : 0u);
    EXPECT_NE(text.substr(text.rfind("every 5 s")).find("b-0000abcd  done"), std::string::npos);
  }
  // --json: one object per line; stop ends the loop after the block it is in.
  int calls = 0;
  std::atomic<bool> stop{false};
  std::ostringstream out;
  WatchOptions o;
  o.json = true;
  watch(
      [&] {
        ++calls;
        return Json{{"now", calls}};
      },
      o, out, stop,
      [&](double) {
        if (calls == 2) stop = true;
      });
  EXPECT_EQ(out.str(), "{\"now\":1}\n{\"now\":2}\n");
}

// A coordinator that stops answering for a while (a restart) does not end
// a watch; one that never answered does, with its error.
TEST(StatusWatch, OutlivesACoordinatorRestartButNotAnAbsentCoordinator) {
  int calls = 0;
  auto fetch = [&]() -> Json {
    if (++calls == 2) throw std::runtime_error("coordinator: timed out");
    return Json{{"now", 1.7e9},
                {"batches", Json::array({batch_entry(calls < 3 ? "running" : "done", nullptr)})},
                {"workers", Json::array()}};
  };
  std::ostringstream out;
  std::atomic<bool> stop{false};
  WatchOptions o;
  o.batch = "b-0000abcd";
  watch(fetch, o, out, stop, [](double) {});
  EXPECT_EQ(calls, 3);
  EXPECT_EQ(count_of(out.str(), "b-0000abcd  "), 2u) << out.str();
  EXPECT_EQ(out.str().find("timed out"), std::string::npos) << "the note goes to the log";
  std::ostringstream none;
  EXPECT_THROW(watch([]() -> Json { throw std::runtime_error("no coordinator"); }, o, none, stop,
                     [](double) {}),
               std::runtime_error);
}

TEST(StatusText, TaskStatesAsOperatorsNameThem) {
  EXPECT_EQ(task_state_from_user("running"), "leased");
  EXPECT_EQ(task_state_from_user("failed"), "failed");
  EXPECT_FALSE(task_state_from_user("broken"));
}

}  // namespace
}  // namespace dofarm::farm
