// Issue 10, defect 4: resume verifies what is on disk. A finished shard that
// is truncated, corrupted or deleted, or a manifest.json that is deleted or
// garbled, used to pass a second `dofarm run` of the same job ("done, 16/16
// frames", exit 0, the damage kept). Now the run packs (and renders) those
// shards again and rebuilds the manifest, and `dofarm verify DIR` reports
// the damage before and nothing after.
#include <gtest/gtest.h>

#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

void flip_byte(const fs::path& file, uintmax_t offset) {
  std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(std::streamoff(offset));
  char c = 0;
  f.read(&c, 1);
  c = char(c ^ 0x5a);
  f.seekp(std::streamoff(offset));
  f.write(&c, 1);
}

CliResult verify(const TempDir& tmp, const fs::path& out, const std::string& name,
                 bool json = false) {
  std::vector<std::string> args = {"verify", out.string()};
  if (json) args.push_back("--json");
  return run_cli(tmp.path(), name, args);
}

TEST(FarmResume, DamagedShardsAndManifestAreRepairedByRunningTheJobAgain) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});  // 2 shards of 2 frames
  const fs::path out = tmp / "out";
  auto run = [&](const std::string& name) {
    CliResult r =
        run_cli(tmp.path(), name, {"run", job.string(), "--out", out.string(), "--workers", "2"});
    EXPECT_EQ(r.status, 0) << r.out << r.err;
    EXPECT_NE(r.out.find(": done, 4/4 frames"), std::string::npos) << r.out << r.err;
    return r;
  };
  run("run_first");
  ASSERT_TRUE(shards_match_render(out, job));
  CliResult clean = verify(tmp, out, "verify_clean");
  EXPECT_EQ(clean.status, 0) << clean.out << clean.err;
  EXPECT_NE(clean.out.find("shard-00000.h5  frames 0..1  OK"), std::string::npos) << clean.out;
  EXPECT_NE(clean.out.find("shard-00001.h5  frames 2..3  OK"), std::string::npos) << clean.out;

  // Truncated, and corrupted in place (same size).
  const fs::path s0 = out / "shard-00000.h5", s1 = out / "shard-00001.h5";
  fs::resize_file(s0, fs::file_size(s0) / 2);
  flip_byte(s1, fs::file_size(s1) / 2);
  CliResult damaged = verify(tmp, out, "verify_damaged");
  EXPECT_EQ(damaged.status, 1) << damaged.out << damaged.err;
  EXPECT_NE(damaged.out.find("shard-00000.h5  frames 0..1  checksum"), std::string::npos)
      << damaged.out;
  EXPECT_NE(damaged.out.find("shard-00001.h5  frames 2..3  checksum"), std::string::npos)
      << damaged.out;
  CliResult as_json = verify(tmp, out, "verify_damaged_json", true);
  EXPECT_EQ(as_json.status, 1);
  const Json j = Json::parse(as_json.out);
  EXPECT_EQ(j.at("ok"), false);
  ASSERT_EQ(j.at("shards").size(), 2u) << j.dump(2);
  EXPECT_EQ(j.at("shards")[0].at("ok"), false);

  run("run_repair_shards");
  EXPECT_TRUE(shards_match_render(out, job));
  CliResult repaired = verify(tmp, out, "verify_repaired");
  EXPECT_EQ(repaired.status, 0) << repaired.out << repaired.err;

  // A deleted shard and a garbled manifest.
  fs::remove(s1);
  write_text(out / kManifestFile, "{ not json");
  CliResult gone = verify(tmp, out, "verify_gone");
  EXPECT_EQ(gone.status, 1) << gone.out;
  EXPECT_NE(gone.out.find("shard-00001.h5  frames 2..3  missing"), std::string::npos) << gone.out;
  EXPECT_NE(gone.out.find("manifest.json"), std::string::npos) << gone.out;
  run("run_repair_manifest");
  EXPECT_TRUE(shards_match_render(out, job));

  // A deleted manifest: rebuilt from the shards, which all verify.
  fs::remove(out / kManifestFile);
  run("run_rebuild_manifest");
  EXPECT_TRUE(shards_match_render(out, job));
  CliResult last = verify(tmp, out, "verify_last");
  EXPECT_EQ(last.status, 0) << last.out << last.err;
}

TEST(FarmVerify, ReportsShardsNoRecordListsAndNeedsAFolder) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});
  const fs::path out = tmp / "out";
  CliResult r = run_cli(tmp.path(), "run", {"run", job.string(), "--out", out.string()});
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  fs::copy_file(out / "shard-00000.h5", out / "shard-00009.h5");
  CliResult v = verify(tmp, out, "verify_stray");
  EXPECT_EQ(v.status, 1) << v.out;
  EXPECT_NE(v.out.find("shard-00009.h5  UNLISTED"), std::string::npos) << v.out;

  CliResult not_dir = verify(tmp, tmp / "nowhere", "verify_nowhere");
  EXPECT_EQ(not_dir.status, 2) << not_dir.out << not_dir.err;
  EXPECT_NE(not_dir.err.find("nowhere: not a folder"), std::string::npos) << not_dir.err;
}

}  // namespace
}  // namespace dofarm::farm_testing

namespace dofarm::farm_testing {
namespace {

// The `resume` message of a standalone coordinator checks the shards of a
// done batch as well: a deleted shard makes the batch run again, and the
// workers that are still there render and pack it.
TEST(FarmResume, ResumeOfADoneBatchWithADeletedShardRunsItAgain) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});
  const fs::path out = tmp / "out";
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 5);
  const std::string ep = coord.endpoint();
  CliResult sub = run_cli(tmp.path(), "submit",
                          {"submit", job.string(), "--coordinator", ep, "--out", out.string()});
  ASSERT_EQ(sub.status, 0) << sub.out << sub.err;
  const std::string batch = sub.out.substr(0, sub.out.find('\n'));
  Child w1 = start_worker(tmp.path(), ep, "w1");
  ASSERT_TRUE(poll_until("the batch to finish", [&] { return batch_state(ep, batch) == "done"; }))
      << coord.child().describe();
  ASSERT_TRUE(shards_match_render(out, job));

  fs::remove(out / "shard-00001.h5");
  CliResult resume = run_cli(tmp.path(), "resume", {"resume", batch, "--coordinator", ep});
  EXPECT_EQ(resume.status, 0) << resume.out << resume.err;
  EXPECT_NE(batch_state(ep, batch), "absent");
  ASSERT_TRUE(poll_until("the batch to finish again", [&] {
    return batch_state(ep, batch) == "done";
  })) << coord.child().describe();
  EXPECT_TRUE(shards_match_render(out, job));
  CliResult v =
      run_cli(tmp.path(), "verify", {"verify", out.string(), "--state", (tmp / "state").string()});
  EXPECT_EQ(v.status, 0) << v.out << v.err;
}

}  // namespace
}  // namespace dofarm::farm_testing

namespace dofarm::farm_testing {
namespace {

// A coordinator restart checks the packed shards of its running batches: a
// shard deleted while it was down is rendered and packed again.
TEST(FarmResume, ShardDeletedWhileTheCoordinatorIsDownIsMadeAgainOnRestart) {
  TempDir tmp;
  TinyJob many;
  many.frame_end = 19;  // ten shards: the batch still runs when the first is packed
  const fs::path job = write_job(tmp.path(), "job.toml", many);
  const fs::path out = tmp / "out", state = tmp / "state";
  std::string batch;
  {
    CoordinatorProcess coord(tmp.path(), "coordinator1", state, 5);
    CliResult sub =
        run_cli(tmp.path(), "submit",
                {"submit", job.string(), "--coordinator", coord.endpoint(), "--out", out.string()});
    ASSERT_EQ(sub.status, 0) << sub.out << sub.err;
    batch = sub.out.substr(0, sub.out.find('\n'));
    Child w1 = start_worker(tmp.path(), coord.endpoint(), "w1");
    // Packed as far as the coordinator knows (the pack's `done` recorded),
    // not only listed in the manifest.
    ASSERT_TRUE(poll_until("the first shard", [&] {
      const Json b = batch_of(farm_status(coord.endpoint(), batch), batch);
      return !b.is_null() && b.at("frames_packed").get<int>() >= 2;
    }));
    w1.kill9();
    ASSERT_EQ(batch_state(coord.endpoint(), batch), "running");
    coord.child().kill9();
  }
  const std::string first = "shard-00000.h5";  // frames are rendered in order
  ASSERT_TRUE(fs::exists(out / first));
  fs::remove(out / first);

  CoordinatorProcess coord(tmp.path(), "coordinator2", state, 5);
  Child w2 = start_worker(tmp.path(), coord.endpoint(), "w2");
  ASSERT_TRUE(poll_until("the batch to finish", [&] {
    return batch_state(coord.endpoint(), batch) == "done";
  })) << coord.child().describe();
  EXPECT_NE(coord.child().err().find(first), std::string::npos)
      << "the restart must say which shard it makes again\n"
      << coord.child().describe();
  EXPECT_TRUE(shards_match_render(out, job));
}

}  // namespace
}  // namespace dofarm::farm_testing
