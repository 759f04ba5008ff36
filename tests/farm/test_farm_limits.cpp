// Defect 7 of issue 10: frames.start = frames.end = 2147483647 (allowed by
// jobs/README.md) ended in std::bad_alloc in the planner. Now the largest
// frame number (2^24 - 1, exact in the shard's float camera table) renders,
// and a spec beyond the documented limits (jobs/README.md, "Limits"), that
// one included, is bad input: exit 2 with the key named, nothing written.
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

// One camera key, a still camera (TinyJob puts a key after the last frame).
fs::path write_last_frame_job(const fs::path& dir) {
  std::ostringstream s;
  s << "scene = \"" << cornell_scene().string() << "\"\nseed = 3\n\n"
    << "[image]\nwidth = 16\nheight = 16\n\n"
    << "[frames]\nstart = 16777215\nend = 16777215\nper_shard = 4\n\n"
    << "[[camera.key]]\nframe = 0\nposition = [0.0, 1.0, 3.9]\nlook_at = [0.0, 1.0, 0.0]\n"
    << "fov = 38.0\nfocal_distance = 3.55\naperture = 0.05\n\n"
    << "[buffers]\nversions = 1\nreference_spp = 2\nalbedo_ref_spp = 1\n\n"
    << "[farm]\ntile = 8\n";
  const fs::path path = dir / "last.toml";
  write_text(path, s.str());
  return path;
}

TEST(FarmLimits, TheLargestFrameNumberRendersIntoOneShard) {
  TempDir tmp;
  const fs::path job = write_last_frame_job(tmp.path());
  CliResult r = run_cli(
      tmp.path(), "run",
      {"run", job.string(), "--out", (tmp / "out").string(), "--workers", "1", "--threads", "1"});
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

TEST(FarmLimits, RunBeyondTheLimitsExitsTwoAndWritesNothing) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});
  struct Case {
    std::vector<std::string> sets;
    std::string key;
  };
  const Case cases[] = {
      {{"frames.start=2147483647", "frames.end=2147483647"}, "\"frames.start\""},
      {{"frames.end=1000000"}, "\"frames.end\""},
      {{"frames.start=0", "frames.end=2147483647"}, "\"frames.end\""},
      {{"image.width=16384", "image.height=16384", "farm.tile=8"}, "\"farm.tile\""},
      {{"frames.per_shard=4097"}, "\"frames.per_shard\""},
  };
  int n = 0;
  for (const Case& c : cases) {
    const fs::path out = tmp / ("out" + std::to_string(n));
    std::vector<std::string> args = {"run", job.string(), "--out", out.string(), "--workers", "1"};
    for (const std::string& s : c.sets) args.insert(args.end(), {"--set", s});
    CliResult r = run_cli(tmp.path(), "run" + std::to_string(n++), args, 30);
    EXPECT_EQ(r.status, 2) << c.sets[0] << ": " << r.out << r.err;
    EXPECT_NE(r.err.find(c.key), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out)) << c.sets[0] << ": the output folder was created";
  }
}

TEST(FarmLimits, SubmitBeyondTheLimitsIsRefusedBeforeItIsSent) {
  TempDir tmp;
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 5);
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});
  CliResult r = run_cli(tmp.path(), "submit",
                        {"submit", job.string(), "--coordinator", coord.endpoint(), "--out",
                         (tmp / "out").string(), "--set", "frames.end=2147483647"});
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("\"frames.end\""), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(tmp / "out"));
  EXPECT_TRUE(farm_status(coord.endpoint()).at("batches").empty());
  EXPECT_TRUE(coord.child().running()) << coord.child().describe();
}

}  // namespace
}  // namespace dofarm::farm_testing
