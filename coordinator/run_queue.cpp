#include "coordinator/run_queue.h"

#include <limits>

#include "common/error.h"

namespace dofarm::coordinator {

namespace {
bool unfinished(TaskState s) { return s == TaskState::kPending || s == TaskState::kLeased; }
}  // namespace

void RunQueue::clear() {
  batches_.clear();
  tasks_.clear();
  runnable_.clear();
  delayed_.clear();
  expiries_.clear();
  ++generation_;
}

void RunQueue::load_batch(const BatchRow& row, const std::vector<TaskRow>& tasks,
                          const std::vector<std::pair<int64_t, int64_t>>& dependencies,
                          const std::vector<std::pair<int64_t, std::string>>& failures,
                          const std::vector<std::string>& blocked, double now) {
  drop_batch(row.id);
  Batch& b = batches_[row.id];
  b.row = row;
  b.shards = shard_ranges(row.frame_start, row.frame_end, row.per_shard);
  b.blocked.insert(blocked.begin(), blocked.end());
  for (const TaskRow& r : tasks) {
    Task& t = tasks_[r.id];
    t.id = r.id;
    t.batch = &b;
    t.kind = r.kind;
    t.frame = r.frame;
    t.rect = r.rect;
    t.shard = r.shard;
    t.state = r.state;
    t.attempts = r.attempts;
    t.not_before = r.not_before;
    if (r.state == TaskState::kLeased) {
      t.lease_worker = r.lease_worker;
      t.lease_expiry = r.lease_expiry;
      expiries_.emplace(t.lease_expiry, t.id);
    }
    if (unfinished(r.state)) ++b.unfinished;
  }
  for (const auto& [task, dep] : dependencies) {
    Task& d = tasks_.at(dep);
    d.dependents.push_back(task);
    if (d.state != TaskState::kDone) ++tasks_.at(task).pending_deps;
  }
  for (const auto& [task, worker] : failures) tasks_.at(task).failed_by.push_back(worker);
  for (const TaskRow& r : tasks) place(tasks_.at(r.id), now);
}

void RunQueue::drop_batch(const std::string& id) {
  auto it = batches_.find(id);
  if (it == batches_.end()) return;
  for (auto t = tasks_.begin(); t != tasks_.end();) {
    if (t->second.batch == &it->second) {
      unplace(t->second);
      expiries_.erase({t->second.lease_expiry, t->first});
      t = tasks_.erase(t);
    } else {
      ++t;
    }
  }
  batches_.erase(it);
  ++generation_;  // a parked worker may have been waiting on nothing but this batch
}

RunQueue::Batch* RunQueue::batch(const std::string& id) {
  auto it = batches_.find(id);
  return it == batches_.end() ? nullptr : &it->second;
}

void RunQueue::set_priority(const std::string& id, int priority, double now) {
  Batch* b = batch(id);
  if (!b || b->row.priority == priority) return;
  // The keys hold the priority: out of the queue under the old one, back
  // in under the new.
  std::vector<Task*> mine;
  for (auto& [task_id, t] : tasks_)
    if (t.batch == b) {
      unplace(t);
      mine.push_back(&t);
    }
  b->row.priority = priority;
  for (Task* t : mine) place(*t, now);
}

RunQueue::Task* RunQueue::task(int64_t id) {
  auto it = tasks_.find(id);
  return it == tasks_.end() ? nullptr : &it->second;
}

void RunQueue::set_state(Task& t, TaskState state, double not_before, double now) {
  const TaskState old = t.state;
  unplace(t);
  if (old == TaskState::kLeased) {
    expiries_.erase({t.lease_expiry, t.id});
    t.lease_worker.clear();
    t.lease_expiry = 0;
  }
  if (unfinished(old) != unfinished(state)) t.batch->unfinished += unfinished(state) ? 1 : -1;
  t.state = state;
  if (state == TaskState::kPending) t.not_before = not_before;
  // Dependents count the dependencies that are not done.
  if ((old == TaskState::kDone) != (state == TaskState::kDone)) {
    for (int64_t id : t.dependents) {
      Task* d = task(id);
      if (!d) continue;
      if (state == TaskState::kDone) {
        DOFARM_CHECK_LT(0, d->pending_deps);
        if (--d->pending_deps == 0) place(*d, now);
      } else {
        if (d->pending_deps++ == 0) unplace(*d);
      }
    }
  }
  place(t, now);
}

void RunQueue::lease(Task& t, const std::string& worker, int attempt, double expiry) {
  DOFARM_CHECK_EQ(static_cast<int>(t.state), static_cast<int>(TaskState::kPending));
  set_state(t, TaskState::kLeased, t.not_before, 0);
  t.attempts = attempt;
  t.lease_worker = worker;
  t.lease_expiry = expiry;
  expiries_.emplace(expiry, t.id);
}

void RunQueue::extend(Task& t, double expiry) {
  expiries_.erase({t.lease_expiry, t.id});
  t.lease_expiry = expiry;
  expiries_.emplace(expiry, t.id);
}

std::vector<int64_t> RunQueue::runnable(const std::string& worker, double now) {
  std::vector<int64_t> out;
  find(worker, now, [&](const Task& t) {
    out.push_back(t.id);
    return false;
  });
  return out;
}

std::vector<int64_t> RunQueue::expired(double now) const {
  std::vector<int64_t> out;
  for (auto it = expiries_.begin(); it != expiries_.end() && it->first < now; ++it) {
    out.push_back(it->second);
  }
  return out;
}

double RunQueue::next_due() const {
  return delayed_.empty() ? std::numeric_limits<double>::infinity() : delayed_.begin()->first;
}

RunQueue::Key RunQueue::key(const Task& t) {
  return {-t.batch->row.priority,
          t.batch->row.created,
          t.batch->row.seq,
          t.kind == TaskKind::kPackShard ? 0 : 1,
          t.frame,
          t.id};
}

void RunQueue::place(Task& t, double now) {
  if (t.state != TaskState::kPending || t.pending_deps > 0) return;
  if (t.not_before <= now) {
    runnable_.insert(key(t));
  } else {
    delayed_.emplace(t.not_before, t.id);
  }
  ++generation_;
}

void RunQueue::unplace(Task& t) {
  runnable_.erase(key(t));
  delayed_.erase({t.not_before, t.id});
}

void RunQueue::promote(double now) {
  while (!delayed_.empty() && delayed_.begin()->first <= now) {
    runnable_.insert(key(tasks_.at(delayed_.begin()->second)));
    delayed_.erase(delayed_.begin());
  }
}

}  // namespace dofarm::coordinator
