#include "coordinator/metrics.h"

#include <fmt/format.h>

#include <cmath>

namespace dofarm::coordinator {

using protocol::Json;

std::string prometheus_label(const std::string& value) {
  std::string out;
  out.reserve(value.size());
  for (char c : value) {
    if (c == '\\')
      out += "\\\\";
    else if (c == '"')
      out += "\\\"";
    else if (c == '\n')
      out += "\\n";
    else
      out += c;
  }
  return out;
}

namespace {

// One metric family: HELP and TYPE once, then its samples.
class Family {
 public:
  Family(std::string& out, const char* name, const char* type, const char* help)
      : out_(out), name_(name) {
    out_ += fmt::format("# HELP {} {}\n# TYPE {} {}\n", name, help, name, type);
  }
  // `labels` already formatted: `batch="b-1",state="done"` (or empty).
  void sample(const std::string& labels, double value) {
    if (!std::isfinite(value)) return;  // never in practice; the format allows no gap
    out_ += name_;
    if (!labels.empty()) out_ += "{" + labels + "}";
    out_ += fmt::format(" {}\n", value);
  }
  void sample(const std::string& labels, uint64_t value) {
    out_ += name_;
    if (!labels.empty()) out_ += "{" + labels + "}";
    out_ += fmt::format(" {}\n", value);
  }

 private:
  std::string& out_;
  const char* name_;
};

std::string label(const char* name, const std::string& value) {
  return fmt::format("{}=\"{}\"", name, prometheus_label(value));
}

double number(const Json& j, const char* key) {
  const auto it = j.find(key);
  return it != j.end() && it->is_number() ? it->get<double>() : 0.0;
}

}  // namespace

std::string metrics_text(const Json& status, const ServerCounters& c, double snapshot_seconds) {
  std::string out;
  const Json batches = status.value("batches", Json::array());
  const Json workers = status.value("workers", Json::array());

  {
    std::map<std::string, uint64_t> by_state;
    for (const char* s : {"running", "done", "failed", "cancelled"}) by_state[s] = 0;
    for (const Json& b : batches) ++by_state[b.value("state", std::string("unknown"))];
    Family f(out, "dofarm_batches", "gauge", "Batches on this coordinator by state");
    for (const auto& [state, n] : by_state) f.sample(label("state", state), n);
  }
  {
    Family f(out, "dofarm_batch_state", "gauge",
             "1 for the state each batch is in (running, done, failed, cancelled)");
    for (const Json& b : batches)
      f.sample(label("batch", b.value("batch", "")) + "," + label("state", b.value("state", "")),
               uint64_t(1));
  }
  {
    // The states of `dofarm status`: running = leased to a worker now.
    Family f(out, "dofarm_tasks", "gauge", "Tasks of a batch by state");
    for (const Json& b : batches) {
      const std::string id = label("batch", b.value("batch", ""));
      f.sample(id + "," + label("state", "pending"), number(b, "tasks_pending"));
      f.sample(id + "," + label("state", "running"), number(b, "tasks_leased"));
      f.sample(id + "," + label("state", "done"), number(b, "tasks_done"));
      f.sample(id + "," + label("state", "failed"), number(b, "tasks_failed"));
    }
  }
  struct FrameGauge {
    const char* name;
    const char* key;
    const char* help;
  };
  for (const FrameGauge& g :
       {FrameGauge{"dofarm_batch_frames", "frames_total", "Frames a batch renders"},
        FrameGauge{"dofarm_frames_rendered", "frames_rendered",
                   "Frames of a batch whose every tile is rendered"},
        FrameGauge{"dofarm_frames_packed", "frames_packed",
                   "Frames of a batch in a finished shard (readable by the trainer)"},
        FrameGauge{"dofarm_frames_per_hour", "frames_per_hour",
                   "Frames rendered per hour over the rate window (10 min, or the batch's age)"}}) {
    Family f(out, g.name, "gauge", g.help);
    for (const Json& b : batches) f.sample(label("batch", b.value("batch", "")), number(b, g.key));
  }
  {
    Family f(out, "dofarm_batch_eta_seconds", "gauge",
             "Seconds until every frame of a running batch is rendered at its rate (absent when "
             "unknown)");
    for (const Json& b : batches)
      if (b.contains("eta_seconds") && b["eta_seconds"].is_number())
        f.sample(label("batch", b.value("batch", "")), b["eta_seconds"].get<double>());
  }
  {
    uint64_t live = 0;
    for (const Json& w : workers) live += w.value("live", false) ? 1 : 0;
    Family f(out, "dofarm_workers_live", "gauge",
             "Workers seen within two lease lengths that have not said goodbye");
    f.sample("", live);
    Family k(out, "dofarm_workers", "gauge", "Workers the coordinator knows (listed in status)");
    k.sample("", uint64_t(workers.size()));
  }
  {
    Family f(out, "dofarm_messages_received_total", "counter",
             "Messages received since the coordinator started, by type (rate() gives the "
             "message rate)");
    for (const auto& [type, n] : c.messages) f.sample(label("type", type), n);
  }
  Family(out, "dofarm_messages_refused_total", "counter",
         "Messages answered with an error: malformed, oversized, or not allowed to the sender")
      .sample("", c.messages_refused);
  Family(out, "dofarm_lease_expiries_total", "counter",
         "Task leases that expired (their task was requeued) since the coordinator started")
      .sample("", c.lease_expiries);
  Family(out, "dofarm_task_failures_total", "counter",
         "Task attempts that workers reported as failed (retried or failed for good)")
      .sample("", c.task_failures);
  Family(out, "dofarm_worker_blocklistings_total", "counter",
         "Times a worker was blocklisted for a batch after failing its tasks")
      .sample("", c.blocklistings);
  Family(out, "dofarm_status_snapshot_seconds", "gauge",
         "Seconds the coordinator's loop spent building the snapshot these numbers come from")
      .sample("", snapshot_seconds);
  return out;
}

}  // namespace dofarm::coordinator
