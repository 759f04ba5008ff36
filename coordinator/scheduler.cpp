#include "coordinator/scheduler.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <map>
#include <random>
#include <set>
#include <string_view>
#include <tuple>

#include "common/error.h"

namespace dofarm::coordinator {

namespace {

using Transaction = JobStore::Transaction;

std::string describe(const TaskRow& t) {
  std::string s = "task " + std::to_string(t.id) + " (" + to_string(t.kind);
  if (t.kind == TaskKind::kRenderTile) {
    s += " frame " + std::to_string(t.frame) + " tile " + std::to_string(t.rect.x) + "," +
         std::to_string(t.rect.y) + "," + std::to_string(t.rect.w) + "," + std::to_string(t.rect.h);
  } else {
    s += " shard " + std::to_string(t.shard);
  }
  return s + ")";
}

void clear_lease(TaskRow& t) {
  t.lease_worker.clear();
  t.lease_expiry = 0;
}

bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

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

const char* to_string(CompleteStatus s) {
  switch (s) {
    case CompleteStatus::kAccepted:
      return "accepted";
    case CompleteStatus::kDuplicate:
      return "duplicate";
    case CompleteStatus::kStale:
      return "stale";
    case CompleteStatus::kUnknownTask:
      return "unknown task";
  }
  return "?";
}

const char* to_string(FailStatus s) {
  switch (s) {
    case FailStatus::kRetry:
      return "retry";
    case FailStatus::kFailedForGood:
      return "failed for good";
    case FailStatus::kStale:
      return "stale";
    case FailStatus::kUnknownTask:
      return "unknown task";
  }
  return "?";
}

Scheduler::Scheduler(JobStore& store, const Clock& clock, SchedulerOptions options)
    : store_(store), clock_(clock), options_(options) {}

std::string Scheduler::submit(const std::string& spec_path,
                              const std::vector<std::string>& overrides, const std::string& out_dir,
                              const JobSpec& spec, std::optional<double> seconds_per_pixel) {
  const double now = clock_.now();
  const Plan plan = plan_batch(spec, seconds_per_pixel);
  Transaction tx(store_);
  BatchRow batch;
  batch.id = new_batch_id();
  batch.spec_path = spec_path;
  batch.overrides = overrides;
  batch.out_dir = out_dir;
  batch.created = now;
  batch.frame_start = spec.frame_start;
  batch.frame_end = spec.frame_end;
  batch.per_shard = spec.per_shard;
  store_.insert_batch(batch);
  std::vector<int64_t> ids;
  ids.reserve(plan.tasks.size());
  for (const PlannedTask& p : plan.tasks) {
    TaskRow row;
    row.batch_id = batch.id;
    row.kind = p.kind;
    row.frame = p.frame;
    row.rect = p.rect;
    row.shard = p.shard;
    row.updated = now;
    ids.push_back(store_.insert_task(row));
    for (int dep : p.depends_on) store_.insert_dependency(ids.back(), ids[dep]);
  }
  store_.add_event(now, batch.id, "info",
                   "submitted " + spec_path + ": " + std::to_string(spec.frame_count()) +
                       " frames, " + std::to_string(plan.shards.size()) + " shards, " +
                       std::to_string(plan.tasks.size()) + " tasks, tile side " +
                       std::to_string(plan.tile_side));
  tx.commit();
  return batch.id;
}

void Scheduler::worker_seen(const std::string& worker, const std::string& host, int threads) {
  const double now = clock_.now();
  Transaction tx(store_);
  WorkerRow row;
  row.id = worker;
  row.host = host;
  row.threads = threads;
  row.first_seen = now;  // kept by the upsert for a known worker
  row.last_seen = now;
  store_.upsert_worker(row);
  tx.commit();
}

void Scheduler::worker_left(const std::string& worker) {
  Transaction tx(store_);
  if (auto row = store_.worker(worker)) {
    row->left = true;
    row->last_seen = clock_.now();
    store_.upsert_worker(*row);
  }
  tx.commit();
}

void Scheduler::touch_worker(const std::string& worker) {
  const double now = clock_.now();
  WorkerRow row;
  if (auto known = store_.worker(worker)) {
    row = *known;
  } else {  // first heard of by a task message (e.g. across a coordinator restart)
    row.id = worker;
    row.first_seen = now;
  }
  row.last_seen = now;
  row.left = false;
  store_.upsert_worker(row);
}

std::optional<Assignment> Scheduler::assign(const std::string& worker) {
  expire_leases();
  const double now = clock_.now();
  Transaction tx(store_);
  touch_worker(worker);
  // Candidates come in assignment order; most are taken at the first look,
  // so a short page usually suffices. Skipped ones are those this worker
  // already failed while another worker could take them.
  for (int limit = 64;; limit *= 4) {
    const std::vector<TaskRow> candidates = store_.runnable_tasks(worker, now, limit);
    for (TaskRow t : candidates) {
      if (contains(store_.failed_workers(t.id, t.retry_base), worker) &&
          another_worker_could_take(t, worker, now)) {
        continue;
      }
      t.state = TaskState::kLeased;
      t.attempts += 1;
      t.lease_worker = worker;
      t.lease_expiry = now + options_.lease_seconds;
      t.updated = now;
      store_.update_task(t);
      AttemptRow attempt;
      attempt.task_id = t.id;
      attempt.attempt = t.attempts;
      attempt.worker = worker;
      attempt.started = now;
      store_.insert_attempt(attempt);

      const BatchRow batch = *store_.batch(t.batch_id);
      Assignment a;
      a.task_id = t.id;
      a.attempt = t.attempts;
      a.kind = t.kind;
      a.batch_id = batch.id;
      a.spec_path = batch.spec_path;
      a.overrides = batch.overrides;
      a.out_dir = batch.out_dir;
      a.frame = t.frame;
      a.rect = t.rect;
      a.shard = t.shard;
      a.shard_range = shard_ranges(batch.frame_start, batch.frame_end, batch.per_shard)[t.shard];
      if (t.kind == TaskKind::kPackShard) a.inputs = inputs_of(t);
      a.lease_expiry = t.lease_expiry;
      tx.commit();
      return a;
    }
    if (static_cast<int>(candidates.size()) < limit) break;
  }
  tx.commit();  // the worker's last_seen
  return std::nullopt;
}

bool Scheduler::another_worker_could_take(const TaskRow& task, const std::string& worker,
                                          double now) {
  const std::vector<std::string> failed = store_.failed_workers(task.id, task.retry_base);
  for (const WorkerRow& w : store_.workers()) {
    if (w.id == worker || w.left || now - w.last_seen > 2 * options_.lease_seconds) continue;
    if (contains(failed, w.id) || store_.blocked(task.batch_id, w.id)) continue;
    return true;
  }
  return false;
}

std::optional<TaskRow> Scheduler::held_task(const std::string& worker, int64_t task, int attempt) {
  std::optional<TaskRow> t = store_.task(task);
  if (!t || t->state != TaskState::kLeased || t->lease_worker != worker || t->attempts != attempt) {
    return std::nullopt;
  }
  return t;
}

bool Scheduler::heartbeat(const std::string& worker, int64_t task, int attempt) {
  const double now = clock_.now();
  Transaction tx(store_);
  touch_worker(worker);
  std::optional<TaskRow> t = held_task(worker, task, attempt);
  if (t) {
    t->lease_expiry = now + options_.lease_seconds;
    store_.update_task(*t);
  }
  tx.commit();
  return t.has_value();
}

CompleteStatus Scheduler::complete(const std::string& worker, int64_t task, int attempt,
                                   const std::string& staged_path, const std::string& checksum) {
  const double now = clock_.now();
  Transaction tx(store_);
  touch_worker(worker);
  std::optional<TaskRow> t = held_task(worker, task, attempt);
  if (!t) {
    CompleteStatus status = CompleteStatus::kUnknownTask;
    if (store_.task(task)) {
      status = CompleteStatus::kStale;
      for (const AttemptRow& a : store_.attempts(task)) {
        if (a.attempt == attempt && a.worker == worker && a.outcome == AttemptOutcome::kDone) {
          status = CompleteStatus::kDuplicate;
        }
      }
    }
    if (status == CompleteStatus::kStale) {
      store_.add_event(now, store_.task(task)->batch_id, "info",
                       "ignored a late result of task " + std::to_string(task) + " attempt " +
                           std::to_string(attempt) + " from " + worker);
    }
    tx.commit();
    return status;
  }
  t->state = TaskState::kDone;
  clear_lease(*t);
  t->staged_path = staged_path;
  t->checksum = checksum;
  t->updated = now;
  store_.update_task(*t);
  store_.finish_attempt(task, attempt, now, AttemptOutcome::kDone, "");
  finish_batch_if_complete(t->batch_id, now);
  tx.commit();
  return CompleteStatus::kAccepted;
}

FailResult Scheduler::fail(const std::string& worker, int64_t task, int attempt,
                           const std::string& error) {
  const double now = clock_.now();
  Transaction tx(store_);
  touch_worker(worker);
  FailResult result;
  std::optional<TaskRow> t = held_task(worker, task, attempt);
  if (!t) {
    result.status = store_.task(task) ? FailStatus::kStale : FailStatus::kUnknownTask;
    tx.commit();
    return result;
  }
  store_.finish_attempt(task, attempt, now, AttemptOutcome::kFailed, error);
  const int failures = store_.failure_count(task, t->retry_base);
  clear_lease(*t);
  t->last_error = error;
  t->updated = now;
  if (failures >= options_.max_task_failures) {
    t->state = TaskState::kFailed;
    store_.update_task(*t);
    std::string by;
    for (const std::string& w : store_.failed_workers(task, t->retry_base)) {
      by += (by.empty() ? "" : ", ") + w;
    }
    store_.add_event(now, t->batch_id, "error",
                     describe(*t) + " failed for good after " + std::to_string(failures) +
                         " failures (" + by + "): " + error);
    fail_dependents(*t, now);
    result.status = FailStatus::kFailedForGood;
  } else {
    t->state = TaskState::kPending;
    const double wait =
        std::min(options_.backoff_max, options_.backoff_base * std::ldexp(1.0, failures - 1));
    t->not_before = now + wait;
    store_.update_task(*t);
    store_.add_event(now, t->batch_id, "warn",
                     describe(*t) + " failed on " + worker + " (failure " +
                         std::to_string(failures) + "), retry in " + std::to_string(wait) +
                         " s: " + error);
    result.status = FailStatus::kRetry;
    result.retry_at = t->not_before;
  }
  if (!store_.blocked(t->batch_id, worker) &&
      store_.tasks_failed_by(t->batch_id, worker) >= options_.blocklist_after) {
    store_.block(t->batch_id, worker, now);
    store_.add_event(now, t->batch_id, "warn",
                     worker + " blocklisted for the batch after failing " +
                         std::to_string(options_.blocklist_after) + " of its tasks");
    result.worker_blocklisted = true;
  }
  finish_batch_if_complete(t->batch_id, now);
  tx.commit();
  return result;
}

void Scheduler::fail_dependents(const TaskRow& failed, double now) {
  for (int64_t id : store_.dependents(failed.id)) {
    TaskRow d = *store_.task(id);
    // A done dependent (a shard packed before the tile was invalidated)
    // keeps its output; only tasks still waiting can no longer run.
    if (d.state != TaskState::kPending) continue;
    d.state = TaskState::kFailed;
    d.last_error = "needs " + describe(failed) + ", which failed: " + failed.last_error;
    d.updated = now;
    store_.update_task(d);
    fail_dependents(d, now);
  }
}

bool Scheduler::release(const std::string& worker, int64_t task, int attempt) {
  const double now = clock_.now();
  Transaction tx(store_);
  touch_worker(worker);
  std::optional<TaskRow> t = held_task(worker, task, attempt);
  if (t) {
    store_.finish_attempt(task, attempt, now, AttemptOutcome::kReleased, "");
    t->state = TaskState::kPending;
    clear_lease(*t);
    t->not_before = now;
    t->updated = now;
    store_.update_task(*t);
  }
  tx.commit();
  return t.has_value();
}

std::vector<int64_t> Scheduler::expire_leases() {
  const double now = clock_.now();
  // Called on every request and poll: look before taking the write lock.
  if (store_.leases_expired_by(now).empty()) return {};
  Transaction tx(store_);
  std::vector<int64_t> ids;
  for (TaskRow t : store_.leases_expired_by(now)) {
    store_.finish_attempt(t.id, t.attempts, now, AttemptOutcome::kExpired, "lease expired");
    store_.add_event(now, t.batch_id, "warn",
                     "lease of " + t.lease_worker + " on " + describe(t) + " expired; requeued");
    t.state = TaskState::kPending;
    clear_lease(t);
    t.not_before = now;  // a dead worker says nothing about the task: no back-off
    t.updated = now;
    store_.update_task(t);
    ids.push_back(t.id);
  }
  tx.commit();
  return ids;
}

void Scheduler::finish_batch_if_complete(const std::string& batch_id, double now) {
  const BatchRow batch = *store_.batch(batch_id);
  if (batch.state != BatchState::kRunning) return;
  // An index seek answers the common case (work left) without counting the
  // whole batch on every completion.
  if (store_.has_unfinished_tasks(batch_id)) return;
  const auto counts = store_.task_counts(batch_id);
  if (counts[static_cast<int>(TaskState::kPending)] > 0 ||
      counts[static_cast<int>(TaskState::kLeased)] > 0) {
    return;
  }
  const int failed = counts[static_cast<int>(TaskState::kFailed)];
  store_.set_batch_state(batch_id, failed > 0 ? BatchState::kFailed : BatchState::kDone, now);
  store_.add_event(
      now, batch_id, failed > 0 ? "error" : "info",
      failed > 0 ? "finished with " + std::to_string(failed) + " failed tasks" : "finished");
}

OpResult Scheduler::cancel(const std::string& batch_id) {
  const double now = clock_.now();
  Transaction tx(store_);
  const std::optional<BatchRow> batch = store_.batch(batch_id);
  if (!batch) return {false, "no batch " + batch_id};
  if (batch->state != BatchState::kRunning) {
    return {false, "batch " + batch_id + " is " + to_string(batch->state) + ", not running"};
  }
  int revoked = 0;
  for (TaskRow t : store_.leased_tasks(batch_id)) {
    store_.finish_attempt(t.id, t.attempts, now, AttemptOutcome::kRevoked, "batch cancelled");
    t.state = TaskState::kPending;
    clear_lease(t);
    t.updated = now;
    store_.update_task(t);
    ++revoked;
  }
  store_.set_batch_state(batch_id, BatchState::kCancelled, now);
  store_.add_event(now, batch_id, "info", "cancelled");
  tx.commit();
  return {true, "cancelled " + batch_id + "; " + std::to_string(revoked) + " leases revoked"};
}

OpResult Scheduler::resume(const std::string& batch_id) {
  const double now = clock_.now();
  Transaction tx(store_);
  const std::optional<BatchRow> batch = store_.batch(batch_id);
  if (!batch) return {false, "no batch " + batch_id};
  if (batch->state == BatchState::kDone) return {false, "batch " + batch_id + " is done"};
  int requeued = 0;
  for (TaskRow t : store_.tasks(batch_id)) {
    if (t.state != TaskState::kFailed) continue;
    t.state = TaskState::kPending;
    t.retry_base = t.attempts;  // a fresh failure count; the history stays
    t.not_before = now;
    t.updated = now;
    store_.update_task(t);
    ++requeued;
  }
  store_.clear_blocklist(batch_id);
  store_.set_batch_state(batch_id, BatchState::kRunning, std::nullopt);
  store_.add_event(now, batch_id, "info",
                   "resumed; " + std::to_string(requeued) + " failed tasks requeued");
  finish_batch_if_complete(batch_id, now);  // nothing left to do: done at once
  tx.commit();
  return {true, "resumed " + batch_id + "; " + std::to_string(requeued) + " failed tasks requeued"};
}

StatusReport Scheduler::status(const std::string& batch_id) {
  const double now = clock_.now();
  StatusReport report;
  report.now = now;
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
    report.batches.push_back(std::move(st));
  }
  std::map<std::string, std::vector<int64_t>> leases;
  for (const TaskRow& t : store_.leased_tasks("")) leases[t.lease_worker].push_back(t.id);
  for (const WorkerRow& w : store_.workers()) {
    WorkerStatus ws;
    ws.worker = w;
    ws.live = !w.left && now - w.last_seen <= 2 * options_.lease_seconds;
    ws.leased_tasks = leases[w.id];
    report.workers.push_back(std::move(ws));
  }
  return report;
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

OpResult Scheduler::invalidate(int64_t task) {
  const double now = clock_.now();
  Transaction tx(store_);
  std::optional<TaskRow> t = store_.task(task);
  if (!t) return {false, "no task " + std::to_string(task)};
  if (t->state != TaskState::kDone) {
    return {false, describe(*t) + " is " + to_string(t->state) + ", not done"};
  }
  t->state = TaskState::kPending;
  t->staged_path.clear();
  t->checksum.clear();
  t->not_before = now;
  t->updated = now;
  store_.update_task(*t);
  // A pack already running with the lost tile as input would fail or, worse,
  // read a half-written replacement: take it back. It is runnable again only
  // when the tile is done again.
  for (int64_t id : store_.dependents(task)) {
    TaskRow d = *store_.task(id);
    if (d.state != TaskState::kLeased) continue;
    store_.finish_attempt(d.id, d.attempts, now, AttemptOutcome::kRevoked,
                          "input task " + std::to_string(task) + " invalidated");
    d.state = TaskState::kPending;
    clear_lease(d);
    d.updated = now;
    store_.update_task(d);
  }
  const BatchRow batch = *store_.batch(t->batch_id);
  if (batch.state == BatchState::kDone || batch.state == BatchState::kFailed) {
    store_.set_batch_state(batch.id, BatchState::kRunning, std::nullopt);
  }
  store_.add_event(now, t->batch_id, "warn", describe(*t) + " invalidated; requeued");
  tx.commit();
  return {true, describe(*t) + " requeued"};
}

std::vector<StagedTile> Scheduler::inputs_of(const TaskRow& pack) {
  std::vector<StagedTile> inputs;
  for (int64_t id : store_.dependencies(pack.id)) {
    const TaskRow t = *store_.task(id);
    inputs.push_back({t.id, t.frame, t.rect, t.shard, t.staged_path, t.checksum});
  }
  std::sort(inputs.begin(), inputs.end(), [](const StagedTile& a, const StagedTile& b) {
    return std::tie(a.frame, a.rect.y, a.rect.x) < std::tie(b.frame, b.rect.y, b.rect.x);
  });
  return inputs;
}

std::string Scheduler::new_batch_id() {
  // Random rather than sequential so ids from different state folders (a
  // farm restarted from scratch) do not collide in logs and manifests.
  static thread_local std::mt19937 rng{std::random_device{}()};
  for (;;) {
    char id[16];
    std::snprintf(id, sizeof id, "b-%08x", static_cast<unsigned>(rng()));
    if (!store_.batch(id)) return id;
  }
}

std::string reproduce_command(const BatchRow& batch, const TaskRow& task) {
  const Rect& r = task.rect;
  std::string cmd = "dofarm render " + shell_quote(batch.spec_path) + " --frame " +
                    std::to_string(task.frame) + " --tile " + std::to_string(r.x) + "," +
                    std::to_string(r.y) + "," + std::to_string(r.w) + "," + std::to_string(r.h) +
                    " --out repro.exr";
  for (const std::string& o : batch.overrides) cmd += " --set " + shell_quote(o);
  return cmd;
}

}  // namespace dofarm::coordinator
