// coordinator/verify.h: the file check every shard and staged tile passes
// through, the resume check that requeues damaged shards, and the folder
// report of `dofarm verify`. Shards here are plain files with a recorded
// checksum (the check never parses a shard that verifies against the store
// and the manifest); a fake clock drives the scheduler.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <fstream>

#include "common/checksum.h"
#include "common/manifest.h"
#include "coordinator/scheduler.h"
#include "coordinator/verify.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;
using testing::tiny_spec;

uint64_t write_file(const fs::path& p, const std::string& bytes) {
  fs::create_directories(p.parent_path());
  std::ofstream(p, std::ios::binary) << bytes;
  return checksum64(bytes.data(), bytes.size());
}

TEST(CheckOutputFile, RefusesFifosSymlinksAndDamagedFilesWithoutBlocking) {
  TempDir dir;
  const fs::path good = dir.path() / "good.h5";
  const uint64_t sum = write_file(good, "shard bytes");
  EXPECT_EQ(check_output_file(good, sum), "");
  EXPECT_EQ(check_output_file(good, sum, 11), "");
  EXPECT_EQ(check_output_file(good, sum, 12), "size 11, expected 12");
  EXPECT_NE(check_output_file(good, sum ^ 1).find("checksum "), std::string::npos);
  EXPECT_EQ(check_output_file(dir.path() / "absent.h5", sum), "missing");
  fs::create_symlink(good, dir.path() / "link.h5");
  EXPECT_EQ(check_output_file(dir.path() / "link.h5", sum), "a symlink, not a regular file");
  ASSERT_EQ(::mkfifo((dir.path() / "fifo.h5").c_str(), 0600), 0);
  EXPECT_EQ(check_output_file(dir.path() / "fifo.h5", sum), "not a regular file");
  EXPECT_EQ(check_output_file(dir.path(), sum), "not a regular file");
}

// A finished batch of two one-tile shards in OUT, as a farm leaves it: the
// shards and the manifest written, the staged tiles removed.
class ResumeCheckTest : public ::testing::Test {
 protected:
  ResumeCheckTest()
      : out_(dir_.path() / "out"), store_(state_file(dir_.path() / "out")), sched_(store_, clock_) {
    batch_ = sched_.submit("/jobs/a.toml", {}, out_.string(), tiny_spec(2, 1));
    sched_.worker_seen("w1", "host", 1);
    Manifest manifest;
    for (int i = 0; i < 4; ++i) {
      const Assignment a = testing::take(sched_, "w1");
      if (a.kind == TaskKind::kRenderTile) {
        const fs::path tile = out_ / ".staging" / batch_ / ("f" + std::to_string(a.frame) + ".exr");
        tiles_[a.frame] = tile;
        const uint64_t sum = write_file(tile, "tile " + std::to_string(a.frame));
        EXPECT_EQ(
            sched_.complete("w1", a.task_id, a.attempt, tile.string(), checksum_to_string(sum)),
            CompleteStatus::kAccepted);
      } else {
        const fs::path shard = out_ / a.shard_range.file;
        const std::string bytes = "shard " + std::to_string(a.shard);
        const uint64_t sum = write_file(shard, bytes);
        manifest.shards.push_back({a.shard_range.file, batch_, "cornell", a.shard_range.frame_start,
                                   a.shard_range.frame_end, bytes.size(), sum});
        EXPECT_EQ(
            sched_.complete("w1", a.task_id, a.attempt, shard.string(), checksum_to_string(sum)),
            CompleteStatus::kAccepted);
        fs::remove(tiles_.at(a.shard));  // packing removes its staged tiles
      }
    }
    save_manifest(out_, manifest);
    EXPECT_EQ(state(), BatchState::kDone);
  }
  BatchState state() { return store_.batch(batch_)->state; }
  static fs::path state_file(const fs::path& out) {
    fs::create_directories(out / ".dofarm-state");
    return out / ".dofarm-state" / "dofarm.sqlite";
  }

  TempDir dir_;
  fs::path out_;
  FakeClock clock_;
  JobStore store_;
  Scheduler sched_;
  std::string batch_;
  std::map<int, fs::path> tiles_;  // by frame
};

TEST_F(ResumeCheckTest, SoundOutputChangesNothing) {
  const ResumeCheck r = verify_batch_outputs(sched_, batch_);
  EXPECT_EQ(r.total(), 0);
  EXPECT_FALSE(r.manifest_rebuilt);
  EXPECT_EQ(state(), BatchState::kDone);
  EXPECT_TRUE(verify_folder(out_).ok());
}

TEST_F(ResumeCheckTest, DamagedShardLeavesTheManifestAndItsTilesAreRenderedAgain) {
  std::ofstream(out_ / "shard-00001.h5", std::ios::binary | std::ios::app) << "junk";
  FolderReport before = verify_folder(out_);
  EXPECT_FALSE(before.ok());
  ASSERT_EQ(before.shards.size(), 2u);
  EXPECT_EQ(before.shards[0].problem, "");
  EXPECT_NE(before.shards[1].problem.find("checksum"), std::string::npos);

  const ResumeCheck r = verify_batch_outputs(sched_, batch_);
  EXPECT_EQ(r.shards_redone, 1);
  EXPECT_EQ(state(), BatchState::kRunning) << "a done batch with a damaged shard runs again";
  const Manifest m = load_manifest(out_);
  ASSERT_EQ(m.shards.size(), 1u);
  EXPECT_EQ(m.shards[0].file, "shard-00000.h5");
  // Its staged tile is gone: the tile is rendered first, then packed.
  const Assignment a = testing::take(sched_, "w1");
  EXPECT_EQ(a.kind, TaskKind::kRenderTile);
  EXPECT_EQ(a.frame, 1);
  EXPECT_FALSE(sched_.assign("w1").has_value()) << "the pack must wait for its tile";
}

TEST_F(ResumeCheckTest, MissingShardWhoseTilesAreStillStagedIsOnlyPackedAgain) {
  const uint64_t sum = write_file(tiles_.at(0), "tile 0");  // as staged before the pack
  (void)sum;
  fs::remove(out_ / "shard-00000.h5");
  const ResumeCheck r = verify_batch_outputs(sched_, batch_);
  EXPECT_EQ(r.shards_redone, 1);
  const Assignment a = testing::take(sched_, "w1");
  EXPECT_EQ(a.kind, TaskKind::kPackShard);
  EXPECT_EQ(a.shard, 0);
}

TEST_F(ResumeCheckTest, FolderReportListsStrayShardsAndStagedLeftovers) {
  write_file(out_ / "shard-00007.h5", "someone else's");
  write_file(out_ / ".staging" / "b-old" / "f00000_x0_y0_w16_h16.exr", "old");
  const FolderReport r = verify_folder(out_);
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.batch_id, batch_);
  EXPECT_EQ(r.unlisted, std::vector<std::string>{"shard-00007.h5"});
  ASSERT_EQ(r.staged.size(), 1u);
  EXPECT_EQ(r.staged[0].problem, "");  // reported, not a failure
  // Without its job store the manifest is the record.
  fs::remove_all(out_ / ".dofarm-state");
  const FolderReport m = verify_folder(out_);
  EXPECT_NE(m.record.find("manifest.json"), std::string::npos);
  EXPECT_EQ(m.shards.size(), 2u);
  EXPECT_EQ(m.unlisted, std::vector<std::string>{"shard-00007.h5"});
}

}  // namespace
}  // namespace dofarm::coordinator
