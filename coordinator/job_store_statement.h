// Internal to the job store (job_store.cpp, job_store_rows.cpp): its
// prepared statements and the text of its enum columns. Not for other users.
#pragma once

#include <sqlite3.h>

#include <optional>
#include <string>
#include <utility>

#include "common/error.h"
#include "coordinator/job_store.h"

namespace dofarm::coordinator {

namespace store_detail {

template <typename Enum, size_t N>
inline Enum parse_enum(const char* const (&names)[N], const std::string& text, const char* what) {
  for (size_t i = 0; i < N; ++i) {
    if (text == names[i]) return static_cast<Enum>(i);
  }
  throw RuntimeError(std::string("job store: unknown ") + what + " '" + text + "'");
}

inline constexpr const char* kBatchStates[] = {"running", "done", "failed", "cancelled"};
inline constexpr const char* kTaskStates[] = {"pending", "leased", "done", "failed"};
inline constexpr const char* kOutcomes[] = {"done", "failed", "expired", "released", "revoked"};
inline constexpr const char* kKinds[] = {"render_tile", "pack_shard"};

}  // namespace store_detail

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

}  // namespace dofarm::coordinator
