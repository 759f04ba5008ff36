// The job store's rows: batches, tasks, attempts, workers, the blocklist
// and events (the store itself: job_store.cpp).
#include <sqlite3.h>

#include <nlohmann/json.hpp>
#include <utility>

#include "common/error.h"
#include "coordinator/job_store.h"
#include "coordinator/job_store_statement.h"

namespace dofarm::coordinator {

using namespace store_detail;

// --- Batches

namespace {
constexpr const char* kBatchColumns =
    "id, spec_path, overrides, out_dir, state, created, finished, frame_start, frame_end, "
    "per_shard, rowid, job, snapshot, priority";
}

template <typename S>
static BatchRow read_batch(const S& s) {
  BatchRow b;
  b.id = s.text(0);
  b.spec_path = s.text(1);
  for (const auto& o : nlohmann::json::parse(s.text(2))) b.overrides.push_back(o);
  b.out_dir = s.text(3);
  b.state = parse_enum<BatchState>(kBatchStates, s.text(4), "batch state");
  b.created = s.real(5);
  if (!s.null(6)) b.finished = s.real(6);
  b.frame_start = s.integer(7);
  b.frame_end = s.integer(8);
  b.per_shard = s.integer(9);
  b.seq = s.int64(10);
  b.job_hash = s.text(11);
  b.snapshot = s.text(12);
  b.priority = s.integer(13);
  return b;
}

void JobStore::insert_batch(const BatchRow& b) {
  Statement s(*this,
              "INSERT INTO batches(id, spec_path, overrides, out_dir, state, created, finished, "
              "frame_start, frame_end, per_shard, job, snapshot, priority) "
              "VALUES(?,?,?,?,?,?,?,?,?,?,?,?,?)");
  s.bind(1, b.id).bind(2, b.spec_path).bind(3, nlohmann::json(b.overrides).dump());
  s.bind(4, b.out_dir).bind(5, to_string(b.state)).bind(6, b.created).bind(7, b.finished);
  s.bind(8, b.frame_start).bind(9, b.frame_end).bind(10, b.per_shard);
  s.bind(11, b.job_hash).bind(12, b.snapshot).bind(13, b.priority).run();
}

std::optional<BatchRow> JobStore::batch(const std::string& id) {
  Statement s(*this, std::string("SELECT ") + kBatchColumns + " FROM batches WHERE id=?");
  s.bind(1, id);
  if (!s.step()) return std::nullopt;
  return read_batch(s);
}

std::vector<BatchRow> JobStore::batches() {
  Statement s(*this,
              std::string("SELECT ") + kBatchColumns + " FROM batches ORDER BY created, rowid");
  std::vector<BatchRow> out;
  while (s.step()) out.push_back(read_batch(s));
  return out;
}

void JobStore::set_batch_state(const std::string& id, BatchState state,
                               std::optional<double> finished) {
  Statement s(*this, "UPDATE batches SET state=?, finished=? WHERE id=?");
  s.bind(1, to_string(state)).bind(2, finished).bind(3, id).run();
}

void JobStore::set_batch_priority(const std::string& id, int priority) {
  Statement s(*this, "UPDATE batches SET priority=? WHERE id=?");
  s.bind(1, priority).bind(2, id).run();
}

// --- Tasks

namespace {
constexpr const char* kTaskColumns =
    "t.id, t.batch_id, t.kind, t.frame, t.x, t.y, t.w, t.h, t.shard, t.state, t.attempts, "
    "t.retry_base, t.lease_worker, t.lease_expiry, t.not_before, t.staged_path, t.checksum, "
    "t.last_error, t.updated";
}

template <typename S>
static TaskRow read_task(const S& s) {
  TaskRow t;
  t.id = s.int64(0);
  t.batch_id = s.text(1);
  t.kind = parse_enum<TaskKind>(kKinds, s.text(2), "task kind");
  t.frame = s.integer(3);
  t.rect = {s.integer(4), s.integer(5), s.integer(6), s.integer(7)};
  t.shard = s.integer(8);
  t.state = parse_enum<TaskState>(kTaskStates, s.text(9), "task state");
  t.attempts = s.integer(10);
  t.retry_base = s.integer(11);
  t.lease_worker = s.text(12);
  t.lease_expiry = s.real(13);
  t.not_before = s.real(14);
  t.staged_path = s.text(15);
  t.checksum = s.text(16);
  t.last_error = s.text(17);
  t.updated = s.real(18);
  return t;
}

int64_t JobStore::insert_task(const TaskRow& t) {
  Statement s(*this,
              "INSERT INTO tasks(batch_id, kind, frame, x, y, w, h, shard, state, attempts, "
              "retry_base, lease_worker, lease_expiry, not_before, staged_path, checksum, "
              "last_error, updated) VALUES(?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)");
  s.bind(1, t.batch_id).bind(2, to_string(t.kind)).bind(3, t.frame);
  s.bind(4, t.rect.x).bind(5, t.rect.y).bind(6, t.rect.w).bind(7, t.rect.h).bind(8, t.shard);
  s.bind(9, to_string(t.state)).bind(10, t.attempts).bind(11, t.retry_base);
  s.bind(12, t.lease_worker).bind(13, t.lease_expiry).bind(14, t.not_before);
  s.bind(15, t.staged_path).bind(16, t.checksum).bind(17, t.last_error).bind(18, t.updated);
  s.run();
  return sqlite3_last_insert_rowid(db_);
}

void JobStore::insert_dependency(int64_t task, int64_t depends_on) {
  Statement s(*this, "INSERT INTO task_deps(task, depends_on) VALUES(?,?)");
  s.bind(1, task).bind(2, depends_on).run();
}

std::optional<TaskRow> JobStore::task(int64_t id) {
  Statement s(*this, std::string("SELECT ") + kTaskColumns + " FROM tasks t WHERE t.id=?");
  s.bind(1, id);
  if (!s.step()) return std::nullopt;
  return read_task(s);
}

std::vector<TaskRow> JobStore::tasks(const std::string& batch_id) {
  Statement s(*this, std::string("SELECT ") + kTaskColumns +
                         " FROM tasks t WHERE t.batch_id=? ORDER BY t.id");
  s.bind(1, batch_id);
  std::vector<TaskRow> out;
  while (s.step()) out.push_back(read_task(s));
  return out;
}

void JobStore::update_task(const TaskRow& t) {
  Statement s(*this,
              "UPDATE tasks SET state=?, attempts=?, retry_base=?, lease_worker=?, "
              "lease_expiry=?, not_before=?, staged_path=?, checksum=?, last_error=?, updated=? "
              "WHERE id=?");
  s.bind(1, to_string(t.state)).bind(2, t.attempts).bind(3, t.retry_base);
  s.bind(4, t.lease_worker).bind(5, t.lease_expiry).bind(6, t.not_before);
  s.bind(7, t.staged_path).bind(8, t.checksum).bind(9, t.last_error).bind(10, t.updated);
  s.bind(11, t.id).run();
  DOFARM_CHECK_EQ(sqlite3_changes(db_), 1);
}

std::vector<int64_t> JobStore::dependencies(int64_t task) {
  Statement s(*this, "SELECT depends_on FROM task_deps WHERE task=? ORDER BY depends_on");
  s.bind(1, task);
  std::vector<int64_t> out;
  while (s.step()) out.push_back(s.int64(0));
  return out;
}

std::vector<int64_t> JobStore::dependents(int64_t task) {
  Statement s(*this, "SELECT task FROM task_deps WHERE depends_on=? ORDER BY task");
  s.bind(1, task);
  std::vector<int64_t> out;
  while (s.step()) out.push_back(s.int64(0));
  return out;
}

std::vector<std::pair<int64_t, int64_t>> JobStore::dependency_pairs(const std::string& batch_id) {
  Statement s(*this,
              "SELECT d.task, d.depends_on FROM tasks t JOIN task_deps d ON d.task = t.id "
              "WHERE t.batch_id=? ORDER BY d.task, d.depends_on");
  s.bind(1, batch_id);
  std::vector<std::pair<int64_t, int64_t>> out;
  while (s.step()) out.emplace_back(s.int64(0), s.int64(1));
  return out;
}

std::optional<int64_t> JobStore::input_with_staged_path(int64_t pack,
                                                        const std::string& staged_path) {
  // The primary key of task_deps (task, depends_on) finds the pack's inputs;
  // each is one row lookup.
  Statement s(*this,
              "SELECT t.id FROM task_deps d JOIN tasks t ON t.id = d.depends_on "
              "WHERE d.task=? AND t.staged_path=? ORDER BY t.id LIMIT 1");
  s.bind(1, pack).bind(2, staged_path);
  if (!s.step()) return std::nullopt;
  return s.int64(0);
}

bool JobStore::extend_lease(int64_t task, int attempt, const std::string& worker, double expiry) {
  Statement s(*this,
              "UPDATE tasks SET lease_expiry=?1 WHERE id=?2 AND state='leased' AND attempts=?3 "
              "AND lease_worker=?4 AND lease_expiry < ?1");
  s.bind(1, expiry).bind(2, task).bind(3, attempt).bind(4, worker).run();
  return sqlite3_changes(db_) == 1;
}

std::vector<TaskRow> JobStore::runnable_tasks(const std::string& worker, double now, int limit) {
  // Batch by batch in submission order, each walked along tasks_queue in
  // assignment order (packs before tiles, 'pack_shard' < 'render_tile', then
  // frame and id), so the query stops after `limit` rows instead of sorting
  // every pending task of the farm on every request. INDEXED BY: left alone,
  // the planner prefers tasks_by_state (state, not_before) and then sorts
  // every pending task. (The walk checks the dependencies of every waiting
  // pack on the way, which is why the scheduler keeps this answer in memory.)
  std::vector<std::string> running;
  {
    Statement b(
        *this,
        "SELECT id FROM batches WHERE state='running' ORDER BY priority DESC, created, rowid");
    while (b.step()) running.push_back(b.text(0));
  }
  std::vector<TaskRow> out;
  for (const std::string& batch : running) {
    if (static_cast<int>(out.size()) >= limit) break;
    if (blocked(batch, worker)) continue;
    Statement s(*this, std::string("SELECT ") + kTaskColumns + R"sql(
      FROM tasks t INDEXED BY tasks_queue
      WHERE t.batch_id = ?1 AND t.state = 'pending' AND t.not_before <= ?2
        AND NOT EXISTS (SELECT 1 FROM task_deps d JOIN tasks p ON p.id = d.depends_on
                        WHERE d.task = t.id AND p.state != 'done')
      ORDER BY t.kind, t.frame, t.id
      LIMIT ?3)sql");
    s.bind(1, batch).bind(2, now).bind(3, limit - static_cast<int>(out.size()));
    while (s.step()) out.push_back(read_task(s));
  }
  return out;
}

std::vector<TaskRow> JobStore::leases_expired_by(double now) {
  Statement s(*this, std::string("SELECT ") + kTaskColumns +
                         " FROM tasks t WHERE t.state='leased' AND t.lease_expiry < ? "
                         "ORDER BY t.id");
  s.bind(1, now);
  std::vector<TaskRow> out;
  while (s.step()) out.push_back(read_task(s));
  return out;
}

std::vector<TaskRow> JobStore::leased_tasks(const std::string& batch_id) {
  Statement s(*this, std::string("SELECT ") + kTaskColumns +
                         " FROM tasks t WHERE t.state='leased' AND (?1='' OR t.batch_id=?1) "
                         "ORDER BY t.id");
  s.bind(1, batch_id);
  std::vector<TaskRow> out;
  while (s.step()) out.push_back(read_task(s));
  return out;
}

bool JobStore::has_unfinished_tasks(const std::string& batch_id) {
  Statement s(*this,
              "SELECT 1 FROM tasks WHERE batch_id=? AND state IN ('pending','leased') LIMIT 1");
  s.bind(1, batch_id);
  return s.step();
}

std::array<int, 4> JobStore::task_counts(const std::string& batch_id) {
  Statement s(*this, "SELECT state, count(*) FROM tasks WHERE batch_id=? GROUP BY state");
  s.bind(1, batch_id);
  std::array<int, 4> counts{};
  while (s.step()) {
    counts[static_cast<int>(parse_enum<TaskState>(kTaskStates, s.text(0), "task state"))] =
        s.integer(1);
  }
  return counts;
}

// --- Attempts

void JobStore::insert_attempt(const AttemptRow& a) {
  Statement s(*this,
              "INSERT INTO attempts(task_id, attempt, worker, started, finished, outcome, error) "
              "VALUES(?,?,?,?,?,?,?)");
  s.bind(1, a.task_id).bind(2, a.attempt).bind(3, a.worker).bind(4, a.started);
  s.bind(5, a.finished);
  if (a.outcome) s.bind(6, to_string(*a.outcome));  // else NULL: running
  s.bind(7, a.error).run();
}

void JobStore::finish_attempt(int64_t task, int attempt, double finished, AttemptOutcome outcome,
                              const std::string& error) {
  Statement s(*this,
              "UPDATE attempts SET finished=?, outcome=?, error=? WHERE task_id=? AND attempt=?");
  s.bind(1, finished).bind(2, to_string(outcome)).bind(3, error).bind(4, task).bind(5, attempt);
  s.run();
}

std::vector<AttemptRow> JobStore::attempts(int64_t task) {
  Statement s(*this,
              "SELECT task_id, attempt, worker, started, finished, outcome, error FROM attempts "
              "WHERE task_id=? ORDER BY attempt");
  s.bind(1, task);
  std::vector<AttemptRow> out;
  while (s.step()) {
    AttemptRow a;
    a.task_id = s.int64(0);
    a.attempt = s.integer(1);
    a.worker = s.text(2);
    a.started = s.real(3);
    if (!s.null(4)) a.finished = s.real(4);
    if (!s.null(5)) a.outcome = parse_enum<AttemptOutcome>(kOutcomes, s.text(5), "outcome");
    a.error = s.text(6);
    out.push_back(std::move(a));
  }
  return out;
}

std::vector<std::string> JobStore::failed_workers(int64_t task, int since_attempt) {
  Statement s(*this,
              "SELECT DISTINCT worker FROM attempts WHERE task_id=? AND attempt>? "
              "AND outcome='failed' ORDER BY worker");
  s.bind(1, task).bind(2, since_attempt);
  std::vector<std::string> out;
  while (s.step()) out.push_back(s.text(0));
  return out;
}

int JobStore::failure_count(int64_t task, int since_attempt) {
  Statement s(*this,
              "SELECT count(*) FROM attempts WHERE task_id=? AND attempt>? AND outcome='failed'");
  s.bind(1, task).bind(2, since_attempt);
  s.step();
  return s.integer(0);
}

std::vector<std::pair<int64_t, std::string>> JobStore::counted_failures(
    const std::string& batch_id) {
  Statement s(*this, R"sql(
    SELECT a.task_id, a.worker FROM tasks t JOIN attempts a ON a.task_id = t.id
    WHERE t.batch_id = ? AND a.outcome = 'failed' AND a.attempt > t.retry_base
    ORDER BY a.task_id, a.attempt)sql");
  s.bind(1, batch_id);
  std::vector<std::pair<int64_t, std::string>> out;
  while (s.step()) out.emplace_back(s.int64(0), s.text(1));
  return out;
}

int JobStore::tasks_failed_by(const std::string& batch_id, const std::string& worker) {
  Statement s(*this, R"sql(
    SELECT count(DISTINCT a.task_id) FROM attempts a JOIN tasks t ON t.id = a.task_id
    WHERE t.batch_id = ? AND a.worker = ? AND a.outcome = 'failed'
      AND a.attempt > t.retry_base)sql");
  s.bind(1, batch_id).bind(2, worker);
  s.step();
  return s.integer(0);
}

// --- Workers

void JobStore::upsert_worker(const WorkerRow& w) {
  Statement s(*this, R"sql(
    INSERT INTO workers(id, host, threads, first_seen, last_seen, state) VALUES(?,?,?,?,?,?)
    ON CONFLICT(id) DO UPDATE SET host=excluded.host, threads=excluded.threads,
      last_seen=excluded.last_seen, state=excluded.state)sql");
  s.bind(1, w.id).bind(2, w.host).bind(3, w.threads).bind(4, w.first_seen).bind(5, w.last_seen);
  s.bind(6, w.left ? "left" : "live").run();
}

void JobStore::delete_worker(const std::string& id) {
  Statement s(*this, "DELETE FROM workers WHERE id=?");
  s.bind(1, id).run();
}

namespace {
template <typename S>
WorkerRow read_worker(const S& s) {
  WorkerRow w;
  w.id = s.text(0);
  w.host = s.text(1);
  w.threads = s.integer(2);
  w.first_seen = s.real(3);
  w.last_seen = s.real(4);
  w.left = s.text(5) == "left";
  return w;
}
}  // namespace

std::optional<WorkerRow> JobStore::worker(const std::string& id) {
  Statement s(*this,
              "SELECT id, host, threads, first_seen, last_seen, state FROM workers WHERE id=?");
  s.bind(1, id);
  if (!s.step()) return std::nullopt;
  return read_worker(s);
}

std::vector<WorkerRow> JobStore::workers() {
  Statement s(*this,
              "SELECT id, host, threads, first_seen, last_seen, state FROM workers ORDER BY id");
  std::vector<WorkerRow> out;
  while (s.step()) out.push_back(read_worker(s));
  return out;
}

// --- Blocklist

void JobStore::block(const std::string& batch_id, const std::string& worker, double since) {
  Statement s(*this, "INSERT OR IGNORE INTO blocklist(batch_id, worker, since) VALUES(?,?,?)");
  s.bind(1, batch_id).bind(2, worker).bind(3, since).run();
}

bool JobStore::blocked(const std::string& batch_id, const std::string& worker) {
  Statement s(*this, "SELECT 1 FROM blocklist WHERE batch_id=? AND worker=?");
  s.bind(1, batch_id).bind(2, worker);
  return s.step();
}

std::vector<std::string> JobStore::blocked_workers(const std::string& batch_id) {
  Statement s(*this, "SELECT worker FROM blocklist WHERE batch_id=? ORDER BY worker");
  s.bind(1, batch_id);
  std::vector<std::string> out;
  while (s.step()) out.push_back(s.text(0));
  return out;
}

void JobStore::clear_blocklist(const std::string& batch_id) {
  Statement s(*this, "DELETE FROM blocklist WHERE batch_id=?");
  s.bind(1, batch_id).run();
}

// --- Events

void JobStore::add_event(const EventRow& e) {
  Statement s(*this,
              "INSERT INTO events(time, batch_id, level, text, kind, task, worker) "
              "VALUES(?,?,?,?,?,?,?)");
  s.bind(1, e.time).bind(2, e.batch_id).bind(3, e.level).bind(4, e.text).bind(5, e.kind);
  s.bind(6, e.task).bind(7, e.worker).run();
}

std::vector<EventRow> JobStore::events(const std::string& batch_id, int limit) {
  Statement s(*this,
              "SELECT id, time, batch_id, level, text, kind, task, worker FROM events "
              "WHERE batch_id=? ORDER BY id DESC LIMIT ?");
  s.bind(1, batch_id).bind(2, limit);
  std::vector<EventRow> out;
  while (s.step())
    out.push_back(
        {s.int64(0), s.real(1), s.text(2), s.text(3), s.text(4), s.text(5), s.int64(6), s.text(7)});
  return out;
}

std::vector<LeaseRow> JobStore::leases(const std::string& batch_id, int limit) {
  // Newest first by the attempts' start (attempts_by_start): the recent
  // leases of a running batch are found without reading its whole history.
  Statement s(*this, R"sql(
    SELECT a.task_id, a.attempt, a.worker, a.started, t.kind, t.frame, t.x, t.y, t.w, t.h, t.shard
    FROM attempts a JOIN tasks t ON t.id = a.task_id
    WHERE t.batch_id = ? ORDER BY a.started DESC, a.task_id DESC, a.attempt DESC LIMIT ?)sql");
  s.bind(1, batch_id).bind(2, limit);
  std::vector<LeaseRow> out;
  while (s.step()) {
    LeaseRow l;
    l.task = s.int64(0);
    l.attempt = s.integer(1);
    l.worker = s.text(2);
    l.started = s.real(3);
    l.kind = parse_enum<TaskKind>(kKinds, s.text(4), "kind");
    l.frame = s.integer(5);
    l.rect = {s.integer(6), s.integer(7), s.integer(8), s.integer(9)};
    l.shard = s.integer(10);
    out.push_back(std::move(l));
  }
  return out;
}

std::map<std::string, WorkerCounts> JobStore::worker_counts() {
  Statement s(*this,
              "SELECT worker, outcome, count(*) FROM attempts WHERE outcome IN ('done','failed') "
              "GROUP BY worker, outcome");
  std::map<std::string, WorkerCounts> out;
  while (s.step()) {
    WorkerCounts& c = out[s.text(0)];
    (s.text(1) == "done" ? c.done : c.failed) += s.int64(2);
  }
  return out;
}

}  // namespace dofarm::coordinator
