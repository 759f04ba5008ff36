// The JSON bodies of the server's replies (common/messages.h defines each):
// the `task` of an assignment, and the bounded `status_reply` and
// `events_reply`, whose every list keeps below its byte budget so that one
// reply never grows past protocol::kMaxMessageBytes.
#include <algorithm>
#include <cctype>
#include <cstring>

#include "common/messages.h"
#include "coordinator/server.h"

namespace dofarm::coordinator {

using protocol::Json;

namespace {

Json rect_json(Rect r) { return Json::array({r.x, r.y, r.w, r.h}); }

// Reply budgets (bytes of JSON): workers, and per batch its failed tasks and
// blocklist; the batches share what is left below kStatusBytes. Each entry
// is bounded by the field limits, so checking before adding one keeps the
// whole reply below protocol::kMaxMessageBytes.
constexpr size_t kStatusBytes = 900 * 1024;
constexpr size_t kStatusWorkerBytes = 256 * 1024;
constexpr size_t kStatusFailedBytes = 32 * 1024;
constexpr size_t kStatusBlocklistBytes = 8 * 1024;
constexpr size_t kStatusListItems = 1000;  // messages.cpp: arrays of a status entry
// `status --tasks`: the listed tasks of every batch share this (the workers'
// share and the batches' counts stay within the rest).
constexpr size_t kStatusTaskBytes = 480 * 1024;
constexpr size_t kStatusTaskItems = 10000;  // messages.cpp: a batch's `tasks`
constexpr size_t kWorkerHeldItems = 16;     // messages.cpp: a worker's `current`
// `events`: at most this much JSON of events per reply, the newest kept.
constexpr size_t kEventsBytes = 900 * 1024;

// An id as the status_reply definition allows it (stores written before the
// limits may hold others).
std::string id_text(const std::string& s) {
  std::string out = s.substr(0, protocol::kMaxIdBytes);
  for (char& c : out)
    if (!std::isalnum(static_cast<unsigned char>(c)) && !std::strchr("._:@+-", c)) c = '_';
  return out;
}

std::string text(const std::string& s, size_t max = protocol::kMaxTextBytes) {
  return protocol::clip_text(s, max);
}

// An event kind as the `events_reply` definition allows it (a-z and _).
std::string kind_text(const std::string& s) {
  std::string out = s.substr(0, 64);
  for (char& c : out)
    if (!(c >= 'a' && c <= 'z') && c != '_') c = '_';
  return out;
}

Json task_json(const TaskStatus& t) {
  return {{"task", t.task_id},
          {"kind", to_string(t.kind)},
          {"frame", t.frame},
          {"rect", rect_json(t.rect)},
          {"shard", t.shard},
          {"state", to_string(t.state)},
          {"worker", id_text(t.worker)},
          {"attempts", std::max(t.attempts, 0)},
          {"error", text(t.error)},
          {"reproduce", text(t.reproduce)}};
}

// `task_bytes`: what is left of kStatusTaskBytes; null when no tasks were asked for.
Json batch_json(const BatchStatus& b, size_t* task_bytes) {
  Json failed = Json::array();
  size_t bytes = 0, omitted = 0;
  for (const FailedTask& f : b.failed) {
    Json j = {{"task", f.task_id},
              {"kind", to_string(f.kind)},
              {"frame", f.frame},
              {"rect", rect_json(f.rect)},
              {"shard", f.shard},
              {"error", text(f.error)},
              {"reproduce", text(f.reproduce)}};
    const size_t n = j.dump().size() + 1;
    if (bytes + n > kStatusFailedBytes || failed.size() >= kStatusListItems) {
      ++omitted;
      continue;
    }
    bytes += n;
    failed.push_back(std::move(j));
  }
  Json blocked = Json::array();
  size_t blocked_bytes = 0, blocked_omitted = 0;
  for (const std::string& w : b.blocklisted) {
    const std::string id = id_text(w);
    if (blocked_bytes + id.size() + 3 > kStatusBlocklistBytes || blocked.size() >= kStatusListItems) {
      ++blocked_omitted;
      continue;
    }
    blocked_bytes += id.size() + 3;
    blocked.push_back(id);
  }
  Json tasks = Json::array();
  int64_t tasks_omitted = b.tasks_omitted;
  if (task_bytes) {
    for (const TaskStatus& t : b.tasks) {
      Json j = task_json(t);
      const size_t n = j.dump().size() + 1;
      if (n > *task_bytes || tasks.size() >= kStatusTaskItems) {
        ++tasks_omitted;
        continue;
      }
      *task_bytes -= n;
      tasks.push_back(std::move(j));
    }
  }
  Json j = {{"batch", id_text(b.batch.id)},
            {"state", to_string(b.batch.state)},
            {"priority", b.batch.priority},
            {"spec_path", text(b.batch.spec_path, protocol::kMaxPathBytes)},
            {"out_dir", text(b.batch.out_dir, protocol::kMaxPathBytes)},
            {"created", b.batch.created},
            {"tasks_total", b.tasks_total},
            {"tasks_done", b.tasks_done},
            {"tasks_failed", b.tasks_failed},
            {"tasks_leased", b.tasks_leased},
            {"tasks_pending", b.tasks_pending},
            {"frames_total", b.frames_total},
            {"frames_rendered", b.frames_rendered},
            {"frames_packed", b.frames_packed},
            {"frames_per_hour", b.frames_per_hour},
            {"eta_seconds", b.eta_seconds ? Json(*b.eta_seconds) : Json(nullptr)},
            {"failed", failed},
            {"failed_omitted", omitted},
            {"blocklisted", blocked},
            {"blocklisted_omitted", blocked_omitted},
            {"reason", text(b.reason)},
            {"stalled_seconds", b.stalled_seconds ? Json(*b.stalled_seconds) : Json(nullptr)}};
  if (task_bytes) {
    j["tasks"] = std::move(tasks);
    j["tasks_omitted"] = tasks_omitted;
  }
  return j;
}

Json worker_json(const WorkerStatus& w, double now) {
  std::vector<int64_t> tasks = w.leased_tasks;
  if (tasks.size() > 100) tasks.resize(100);
  Json current = Json::array();
  for (const HeldTask& h : w.current) {
    if (current.size() >= kWorkerHeldItems) break;
    current.push_back({{"task", h.task_id},
                       {"batch", id_text(h.batch_id)},
                       {"kind", to_string(h.kind)},
                       {"frame", h.frame},
                       {"rect", rect_json(h.rect)},
                       {"shard", h.shard}});
  }
  return {{"worker", id_text(w.worker.id)},
          {"host", id_text(w.worker.host).substr(0, protocol::kMaxHostBytes)},
          {"threads", std::clamp(w.worker.threads, 0, 4096)},
          {"last_seen", w.worker.last_seen},
          {"live", w.live},
          {"tasks", tasks},
          {"state", to_string(w.state)},
          {"heartbeat_age", std::clamp(now - w.worker.last_seen, 0.0, 1e12)},
          {"tasks_done", std::max<int64_t>(w.counts.done, 0)},
          {"tasks_failed", std::max<int64_t>(w.counts.failed, 0)},
          {"current", current}};
}

// Indices of `n` entries in the order they get into a bounded reply.
template <typename Before>
std::vector<size_t> priority_order(size_t n, Before before) {
  std::vector<size_t> order(n);
  for (size_t i = 0; i < n; ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), before);
  return order;
}

}  // namespace

Json assignment_json(const Assignment& a, double lease_seconds, const std::string& token) {
  Json j = {{"task", a.task_id},
            {"attempt", a.attempt},
            {"token", token},
            {"kind", to_string(a.kind)},
            {"batch", a.batch_id},
            {"job", a.job_hash},
            {"out_dir", a.out_dir},
            {"frame", a.frame},
            {"rect", rect_json(a.rect)},
            {"shard", a.shard},
            {"shard_file", a.shard_range.file},
            {"frame_start", a.shard_range.frame_start},
            {"frame_end", a.shard_range.frame_end},
            {"lease_seconds", lease_seconds}};
  Json inputs = Json::array();
  for (const StagedTile& t : a.inputs)
    inputs.push_back({{"task", t.task_id},
                      {"frame", t.frame},
                      {"rect", rect_json(t.rect)},
                      {"path", t.staged_path},
                      {"checksum", t.checksum}});
  j["inputs"] = inputs;
  return j;
}

StatusQuery status_query(const protocol::Message& m) {
  StatusQuery q;
  if (m.has("batch")) q.batch = m.str("batch");
  q.tasks = m.body.value("tasks", false);
  if (m.has("state")) {
    const std::string& state = m.str("state");
    for (TaskState st :
         {TaskState::kPending, TaskState::kLeased, TaskState::kDone, TaskState::kFailed})
      if (state == to_string(st)) q.state = st;
    if (!q.state)
      throw protocol::ProtocolError("\"status\".state: \"" + state +
                                    "\" is not a task state (pending, leased, done, failed)");
  }
  if (m.has("limit")) q.task_limit = size_t(m.integer("limit"));
  return q;
}

Json events_to_json(const std::string& batch, const std::vector<EventRow>& events, bool older) {
  // Newest kept first when the reply would grow past its bound.
  std::vector<Json> entries;
  size_t bytes = 0;
  int64_t omitted = 0;
  for (auto it = events.rbegin(); it != events.rend(); ++it) {
    const EventRow& e = *it;
    Json j = {{"time", std::clamp(e.time, 0.0, 1e12)},
              {"level", e.level == "warn" || e.level == "error" ? e.level : "info"},
              {"kind", kind_text(e.kind)},
              {"task", std::max<int64_t>(e.task, 0)},
              {"worker", id_text(e.worker)},
              {"text", text(e.text)}};
    const size_t n = j.dump().size() + 1;
    if (bytes + n > kEventsBytes) {
      ++omitted;
      continue;
    }
    bytes += n;
    entries.push_back(std::move(j));
  }
  std::reverse(entries.begin(), entries.end());
  return {{"batch", id_text(batch)},
          {"events", entries},
          {"events_omitted", omitted},
          {"older", older}};
}

Json status_to_json(const StatusReport& r) {
  // Workers: live first, then the most recently seen.
  std::vector<Json> worker_entries(r.workers.size());
  size_t worker_bytes = 0, workers_omitted = 0;
  for (size_t i : priority_order(r.workers.size(), [&](size_t a, size_t b) {
         const WorkerStatus &x = r.workers[a], &y = r.workers[b];
         if (x.live != y.live) return x.live;
         return x.worker.last_seen > y.worker.last_seen;
       })) {
    Json j = worker_json(r.workers[i], r.now);
    const size_t n = j.dump().size() + 1;
    if (worker_bytes + n > kStatusWorkerBytes) {
      ++workers_omitted;
      continue;
    }
    worker_bytes += n;
    worker_entries[i] = std::move(j);
  }
  // Batches: running first, then the newest.
  std::vector<Json> batch_entries(r.batches.size());
  size_t batch_bytes = 0, batches_omitted = 0;
  size_t task_bytes = kStatusTaskBytes;
  for (size_t i : priority_order(r.batches.size(), [&](size_t a, size_t b) {
         const BatchRow &x = r.batches[a].batch, &y = r.batches[b].batch;
         const bool xr = x.state == BatchState::kRunning, yr = y.state == BatchState::kRunning;
         if (xr != yr) return xr;
         return x.created > y.created;
       })) {
    Json j = batch_json(r.batches[i], r.tasks_listed ? &task_bytes : nullptr);
    const size_t n = j.dump().size() + 1;
    if (worker_bytes + batch_bytes + n > kStatusBytes) {
      ++batches_omitted;
      continue;
    }
    batch_bytes += n;
    batch_entries[i] = std::move(j);
  }
  Json batches = Json::array(), workers = Json::array();
  for (Json& j : batch_entries)
    if (!j.is_null()) batches.push_back(std::move(j));
  for (Json& j : worker_entries)
    if (!j.is_null()) workers.push_back(std::move(j));
  return {{"now", r.now},
          {"batches", batches},
          {"batches_omitted", batches_omitted},
          {"workers", workers},
          {"workers_omitted", workers_omitted}};
}

}  // namespace dofarm::coordinator
