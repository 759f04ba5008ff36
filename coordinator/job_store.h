// The coordinator's journal: batches, tasks, attempts, workers, blocklist and
// events in one SQLite database (sqlite3 C API). It holds the whole state, so
// a coordinator killed at any point restarts where it was: it opens the store
// and goes on. The scheduler decides; the store only records.
//
// Durability. WAL journal with synchronous=NORMAL: a commit is in the WAL
// file before the call returns, so it survives a kill -9 of the coordinator
// (the failure the farm is built and tested for); only an OS crash or power
// loss can lose the last commits before a checkpoint. FULL (an fsync per
// commit) measured 2.4x fewer messages per second in bench/farm_throughput,
// and heartbeats alone make many commits per second on a large farm.
//
// Transactions. Every state change is one transaction: the scheduler opens a
// Transaction, makes its reads and writes through this class and commits;
// destroying an uncommitted Transaction rolls back. Transactions start with
// BEGIN IMMEDIATE so that a second connection (an operator's sqlite3 shell)
// makes us wait busy_timeout instead of failing half-way through. A
// Transaction opened inside another is a savepoint of it: it commits or rolls
// back its own changes only, and they reach the disk with the outer one.
//
// Group commit. Between begin_group() and commit_group() every Transaction is
// such a savepoint of one transaction, begun by the first of them: the
// coordinator's loop handles all the messages it received at once, commits
// them with one write to the WAL, and only then sends the replies. A message
// whose handling fails rolls back its savepoint alone.
//
// Versioning. PRAGMA user_version holds kSchemaVersion; a store of another
// version is refused rather than guessed at.
//
// Errors. Every SQLite failure becomes a RuntimeError carrying sqlite3_errmsg,
// the statement and the database path.
//
// Not thread-safe: one JobStore per thread (the coordinator's loop owns one).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "common/image.h"
#include "common/messages.h"
#include "coordinator/planner.h"

struct sqlite3;
struct sqlite3_stmt;

namespace dofarm::coordinator {

inline constexpr int kStoreSchemaVersion = 1;

// A batch's priority, as the protocol defines it (common/messages.h).
using protocol::kDefaultPriority;
using protocol::kMaxPriority;
using protocol::kMinPriority;

enum class BatchState { kRunning, kDone, kFailed, kCancelled };
// kFailed: every task is finished and at least one failed for good (the
// batch went on without it, "done with failures").
enum class TaskState { kPending, kLeased, kDone, kFailed };
enum class AttemptOutcome { kDone, kFailed, kExpired, kReleased, kRevoked };
// kRevoked: the coordinator took the lease back (cancel, invalidate).

const char* to_string(BatchState s);
const char* to_string(TaskState s);
const char* to_string(AttemptOutcome s);

struct BatchRow {
  std::string id;  // "b-" + 8 hex digits
  std::string spec_path;
  std::vector<std::string> overrides;  // --set KEY=VALUE, in order (stored as JSON)
  std::string out_dir;
  // The job as a value (common/job_snapshot.h): its hash and the text of its
  // job.json. Empty only in stores written before snapshots existed.
  std::string job_hash;
  std::string snapshot;
  BatchState state = BatchState::kRunning;
  double created = 0;
  std::optional<double> finished;
  int frame_start = 0;
  int frame_end = 0;  // inclusive
  int per_shard = 1;  // shard k holds frames frame_start + k*per_shard ...
  // Submission order (the row id): ties of `created` are broken by it. Read
  // only; insert_batch ignores it.
  int64_t seq = 0;
  int priority = kDefaultPriority;  // kMinPriority..kMaxPriority, higher first
};

struct TaskRow {
  int64_t id = 0;  // assigned by insert_task()
  std::string batch_id;
  TaskKind kind = TaskKind::kRenderTile;
  int frame = -1;
  Rect rect;
  int shard = 0;
  TaskState state = TaskState::kPending;
  // Leases handed out so far; the current lease is attempt number `attempts`.
  // Only ever grows, so a result of an earlier attempt can never pass for the
  // current one.
  int attempts = 0;
  // Failures counted by the policy are those of attempts > retry_base; resume
  // raises it to give failed tasks a fresh count without rewriting history.
  int retry_base = 0;
  std::string lease_worker;  // empty unless leased
  double lease_expiry = 0;
  double not_before = 0;    // back-off: not assigned before this time
  std::string staged_path;  // done: the staged tile file, or the shard
  std::string checksum;     // done: checksum_to_string() of that file
  std::string last_error;
  double updated = 0;  // time of the last state change
};

struct AttemptRow {
  int64_t task_id = 0;
  int attempt = 0;
  std::string worker;
  double started = 0;
  std::optional<double> finished;
  std::optional<AttemptOutcome> outcome;  // empty while running
  std::string error;
};

struct WorkerRow {
  std::string id;
  std::string host;
  int threads = 0;
  double first_seen = 0;
  double last_seen = 0;
  bool left = false;  // said goodbye; stored as state 'live' / 'left'
};

struct EventRow {
  int64_t id = 0;
  double time = 0;
  std::string batch_id;  // empty: farm-wide
  std::string level;     // "info", "warn", "error"
  std::string text;
  // What happened, one word (`dofarm events`, docs/farm.md): submitted,
  // retry, failed, blocklisted, expired, finished, cancelled, resumed,
  // invalidated, late_result. Empty in stores written before it existed.
  std::string kind;
  int64_t task = 0;    // the task it is about; 0: none
  std::string worker;  // the worker it is about; empty: none
};

// One lease (an attempt) with the place of its task: the lease events of
// `dofarm events` come from the attempts table, the record of every lease,
// rather than from one more row per assignment.
struct LeaseRow {
  int64_t task = 0;
  int attempt = 0;
  std::string worker;
  double started = 0;
  TaskKind kind = TaskKind::kRenderTile;
  int frame = -1;
  Rect rect;
  int shard = 0;
};

// Attempts a worker finished, by outcome.
struct WorkerCounts {
  int64_t done = 0, failed = 0;
};

class JobStore {
 public:
  // Opens `path`, creating it (and the schema) when absent. Throws
  // RuntimeError when it is not a SQLite database or of another schema version.
  explicit JobStore(const std::filesystem::path& path);
  ~JobStore();
  JobStore(const JobStore&) = delete;
  JobStore& operator=(const JobStore&) = delete;

  const std::filesystem::path& path() const { return path_; }

  class Transaction {
   public:
    explicit Transaction(JobStore& store);
    ~Transaction();  // rolls back unless committed
    void commit();
    Transaction(const Transaction&) = delete;
    Transaction& operator=(const Transaction&) = delete;

   private:
    JobStore& store_;
    bool savepoint_ = false;  // nested, or within a group
    bool done_ = false;
  };

  // See "Group commit" above. commit_group() throws when the commit fails;
  // then nothing of the group is in the store. rollback_group() never throws.
  void begin_group();
  void commit_group();
  void rollback_group();

  // Batches
  void insert_batch(const BatchRow& batch);
  std::optional<BatchRow> batch(const std::string& id);
  std::vector<BatchRow> batches();  // oldest first
  void set_batch_state(const std::string& id, BatchState state, std::optional<double> finished);
  void set_batch_priority(const std::string& id, int priority);

  // Tasks
  int64_t insert_task(const TaskRow& task);  // ignores task.id, returns the new one
  void insert_dependency(int64_t task, int64_t depends_on);
  std::optional<TaskRow> task(int64_t id);
  std::vector<TaskRow> tasks(const std::string& batch_id);  // by id
  void update_task(const TaskRow& task);  // every column but id, batch, kind, place
  std::vector<int64_t> dependencies(int64_t task);
  std::vector<int64_t> dependents(int64_t task);
  // Every (task, depends_on) pair of the batch's tasks, for loading the
  // scheduler's in-memory queue in one query.
  std::vector<std::pair<int64_t, int64_t>> dependency_pairs(const std::string& batch_id);
  // The input of `pack` whose staged file is `staged_path` (a pack that found
  // a bad staged tile names it by path).
  std::optional<int64_t> input_with_staged_path(int64_t pack, const std::string& staged_path);
  // Extends the lease of `task` to `expiry` if `worker` still holds attempt
  // `attempt` and the stored expiry is earlier; false when nothing changed.
  // (Heartbeats are written in groups: this never revives a lost lease.)
  bool extend_lease(int64_t task, int attempt, const std::string& worker, double expiry);
  // Pending tasks whose back-off has passed, whose dependencies are all done,
  // of running batches that have not blocklisted `worker`; in assignment order:
  // highest batch priority first, then oldest batch, then pack tasks (they unblock the trainer),
  // then render tiles by frame (so shards complete early), then by id. The scheduler answers this
  // from memory (RunQueue); this query is the reference its tests hold the memory to.
  std::vector<TaskRow> runnable_tasks(const std::string& worker, double now, int limit);
  std::vector<TaskRow> leases_expired_by(double now);
  std::vector<TaskRow> leased_tasks(const std::string& batch_id);  // empty: every batch
  // Tasks of the batch per TaskState, indexed by the enum's value.
  std::array<int, 4> task_counts(const std::string& batch_id);
  // Whether any task of the batch is pending or leased.
  bool has_unfinished_tasks(const std::string& batch_id);

  // Attempts
  void insert_attempt(const AttemptRow& attempt);
  void finish_attempt(int64_t task, int attempt, double finished, AttemptOutcome outcome,
                      const std::string& error);
  std::vector<AttemptRow> attempts(int64_t task);  // by attempt number
  // Workers whose attempts > since_attempt of `task` failed (each once).
  std::vector<std::string> failed_workers(int64_t task, int since_attempt);
  int failure_count(int64_t task, int since_attempt);
  // (task, worker) of every failed attempt counted by the policy (attempt >
  // the task's retry_base) of the batch's tasks.
  std::vector<std::pair<int64_t, std::string>> counted_failures(const std::string& batch_id);
  // Tasks of `batch` that `worker` failed, counting only each task's attempts
  // after its retry_base.
  int tasks_failed_by(const std::string& batch_id, const std::string& worker);

  // Workers
  void upsert_worker(const WorkerRow& worker);
  // Forgets a worker (bounded memory); its attempts and blocklist rows stay.
  void delete_worker(const std::string& id);
  std::optional<WorkerRow> worker(const std::string& id);
  std::vector<WorkerRow> workers();

  // Blocklist
  void block(const std::string& batch_id, const std::string& worker, double since);
  bool blocked(const std::string& batch_id, const std::string& worker);
  std::vector<std::string> blocked_workers(const std::string& batch_id);
  void clear_blocklist(const std::string& batch_id);

  // Events
  void add_event(const EventRow& event);  // ignores event.id
  void add_event(double time, const std::string& batch_id, const std::string& level,
                 const std::string& text) {
    add_event(EventRow{0, time, batch_id, level, text, "", 0, ""});
  }
  std::vector<EventRow> events(const std::string& batch_id, int limit);  // newest first
  // The batch's newest `limit` leases, newest first.
  std::vector<LeaseRow> leases(const std::string& batch_id, int limit);
  // Done and failed attempts per worker (every batch).
  std::map<std::string, WorkerCounts> worker_counts();

 private:
  friend class Transaction;
  class Statement;
  void exec(const char* sql);
  void create_schema();
  void add_missing_batch_columns();
  void add_missing_event_columns();
  bool has_column(const std::string& table, const std::string& column);  // literals only

  std::filesystem::path path_;
  sqlite3* db_ = nullptr;
  int depth_ = 0;            // open Transactions
  bool group_ = false;       // between begin_group() and commit_group()
  bool group_open_ = false;  // the group's transaction has begun
  // Prepared statements kept for reuse, by SQL text; one that is in use is
  // out of the map, so a nested use of the same SQL prepares its own.
  std::unordered_map<std::string, sqlite3_stmt*> statements_;
};

}  // namespace dofarm::coordinator
