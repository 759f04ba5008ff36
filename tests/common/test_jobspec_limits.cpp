// The limits of one batch (jobs/README.md, "Limits"): frame numbers up to
// 2^24 - 1 are accepted (frames.start = frames.end = 2147483647 used to end
// in std::bad_alloc), ranges and plans beyond the limits are refused with a
// located error naming the key, also when an override makes them so. The
// bad-spec corpus (tests/data/bad_specs/frame*, tasks_*, tiles_*) covers the
// file locations.
#include <gtest/gtest.h>

#include <climits>
#include <filesystem>
#include <string>

#include "common/error.h"
#include "common/jobspec.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;

std::string spec_text(const std::string& frames) {
  return "scene = \"" + (fs::path(DOFARM_SOURCE_DIR) / "jobs/scenes/cornell.gltf").string() +
         "\"\n[frames]\n" + frames +
         "\n[[camera.key]]\nframe = 0\nposition = [0.0, 1.0, 4.0]\nlook_at = [0.0, 1.0, 0.0]\n";
}

SpecError parse_error(const std::string& text, const std::vector<std::string>& sets = {}) {
  try {
    parse_job_spec(text, "/virtual/job.toml", sets);
  } catch (const SpecError& e) {
    return e;
  }
  ADD_FAILURE() << "accepted:\n" << text;
  return SpecError(FileLoc{}, "", "none");
}

TEST(JobSpecLimits, FrameNumbersUpTo2To24Minus1) {
  const JobSpec spec =
      parse_job_spec(spec_text("start = 16777215\nend = 16777215"), "/virtual/job.toml");
  EXPECT_EQ(spec.frame_start, kMaxFrameNumber);
  EXPECT_EQ(spec.frame_end, kMaxFrameNumber);
  EXPECT_EQ(spec.frame_count(), 1);
  EXPECT_EQ(double(float(kMaxFrameNumber)), double(kMaxFrameNumber)) << "not exact in a float";
  const JobSpec last = parse_job_spec(
      spec_text("start = 16777200\nend = 16777215\nper_shard = 4096"), "/virtual/job.toml");
  EXPECT_EQ(last.per_shard, 4096);
  // The spec: refused with the key, no std::bad_alloc.
  SpecError e = parse_error(spec_text("start = 2147483647\nend = 2147483647"));
  EXPECT_EQ(e.key(), "frames.start");
  EXPECT_EQ(e.loc().line, 3) << e.what();
  SpecError next = parse_error(spec_text("start = 0\nend = 16777216"));
  EXPECT_EQ(next.key(), "frames.end");
}

TEST(JobSpecLimits, FrameCountIsSixtyFourBit) {
  JobSpec spec;
  spec.frame_start = 0;
  spec.frame_end = INT_MAX;
  EXPECT_EQ(spec.frame_count(), int64_t(INT_MAX) + 1);
}

TEST(JobSpecLimits, AMillionFramesAreAcceptedOneMoreIsNot) {
  const JobSpec spec = parse_job_spec(
      spec_text("start = 1000\nend = 1000999\nper_shard = 1000\n[farm]\ntile = 4096"),
      "/virtual/job.toml");
  EXPECT_EQ(spec.frame_count(), kMaxFramesPerBatch);
  SpecError e = parse_error(spec_text("start = 1000\nend = 1001000"));
  EXPECT_EQ(e.key(), "frames.end");
  EXPECT_NE(std::string(e.what()).find("1000001 frames"), std::string::npos) << e.what();
}

TEST(JobSpecLimits, OverrideBeyondTheLimitsIsBlamedOnTheSet) {
  SpecError e = parse_error(spec_text("end = 9"), {"frames.end=1000000"});
  EXPECT_EQ(e.key(), "frames.end");
  EXPECT_EQ(e.loc().line, 0) << e.what();  // the --set, not the file
  EXPECT_NE(std::string(e.what()).find("more than the 1000000"), std::string::npos) << e.what();
  SpecError tile = parse_error(spec_text("end = 99"),
                               {"image.width=16384", "image.height=16384", "farm.tile=8"});
  EXPECT_EQ(tile.key(), "farm.tile") << tile.what();
}

TEST(JobSpecLimits, TaskCountSaturatesInsteadOfOverflowing) {
  JobSpec spec;
  spec.width = INT_MAX;
  spec.height = INT_MAX;
  spec.frame_start = 0;
  spec.frame_end = INT_MAX;
  spec.per_shard = 1;
  EXPECT_EQ(batch_task_count(spec, 1), INT64_MAX);
  spec.width = 70;
  spec.height = 40;
  spec.frame_start = 3;
  spec.frame_end = 9;
  spec.per_shard = 3;
  EXPECT_EQ(batch_task_count(spec, 32), 7 * 6 + 3);  // as Planner.EachPackDependsOn... counts
}

TEST(JobSpecLimits, TaskSecondsSpecsAreLeftToThePlanner) {
  // With task_seconds the planner picks tiles large enough; the spec is fine.
  const JobSpec spec = parse_job_spec(
      spec_text("end = 999999\n[image]\nwidth = 16384\nheight = 16384\n[farm]\ntask_seconds = 1"),
      "/virtual/job.toml");
  EXPECT_EQ(spec.frame_count(), 1000000);
}

}  // namespace
}  // namespace dofarm
