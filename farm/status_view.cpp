#include "farm/status_view.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <ctime>
#include <sstream>
#include <thread>

#include "common/progress.h"

namespace dofarm::farm {

namespace {

std::string str(const Json& j, const char* key) {
  auto it = j.find(key);
  return it != j.end() && it->is_string() ? it->get<std::string>() : std::string();
}

int64_t num(const Json& j, const char* key) {
  auto it = j.find(key);
  return it != j.end() && it->is_number() ? it->get<int64_t>() : 0;
}

std::string rect_text(const Json& r) {
  if (!r.is_array() || r.size() != 4) return "-";
  return fmt::format("{},{},{},{}", r[0].get<int64_t>(), r[1].get<int64_t>(), r[2].get<int64_t>(),
                     r[3].get<int64_t>());
}

// Where a task is: "frame 3 tile 0,16,16,8" or "shard 1".
std::string place(const Json& t) {
  if (str(t, "kind") == "pack_shard") return fmt::format("shard {}", num(t, "shard"));
  return fmt::format("frame {} tile {}", num(t, "frame"), rect_text(t.value("rect", Json())));
}

std::string local_time(double t) {
  const std::time_t s = std::time_t(t);
  std::tm tm{};
  localtime_r(&s, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M:%S", &tm);
  return buf;
}

void print_batch(const Json& b, std::ostream& out) {
  out << str(b, "batch") << "  " << str(b, "state");
  // Older coordinators do not send it.
  if (b.contains("priority")) out << "  priority " << num(b, "priority");
  out << "  " << str(b, "spec_path") << "\n";
  const Json& eta = b.value("eta_seconds", Json());
  // The same duration format as the progress bar (common/progress.h).
  out << fmt::format(
      "  frames {}/{} rendered, {} packed | tasks {} done, {} running, {} pending, {} failed | "
      "{:.1f} frames/h | ETA {}\n",
      num(b, "frames_rendered"), num(b, "frames_total"), num(b, "frames_packed"),
      num(b, "tasks_done"), num(b, "tasks_leased"), num(b, "tasks_pending"), num(b, "tasks_failed"),
      b.value("frames_per_hour", 0.0),
      eta.is_number() ? format_duration(eta.get<double>()) : std::string("-"));
  for (const Json& f : b.value("failed", Json::array())) {
    out << "  FAILED task " << num(f, "task") << " (" << str(f, "kind") << ", " << place(f)
        << "): " << str(f, "error") << "\n";
    if (!str(f, "reproduce").empty()) out << "    reproduce: " << str(f, "reproduce") << "\n";
  }
  if (num(b, "failed_omitted") > 0)
    out << "  ... and " << num(b, "failed_omitted") << " more failed tasks\n";
  if (!b.value("blocklisted", Json::array()).empty())
    out << "  blocklisted workers: " << b["blocklisted"].dump()
        << (num(b, "blocklisted_omitted") > 0
                ? " and " + std::to_string(num(b, "blocklisted_omitted")) + " more"
                : "")
        << "\n";
  if (!str(b, "reason").empty()) out << "  reason: " << str(b, "reason") << "\n";
  if (b.contains("stalled_seconds") && b["stalled_seconds"].is_number())
    out << "  stalled: no eligible worker for "
        << format_duration(b["stalled_seconds"].get<double>()) << "\n";
  if (b.contains("tasks")) out << format_tasks(b);
}

// A worker's state: older coordinators send only `live`.
std::string worker_state(const Json& w) {
  const std::string s = str(w, "state");
  if (!s.empty()) return s;
  return w.value("live", false) ? "live" : "lost";
}

}  // namespace

std::optional<std::string> task_state_from_user(const std::string& text) {
  if (text == "running" || text == "leased") return std::string("leased");
  if (text == "pending" || text == "done" || text == "failed") return text;
  return std::nullopt;
}

std::string format_tasks(const Json& b) {
  std::ostringstream out;
  const Json& tasks = b.value("tasks", Json::array());
  out << fmt::format("  {:>8}  {:<11}  {:>6}  {:<17}  {:<7}  {:<20}  {:>8}\n", "TASK", "KIND",
                     "FRAME", "TILE", "STATE", "WORKER", "ATTEMPTS");
  for (const Json& t : tasks) {
    const bool pack = str(t, "kind") == "pack_shard";
    std::string state = str(t, "state");
    if (state == "leased") state = "running";
    out << fmt::format(
        "  {:>8}  {:<11}  {:>6}  {:<17}  {:<7}  {:<20}  {:>8}\n", num(t, "task"), str(t, "kind"),
        pack ? std::string("-") : std::to_string(num(t, "frame")),
        pack ? "shard " + std::to_string(num(t, "shard")) : rect_text(t.value("rect", Json())),
        state, str(t, "worker").empty() ? "-" : str(t, "worker"), num(t, "attempts"));
    // The last error, and how to render the tile alone, for tasks that have
    // failed (for good, or once and wait for their retry).
    if (!str(t, "error").empty()) {
      out << "            error: " << str(t, "error") << "\n";
      if (!str(t, "reproduce").empty())
        out << "            reproduce: " << str(t, "reproduce") << "\n";
    }
  }
  if (tasks.empty()) out << "  (no task matches)\n";
  if (num(b, "tasks_omitted") > 0)
    out << "  ... and " << num(b, "tasks_omitted") << " more tasks (see --limit)\n";
  return out.str();
}

std::string format_status(const Json& st) {
  std::ostringstream out;
  for (const Json& b : st.value("batches", Json::array())) print_batch(b, out);
  // A bounded reply (docs/farm.md "Bounded inputs") counts what it leaves out.
  if (num(st, "batches_omitted") > 0)
    out << "... and " << num(st, "batches_omitted") << " older batches not shown\n";
  int live = 0, lost = 0, left = 0;
  for (const Json& w : st.value("workers", Json::array())) {
    const std::string s = worker_state(w);
    (s == "live" ? live : s == "left" ? left : lost) += 1;
  }
  out << fmt::format("workers: {} live, {} lost, {} left", live, lost, left);
  if (num(st, "workers_omitted") > 0)
    out << " (" << num(st, "workers_omitted") << " more workers not shown)";
  out << "\n";
  if (live + lost == 0) return out.str();
  out << fmt::format("  {:<24}  {:<20}  {:<5}  {:>8}  {:>6}  {:>6}  {}\n", "WORKER", "HOST",
                     "STATE", "SEEN", "DONE", "FAILED", "NOW");
  // Those that left said goodbye: counted above, not listed.
  for (const Json& w : st.value("workers", Json::array())) {
    const std::string state = worker_state(w);
    if (state == "left") continue;
    const double age = w.contains("heartbeat_age")
                           ? w["heartbeat_age"].get<double>()
                           : st.value("now", 0.0) - w.value("last_seen", 0.0);
    std::string now;
    for (const Json& h : w.value("current", Json::array()))
      now += (now.empty() ? "" : "; ") + str(h, "batch") + " " + place(h);
    if (now.empty() && !w.value("tasks", Json::array()).empty())
      now = "tasks " + w["tasks"].dump();  // an older coordinator: ids only
    out << fmt::format("  {:<24}  {:<20}  {:<5}  {:>8}  {:>6}  {:>6}  {}\n", str(w, "worker"),
                       str(w, "host").empty() ? "-" : str(w, "host"), state,
                       format_duration(age) + " ago", num(w, "tasks_done"), num(w, "tasks_failed"),
                       now.empty() ? "idle" : now);
  }
  return out.str();
}

std::string format_events(const Json& reply) {
  std::ostringstream out;
  if (reply.value("older", false)) out << "(older events not shown; see --limit)\n";
  for (const Json& e : reply.value("events", Json::array())) {
    const int64_t task = num(e, "task");
    out << fmt::format("{}  {:<5}  {:<11}  {:>8}  {:<16}  {}\n", local_time(e.value("time", 0.0)),
                       str(e, "level"), str(e, "kind").empty() ? "-" : str(e, "kind"),
                       task > 0 ? "task " + std::to_string(task) : std::string("-"),
                       str(e, "worker").empty() ? "-" : str(e, "worker"), str(e, "text"));
  }
  if (num(reply, "events_omitted") > 0)
    out << "(" << num(reply, "events_omitted") << " more events left out: the reply is bounded)\n";
  return out.str();
}

namespace {
bool batch_running(const Json& st, const std::string& batch) {
  for (const Json& b : st.value("batches", Json::array()))
    if (str(b, "batch") == batch) return str(b, "state") == "running";
  return false;
}
}  // namespace

void watch(const std::function<Json()>& fetch, const WatchOptions& o, std::ostream& out,
           const std::atomic<bool>& stop, const std::function<void(double)>& sleep) {
  auto wait = [&](double seconds) {
    if (sleep) return sleep(seconds);
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (!stop && std::chrono::steady_clock::now() < end)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
  };
  bool shown = false;
  while (!stop) {
    Json st;
    try {
      st = fetch();
    } catch (const std::exception& e) {
      // The first refresh fails as the command without --watch would. Later
      // a coordinator that restarts or is out of reach for a while is waited
      // for, as a monitor does; the note goes to the log (stderr), so the
      // blocks (and JSON lines) stay clean.
      if (!shown || stop) throw;
      spdlog::warn("no answer from the coordinator ({}); trying again in {:g} s", e.what(),
                   o.interval_seconds);
      wait(o.interval_seconds);
      continue;
    }
    shown = true;
    if (o.json) {
      out << st.dump() << "\n";  // JSON lines: one object per refresh
    } else {
      const std::string header =
          fmt::format("{}  every {:g} s; Ctrl-C to stop\n", local_time(double(std::time(nullptr))),
                      o.interval_seconds);
      // On a terminal: home, clear, redraw. Elsewhere (a log, a pipe): plain
      // blocks, one after the other, each starting with its time.
      if (o.terminal) out << "\x1b[H\x1b[2J";
      out << header << format_status(st);
      if (!o.terminal) out << "\n";
    }
    out.flush();
    if (!o.batch.empty() && !batch_running(st, o.batch)) return;  // it ended: this was the last
    wait(o.interval_seconds);
  }
}

}  // namespace dofarm::farm
