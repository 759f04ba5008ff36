// What `dofarm status` and `dofarm events` print, from the JSON the
// coordinator sends (the `status_reply` and `events_reply` of
// docs/protocol.md, which `--json` prints as they are): a thin CLI calls
// these, and tests can check them without a terminal. `watch()` is the loop
// of `status --watch`.
#pragma once

#include <atomic>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <string>

namespace dofarm::farm {

using Json = nlohmann::json;

// A task state as an operator names it: pending, running (or leased), done,
// failed. Returns the wire name (`running` is `leased`), nothing when unknown.
std::optional<std::string> task_state_from_user(const std::string& text);

// Batches with counts, rate, ETA, failures; workers with host, state, last
// heartbeat age, counts and what they render now; with `tasks` in the reply
// (`status --tasks`), the task table of each batch.
std::string format_status(const Json& status);
// The task table of one batch entry of a status reply.
std::string format_tasks(const Json& batch);
// One line per event, oldest first: local time, level, kind, task, worker, text.
std::string format_events(const Json& events_reply);

struct WatchOptions {
  double interval_seconds = 2;
  bool terminal = false;  // redraw in place (ANSI clear) rather than print blocks
  // Ends the loop once this batch is no longer running (empty: only `stop` ends it).
  std::string batch;
  bool json = false;  // one compact JSON object per line instead of the table
};

// Fetches and prints the status every interval until `stop` is set or the
// watched batch ends; the last block shows the final state. `fetch` throws
// on failure: the first failure ends the loop with that exception, a later
// one (a coordinator restarting) is logged and tried again next interval.
// `sleep` waits (or returns early when stop is set); injected so tests need
// not wait.
void watch(const std::function<Json()>& fetch, const WatchOptions& options, std::ostream& out,
           const std::atomic<bool>& stop, const std::function<void(double seconds)>& sleep = {});

}  // namespace dofarm::farm
