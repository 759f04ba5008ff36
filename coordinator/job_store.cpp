#include "coordinator/job_store.h"

#include <sqlite3.h>

#include <nlohmann/json.hpp>
#include <utility>

#include "common/error.h"

namespace dofarm::coordinator {

namespace {

// Version 1. Times are REAL seconds since the Unix epoch. Enum columns are
// text (readable in a sqlite3 shell) with CHECK constraints, so a bad write
// fails loudly instead of corrupting the journal.
constexpr const char* kSchema = R"sql(
CREATE TABLE batches(
  id TEXT PRIMARY KEY,
  spec_path TEXT NOT NULL,
  overrides TEXT NOT NULL,
  out_dir TEXT NOT NULL,
  state TEXT NOT NULL CHECK(state IN ('running','done','failed','cancelled')),
  created REAL NOT NULL,
  finished REAL,
  frame_start INTEGER NOT NULL,
  frame_end INTEGER NOT NULL,
  per_shard INTEGER NOT NULL,
  job TEXT NOT NULL DEFAULT '',
  snapshot TEXT NOT NULL DEFAULT '',
  priority INTEGER NOT NULL DEFAULT 50);
CREATE TABLE tasks(
  id INTEGER PRIMARY KEY,
  batch_id TEXT NOT NULL REFERENCES batches(id),
  kind TEXT NOT NULL CHECK(kind IN ('render_tile','pack_shard')),
  frame INTEGER NOT NULL,
  x INTEGER NOT NULL, y INTEGER NOT NULL, w INTEGER NOT NULL, h INTEGER NOT NULL,
  shard INTEGER NOT NULL,
  state TEXT NOT NULL CHECK(state IN ('pending','leased','done','failed')),
  attempts INTEGER NOT NULL DEFAULT 0,
  retry_base INTEGER NOT NULL DEFAULT 0,
  lease_worker TEXT NOT NULL DEFAULT '',
  lease_expiry REAL NOT NULL DEFAULT 0,
  not_before REAL NOT NULL DEFAULT 0,
  staged_path TEXT NOT NULL DEFAULT '',
  checksum TEXT NOT NULL DEFAULT '',
  last_error TEXT NOT NULL DEFAULT '',
  updated REAL NOT NULL);
CREATE INDEX tasks_by_state ON tasks(state, not_before);
CREATE INDEX tasks_by_batch ON tasks(batch_id, kind, frame);
CREATE INDEX tasks_queue ON tasks(batch_id, state, kind, frame, id);
CREATE TABLE task_deps(
  task INTEGER NOT NULL REFERENCES tasks(id),
  depends_on INTEGER NOT NULL REFERENCES tasks(id),
  PRIMARY KEY(task, depends_on)) WITHOUT ROWID;
CREATE INDEX task_deps_reverse ON task_deps(depends_on);
CREATE TABLE attempts(
  task_id INTEGER NOT NULL REFERENCES tasks(id),
  attempt INTEGER NOT NULL,
  worker TEXT NOT NULL,
  started REAL NOT NULL,
  finished REAL,
  outcome TEXT CHECK(outcome IN ('done','failed','expired','released','revoked')),
  error TEXT NOT NULL DEFAULT '',
  PRIMARY KEY(task_id, attempt));
CREATE INDEX attempts_by_worker ON attempts(worker, outcome);
CREATE TABLE workers(
  id TEXT PRIMARY KEY,
  host TEXT NOT NULL,
  threads INTEGER NOT NULL,
  first_seen REAL NOT NULL,
  last_seen REAL NOT NULL,
  state TEXT NOT NULL CHECK(state IN ('live','left')));
CREATE TABLE blocklist(
  batch_id TEXT NOT NULL REFERENCES batches(id),
  worker TEXT NOT NULL,
  since REAL NOT NULL,
  PRIMARY KEY(batch_id, worker));
CREATE TABLE events(
  id INTEGER PRIMARY KEY,
  time REAL NOT NULL,
  batch_id TEXT NOT NULL,
  level TEXT NOT NULL,
  text TEXT NOT NULL,
  kind TEXT NOT NULL DEFAULT '',
  task INTEGER NOT NULL DEFAULT 0,
  worker TEXT NOT NULL DEFAULT '');
CREATE INDEX events_by_batch ON events(batch_id, id);
CREATE INDEX attempts_by_start ON attempts(started);
)sql";

template <typename Enum, size_t N>
Enum parse_enum(const char* const (&names)[N], const std::string& text, const char* what) {
  for (size_t i = 0; i < N; ++i) {
    if (text == names[i]) return static_cast<Enum>(i);
  }
  throw RuntimeError(std::string("job store: unknown ") + what + " '" + text + "'");
}

constexpr const char* kBatchStates[] = {"running", "done", "failed", "cancelled"};
constexpr const char* kTaskStates[] = {"pending", "leased", "done", "failed"};
constexpr const char* kOutcomes[] = {"done", "failed", "expired", "released", "revoked"};
constexpr const char* kKinds[] = {"render_tile", "pack_shard"};

}  // namespace

const char* to_string(BatchState s) { return kBatchStates[static_cast<int>(s)]; }
const char* to_string(TaskState s) { return kTaskStates[static_cast<int>(s)]; }
const char* to_string(AttemptOutcome s) { return kOutcomes[static_cast<int>(s)]; }

// One prepared statement: bind by position (1-based, as SQLite counts),
// step, read columns. Every failure throws with the message, the SQL and the
// database.
class JobStore::Statement {
 public:
  // Takes the prepared statement for `sql` from the store's cache, or
  // prepares it; gives it back, reset, when done (preparing costs more than
  // running most of these statements).
  Statement(JobStore& store, std::string sql) : store_(store), sql_(std::move(sql)) {
    auto it = store_.statements_.find(sql_);
    if (it != store_.statements_.end()) {
      stmt_ = it->second;
      store_.statements_.erase(it);
    } else if (sqlite3_prepare_v2(store_.db_, sql_.c_str(), -1, &stmt_, nullptr) != SQLITE_OK) {
      fail();
    }
  }
  ~Statement() {
    if (!stmt_) return;
    sqlite3_reset(stmt_);
    sqlite3_clear_bindings(stmt_);
    if (!store_.statements_.emplace(sql_, stmt_).second) sqlite3_finalize(stmt_);
  }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  Statement& bind(int i, int64_t v) { return check(sqlite3_bind_int64(stmt_, i, v)); }
  Statement& bind(int i, int v) { return bind(i, static_cast<int64_t>(v)); }
  Statement& bind(int i, double v) { return check(sqlite3_bind_double(stmt_, i, v)); }
  Statement& bind(int i, const std::string& v) {
    return check(
        sqlite3_bind_text(stmt_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
  }
  Statement& bind(int i, const char* v) { return bind(i, std::string(v)); }
  Statement& bind(int i, std::optional<double> v) {
    return v ? bind(i, *v) : check(sqlite3_bind_null(stmt_, i));
  }

  // True while there is a row to read.
  bool step() {
    const int rc = sqlite3_step(stmt_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    fail();
  }
  void run() {
    while (step()) {
    }
  }

  int64_t int64(int col) const { return sqlite3_column_int64(stmt_, col); }
  int integer(int col) const { return sqlite3_column_int(stmt_, col); }
  double real(int col) const { return sqlite3_column_double(stmt_, col); }
  bool null(int col) const { return sqlite3_column_type(stmt_, col) == SQLITE_NULL; }
  std::string text(int col) const {
    const auto* p = reinterpret_cast<const char*>(sqlite3_column_text(stmt_, col));
    return p ? std::string(p, sqlite3_column_bytes(stmt_, col)) : std::string();
  }

 private:
  Statement& check(int rc) {
    if (rc != SQLITE_OK) fail();
    return *this;
  }
  [[noreturn]] void fail() {
    throw RuntimeError("job store " + store_.path_.string() + ": " + sqlite3_errmsg(store_.db_) +
                       " in: " + sql_);
  }

  JobStore& store_;
  std::string sql_;
  sqlite3_stmt* stmt_ = nullptr;
};

JobStore::JobStore(const std::filesystem::path& path) : path_(path) {
  const int rc =
      sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr);
  if (rc != SQLITE_OK) {
    const std::string msg = db_ ? sqlite3_errmsg(db_) : sqlite3_errstr(rc);
    sqlite3_close(db_);
    throw RuntimeError("job store " + path.string() + ": cannot open: " + msg);
  }
  try {
    // Another connection (an operator's shell, a second coordinator by
    // mistake) holding the write lock makes us wait this long, not fail.
    sqlite3_busy_timeout(db_, 10000);
    int version = 0;
    {
      // Reading the version is also the first read of the file, so a file
      // that is not a database fails here, with SQLite's "file is not a
      // database".
      Statement s(*this, "PRAGMA user_version");
      if (s.step()) version = s.integer(0);
    }
    int tables = 0;
    {
      Statement s(*this, "SELECT count(*) FROM sqlite_schema");
      if (s.step()) tables = s.integer(0);
    }
    if (version == 0 && tables == 0) {
      create_schema();
    } else if (version != kStoreSchemaVersion) {
      throw RuntimeError("job store " + path.string() + ": schema version " +
                         std::to_string(version) + ", this build reads version " +
                         std::to_string(kStoreSchemaVersion) +
                         " only; use the dofarm that wrote it or start a new state folder");
    }
    add_missing_batch_columns();
    add_missing_event_columns();
    exec("PRAGMA journal_mode=WAL");
    exec("PRAGMA synchronous=NORMAL");  // see the header
    exec("PRAGMA foreign_keys=ON");
  } catch (...) {
    for (auto& [sql, stmt] : statements_) sqlite3_finalize(stmt);
    sqlite3_close(db_);
    throw;
  }
}

JobStore::~JobStore() {
  for (auto& [sql, stmt] : statements_) sqlite3_finalize(stmt);
  sqlite3_close(db_);
}

void JobStore::exec(const char* sql) {
  char* err = nullptr;
  if (sqlite3_exec(db_, sql, nullptr, nullptr, &err) != SQLITE_OK) {
    const std::string msg = err ? err : sqlite3_errmsg(db_);
    sqlite3_free(err);
    throw RuntimeError("job store " + path_.string() + ": " + msg + " in: " + sql);
  }
}

// Whether `table` of this store has `column` (stores of older versions may lack it).
bool JobStore::has_column(const std::string& table, const std::string& column) {
  Statement s(*this, "SELECT count(*) FROM pragma_table_info('" + table + "') WHERE name='" +
                         column + "'");
  return s.step() && s.integer(0) > 0;
}

// Stores written before jobs were snapshots lack the batches' job columns;
// they are added in place (empty for the old batches), so such a store still
// opens and its batches still run.
// Stores written before batch priorities get the column with every batch at
// the default priority, which orders them as before (oldest first).
void JobStore::add_missing_batch_columns() {
  if (!has_column("batches", "job")) {
    Transaction t(*this);
    exec("ALTER TABLE batches ADD COLUMN job TEXT NOT NULL DEFAULT ''");
    exec("ALTER TABLE batches ADD COLUMN snapshot TEXT NOT NULL DEFAULT ''");
    t.commit();
  }
  if (!has_column("batches", "priority")) {
    Transaction t(*this);
    exec("ALTER TABLE batches ADD COLUMN priority INTEGER NOT NULL DEFAULT 50");
    t.commit();
  }
}

// Stores written before `dofarm events` lack the events' kind, task and
// worker columns and the index that finds a batch's newest leases; they are
// added in place (old events get an empty kind), so such a store opens as it
// was and reads the same.
void JobStore::add_missing_event_columns() {
  if (has_column("events", "kind")) return;
  Transaction t(*this);
  exec("ALTER TABLE events ADD COLUMN kind TEXT NOT NULL DEFAULT ''");
  exec("ALTER TABLE events ADD COLUMN task INTEGER NOT NULL DEFAULT 0");
  exec("ALTER TABLE events ADD COLUMN worker TEXT NOT NULL DEFAULT ''");
  exec("CREATE INDEX IF NOT EXISTS attempts_by_start ON attempts(started)");
  t.commit();
}

void JobStore::create_schema() {
  Transaction t(*this);
  exec(kSchema);
  exec(("PRAGMA user_version=" + std::to_string(kStoreSchemaVersion)).c_str());
  t.commit();
}

JobStore::Transaction::Transaction(JobStore& store) : store_(store) {
  if (store_.group_ && !store_.group_open_) {
    store_.exec("BEGIN IMMEDIATE");
    store_.group_open_ = true;
  }
  savepoint_ = store_.group_ || store_.depth_ > 0;
  store_.exec(savepoint_ ? "SAVEPOINT tx" : "BEGIN IMMEDIATE");
  ++store_.depth_;
}

JobStore::Transaction::~Transaction() {
  if (done_) return;
  --store_.depth_;
  // A failed ROLLBACK (the transaction was already rolled back by SQLite)
  // must not escape a destructor.
  if (savepoint_) {
    sqlite3_exec(store_.db_, "ROLLBACK TO tx; RELEASE tx", nullptr, nullptr, nullptr);
  } else {
    sqlite3_exec(store_.db_, "ROLLBACK", nullptr, nullptr, nullptr);
  }
}

void JobStore::Transaction::commit() {
  store_.exec(savepoint_ ? "RELEASE tx" : "COMMIT");
  done_ = true;
  --store_.depth_;
}

void JobStore::begin_group() {
  DOFARM_CHECK_EQ(depth_, 0);
  group_ = true;
  group_open_ = false;
}

void JobStore::commit_group() {
  const bool open = group_open_;
  group_ = false;
  group_open_ = false;
  if (!open) return;  // nothing was written
  try {
    exec("COMMIT");
  } catch (...) {
    sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    throw;
  }
}

void JobStore::rollback_group() {
  if (group_open_) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
  group_ = false;
  group_open_ = false;
}

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
