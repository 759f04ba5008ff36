#include "coordinator/scheduler.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <random>
#include <set>
#include <string_view>
#include <tuple>

#include <spdlog/spdlog.h>

#include "common/job_snapshot.h"
#include "common/error.h"
#include "common/staging.h"

namespace dofarm::coordinator {

namespace {

using Transaction = JobStore::Transaction;

std::string describe(const TaskRow& t) { return describe_task(t); }

void clear_lease(TaskRow& t) {
  t.lease_worker.clear();
  t.lease_expiry = 0;
}

bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

}  // namespace

std::string describe_task(const TaskRow& t) {
  std::string s = "task " + std::to_string(t.id) + " (" + to_string(t.kind);
  if (t.kind == TaskKind::kRenderTile) {
    s += " frame " + std::to_string(t.frame) + " tile " + std::to_string(t.rect.x) + "," +
         std::to_string(t.rect.y) + "," + std::to_string(t.rect.w) + "," + std::to_string(t.rect.h);
  } else {
    s += " shard " + std::to_string(t.shard);
  }
  return s + ")";
}

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
    : store_(store), clock_(clock), options_(options) {
  rebuild();
}

Scheduler::~Scheduler() {
  // A clean shutdown keeps the last heartbeats; a crash loses at most
  // heartbeat_flush_seconds of them, which only shortens leases.
  try {
    flush();
  } catch (...) {
  }
}

template <typename F>
auto Scheduler::guarded(F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (...) {
    // The transaction rolled back, so the memory may be ahead of the store:
    // load it again from the store, which is the record.
    try {
      rebuild();
    } catch (...) {
    }
    throw;
  }
}

void Scheduler::rebuild() {
  const double now = clock_.now();
  queue_.clear();
  workers_.clear();
  dirty_leases_.clear();
  dirty_workers_.clear();
  last_flush_ = now;
  for (const BatchRow& b : store_.batches()) {
    if (b.state == BatchState::kRunning) load_batch(b, now);
  }
  for (const WorkerRow& w : store_.workers()) workers_[w.id] = w;
  counts_ = store_.worker_counts();
  std::erase_if(counts_, [&](const auto& c) { return !workers_.count(c.first); });
}

void Scheduler::load_batch(const BatchRow& batch, double now) {
  queue_.load_batch(batch, store_.tasks(batch.id), store_.dependency_pairs(batch.id),
                    store_.counted_failures(batch.id), store_.blocked_workers(batch.id), now);
}

std::vector<int64_t> Scheduler::runnable(const std::string& worker) {
  return queue_.runnable(worker, clock_.now());
}

std::string Scheduler::submit(const std::string& spec_path,
                              const std::vector<std::string>& overrides, const std::string& out_dir,
                              const JobSpec& spec, const JobRef& job,
                              std::optional<double> seconds_per_pixel) {
  const double now = clock_.now();
  const Plan plan = plan_batch(spec, seconds_per_pixel);
  return guarded([&] {
    Transaction tx(store_);
    BatchRow batch;
    batch.id = new_batch_id();
    batch.spec_path = spec_path;
    batch.overrides = overrides;
    batch.out_dir = out_dir;
    batch.job_hash = job.hash;
    batch.snapshot = job.snapshot;
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
    store_.add_event({0, now, batch.id, "info",
                      "submitted " + spec_path + ": " + std::to_string(spec.frame_count()) +
                          " frames, " + std::to_string(plan.shards.size()) + " shards, " +
                          std::to_string(plan.tasks.size()) + " tasks, tile side " +
                          std::to_string(plan.tile_side),
                      "submitted", 0, ""});
    load_batch(*store_.batch(batch.id), now);  // read back: the row id orders batches
    tx.commit();
    return batch.id;
  });
}

void Scheduler::worker_seen(const std::string& worker, const std::string& host, int threads) {
  const double now = clock_.now();
  auto it = workers_.find(worker);
  if (it != workers_.end() && !it->second.left && it->second.host == host &&
      it->second.threads == threads) {
    it->second.last_seen = now;  // nothing new but the time: group-committed
    dirty_workers_.insert(worker);
    return;
  }
  guarded([&] {
    Transaction tx(store_);
    WorkerRow row;
    row.id = worker;
    row.host = host;
    row.threads = threads;
    row.first_seen = it != workers_.end() ? it->second.first_seen : now;  // as the upsert keeps it
    row.last_seen = now;
    store_.upsert_worker(row);
    workers_[worker] = row;
    dirty_workers_.erase(worker);
    prune_workers();
    tx.commit();
  });
}

void Scheduler::worker_left(const std::string& worker) {
  guarded([&] {
    Transaction tx(store_);
    auto it = workers_.find(worker);
    if (it != workers_.end()) {
      it->second.left = true;
      it->second.last_seen = clock_.now();
      store_.upsert_worker(it->second);
      dirty_workers_.erase(worker);
    }
    tx.commit();
  });
}

bool Scheduler::touch_worker_in_memory(const std::string& worker, double now) {
  auto it = workers_.find(worker);
  if (it == workers_.end() || it->second.left) return false;
  it->second.last_seen = now;
  dirty_workers_.insert(worker);
  return true;
}

void Scheduler::touch_worker(const std::string& worker, double now) {
  if (touch_worker_in_memory(worker, now)) return;
  WorkerRow row;
  if (auto known = workers_.find(worker); known != workers_.end()) {
    row = known->second;  // it had said goodbye and is back
  } else {                // first heard of by a task message (e.g. across a coordinator restart)
    row.id = worker;
    row.first_seen = now;
  }
  row.last_seen = now;
  row.left = false;
  store_.upsert_worker(row);
  workers_[worker] = row;
  dirty_workers_.erase(worker);
  prune_workers();
}

void Scheduler::prune_workers() {
  if (workers_.size() <= options_.max_workers) return;
  std::set<std::string> holders;  // a lease holder stays: its reports must still count
  for (int64_t id : queue_.expired(std::numeric_limits<double>::infinity()))
    if (const RunQueue::Task* t = queue_.task(id)) holders.insert(t->lease_worker);
  std::vector<std::pair<double, std::string>> idle;
  for (const auto& [id, w] : workers_)
    if (!holders.count(id)) idle.emplace_back(w.last_seen, id);
  std::sort(idle.begin(), idle.end());
  // Down to 3/4 at once, so a flood of new ids prunes once per thousand, not per id.
  const size_t keep = options_.max_workers * 3 / 4;
  for (const auto& [seen, id] : idle) {
    if (workers_.size() <= keep) break;
    store_.delete_worker(id);
    workers_.erase(id);
    counts_.erase(id);
    dirty_workers_.erase(id);
  }
}

void Scheduler::touch(const std::string& worker, double now) {
  if (touch_worker_in_memory(worker, now)) return;
  guarded([&] {
    Transaction tx(store_);
    touch_worker(worker, now);
    tx.commit();
  });
}

void Scheduler::apply(TaskRow& row, double now) {
  row.updated = now;
  if (row.state != TaskState::kLeased) {
    clear_lease(row);
    dirty_leases_.erase(row.id);  // nothing left to renew
  }
  store_.update_task(row);
  RunQueue::Task* m = queue_.task(row.id);
  if (!m) return;  // its batch is not in memory (finished or cancelled)
  if (row.state == TaskState::kLeased)
    queue_.lease(*m, row.lease_worker, row.attempts, row.lease_expiry);
  else
    queue_.set_state(*m, row.state, row.state == TaskState::kPending ? row.not_before : 0, now);
}

std::optional<Assignment> Scheduler::assign(const std::string& worker) {
  expire_leases();
  const double now = clock_.now();
  // The queue is in assignment order; skipped are only the tasks this worker
  // already failed while another worker could take them.
  RunQueue::Task* t = queue_.find(worker, now, [&](const RunQueue::Task& c) {
    return !(contains(c.failed_by, worker) && another_worker_could_take(c, worker, now));
  });
  if (!t) {
    touch(worker, now);
    return std::nullopt;
  }
  return guarded([&] {
    Transaction tx(store_);
    touch_worker(worker, now);
    TaskRow row = *store_.task(t->id);
    DOFARM_CHECK_EQ(static_cast<int>(row.state), static_cast<int>(TaskState::kPending));
    DOFARM_CHECK_EQ(row.attempts, t->attempts);
    row.state = TaskState::kLeased;
    row.attempts += 1;
    row.lease_worker = worker;
    row.lease_expiry = now + options_.lease_seconds;
    apply(row, now);
    AttemptRow attempt;
    attempt.task_id = row.id;
    attempt.attempt = row.attempts;
    attempt.worker = worker;
    attempt.started = now;
    store_.insert_attempt(attempt);

    const RunQueue::Batch& batch = *t->batch;
    Assignment a;
    a.task_id = row.id;
    a.attempt = row.attempts;
    a.kind = row.kind;
    a.batch_id = batch.row.id;
    a.job_hash = batch.row.job_hash;
    a.spec_path = batch.row.spec_path;
    a.out_dir = batch.row.out_dir;
    a.frame = row.frame;
    a.rect = row.rect;
    a.shard = row.shard;
    a.shard_range = batch.shards.at(row.shard);
    if (row.kind == TaskKind::kPackShard) a.inputs = inputs_of(row);
    a.lease_expiry = row.lease_expiry;
    tx.commit();
    return std::optional<Assignment>(std::move(a));
  });
}

bool Scheduler::another_worker_could_take(const RunQueue::Task& task, const std::string& worker,
                                          double now) const {
  for (const auto& [id, w] : workers_) {
    if (id == worker || !live(w, now)) continue;
    if (contains(task.failed_by, id) || task.batch->blocked.count(id)) continue;
    return true;
  }
  return false;
}

RunQueue::Task* Scheduler::held(const std::string& worker, int64_t task, int attempt) {
  RunQueue::Task* t = queue_.task(task);
  if (!t || t->state != TaskState::kLeased || t->lease_worker != worker || t->attempts != attempt) {
    return nullptr;
  }
  return t;
}

bool Scheduler::heartbeat(const std::string& worker, int64_t task, int attempt) {
  const double now = clock_.now();
  touch(worker, now);
  RunQueue::Task* t = held(worker, task, attempt);
  if (!t) return false;
  // Group commit: the new expiry is written by the next flush. Losing it in
  // a crash only gives the lease its previous, earlier expiry.
  queue_.extend(*t, now + options_.lease_seconds);
  dirty_leases_.insert(task);
  return true;
}

std::optional<ExpectedOutput> Scheduler::expected_output(const std::string& worker, int64_t task,
                                                         int attempt) {
  RunQueue::Task* t = held(worker, task, attempt);
  if (!t) return std::nullopt;
  const BatchRow& batch = t->batch->row;
  ExpectedOutput e;
  e.kind = t->kind;
  if (t->kind == TaskKind::kRenderTile) {
    // From memory: this is on the path of every tile's `done`.
    e.path = staged_tile_path(batch.out_dir, batch.id, t->frame, t->rect).string();
    e.max_bytes = staged_tile_max_bytes(t->rect);
  } else {
    e.path = (std::filesystem::path(batch.out_dir) / t->batch->shards.at(t->shard).file).string();
    // A shard holds the pixels of its tiles (plus HDF5 metadata).
    uint64_t bytes = uint64_t(4) << 20;
    for (int64_t id : store_.dependencies(task))
      if (const std::optional<TaskRow> tile = store_.task(id)) bytes += staged_tile_max_bytes(tile->rect);
    e.max_bytes = bytes;
  }
  return e;
}

CompleteStatus Scheduler::complete(const std::string& worker, int64_t task, int attempt,
                                   const std::string& staged_path, const std::string& checksum) {
  const double now = clock_.now();
  return guarded([&] {
    Transaction tx(store_);
    touch_worker(worker, now);
    RunQueue::Task* t = held(worker, task, attempt);
    if (!t) {
      CompleteStatus status = CompleteStatus::kUnknownTask;
      const std::optional<TaskRow> row = store_.task(task);
      if (row) {
        status = CompleteStatus::kStale;
        for (const AttemptRow& a : store_.attempts(task)) {
          if (a.attempt == attempt && a.worker == worker && a.outcome == AttemptOutcome::kDone) {
            status = CompleteStatus::kDuplicate;
          }
        }
      }
      if (status == CompleteStatus::kStale) {
        store_.add_event({0, now, row->batch_id, "info",
                          "ignored a late result of task " + std::to_string(task) + " attempt " +
                              std::to_string(attempt) + " from " + worker,
                          "late_result", task, worker});
      }
      tx.commit();
      return status;
    }
    TaskRow row = *store_.task(task);
    row.state = TaskState::kDone;
    row.staged_path = staged_path;
    row.checksum = checksum;
    apply(row, now);  // its pack may become runnable
    store_.finish_attempt(task, attempt, now, AttemptOutcome::kDone, "");
    ++counts_[worker].done;  // rebuilt from the store should the transaction fail
    finish_batch_if_complete(row.batch_id, now);
    tx.commit();
    return CompleteStatus::kAccepted;
  });
}

FailResult Scheduler::fail(const std::string& worker, int64_t task, int attempt,
                           const std::string& error) {
  const double now = clock_.now();
  return guarded([&] {
    Transaction tx(store_);
    touch_worker(worker, now);
    FailResult result;
    RunQueue::Task* m = held(worker, task, attempt);
    if (!m) {
      result.status = store_.task(task) ? FailStatus::kStale : FailStatus::kUnknownTask;
      tx.commit();
      return result;
    }
    TaskRow t = *store_.task(task);
    store_.finish_attempt(task, attempt, now, AttemptOutcome::kFailed, error);
    ++counts_[worker].failed;
    m->failed_by.push_back(worker);
    const int failures = store_.failure_count(task, t.retry_base);
    t.last_error = error;
    // The blocklist first: it decides whether anybody is left to retry.
    RunQueue::Batch& batch = *m->batch;
    if (!batch.blocked.count(worker) &&
        store_.tasks_failed_by(t.batch_id, worker) >= options_.blocklist_after) {
      store_.block(t.batch_id, worker, now);
      batch.blocked.insert(worker);
      // The reason: how many of its tasks failed, and the last error (the
      // failures themselves are events of their own).
      const std::string text = worker + " blocklisted for the batch after failing " +
                               std::to_string(options_.blocklist_after) +
                               " of its tasks (last: " + describe(t) + ": " + error + ")";
      store_.add_event({0, now, t.batch_id, "warn", text, "blocklisted", task, worker});
      spdlog::warn("batch {}: {}", t.batch_id, text);
      result.worker_blocklisted = true;
    }
    if (failures >= options_.max_task_failures || hopeless(*m, now)) {
      t.state = TaskState::kPending;  // fail_for_good moves it on
      fail_for_good(t, *m,
                    failures >= options_.max_task_failures
                        ? "after " + std::to_string(failures) + " failures"
                        : "after " + std::to_string(failures) +
                              " failures: no other worker can take it",
                    now);
      result.status = FailStatus::kFailedForGood;
    } else {
      t.state = TaskState::kPending;
      const double wait =
          std::min(options_.backoff_max, options_.backoff_base * std::ldexp(1.0, failures - 1));
      t.not_before = now + wait;
      apply(t, now);
      store_.add_event({0, now, t.batch_id, "warn",
                        describe(t) + " failed on " + worker + " (failure " +
                            std::to_string(failures) + "), retry in " + fmt::format("{:g}", wait) +
                            " s: " + error,
                        "retry", task, worker});
      result.status = FailStatus::kRetry;
      result.retry_at = t.not_before;
    }
    if (result.worker_blocklisted) {
      // The other tasks this worker failed may now have nobody left.
      for (TaskRow other : store_.tasks(t.batch_id)) {
        RunQueue::Task* o = queue_.task(other.id);
        if (other.state != TaskState::kPending || !o || o->state != TaskState::kPending ||
            !hopeless(*o, now))
          continue;
        fail_for_good(other, *o, "no worker that could take it is left", now);
      }
    }
    finish_batch_if_complete(t.batch_id, now);
    tx.commit();
    return result;
  });
}

bool Scheduler::live(const WorkerRow& w, double now) const {
  return worker_liveness(w, now, options_.lease_seconds) == Liveness::kLive;
}

Liveness worker_liveness(const WorkerRow& w, double now, double lease_seconds) {
  if (w.left) return Liveness::kLeft;
  // A working worker heartbeats well within a lease and an idle one asks for
  // work every wait_seconds, so one lease of silence means it is gone.
  return now - w.last_seen <= lease_seconds ? Liveness::kLive : Liveness::kLost;
}

const char* to_string(Liveness l) {
  switch (l) {
    case Liveness::kLive:
      return "live";
    case Liveness::kLost:
      return "lost";
    case Liveness::kLeft:
      return "left";
  }
  return "?";
}

int Scheduler::eligible_workers(const RunQueue::Batch& batch,
                                const std::vector<std::string>& except, double now) const {
  int n = 0;
  for (const auto& [id, w] : workers_) {
    if (live(w, now) && !batch.blocked.count(id) && !contains(except, id)) ++n;
  }
  return n;
}

bool Scheduler::hopeless(const RunQueue::Task& task, double now) const {
  if (task.failed_by.empty()) return false;  // never tried: the stall timeout decides
  if (eligible_workers(*task.batch, task.failed_by, now) > 0) return false;
  std::set<std::string> distinct(task.failed_by.begin(), task.failed_by.end());
  // Two machines agree, or none of the failers may try again.
  return distinct.size() >= 2 || eligible_workers(*task.batch, {}, now) == 0;
}

void Scheduler::fail_for_good(TaskRow& t, RunQueue::Task& m, const std::string& why,
                              double now) {
  t.state = TaskState::kFailed;
  apply(t, now);
  std::string by;
  for (const std::string& w : store_.failed_workers(t.id, t.retry_base)) {
    by += (by.empty() ? "" : ", ") + w;
  }
  const std::string text = describe(t) + " failed for good " + why +
                           (by.empty() ? "" : " (" + by + ")") + ": " + t.last_error;
  store_.add_event({0, now, t.batch_id, "error", text, "failed", t.id, ""});
  spdlog::warn("batch {}: {}", t.batch_id, text);
  fail_dependents(t, now);
}

void Scheduler::fail_dependents(const TaskRow& failed, double now) {
  for (int64_t id : store_.dependents(failed.id)) {
    TaskRow d = *store_.task(id);
    // A done dependent (a shard packed before the tile was invalidated)
    // keeps its output; only tasks still waiting can no longer run.
    if (d.state != TaskState::kPending) continue;
    d.state = TaskState::kFailed;
    d.last_error = "needs " + describe(failed) + ", which failed: " + failed.last_error;
    apply(d, now);
    fail_dependents(d, now);
  }
}

bool Scheduler::release(const std::string& worker, int64_t task, int attempt) {
  const double now = clock_.now();
  return guarded([&] {
    Transaction tx(store_);
    touch_worker(worker, now);
    RunQueue::Task* m = held(worker, task, attempt);
    if (m) {
      TaskRow t = *store_.task(task);
      store_.finish_attempt(task, attempt, now, AttemptOutcome::kReleased, "");
      t.state = TaskState::kPending;
      t.not_before = now;
      apply(t, now);
    }
    tx.commit();
    return m != nullptr;
  });
}

std::vector<int64_t> Scheduler::expire_leases() {
  const double now = clock_.now();
  // Called on every request and poll: the memory answers the common case.
  const std::vector<int64_t> ids = queue_.expired(now);
  if (ids.empty()) return {};
  return guarded([&] {
    Transaction tx(store_);
    for (int64_t id : ids) {
      RunQueue::Task& m = *queue_.task(id);
      TaskRow t = *store_.task(id);
      DOFARM_CHECK_EQ(t.attempts, m.attempts);
      store_.finish_attempt(t.id, t.attempts, now, AttemptOutcome::kExpired, "lease expired");
      store_.add_event({0, now, t.batch_id, "warn",
                        "lease of " + m.lease_worker + " on " + describe(t) + " expired; requeued",
                        "expired", t.id, m.lease_worker});
      t.state = TaskState::kPending;
      t.not_before = now;  // a dead worker says nothing about the task: no back-off
      apply(t, now);
    }
    tx.commit();
    return ids;
  });
}

void Scheduler::flush() {
  const double now = clock_.now();
  last_flush_ = now;
  if (dirty_leases_.empty() && dirty_workers_.empty()) return;
  guarded([&] {
    Transaction tx(store_);
    for (int64_t id : dirty_leases_) {
      // Written only while the same worker holds the same attempt, and only
      // forward (JobStore::extend_lease).
      const RunQueue::Task* t = queue_.task(id);
      if (t && t->state == TaskState::kLeased) {
        store_.extend_lease(id, t->attempts, t->lease_worker, t->lease_expiry);
      }
    }
    for (const std::string& w : dirty_workers_) store_.upsert_worker(workers_.at(w));
    tx.commit();
    dirty_leases_.clear();
    dirty_workers_.clear();
  });
}

void Scheduler::flush_if_due() {
  if (clock_.now() - last_flush_ >= options_.heartbeat_flush_seconds) flush();
}

void Scheduler::finish_batch_if_complete(const std::string& batch_id, double now,
                                         const std::string& reason) {
  // The running batch's count in memory answers the common case (work left)
  // without a query on every completion.
  const RunQueue::Batch* b = queue_.batch(batch_id);
  if (!b || b->unfinished > 0) return;
  const auto counts = store_.task_counts(batch_id);
  DOFARM_CHECK_EQ(
      counts[static_cast<int>(TaskState::kPending)] + counts[static_cast<int>(TaskState::kLeased)],
      0);
  const int failed = counts[static_cast<int>(TaskState::kFailed)];
  store_.set_batch_state(batch_id, failed > 0 ? BatchState::kFailed : BatchState::kDone, now);
  std::string text = "finished";
  if (failed > 0) {
    // The event is the batch's failure reason in `status`: say why.
    std::string why = reason;
    if (why.empty()) {
      for (const TaskRow& t : store_.tasks(batch_id)) {
        if (t.state != TaskState::kFailed) continue;
        why = "first: " + describe(t) + ": " + t.last_error;
        break;
      }
    }
    text = "finished with " + std::to_string(failed) + " failed tasks; " + why;
    spdlog::warn("batch {}: {}", batch_id, text);
  }
  store_.add_event({0, now, batch_id, failed > 0 ? "error" : "info", text, "finished", 0, ""});
  stalled_since_.erase(batch_id);
  queue_.drop_batch(batch_id);
}

std::vector<std::string> Scheduler::fail_stalled_batches() {
  const double now = clock_.now();
  if (options_.stall_timeout <= 0 || now - last_stall_check_ < 1) return {};
  last_stall_check_ = now;
  std::vector<std::string> failed;
  for (const BatchRow& row : store_.batches()) {
    if (row.state != BatchState::kRunning) continue;
    RunQueue::Batch* b = queue_.batch(row.id);
    if (!b || b->unfinished == 0 || eligible_workers(*b, {}, now) > 0 ||
        !store_.leased_tasks(row.id).empty()) {
      stalled_since_.erase(row.id);
      continue;
    }
    const double since = stalled_since_.try_emplace(row.id, now).first->second;
    if (now - since < options_.stall_timeout) continue;
    std::string blocked;
    for (const std::string& w : b->blocked) blocked += (blocked.empty() ? "" : ", ") + w;
    const std::string reason =
        "no eligible worker for " + std::to_string(int(now - since)) + " s (stall timeout " +
        std::to_string(int(options_.stall_timeout)) + " s; " +
        (blocked.empty() ? std::string("no live worker") : "blocklisted: " + blocked) + ")";
    guarded([&] {
      Transaction tx(store_);
      for (TaskRow t : store_.tasks(row.id)) {
        RunQueue::Task* m = queue_.task(t.id);
        if (t.state != TaskState::kPending || !m) continue;
        t.state = TaskState::kFailed;
        if (t.last_error.empty()) t.last_error = reason;
        apply(t, now);
      }
      finish_batch_if_complete(row.id, now, reason);
      tx.commit();
    });
    failed.push_back(row.id);
  }
  return failed;
}

OpResult Scheduler::cancel(const std::string& batch_id) {
  const double now = clock_.now();
  return guarded([&]() -> OpResult {
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
      apply(t, now);
      ++revoked;
    }
    store_.set_batch_state(batch_id, BatchState::kCancelled, now);
    store_.add_event({0, now, batch_id, "info", "cancelled", "cancelled", 0, ""});
    queue_.drop_batch(batch_id);
    tx.commit();
    return {true, "cancelled " + batch_id + "; " + std::to_string(revoked) + " leases revoked"};
  });
}

OpResult Scheduler::resume(const std::string& batch_id) {
  const double now = clock_.now();
  return guarded([&]() -> OpResult {
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
      apply(t, now);
      ++requeued;
    }
    store_.clear_blocklist(batch_id);
    store_.set_batch_state(batch_id, BatchState::kRunning, std::nullopt);
    store_.add_event({0, now, batch_id, "info",
                      "resumed; " + std::to_string(requeued) + " failed tasks requeued", "resumed",
                      0, ""});
    load_batch(*store_.batch(batch_id), now);
    finish_batch_if_complete(batch_id, now);  // nothing left to do: done at once
    tx.commit();
    return {true,
            "resumed " + batch_id + "; " + std::to_string(requeued) + " failed tasks requeued"};
  });
}

OpResult Scheduler::invalidate(int64_t task) {
  const double now = clock_.now();
  return guarded([&]() -> OpResult {
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
    apply(*t, now);  // its dependents count it as not done again: its pack leaves the queue
    // A pack already running with the lost tile as input would fail or, worse,
    // read a half-written replacement: take it back. It is runnable again only
    // when the tile is done again.
    for (int64_t id : store_.dependents(task)) {
      TaskRow d = *store_.task(id);
      if (d.state != TaskState::kLeased) continue;
      store_.finish_attempt(d.id, d.attempts, now, AttemptOutcome::kRevoked,
                            "input task " + std::to_string(task) + " invalidated");
      d.state = TaskState::kPending;
      apply(d, now);
    }
    const BatchRow batch = *store_.batch(t->batch_id);
    if (batch.state == BatchState::kDone || batch.state == BatchState::kFailed) {
      store_.set_batch_state(batch.id, BatchState::kRunning, std::nullopt);
      load_batch(*store_.batch(batch.id), now);  // it runs again
    }
    store_.add_event({0, now, t->batch_id, "warn", describe(*t) + " invalidated; requeued",
                      "invalidated", t->id, ""});
    tx.commit();
    return {true, describe(*t) + " requeued"};
  });
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

}  // namespace dofarm::coordinator
