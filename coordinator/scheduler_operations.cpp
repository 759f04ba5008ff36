// The operator's commands on a batch or task (coordinator/scheduler.h):
// cancel, resume and invalidate, each one store transaction.
#include <string>

#include "coordinator/scheduler_internal.h"

namespace dofarm::coordinator {

using scheduler_internal::describe;
using scheduler_internal::Transaction;

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

OpResult Scheduler::set_priority(const std::string& batch_id, int priority) {
  const double now = clock_.now();
  return guarded([&]() -> OpResult {
    if (priority < kMinPriority || priority > kMaxPriority)
      return {false, "priority " + std::to_string(priority) + " is outside " +
                         std::to_string(kMinPriority) + ".." + std::to_string(kMaxPriority)};
    Transaction tx(store_);
    const std::optional<BatchRow> batch = store_.batch(batch_id);
    if (!batch) return {false, "no batch " + batch_id};
    const std::string change =
        "priority " + std::to_string(batch->priority) + " -> " + std::to_string(priority);
    if (batch->priority == priority) return {true, batch_id + ": " + change + " (unchanged)"};
    store_.set_batch_priority(batch_id, priority);
    store_.add_event({0, now, batch_id, "info", change, "priority", 0, ""});
    queue_.set_priority(batch_id, priority, now);
    tx.commit();
    return {true, batch_id + ": " + change};
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

}  // namespace dofarm::coordinator
