// The shards' manifest (common/manifest.h): listing, loading and verifying
// shards, and located errors for a malformed manifest.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common/checksum.h"
#include "common/manifest.h"
#include "common/shard.h"
#include "shard_fixtures.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;
using namespace shard_testing;

// Writes shard `index` of the test batch into `dir` and lists it.
ManifestEntry write_and_list(const fs::path& dir, int index) {
  ShardInfo info = make_info();
  info.frame_start = kFirstFrame + index * kFrames;
  info.frame_end = info.frame_start + kFrames - 1;
  std::vector<FrameBuffers> frames;
  for (int f = info.frame_start; f <= info.frame_end; ++f) frames.push_back(make_frame(f));
  char name[32];
  std::snprintf(name, sizeof name, "shard-%05d.h5", index);
  ShardWriteResult res = write_shard(dir / name, info, frames);
  ManifestEntry e = manifest_entry(info, res);
  add_to_manifest(dir, e);
  return e;
}

TEST(Manifest, AbsentManifestIsEmpty) {
  TempDir dir;
  EXPECT_TRUE(load_manifest(dir.path()).shards.empty());
  EXPECT_TRUE(verify_manifest(dir.path()).empty());
}

TEST(Manifest, AddLoadAndVerifyShards) {
  TempDir dir;
  ManifestEntry b = write_and_list(dir.path(), 1);
  ManifestEntry a = write_and_list(dir.path(), 0);
  Manifest m = load_manifest(dir.path());
  ASSERT_EQ(m.shards.size(), 2u);
  EXPECT_EQ(m.shards[0], a);  // sorted by file name
  EXPECT_EQ(m.shards[1], b);
  EXPECT_EQ(a.file, "shard-00000.h5");
  EXPECT_EQ(b.frame_start, kFirstFrame + kFrames);
  EXPECT_EQ(b.frame_end, kFirstFrame + 2 * kFrames - 1);
  EXPECT_EQ(a.scene_id, "cornell");
  EXPECT_EQ(a.size, fs::file_size(dir.path() / a.file));
  EXPECT_EQ(a.checksum, checksum_file(dir.path() / a.file));
  EXPECT_TRUE(verify_manifest(dir.path()).empty());
  // Listing the same shard again (a retried pack job) replaces, not duplicates.
  add_to_manifest(dir.path(), a);
  EXPECT_EQ(load_manifest(dir.path()).shards.size(), 2u);
  for (const std::string& f : dir.files())  // no temporary files left behind
    EXPECT_EQ(f.find(".tmp-"), std::string::npos) << f;
}

TEST(Manifest, VerifyCatchesCorruptionMissingAndResizedShards) {
  TempDir dir;
  ManifestEntry a = write_and_list(dir.path(), 0);
  ManifestEntry b = write_and_list(dir.path(), 1);
  ManifestEntry c = write_and_list(dir.path(), 2);
  corrupt_middle(dir.path() / a.file, 4);  // same size: only the checksum sees it
  fs::remove(dir.path() / b.file);
  fs::resize_file(dir.path() / c.file, c.size + 10);
  std::vector<ManifestProblem> problems = verify_manifest(dir.path());
  ASSERT_EQ(problems.size(), 3u);
  EXPECT_EQ(problems[0].file, a.file);
  EXPECT_EQ(problems[0].problem.rfind("checksum ", 0), 0u) << problems[0].problem;
  EXPECT_EQ(problems[1].file, b.file);
  EXPECT_EQ(problems[1].problem.rfind("missing", 0), 0u) << problems[1].problem;
  EXPECT_EQ(problems[2].file, c.file);
  EXPECT_EQ(problems[2].problem.rfind("size ", 0), 0u) << problems[2].problem;
  // Without checksums only the cheap checks run, so the corruption passes.
  EXPECT_EQ(verify_manifest(dir.path(), false).size(), 2u);
}

TEST(Manifest, MalformedManifestNamesTheKey) {
  TempDir dir;
  write_and_list(dir.path(), 0);
  fs::path p = dir.path() / kManifestFile;
  std::ifstream in(p);
  nlohmann::json j = nlohmann::json::parse(in);
  j["shards"][0]["checksum"] = "12345";
  std::ofstream(p) << j.dump();
  try {
    load_manifest(dir.path());
    FAIL() << "bad checksum accepted";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("shards[0].checksum"), std::string::npos) << e.what();
  }
  std::ofstream(p) << R"({"schema": "dofarm.manifest/9", "shards": []})";
  EXPECT_THROW(load_manifest(dir.path()), RuntimeError);
  std::ofstream(p) << R"({"schema": "dofarm.manifest/1", "shards": [{"file": "../x.h5"}]})";
  EXPECT_THROW(load_manifest(dir.path()), RuntimeError);
}
}  // namespace
}  // namespace dofarm
