// What the scheduler reports, without changing anything: the status of
// batches and workers, what a resume must check on disk, and the command
// that reproduces a failed tile. Split from scheduler.cpp, which holds the
// state changes.
#include <algorithm>
#include <cctype>
#include <map>
#include <set>
#include <string_view>

#include "common/job_snapshot.h"
#include "coordinator/scheduler.h"

namespace dofarm::coordinator {

namespace {

// Quotes for a POSIX shell only where needed, so the common case stays readable.
std::string shell_quote(const std::string& arg) {
  const bool plain = !arg.empty() && std::all_of(arg.begin(), arg.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) ||
           std::string_view("_./=,:+-@%").find(c) != std::string_view::npos;
  });
  if (plain) return arg;
  std::string out = "'";
  for (char c : arg) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

}  // namespace

StatusReport Scheduler::status(const std::string& batch_id) {
  StatusQuery q;
  q.batch = batch_id;
  return status(q);
}

StatusReport Scheduler::status(const StatusQuery& query) {
  const std::string& batch_id = query.batch;
  flush();  // last_seen of the workers, as of now
  const double now = clock_.now();
  StatusReport report;
  report.now = now;
  report.tasks_listed = query.tasks;
  size_t listed = 0;  // tasks listed so far
  std::vector<BatchRow> batches;
  if (batch_id.empty()) {
    batches = store_.batches();
  } else if (auto b = store_.batch(batch_id)) {
    batches.push_back(*b);
  }
  for (const BatchRow& batch : batches) {
    BatchStatus st;
    st.batch = batch;
    st.frames_total = batch.frame_end - batch.frame_start + 1;
    struct Frame {
      int tiles = 0, done = 0;
      double last_done = 0;  // when its last tile was done
      int shard = 0;
    };
    std::map<int, Frame> frames;
    std::set<int> packed_shards;
    for (const TaskRow& t : store_.tasks(batch.id)) {
      if (query.tasks && (!query.state || t.state == *query.state)) {
        if (listed < query.task_limit) {  // the limit holds across batches too
          ++listed;
          TaskStatus ts;
          ts.task_id = t.id;
          ts.kind = t.kind;
          ts.frame = t.frame;
          ts.rect = t.rect;
          ts.shard = t.shard;
          ts.state = t.state;
          ts.worker = t.lease_worker;
          // Who had it last: one keyed query per listed task (the list is bounded).
          if (ts.worker.empty() && t.attempts > 0) {
            const std::vector<AttemptRow> a = store_.attempts(t.id);
            if (!a.empty()) ts.worker = a.back().worker;
          }
          ts.attempts = t.attempts;
          ts.error = t.last_error;
          if (t.kind == TaskKind::kRenderTile) ts.reproduce = reproduce_command(batch, t);
          st.tasks.push_back(std::move(ts));
        } else {
          ++st.tasks_omitted;
        }
      }
      ++st.tasks_total;
      switch (t.state) {
        case TaskState::kPending:
          ++st.tasks_pending;
          break;
        case TaskState::kLeased:
          ++st.tasks_leased;
          break;
        case TaskState::kDone:
          ++st.tasks_done;
          break;
        case TaskState::kFailed:
          ++st.tasks_failed;
          st.failed.push_back({t.id, t.kind, t.frame, t.rect, t.shard, t.last_error,
                               t.kind == TaskKind::kRenderTile ? reproduce_command(batch, t) : ""});
          break;
      }
      if (t.kind == TaskKind::kPackShard) {
        if (t.state == TaskState::kDone) packed_shards.insert(t.shard);
        continue;
      }
      Frame& f = frames[t.frame];
      f.shard = t.shard;
      ++f.tiles;
      if (t.state == TaskState::kDone) {
        ++f.done;
        f.last_done = std::max(f.last_done, t.updated);  // a done task's last change
      }
    }
    // The rate counts frames rendered within the window; a batch younger than
    // the window is measured over its own age, so a fresh batch is not
    // underrated.
    const double window_start = std::max(now - options_.rate_window, batch.created);
    int recent = 0;
    for (const auto& [frame, f] : frames) {
      if (f.done < f.tiles) continue;
      ++st.frames_rendered;
      if (packed_shards.count(f.shard)) ++st.frames_packed;
      if (f.last_done >= window_start) ++recent;
    }
    if (now > window_start) st.frames_per_hour = recent / (now - window_start) * 3600.0;
    if (batch.state == BatchState::kRunning && st.frames_per_hour > 0) {
      st.eta_seconds = (st.frames_total - st.frames_rendered) / st.frames_per_hour * 3600.0;
    }
    st.blocklisted = store_.blocked_workers(batch.id);
    if (batch.state == BatchState::kFailed) {
      for (const EventRow& e : store_.events(batch.id, 50)) {
        if (e.level != "error") continue;
        st.reason = e.text;
        break;
      }
    }
    if (auto it = stalled_since_.find(batch.id);
        it != stalled_since_.end() && batch.state == BatchState::kRunning) {
      st.stalled_seconds = now - it->second;
    }
    report.batches.push_back(std::move(st));
  }
  std::map<std::string, std::vector<HeldTask>> leases;
  for (const TaskRow& t : store_.leased_tasks(""))
    leases[t.lease_worker].push_back({t.id, t.batch_id, t.kind, t.frame, t.rect, t.shard});
  for (const WorkerRow& w : store_.workers()) {
    WorkerStatus ws;
    ws.worker = w;
    ws.state = worker_liveness(w, now, options_.lease_seconds);
    ws.live = ws.state == Liveness::kLive;
    if (auto it = leases.find(w.id); it != leases.end()) ws.current = std::move(it->second);
    for (const HeldTask& h : ws.current) ws.leased_tasks.push_back(h.task_id);
    if (auto it = counts_.find(w.id); it != counts_.end()) ws.counts = it->second;
    report.workers.push_back(std::move(ws));
  }
  return report;
}

std::vector<EventRow> Scheduler::events(const std::string& batch_id, int limit) {
  if (limit <= 0) return {};
  std::vector<EventRow> out = store_.events(batch_id, limit);
  for (const LeaseRow& l : store_.leases(batch_id, limit)) {
    TaskRow t;
    t.id = l.task;
    t.kind = l.kind;
    t.frame = l.frame;
    t.rect = l.rect;
    t.shard = l.shard;
    out.push_back({0, l.started, batch_id, "info",
                   describe_task(t) + " leased to " + l.worker + " (attempt " +
                       std::to_string(l.attempt) + ")",
                   "lease", l.task, l.worker});
  }
  // Newest first; at equal times a lease (id 0) goes after what the same
  // instant recorded, so read oldest first it comes before it: a lease
  // precedes its expiry or failure.
  std::stable_sort(out.begin(), out.end(), [](const EventRow& a, const EventRow& b) {
    if (a.time != b.time) return a.time > b.time;
    return a.id > b.id;
  });
  if (out.size() > size_t(limit)) out.resize(size_t(limit));
  std::reverse(out.begin(), out.end());
  return out;
}

std::vector<StagedTile> Scheduler::staged_tiles_to_verify(const std::string& batch_id) {
  const std::vector<TaskRow> tasks = store_.tasks(batch_id);
  std::set<int> packed;
  for (const TaskRow& t : tasks) {
    if (t.kind == TaskKind::kPackShard && t.state == TaskState::kDone) packed.insert(t.shard);
  }
  std::vector<StagedTile> out;
  for (const TaskRow& t : tasks) {
    if (t.kind == TaskKind::kRenderTile && t.state == TaskState::kDone && !packed.count(t.shard)) {
      out.push_back({t.id, t.frame, t.rect, t.shard, t.staged_path, t.checksum});
    }
  }
  return out;
}

std::vector<PackedShard> Scheduler::packed_shards(const std::string& batch_id) {
  const std::optional<BatchRow> batch = store_.batch(batch_id);
  if (!batch) return {};
  const std::vector<ShardRange> ranges =
      shard_ranges(batch->frame_start, batch->frame_end, batch->per_shard);
  std::vector<PackedShard> out;
  for (const TaskRow& t : store_.tasks(batch_id)) {
    if (t.kind != TaskKind::kPackShard || t.state != TaskState::kDone) continue;
    out.push_back({t.id, batch->out_dir, ranges.at(t.shard), t.checksum, inputs_of(t)});
  }
  return out;
}

std::vector<std::string> Scheduler::running_batch_ids() {
  std::vector<std::string> out;
  for (const BatchRow& b : store_.batches())
    if (b.state == BatchState::kRunning) out.push_back(b.id);
  return out;
}

std::optional<int64_t> Scheduler::input_with_staged_path(int64_t pack,
                                                         const std::string& staged_path) {
  return store_.input_with_staged_path(pack, staged_path);
}

std::vector<BatchRow> Scheduler::batches_in(const std::string& out_dir) {
  std::vector<BatchRow> out;
  for (BatchRow& b : store_.batches())
    if (b.out_dir == out_dir) out.push_back(std::move(b));
  return out;
}

std::string reproduce_command(const BatchRow& batch, const TaskRow& task) {
  const Rect& r = task.rect;
  // A snapshot batch is rendered from its job folder's canonical spec, which
  // already holds the overrides: exactly what the workers rendered.
  const bool snapshot = !batch.job_hash.empty();
  const std::string spec =
      snapshot ? (job_dir(batch.out_dir, batch.job_hash) / "job.toml").string() : batch.spec_path;
  std::string cmd = "dofarm render " + shell_quote(spec) + " --frame " +
                    std::to_string(task.frame) + " --tile " + std::to_string(r.x) + "," +
                    std::to_string(r.y) + "," + std::to_string(r.w) + "," + std::to_string(r.h) +
                    " --out repro.exr";
  if (!snapshot)
    for (const std::string& o : batch.overrides) cmd += " --set " + shell_quote(o);
  return cmd;
}

}  // namespace dofarm::coordinator
