// `dofarm run` (embedded coordinator + local worker processes) end to end,
// and bad job specs refused before anything is written or submitted.
#include <gtest/gtest.h>

#include <fstream>

#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

TEST(FarmRun, ShardsAreBitIdenticalToInProcessRenderForAnyWorkerCountAndTiling) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});

  CliResult two = run_cli(
      tmp.path(), "run2",
      {"run", job.string(), "--out", (tmp / "A").string(), "--workers", "2", "--lease", "2"});
  ASSERT_EQ(two.status, 0) << two.out << two.err;
  EXPECT_NE(two.out.find(": done,"), std::string::npos) << two.out;
  EXPECT_TRUE(shards_match_render(tmp / "A", job));

  // Another tiling and one worker: the same bytes.
  CliResult one = run_cli(tmp.path(), "run1",
                          {"run", job.string(), "--out", (tmp / "B").string(), "--workers", "1",
                           "--lease", "2", "--set", "farm.tile=8"});
  ASSERT_EQ(one.status, 0) << one.out << one.err;
  std::map<int, FrameBuffers> a, b;
  ASSERT_TRUE(read_manifest_frames(tmp / "A", a));
  ASSERT_TRUE(read_manifest_frames(tmp / "B", b));
  ASSERT_EQ(a.size(), b.size());
  for (const auto& [f, fb] : a) {
    ASSERT_TRUE(b.count(f)) << "frame " << f;
    EXPECT_TRUE(same_frame(fb, b.at(f))) << "frame " << f;
  }
  // The staged tiles are gone once packed.
  if (fs::exists(tmp / "B" / ".staging")) {
    for (const auto& e : fs::recursive_directory_iterator(tmp / "B" / ".staging"))
      EXPECT_FALSE(e.is_regular_file()) << "left behind: " << e.path();
  }
}

// A spec with image.width = 0 on line 6, column 9.
fs::path write_bad_job(const fs::path& dir) {
  fs::path p = dir / "bad.toml";
  write_text(p, "scene = \"" + cornell_scene().string() +
                    "\"\nseed = 7\n\n[image]\nheight = 24\nwidth = 0\n\n[[camera.key]]\nframe = "
                    "0\nposition = [0.0, 1.0, 3.9]\nlook_at = [0.0, 1.0, 0.0]\naperture = 0.05\n");
  return p;
}

TEST(FarmSubmit, BadSpecIsRefusedWithItsLocationAndNothingIsAdded) {
  TempDir tmp;
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 2);
  const fs::path bad = write_bad_job(tmp.path());

  CliResult r = run_cli(
      tmp.path(), "submit_bad",
      {"submit", bad.string(), "--coordinator", coord.endpoint(), "--out", (tmp / "out").string()});
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("bad.toml:6:9"), std::string::npos) << r.err;
  EXPECT_TRUE(r.out.empty()) << "no batch id may be printed: " << r.out;

  // A bad override of a good spec, likewise.
  const fs::path good = write_job(tmp.path(), "good.toml", TinyJob{});
  CliResult o = run_cli(tmp.path(), "submit_bad_set",
                        {"submit", good.string(), "--coordinator", coord.endpoint(), "--out",
                         (tmp / "out").string(), "--set", "image.width=-4"});
  EXPECT_EQ(o.status, 2) << o.out << o.err;
  EXPECT_NE(o.err.find("--set image.width=-4"), std::string::npos) << o.err;

  CliResult st =
      run_cli(tmp.path(), "status", {"status", "--coordinator", coord.endpoint(), "--json"});
  ASSERT_EQ(st.status, 0) << st.err;
  EXPECT_TRUE(Json::parse(st.out).at("batches").empty()) << st.out;
  EXPECT_FALSE(fs::exists(tmp / "out"));
}

TEST(FarmRun, BadSpecExitsTwoAndWritesNothing) {
  TempDir tmp;
  const fs::path bad = write_bad_job(tmp.path());
  CliResult r =
      run_cli(tmp.path(), "run_bad", {"run", bad.string(), "--out", (tmp / "D").string()});
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("bad.toml:6:9"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(tmp / "D")) << "the output folder must not be created";
}

TEST(FarmRun, StopsWhenEveryWorkerIsBlocklisted) {
  // A job that is fine (its scene loads at submit) in a folder where no tile
  // can be staged (a file stands where the staging folder must go): every
  // task fails on every worker, both local workers get blocklisted, and
  // nobody is left to render. `run` must say so and exit 1, not wait forever.
  TempDir tmp;
  TinyJob job;
  job.tile = 8;  // 12 tiles a frame: more failing tasks than the blocklist needs
  const fs::path spec = write_job(tmp.path(), "job.toml", job);
  fs::create_directories(tmp / "out");
  write_text(tmp / "out" / ".staging", "in the way");
  CliResult r = run_cli(tmp.path(), "run_broken",
                        {"run", spec.string(), "--out", (tmp / "out").string(), "--workers", "2"},
                        /*deadline_seconds=*/60);
  EXPECT_EQ(r.status, 1) << r.out << r.err;
  EXPECT_NE(r.err.find("blocklisted"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(tmp / "out" / "manifest.json"));
  // The progress says what it counts and how the run ended: never "done".
  EXPECT_EQ(r.err.find(" done in "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(" tasks failed after "), std::string::npos) << r.err;
}

// A batch that does not exist: status, cancel and resume exit 2 with one
// "dofarm: error:" line on stderr and nothing on stdout.
TEST(FarmCli, UnknownBatchIsAnErrorOnStderr) {
  TempDir tmp;
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 5);
  for (const std::string op : {"status", "cancel", "resume"}) {
    CliResult r = run_cli(tmp.path(), op, {op, "b-nope", "--coordinator", coord.endpoint()});
    EXPECT_EQ(r.status, 2) << op << ": " << r.out << r.err;
    EXPECT_EQ(r.out, "") << op;
    EXPECT_NE(r.err.find("dofarm: error:"), std::string::npos) << op << ": " << r.err;
    EXPECT_NE(r.err.find("b-nope"), std::string::npos) << op << ": " << r.err;
  }
}

// Small CLI manners: an endpoint without its transport and a negative
// thread count are bad input with a short message that says what to write.
TEST(FarmCli, EndpointWithoutTransportAndNegativeThreadsSayWhatToWrite) {
  TempDir tmp;
  CliResult r = run_cli(tmp.path(), "status", {"status", "--coordinator", "127.0.0.1:15555"});
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("tcp://127.0.0.1:15555"), std::string::npos) << r.err;
  r = run_cli(tmp.path(), "worker", {"worker", "--connect", "127.0.0.1:15555"});
  EXPECT_EQ(r.status, 2) << r.err;
  std::ofstream(tmp / "spec.toml") << "scene = \"nothing.gltf\"\n";
  r = run_cli(tmp.path(), "render",
              {"render", (tmp / "spec.toml").string(), "--frame", "0", "--out",
               (tmp / "x.exr").string(), "--threads", "-2"});
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_LT(r.err.size(), 200u) << r.err;
  EXPECT_NE(r.err.find("--threads"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace dofarm::farm_testing
