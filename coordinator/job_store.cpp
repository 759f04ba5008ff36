// The store itself: opening, the schema, migrations of older stores in
// place, transactions. Its rows are read and written in job_store_rows.cpp.
#include "coordinator/job_store.h"

#include <sqlite3.h>

#include <utility>

#include "common/error.h"
#include "coordinator/job_store_statement.h"

namespace dofarm::coordinator {

using namespace store_detail;

namespace {

// Version 1. Times are REAL seconds since the Unix epoch. Enum columns are
// text (readable in a sqlite3 shell) with CHECK constraints, so a bad write
// fails loudly instead of corrupting the journal.
// The batches' priority DEFAULT (here and in add_missing_batch_columns) is
// the protocol's default priority.
static_assert(kDefaultPriority == 50);
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

}  // namespace

const char* to_string(BatchState s) { return kBatchStates[static_cast<int>(s)]; }
const char* to_string(TaskState s) { return kTaskStates[static_cast<int>(s)]; }
const char* to_string(AttemptOutcome s) { return kOutcomes[static_cast<int>(s)]; }

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

}  // namespace dofarm::coordinator
