// The scheduler (coordinator/scheduler.h): its memory rebuilt from the store,
// submission, workers, leases, heartbeats, completions, releases, lease expiry
// and the group commit. The failure policy is scheduler_failures.cpp, the
// operator's commands scheduler_operations.cpp, the reports scheduler_report.cpp.
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
#include "coordinator/scheduler_internal.h"

namespace dofarm::coordinator {

using scheduler_internal::contains;
using scheduler_internal::describe;
using scheduler_internal::Transaction;

namespace {

void clear_lease(TaskRow& t) {
  t.lease_worker.clear();
  t.lease_expiry = 0;
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
                              std::optional<double> seconds_per_pixel, int priority) {
  DOFARM_CHECK(priority >= kMinPriority && priority <= kMaxPriority);
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
    batch.priority = priority;
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
                          std::to_string(plan.tile_side) + ", priority " + std::to_string(priority),
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
