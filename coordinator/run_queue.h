// The scheduler's in-memory view of the running batches: every task's state,
// lease and pending-dependency count, the runnable queue in assignment order,
// the tasks waiting out a back-off, and the blocklists.
//
// It is a cache of the job store, never the record: the scheduler changes it
// in the same call as the store, and rebuilds it from the store on start and
// whenever a transaction fails (Scheduler::rebuild). It lets a request find its task
// without a query and a completion make its pack runnable in O(1):
//
//  - runnable: pending tasks whose dependencies are all done and whose
//    back-off has passed, ordered as JobStore::runnable_tasks orders them
//    (highest batch priority first, then oldest batch, packs before tiles,
//    then frame, then id);
//  - delayed: pending tasks with all dependencies done, still in back-off,
//    by the time they become runnable (promoted when a caller looks);
//  - per task, the number of its dependencies that are not done: a task
//    becomes runnable when it reaches 0 (its last tile is done) and leaves
//    the queue when a done dependency is reopened (invalidated);
//  - leases by expiry, so expiry is found without a scan.
//
// Only running batches are held; a batch that finishes or is cancelled is
// dropped, one that runs again is loaded again. No I/O, no clock: times are
// passed in. Not thread-safe (the coordinator's loop owns it).
#pragma once

#include <cstdint>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "coordinator/job_store.h"
#include "coordinator/planner.h"

namespace dofarm::coordinator {

class RunQueue {
 public:
  struct Batch {
    BatchRow row;
    std::vector<ShardRange> shards;  // shard_ranges() of the batch
    std::set<std::string> blocked;   // workers blocklisted for it
    int unfinished = 0;              // pending or leased tasks
  };

  struct Task {
    int64_t id = 0;
    Batch* batch = nullptr;
    TaskKind kind = TaskKind::kRenderTile;
    int frame = -1;
    Rect rect;      // render tiles: where the staged output is (claim checks)
    int shard = 0;
    TaskState state = TaskState::kPending;
    int attempts = 0;          // the current lease is attempt `attempts`
    double not_before = 0;     // back-off
    int pending_deps = 0;      // dependencies not done
    std::string lease_worker;  // leased only
    double lease_expiry = 0;   // leased only
    std::vector<int64_t> dependents;
    std::vector<std::string> failed_by;  // workers with a counted failure
  };

  // Drops everything.
  void clear();

  // Adds a running batch and its tasks (rows as stored), their dependencies
  // as (task, depends_on) pairs, and its blocklist. Replaces the batch if
  // held. `now` decides which pending tasks are in back-off.
  void load_batch(const BatchRow& batch, const std::vector<TaskRow>& tasks,
                  const std::vector<std::pair<int64_t, int64_t>>& dependencies,
                  const std::vector<std::pair<int64_t, std::string>>& failures,
                  const std::vector<std::string>& blocked, double now);
  // Forgets a batch that no longer runs, with its tasks.
  void drop_batch(const std::string& id);

  Batch* batch(const std::string& id);
  // Gives a held batch another priority: its runnable tasks move to their
  // new place in the queue (`now` as in load_batch).
  void set_priority(const std::string& id, int priority, double now);
  size_t batch_count() const { return batches_.size(); }
  // A task of a held batch, or null.
  Task* task(int64_t id);

  // Moves a task to `state`, keeping the queue, the dependency counts of its
  // dependents and its batch's unfinished count right. Leaving kLeased ends
  // the lease. A task that is (or stays) pending gets `not_before`.
  void set_state(Task& t, TaskState state, double not_before, double now);
  // Leases a pending task: it leaves the queue.
  void lease(Task& t, const std::string& worker, int attempt, double expiry);
  // Moves the expiry of a leased task.
  void extend(Task& t, double expiry);

  // The first runnable task, in assignment order, of a batch that has not
  // blocklisted `worker` and that `accept` takes; promotes tasks whose
  // back-off ended by `now` first.
  template <typename Accept>
  Task* find(const std::string& worker, double now, Accept&& accept);
  // Every runnable task id for `worker`, in assignment order (tests, status).
  std::vector<int64_t> runnable(const std::string& worker, double now);

  // Leased tasks whose lease ended before `now`.
  std::vector<int64_t> expired(double now) const;
  // When the next back-off ends (infinity when none waits).
  double next_due() const;
  // Grows whenever a task joins the queue or the delayed set: a caller that
  // saw nothing to run may try again when it changed.
  uint64_t generation() const { return generation_; }

 private:
  // (-batch priority, batch created, batch seq, kind, frame, id):
  // JobStore::runnable_tasks' order; 'pack_shard' sorts before 'render_tile'
  // there too.
  using Key = std::tuple<int, double, int64_t, int, int, int64_t>;
  static Key key(const Task& t);
  void place(Task& t, double now);  // into the queue or the delayed set, if it may run
  void unplace(Task& t);
  void promote(double now);

  std::map<std::string, Batch> batches_;
  std::unordered_map<int64_t, Task> tasks_;
  std::set<Key> runnable_;
  std::set<std::pair<double, int64_t>> delayed_;   // (not_before, id)
  std::set<std::pair<double, int64_t>> expiries_;  // (lease_expiry, id)
  uint64_t generation_ = 0;
};

template <typename Accept>
RunQueue::Task* RunQueue::find(const std::string& worker, double now, Accept&& accept) {
  promote(now);
  for (auto it = runnable_.begin(); it != runnable_.end();) {
    Task& t = tasks_.at(std::get<5>(*it));
    if (t.batch->blocked.count(worker)) {
      // Skip the rest of this batch in one step: to the first key of the
      // next (the smallest possible rest of a key: packs have frame -1, so a
      // rest of zeros skipped the next batch's packs).
      it = runnable_.lower_bound(Key{
          std::get<0>(*it), std::get<1>(*it), std::get<2>(*it) + 1, std::numeric_limits<int>::min(),
          std::numeric_limits<int>::min(), std::numeric_limits<int64_t>::min()});
      continue;
    }
    if (accept(t)) return &t;
    ++it;
  }
  return nullptr;
}

}  // namespace dofarm::coordinator
