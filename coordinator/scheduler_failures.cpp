// The scheduler's failure policy (coordinator/scheduler.h): a failed
// attempt's retry, back-off and blocklist, failing for good (with the tasks
// that depend on it), the liveness of workers, the end of a batch, and the
// stall timeout of a batch no worker can serve.
#include <algorithm>
#include <cmath>
#include <set>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "coordinator/scheduler_internal.h"

namespace dofarm::coordinator {

using scheduler_internal::contains;
using scheduler_internal::describe;
using scheduler_internal::Transaction;

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

}  // namespace dofarm::coordinator
