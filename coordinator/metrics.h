// The coordinator's metrics in the Prometheus text exposition format
// (version 0.0.4): gauges taken from the status report (the very JSON that
// `dofarm status --json` prints) and counters the server loop keeps since it
// started. docs/farm.md, "Web page and metrics", lists every series.
#pragma once

#include <cstdint>
#include <map>
#include <string>

#include "common/protocol.h"

namespace dofarm::coordinator {

// Counted by the server loop (single-threaded); copied into each snapshot.
struct ServerCounters {
  // Messages parsed, by type. protocol::parse() admits only the protocol's
  // types, so the label set is bounded.
  std::map<std::string, uint64_t> messages;
  uint64_t messages_refused = 0;  // malformed, oversized, or not allowed to the sender's role
  uint64_t lease_expiries = 0;    // leases that ran out (their task requeued)
  uint64_t task_failures = 0;     // `failed` reports that counted (retry or failed for good)
  uint64_t blocklistings = 0;     // workers blocklisted for a batch by such a failure
};

// The text of /metrics: `status` is status_to_json() of the whole farm;
// `snapshot_seconds` how long the loop took to build it.
std::string metrics_text(const protocol::Json& status, const ServerCounters& counters,
                         double snapshot_seconds);

// A label value escaped as the format asks (backslash, double quote, newline).
std::string prometheus_label(const std::string& value);

}  // namespace dofarm::coordinator
