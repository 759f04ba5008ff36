// The scheduler: the farm's failure policy (DESIGN.md "The farm", after
// Flamenco and Deadline) on top of the job store and an injected clock.
// Transport-free: the ZeroMQ server turns messages into these calls and the
// results into replies. Every call that changes state is one store
// transaction, so the coordinator may be killed between any two calls.
//
// The policy:
//  - A task is leased to one worker at a time, for lease_seconds; heartbeats
//    extend the lease. Each lease is a new attempt number; only the current
//    holder with the current attempt may heartbeat, complete, fail or release.
//  - A lease that expires (a dead worker) is requeued at once and does not
//    count as a failure. A result that arrives after its lease was taken away
//    is ignored; a second completion of a done task is harmless.
//  - A worker fails a task at most once before another worker gets it: after
//    a failure the task is not leased to that worker again while any other
//    live worker could take it (not blocklisted for the batch, not itself a
//    failer of the task). When no such worker exists (a one-worker farm) the
//    same worker retries it after the back-off, so a small farm still ends.
//  - A task fails for good at its max_task_failures-th counted failure; with
//    enough live workers those are as many distinct workers. It also fails
//    for good, with fewer failures, once it failed on every worker that
//    could take it: no live worker outside its failers and the batch's
//    blocklist is left, and either two distinct workers failed it or none of
//    its failers may retry it (all blocklisted). A one-worker farm still
//    retries. Its error is kept, the tasks that depend on it (its shard's
//    pack) fail with it, and the batch goes on; a batch with failed tasks
//    ends as kFailed.
//  - A running batch that has had no eligible worker (live and not
//    blocklisted for it) and no lease for stall_timeout seconds fails: its
//    unfinished tasks fail for good with that reason (fail_stalled_batches).
//    The time is measured in memory, so a restarted coordinator gives the
//    batch a fresh stall_timeout.
//  - Otherwise a failed task waits backoff_base * 2^(failures-1) seconds,
//    at most backoff_max, before it is leased again.
//  - A worker that failed blocklist_after distinct tasks of a batch gets no
//    more tasks of that batch.
//  - Release (SIGTERM, preemption) hands a task back: pending at once, no
//    failure counted.
//
// Speed without giving up the journal. The store is the record; a RunQueue
// in memory (rebuilt from the store on start, and after any failed
// transaction) answers "what runs next" without a query and turns a
// completion into a runnable pack in O(1). Every state change is still
// committed to the store before the call returns, with two exceptions that
// are safe to lose in a crash, so they are group-committed (flush(), at most
// every heartbeat_flush_seconds, and on destruction):
//  - heartbeat lease renewals: a lost renewal leaves the stored expiry at
//    the previous, earlier value, so a restarted coordinator can only end a
//    lease early (the task is rendered again), never keep a dead worker's
//    lease; and a renewal is written only while the same worker still holds
//    the same attempt, and only forward (JobStore::extend_lease);
//  - a known worker's last_seen, which only decides who counts as live.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "common/image.h"
#include "common/jobspec.h"
#include "coordinator/clock.h"
#include "coordinator/job_store.h"
#include "coordinator/planner.h"
#include "coordinator/run_queue.h"

namespace dofarm::coordinator {

struct SchedulerOptions {
  double lease_seconds = 30;
  double backoff_base = 2;    // seconds before the first retry
  double backoff_max = 300;   // cap of the exponential back-off
  int max_task_failures = 3;  // distinct workers, when the farm has them
  int blocklist_after = 3;    // failed tasks of one batch
  double rate_window = 600;   // seconds of history behind frames/hour
  // Heartbeat renewals and last_seen times are written at most this long
  // after they happen (group commit; see the header comment).
  double heartbeat_flush_seconds = 1;
  // A running batch with no eligible worker for this long fails; 0 = never.
  double stall_timeout = 600;
  // Workers remembered (memory and store); past it the longest unseen ones
  // that hold no lease are forgotten, so made-up worker ids cannot grow the
  // coordinator without bound.
  size_t max_workers = 4096;
};

// Where a leased task's output must be, for checking a `done` claim: a render
// tile's staged EXR (staged_tile_path) or a pack's shard (OUT/shard file).
struct ExpectedOutput {
  TaskKind kind = TaskKind::kRenderTile;
  std::string path;
  uint64_t max_bytes = 0;  // no honest output is larger
};

// What a pack task merges: one done render tile.
struct StagedTile {
  int64_t task_id = 0;
  int frame = 0;
  Rect rect;
  int shard = 0;
  std::string staged_path;
  std::string checksum;  // checksum_to_string() form
};

struct JobRef {
  std::string hash;      // the job hash
  std::string snapshot;  // the text of its job.json
};

// A done pack task: its shard as recorded when it was packed.
struct PackedShard {
  int64_t task_id = 0;
  std::string out_dir;             // the batch's output folder
  ShardRange range;                // frames and file name (in out_dir)
  std::string checksum;            // checksum_to_string() of the shard file, reported at pack time
  std::vector<StagedTile> inputs;  // its tiles; their staged files are gone once packed
};

struct Assignment {
  int64_t task_id = 0;
  int attempt = 0;
  TaskKind kind = TaskKind::kRenderTile;
  std::string batch_id;
  std::string job_hash;  // the worker loads OUT/.dofarm-jobs/job_hash
  std::string spec_path;  // where the job came from, for messages only
  std::string out_dir;
  int frame = -1;  // render_tile
  Rect rect;       // render_tile
  int shard = 0;
  ShardRange shard_range;          // frames and file name of `shard`
  std::vector<StagedTile> inputs;  // pack_shard: its tiles, frame-major
  double lease_expiry = 0;
};

enum class CompleteStatus {
  kAccepted,   // recorded; the task is done
  kDuplicate,  // this attempt was already recorded as done: nothing changed
  kStale,      // the worker does not hold this attempt's lease: ignored
  kUnknownTask,
};
const char* to_string(CompleteStatus s);

enum class FailStatus {
  kRetry,          // pending again after the back-off
  kFailedForGood,  // the task failed for good
  kStale,          // the worker does not hold this attempt's lease: ignored
  kUnknownTask,
};
const char* to_string(FailStatus s);

struct FailResult {
  FailStatus status = FailStatus::kStale;
  bool worker_blocklisted = false;  // this failure blocklisted the worker
  double retry_at = 0;              // kRetry: not_before of the task
};

// Answer of submit-less user commands (cancel, resume, invalidate).
struct OpResult {
  bool ok = false;
  std::string message;  // why not, or what was done
};

struct FailedTask {
  int64_t task_id = 0;
  TaskKind kind = TaskKind::kRenderTile;
  int frame = -1;
  Rect rect;
  int shard = 0;
  std::string error;
  std::string reproduce;  // render_tile: a `dofarm render` command line; pack: empty
};

// One task of a batch, for `dofarm status BATCH --tasks`.
struct TaskStatus {
  int64_t task_id = 0;
  TaskKind kind = TaskKind::kRenderTile;
  int frame = -1;
  Rect rect;
  int shard = 0;
  TaskState state = TaskState::kPending;
  std::string worker;     // the lease holder, else the worker of its last attempt
  int attempts = 0;       // leases handed out so far
  std::string error;      // its last error, if any
  std::string reproduce;  // render_tile: a `dofarm render` command line; pack: empty
};

struct BatchStatus {
  BatchRow batch;
  int tasks_total = 0, tasks_done = 0, tasks_failed = 0, tasks_leased = 0, tasks_pending = 0;
  int frames_total = 0;
  // A frame is rendered when all its tiles are done (it could be packed), and
  // packed when its shard's pack task is done (the trainer can read it).
  int frames_rendered = 0;
  int frames_packed = 0;
  // Frames rendered per hour over the last rate_window seconds (or since the
  // batch was created, if later); 0 when none were.
  double frames_per_hour = 0;
  // Seconds until every frame is rendered at that rate; empty at rate 0 or
  // when the batch is not running.
  std::optional<double> eta_seconds;
  std::vector<FailedTask> failed;
  std::vector<std::string> blocklisted;
  // Why a failed batch failed (its last error event), empty otherwise.
  std::string reason;
  // Seconds the running batch has had no eligible worker; empty when it has one.
  std::optional<double> stalled_seconds;
  // StatusQuery::tasks: the tasks asked for (by id) and how many more matched.
  std::vector<TaskStatus> tasks;
  int64_t tasks_omitted = 0;
};

// A worker as the operator sees it (docs/farm.md "Worker liveness"): live
// while it said no goodbye and was heard from (any message: a request, a
// heartbeat, a result) within one lease length; lost after that silence
// (killed, hung, cut off); left after it said goodbye. Only live workers count
// as eligible for the failure policy and the stall timeout.
enum class Liveness { kLive, kLost, kLeft };
const char* to_string(Liveness l);  // "live", "lost", "left"
Liveness worker_liveness(const WorkerRow& w, double now, double lease_seconds);

// A task a worker holds now, where in the batch.
struct HeldTask {
  int64_t task_id = 0;
  std::string batch_id;
  TaskKind kind = TaskKind::kRenderTile;
  int frame = -1;
  Rect rect;
  int shard = 0;
};

struct WorkerStatus {
  WorkerRow worker;
  bool live = false;  // state == kLive
  Liveness state = Liveness::kLost;
  std::vector<int64_t> leased_tasks;
  std::vector<HeldTask> current;  // the same tasks, with their frame and tile
  WorkerCounts counts;            // attempts it finished done / failed (job store)
};

// What a status report holds besides the counts.
struct StatusQuery {
  std::string batch;               // empty: every batch
  bool tasks = false;              // list the batch's tasks (BatchStatus::tasks)
  std::optional<TaskState> state;  // only the tasks in this state
  size_t task_limit = 1000;        // at most this many in all, by task id; the rest counted
};

struct StatusReport {
  double now = 0;
  std::vector<BatchStatus> batches;  // oldest first
  std::vector<WorkerStatus> workers;
  bool tasks_listed = false;  // the query asked for tasks
};

class Scheduler {
 public:
  // Loads the running batches from the store (a restart goes on from there).
  Scheduler(JobStore& store, const Clock& clock, SchedulerOptions options = {});
  ~Scheduler();  // flushes
  Scheduler(const Scheduler&) = delete;
  Scheduler& operator=(const Scheduler&) = delete;

  // Plans and records a batch; returns its id ("b-" + 8 hex digits). The
  // spec must already be loaded and checked (load_job_spec with `overrides`).
  // `job` is the job's hash and snapshot (common/job_snapshot.h): workers
  // render the batch from OUT/.dofarm-jobs/HASH. Empty only in tests that
  // never hand tasks to a real worker.
  std::string submit(const std::string& spec_path, const std::vector<std::string>& overrides,
                     const std::string& out_dir, const JobSpec& spec, const JobRef& job = {},
                     std::optional<double> seconds_per_pixel = std::nullopt,
                     int priority = kDefaultPriority);

  // A worker said hello (or is still there); any call from a worker counts too.
  void worker_seen(const std::string& worker, const std::string& host, int threads);
  // A worker said goodbye. Its leases stay until released or expired.
  void worker_left(const std::string& worker);

  // The next task for `worker`, leased to it, or nothing to do now. Expires
  // overdue leases first.
  std::optional<Assignment> assign(const std::string& worker);
  // Extends the lease; false when the worker no longer holds it (it should
  // stop working on the task).
  bool heartbeat(const std::string& worker, int64_t task, int attempt);
  // Where the output of a task `worker` holds at `attempt` belongs; nothing
  // when it does not hold that lease (complete() then says why).
  std::optional<ExpectedOutput> expected_output(const std::string& worker, int64_t task,
                                                int attempt);
  CompleteStatus complete(const std::string& worker, int64_t task, int attempt,
                          const std::string& staged_path, const std::string& checksum);
  FailResult fail(const std::string& worker, int64_t task, int attempt, const std::string& error);
  bool release(const std::string& worker, int64_t task, int attempt);
  // Requeues every lease past its expiry; returns the task ids.
  std::vector<int64_t> expire_leases();
  // Fails the running batches that have had no eligible worker for
  // stall_timeout (see the policy above); returns their ids. Looks at most
  // once a second; the coordinator's loop calls it on every round.
  std::vector<std::string> fail_stalled_batches();
  // Writes the group-committed heartbeats and last_seen times (one
  // transaction); flush_if_due() does so when heartbeat_flush_seconds passed
  // since the last flush.
  void flush();
  void flush_if_due();

  // Cancel: the batch gets no more tasks and its leases are revoked (their
  // heartbeats answer false). Resume: a cancelled or finished-with-failures
  // batch runs again; its failed tasks get a fresh failure count and its
  // blocklist is cleared.
  OpResult cancel(const std::string& batch_id);
  OpResult resume(const std::string& batch_id);
  // Gives a batch another priority (kMinPriority..kMaxPriority; higher is
  // served first). Leases already held are kept; what is handed out next
  // follows the new order. Any state: a resumed batch keeps it.
  OpResult set_priority(const std::string& batch_id, int priority);

  // Ids of the batches that are running, oldest first (a restarted
  // coordinator checks their staged files).
  std::vector<std::string> running_batch_ids();
  // The input of pack task `pack` whose staged file is `staged_path` (a pack
  // that found a bad staged tile names it by path).
  std::optional<int64_t> input_with_staged_path(int64_t pack, const std::string& staged_path);

  bool has_batch(const std::string& batch_id) { return store_.batch(batch_id).has_value(); }

  // Every batch ever written into `out_dir`, oldest first.
  std::vector<BatchRow> batches_in(const std::string& out_dir);

  // One batch, or every batch when empty; workers always.
  StatusReport status(const std::string& batch_id = "");
  StatusReport status(const StatusQuery& query);
  // `dofarm events`: the batch's newest `limit` events, oldest first: the
  // events table merged by time with its leases (the attempts table, kind
  // "lease"), so the journal gains no row per assignment.
  std::vector<EventRow> events(const std::string& batch_id, int limit);

  // Done render tiles of `batch` whose shard is not packed yet: the caller
  // checks each staged file against its checksum (on resume, after a
  // restart) and calls invalidate() for those missing or corrupt.
  std::vector<StagedTile> staged_tiles_to_verify(const std::string& batch_id);
  // Done pack tasks of `batch`, for the caller to check their shards (on
  // resume and after a restart; coordinator/verify.h) and invalidate() the
  // pack, and its tiles whose staged files are gone, for a damaged one.
  std::vector<PackedShard> packed_shards(const std::string& batch_id);
  // A done task becomes pending again (its output is gone); the pack task of
  // its shard, unless already done, waits for it again. A done or failed
  // batch runs again.
  OpResult invalidate(int64_t task);

  // Runnable task ids for `worker` now, in assignment order, from memory:
  // what JobStore::runnable_tasks answers from the store.
  std::vector<int64_t> runnable(const std::string& worker);
  // For callers waiting for work (the server's parked requests): the count
  // grows whenever a task may have become runnable; next_due() is when the
  // next back-off ends (infinity when none).
  uint64_t generation() const { return queue_.generation(); }
  double next_due() const { return queue_.next_due(); }
  // Batches still running (done, failed and cancelled ones are not).
  size_t running_batches() const { return queue_.batch_count(); }
  // Drops the memory and loads it again from the store.
  void rebuild();

  const SchedulerOptions& options() const { return options_; }

 private:
  // Runs `f`; when it throws (its transaction rolled back), rebuilds the
  // memory from the store before passing the exception on.
  template <typename F>
  auto guarded(F&& f) -> decltype(f());
  void load_batch(const BatchRow& batch, double now);
  // The one door of a task's state (STYLE.md 16, after LevelDB's
  // LogAndApply): every change of a task's row, whatever the cause (lease,
  // done, fail, release, expiry, cancel, resume, invalidate, stall), goes
  // through here, which writes the row to the store (in the caller's
  // transaction) and the in-memory queue together. `row` holds the new
  // state; a task that is not leased loses its lease and its pending
  // heartbeat renewal; `updated` becomes `now`.
  void apply(TaskRow& row, double now);
  RunQueue::Task* held(const std::string& worker, int64_t task, int attempt);
  // last_seen of a known, live worker, in memory only; false otherwise.
  bool touch_worker_in_memory(const std::string& worker, double now);
  // Forgets the longest unseen workers without a lease once more than
  // options_.max_workers are known (within a transaction).
  void prune_workers();
  // Within a transaction: a new or returning worker is written at once.
  void touch_worker(const std::string& worker, double now);
  // Outside one: opens a transaction only when touch_worker must write.
  void touch(const std::string& worker, double now);
  bool another_worker_could_take(const RunQueue::Task& task, const std::string& worker,
                                 double now) const;
  bool live(const WorkerRow& w, double now) const;
  // Live workers not blocklisted for `batch` and not in `except`.
  int eligible_workers(const RunQueue::Batch& batch, const std::vector<std::string>& except,
                       double now) const;
  // A pending task that failed on every worker that could take it (policy above).
  bool hopeless(const RunQueue::Task& task, double now) const;
  // Within a transaction: `t` (its row) fails for good; `why` is logged.
  void fail_for_good(TaskRow& t, RunQueue::Task& m, const std::string& why, double now);
  void fail_dependents(const TaskRow& failed, double now);
  // `reason`: why the batch failed, when it did not end by its tasks alone.
  void finish_batch_if_complete(const std::string& batch_id, double now,
                                const std::string& reason = "");
  std::vector<StagedTile> inputs_of(const TaskRow& pack);
  std::string new_batch_id();

  JobStore& store_;
  const Clock& clock_;
  SchedulerOptions options_;
  RunQueue queue_;
  std::map<std::string, WorkerRow> workers_;  // every worker the store knows
  // Done and failed attempts of the known workers: loaded from the store
  // (rebuild()), then counted as complete() and fail() record them.
  std::map<std::string, WorkerCounts> counts_;
  std::set<int64_t> dirty_leases_;            // renewed since the last flush
  std::set<std::string> dirty_workers_;       // seen since the last flush
  double last_flush_ = 0;
  std::map<std::string, double> stalled_since_;  // running batch -> first seen without worker
  double last_stall_check_ = 0;
};

// "task 12 (render_tile frame 3 tile 0,16,16,8)", "task 40 (pack_shard shard 1)".
std::string describe_task(const TaskRow& t);

// `dofarm render SPEC --frame N --tile X,Y,W,H --out repro.exr --set K=V ...`
// with shell quoting, for a failed render tile.
std::string reproduce_command(const BatchRow& batch, const TaskRow& task);

}  // namespace dofarm::coordinator
