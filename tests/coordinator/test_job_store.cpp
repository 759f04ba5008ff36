// Job store: everything survives a close and reopen, each committed change is
// visible to a second connection at once (it is on disk, not in a cache), an
// uncommitted one is not, and stores of another schema version are refused.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <fstream>

#include "common/error.h"
#include "coordinator/job_store.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

using testing::TempDir;

BatchRow sample_batch() {
  BatchRow b;
  b.id = "b-0123abcd";
  b.spec_path = "/jobs/cornell.toml";
  b.overrides = {"image.width=64", "buffers.reference_spp=16"};
  b.out_dir = "/out";
  b.created = 100.5;
  b.frame_start = 3;
  b.frame_end = 9;
  b.per_shard = 4;
  return b;
}

TaskRow sample_task(const std::string& batch) {
  TaskRow t;
  t.batch_id = batch;
  t.frame = 4;
  t.rect = {16, 32, 16, 8};
  t.shard = 0;
  t.updated = 101;
  return t;
}

TEST(JobStore, ReopenKeepsEverything) {
  TempDir dir;
  const auto path = dir.path() / "state.db";
  int64_t tile = 0, pack = 0;
  {
    JobStore store(path);
    JobStore::Transaction tx(store);
    store.insert_batch(sample_batch());
    tile = store.insert_task(sample_task("b-0123abcd"));
    TaskRow p = sample_task("b-0123abcd");
    p.kind = TaskKind::kPackShard;
    pack = store.insert_task(p);
    store.insert_dependency(pack, tile);
    TaskRow leased = *store.task(tile);
    leased.state = TaskState::kLeased;
    leased.attempts = 2;
    leased.lease_worker = "w1";
    leased.lease_expiry = 130;
    leased.last_error = "out of memory";
    store.update_task(leased);
    store.insert_attempt({tile, 2, "w1", 100, std::nullopt, std::nullopt, ""});
    store.upsert_worker({"w1", "node7", 16, 90, 100, false});
    store.block("b-0123abcd", "w9", 99);
    store.add_event(100, "b-0123abcd", "info", "submitted");
    tx.commit();
  }
  JobStore store(path);
  const BatchRow b = *store.batch("b-0123abcd");
  EXPECT_EQ(b.overrides, sample_batch().overrides);
  EXPECT_EQ(b.state, BatchState::kRunning);
  EXPECT_EQ(b.per_shard, 4);
  EXPECT_FALSE(b.finished.has_value());
  const TaskRow t = *store.task(tile);
  EXPECT_EQ(t.state, TaskState::kLeased);  // a lease outlives the coordinator
  EXPECT_EQ(t.lease_worker, "w1");
  EXPECT_EQ(t.lease_expiry, 130);
  EXPECT_EQ(t.attempts, 2);
  EXPECT_EQ(t.rect, (Rect{16, 32, 16, 8}));
  EXPECT_EQ(t.last_error, "out of memory");
  EXPECT_EQ(store.dependencies(pack), std::vector<int64_t>{tile});
  EXPECT_EQ(store.dependents(tile), std::vector<int64_t>{pack});
  ASSERT_EQ(store.attempts(tile).size(), 1u);
  EXPECT_FALSE(store.attempts(tile)[0].outcome.has_value());
  EXPECT_EQ(store.worker("w1")->host, "node7");
  EXPECT_TRUE(store.blocked("b-0123abcd", "w9"));
  ASSERT_EQ(store.events("b-0123abcd", 10).size(), 1u);
}

TEST(JobStore, CommittedChangesAreSeenByASecondConnectionAndRolledBackOnesAreNot) {
  TempDir dir;
  const auto path = dir.path() / "state.db";
  JobStore writer(path);
  JobStore reader(path);
  {
    JobStore::Transaction tx(writer);
    writer.insert_batch(sample_batch());
    tx.commit();
  }
  EXPECT_TRUE(reader.batch("b-0123abcd").has_value());
  {
    JobStore::Transaction tx(writer);
    writer.set_batch_state("b-0123abcd", BatchState::kCancelled, 200);
    // Not committed: the destructor rolls back.
  }
  EXPECT_EQ(reader.batch("b-0123abcd")->state, BatchState::kRunning);
  {
    JobStore::Transaction tx(writer);
    writer.set_batch_state("b-0123abcd", BatchState::kCancelled, 200);
    tx.commit();
  }
  EXPECT_EQ(reader.batch("b-0123abcd")->state, BatchState::kCancelled);
  EXPECT_EQ(reader.batch("b-0123abcd")->finished, 200);
}

TEST(JobStore, NestedTransactionRollsBackItsOwnChangesOnly) {
  TempDir dir;
  const auto path = dir.path() / "state.db";
  JobStore writer(path);
  JobStore reader(path);
  {
    JobStore::Transaction outer(writer);
    writer.insert_batch(sample_batch());
    {
      JobStore::Transaction inner(writer);
      writer.set_batch_state("b-0123abcd", BatchState::kCancelled, 200);
      // Not committed: back to the outer transaction's state.
    }
    EXPECT_EQ(writer.batch("b-0123abcd")->state, BatchState::kRunning);
    {
      JobStore::Transaction inner(writer);
      writer.add_event(201, "b-0123abcd", "info", "kept");
      inner.commit();
    }
    EXPECT_FALSE(reader.batch("b-0123abcd").has_value()) << "visible before the outer commit";
    outer.commit();
  }
  EXPECT_EQ(reader.batch("b-0123abcd")->state, BatchState::kRunning);
  EXPECT_EQ(reader.events("b-0123abcd", 10).size(), 1u);
}

TEST(JobStore, GroupIsCommittedOnceAndAFailedMemberIsLeftOut) {
  TempDir dir;
  const auto path = dir.path() / "state.db";
  JobStore writer(path);
  JobStore reader(path);
  writer.begin_group();
  {
    JobStore::Transaction tx(writer);
    writer.insert_batch(sample_batch());
    tx.commit();
  }
  try {
    JobStore::Transaction tx(writer);
    writer.add_event(1, "b-0123abcd", "info", "lost with its failing member");
    writer.insert_batch(sample_batch());  // the same primary key: throws
    tx.commit();
  } catch (const RuntimeError&) {
  }
  {
    JobStore::Transaction tx(writer);
    writer.add_event(2, "b-0123abcd", "info", "kept");
    tx.commit();
  }
  EXPECT_FALSE(reader.batch("b-0123abcd").has_value()) << "visible before the group commit";
  writer.commit_group();
  ASSERT_TRUE(reader.batch("b-0123abcd").has_value());
  const std::vector<EventRow> events = reader.events("b-0123abcd", 10);
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].text, "kept");
  // After the group, transactions commit on their own again.
  {
    JobStore::Transaction tx(writer);
    writer.set_batch_state("b-0123abcd", BatchState::kDone, 300);
    tx.commit();
  }
  EXPECT_EQ(reader.batch("b-0123abcd")->state, BatchState::kDone);
  // A group rolled back leaves nothing.
  writer.begin_group();
  {
    JobStore::Transaction tx(writer);
    writer.set_batch_state("b-0123abcd", BatchState::kCancelled, 400);
    tx.commit();
  }
  writer.rollback_group();
  EXPECT_EQ(reader.batch("b-0123abcd")->state, BatchState::kDone);
}

TEST(JobStore, UsesWalAndRecordsTheSchemaVersion) {
  TempDir dir;
  const auto path = dir.path() / "state.db";
  { JobStore store(path); }
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  auto pragma = [&](const char* sql) {
    sqlite3_stmt* s = nullptr;
    sqlite3_prepare_v2(db, sql, -1, &s, nullptr);
    sqlite3_step(s);
    std::string v = reinterpret_cast<const char*>(sqlite3_column_text(s, 0));
    sqlite3_finalize(s);
    return v;
  };
  EXPECT_EQ(pragma("PRAGMA journal_mode"), "wal");
  EXPECT_EQ(pragma("PRAGMA user_version"), std::to_string(kStoreSchemaVersion));
  sqlite3_close(db);
}

TEST(JobStore, RefusesAnUnknownSchemaVersion) {
  TempDir dir;
  const auto path = dir.path() / "state.db";
  { JobStore store(path); }
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(db, "PRAGMA user_version=99", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(db);
  try {
    JobStore store(path);
    FAIL() << "opened a version 99 store";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("schema version 99"), std::string::npos) << e.what();
  }
}

TEST(JobStore, RefusesAFileThatIsNotADatabase) {
  TempDir dir;
  const auto path = dir.path() / "state.db";
  std::ofstream(path) << "this is a text file, long enough to fill a database header page....";
  EXPECT_THROW(JobStore store(path), RuntimeError);
}

TEST(JobStore, SqlErrorsNameTheStatement) {
  TempDir dir;
  JobStore store(dir.path() / "state.db");
  store.insert_batch(sample_batch());
  try {
    store.insert_batch(sample_batch());  // the same primary key again
    FAIL() << "inserted a duplicate batch";
  } catch (const RuntimeError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("UNIQUE constraint failed"), std::string::npos) << what;
    EXPECT_NE(what.find("INSERT INTO batches"), std::string::npos) << what;
  }
}

}  // namespace
}  // namespace dofarm::coordinator
