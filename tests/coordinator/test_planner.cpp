// Planner: tiles cover each frame exactly once for any size, shards split the
// frame range as documented, each pack waits for exactly its shard's tiles,
// and task_seconds sizes tiles by the documented rule.
#include <gtest/gtest.h>

#include <chrono>
#include <climits>
#include <set>
#include <vector>

#include "common/error.h"
#include "coordinator/planner.h"

namespace dofarm::coordinator {
namespace {

JobSpec spec_of(int width, int height, int start, int end, int per_shard, int tile) {
  JobSpec spec;
  spec.width = width;
  spec.height = height;
  spec.frame_start = start;
  spec.frame_end = end;
  spec.per_shard = per_shard;
  spec.tile = tile;
  return spec;
}

TEST(Planner, TilesCoverEveryPixelExactlyOnce) {
  struct Case {
    int w, h, side;
  };
  for (const Case& c : {Case{64, 64, 64}, Case{512, 512, 64}, Case{100, 37, 16}, Case{1, 1, 8},
                        Case{65, 129, 64}, Case{30, 20, 64}}) {
    std::vector<int> hits(c.w * c.h, 0);
    for (const Rect& r : tile_rects(c.w, c.h, c.side)) {
      ASSERT_GT(r.w, 0);
      ASSERT_GT(r.h, 0);
      ASSERT_LE(r.w, c.side);
      ASSERT_LE(r.h, c.side);
      for (int y = r.y; y < r.y + r.h; ++y) {
        for (int x = r.x; x < r.x + r.w; ++x) {
          ASSERT_TRUE(x >= 0 && x < c.w && y >= 0 && y < c.h) << x << "," << y;
          ++hits[y * c.w + x];
        }
      }
    }
    for (int i = 0; i < c.w * c.h; ++i) {
      ASSERT_EQ(hits[i], 1) << c.w << "x" << c.h << " side " << c.side << " pixel " << i;
    }
  }
}

TEST(Planner, EdgeTilesAreNarrower) {
  const std::vector<Rect> rects = tile_rects(100, 37, 32);
  ASSERT_EQ(rects.size(), 8u);  // 4 columns x 2 rows
  EXPECT_EQ(rects[3], (Rect{96, 0, 4, 32}));
  EXPECT_EQ(rects[7], (Rect{96, 32, 4, 5}));
}

TEST(Planner, ShardRangesSplitFramesAndTheLastIsShorter) {
  const std::vector<ShardRange> shards = shard_ranges(10, 44, 16);
  ASSERT_EQ(shards.size(), 3u);
  EXPECT_EQ(shards[0].frame_start, 10);
  EXPECT_EQ(shards[0].frame_end, 25);
  EXPECT_EQ(shards[1].frame_start, 26);
  EXPECT_EQ(shards[1].frame_end, 41);
  EXPECT_EQ(shards[2].frame_start, 42);
  EXPECT_EQ(shards[2].frame_end, 44);
  EXPECT_EQ(shards[2].index, 2);
  EXPECT_EQ(shards[2].file, "shard-00002.h5");
  EXPECT_EQ(shard_file_name(12345), "shard-12345.h5");
  EXPECT_EQ(shard_ranges(0, 0, 16).size(), 1u);
}

TEST(Planner, EachPackDependsOnExactlyTheTilesOfItsFrames) {
  const JobSpec spec = spec_of(70, 40, 3, 9, 3, 32);  // 3x2 tiles, shards 3-5, 6-8, 9
  const Plan plan = plan_batch(spec);
  ASSERT_EQ(plan.shards.size(), 3u);
  int packs = 0;
  std::set<int> depended;
  for (size_t i = 0; i < plan.tasks.size(); ++i) {
    const PlannedTask& t = plan.tasks[i];
    if (t.kind == TaskKind::kRenderTile) {
      EXPECT_TRUE(t.depends_on.empty());
      const ShardRange& s = plan.shards[t.shard];
      EXPECT_GE(t.frame, s.frame_start);
      EXPECT_LE(t.frame, s.frame_end);
      continue;
    }
    ++packs;
    const ShardRange& s = plan.shards[t.shard];
    const size_t expected = static_cast<size_t>(s.frame_end - s.frame_start + 1) * 6;
    EXPECT_EQ(t.depends_on.size(), expected) << "shard " << t.shard;
    for (int d : t.depends_on) {
      ASSERT_LT(static_cast<size_t>(d), i) << "a dependency comes before its pack";
      EXPECT_EQ(plan.tasks[d].kind, TaskKind::kRenderTile);
      EXPECT_EQ(plan.tasks[d].shard, t.shard);
      EXPECT_TRUE(depended.insert(d).second) << "tile " << d << " in two packs";
    }
  }
  EXPECT_EQ(packs, 3);
  EXPECT_EQ(depended.size(), 7u * 6u);  // every tile of every frame, once
  EXPECT_EQ(plan.tasks.size(), 7u * 6u + 3u);
}

TEST(Planner, FixedTileSideWithoutTaskSeconds) {
  const JobSpec spec = spec_of(512, 256, 0, 0, 1, 48);
  EXPECT_EQ(tile_side(spec, 1e-3), 48);  // a measurement changes nothing
}

TEST(Planner, TaskSecondsSizeTilesBySqrtRoundedAndClamped) {
  JobSpec spec = spec_of(1024, 512, 0, 0, 1, 64);
  spec.task_seconds = 60;
  // sqrt(60 / 6e-3) = 100 -> nearest multiple of 8 is 104 (100/8 = 12.5 rounds up).
  EXPECT_EQ(tile_side(spec, 6e-3), 104);
  // sqrt(60 / 1e-2) = 77.46 -> 80.
  EXPECT_EQ(tile_side(spec, 1e-2), 80);
  // Very expensive pixels: clamped up to 16.
  EXPECT_EQ(tile_side(spec, 10.0), 16);
  // Very cheap pixels: clamped down to the larger image side.
  EXPECT_EQ(tile_side(spec, 1e-9), 1024);
  // Without a measurement the estimate is used; the rule still holds.
  const int estimated = tile_side(spec);
  EXPECT_EQ(estimated % 8, 0);
  EXPECT_GE(estimated, 16);
  EXPECT_LE(estimated, 1024);
  EXPECT_EQ(plan_batch(spec, 1e-2).tile_side, 80);
}

// Defect 7 of issue 10: frames.start = frames.end = 2147483647 (allowed by
// jobs/README.md) overflowed the frame loops and ended in std::bad_alloc.
TEST(PlannerLimits, IntMaxFrameIsOneShardOfOneFrame) {
  const JobSpec spec = spec_of(40, 20, INT_MAX, INT_MAX, 16, 16);
  const Plan plan = plan_batch(spec);
  ASSERT_EQ(plan.shards.size(), 1u);
  EXPECT_EQ(plan.shards[0].frame_start, INT_MAX);
  EXPECT_EQ(plan.shards[0].frame_end, INT_MAX);
  ASSERT_EQ(plan.tasks.size(), 3u * 2u + 1u);
  for (size_t i = 0; i + 1 < plan.tasks.size(); ++i) EXPECT_EQ(plan.tasks[i].frame, INT_MAX);
  EXPECT_EQ(plan.tasks.back().depends_on.size(), 6u);
}

TEST(PlannerLimits, ShardRangesEndingAtIntMaxDoNotWrap) {
  const std::vector<ShardRange> shards = shard_ranges(INT_MAX - 5, INT_MAX, 4);
  ASSERT_EQ(shards.size(), 2u);
  EXPECT_EQ(shards[0].frame_start, INT_MAX - 5);
  EXPECT_EQ(shards[0].frame_end, INT_MAX - 2);
  EXPECT_EQ(shards[1].frame_start, INT_MAX - 1);
  EXPECT_EQ(shards[1].frame_end, INT_MAX);
  // A shard larger than what is left of the int range.
  const std::vector<ShardRange> one = shard_ranges(INT_MAX - 1, INT_MAX, INT_MAX);
  ASSERT_EQ(one.size(), 1u);
  EXPECT_EQ(one[0].frame_end, INT_MAX);
}

TEST(PlannerLimits, TileRectsOfTheLargestImageWithTheLargestTile) {
  const std::vector<Rect> rects = tile_rects(INT_MAX, 1, INT_MAX - 1);
  ASSERT_EQ(rects.size(), 2u);
  EXPECT_EQ(rects[1], (Rect{INT_MAX - 1, 0, 1, 1}));
}

// Refused before anything is allocated: each case must answer at once.
TEST(PlannerLimits, HugePlansAreRefusedBeforeTheyAreMade) {
  struct Case {
    const char* what;
    JobSpec spec;
  };
  const Case cases[] = {
      {"every int frame", spec_of(64, 64, 0, INT_MAX, 16, 64)},
      {"a million and one frames", spec_of(64, 64, 0, 1000000, 16, 64)},
      {"huge images with tiny tiles", spec_of(16384, 16384, 0, 99, 100, 8)},
      {"int-sized images", spec_of(INT_MAX, INT_MAX, 0, 0, 1, 8)},
  };
  for (const Case& c : cases) {
    const auto t0 = std::chrono::steady_clock::now();
    try {
      plan_batch(c.spec);
      ADD_FAILURE() << c.what << ": planned";
    } catch (const SpecError& e) {
      EXPECT_NE(std::string(e.what()).find("one batch may have"), std::string::npos)
          << c.what << ": " << e.what();
    }
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 1.0)
        << c.what;
  }
}

TEST(PlannerLimits, TheLargestAllowedBatchIsPlanned) {
  // A million frames at one tile each plus a pack per frame: 2,000,000 tasks.
  const JobSpec spec = spec_of(64, 64, INT_MAX - 999999, INT_MAX, 1, 64);
  const Plan plan = plan_batch(spec);
  EXPECT_EQ(int64_t(plan.tasks.size()), kMaxTasksPerBatch);
  EXPECT_EQ(plan.shards.back().frame_end, INT_MAX);
  EXPECT_EQ(plan.shards.back().index, 999999);
}

TEST(PlannerLimits, TaskSecondsGrowsTilesToStayWithinTheTaskLimit) {
  JobSpec spec = spec_of(16384, 16384, 0, 999, 100, 64);
  spec.task_seconds = 1;
  // Very expensive pixels would give 16 px tiles: 1,048,576 per frame.
  const int side = tile_side(spec, 10.0);
  EXPECT_LE(batch_task_count(spec, side), kMaxTasksPerBatch) << "side " << side;
  EXPECT_EQ(side % 8, 0);
  EXPECT_LE(shard_tile_count(spec, side), kMaxTilesPerShard) << "side " << side;
  EXPECT_TRUE(batch_task_count(spec, side / 2) > kMaxTasksPerBatch ||
              shard_tile_count(spec, side / 2) > kMaxTilesPerShard)
      << "the side is not minimal";
  // With one frame per shard the task limit is the one that binds.
  spec.per_shard = 1;
  const int one = tile_side(spec, 10.0);
  EXPECT_LE(batch_task_count(spec, one), kMaxTasksPerBatch) << "side " << one;
  EXPECT_GT(batch_task_count(spec, one / 2), kMaxTasksPerBatch) << "side " << one;
  // A job small enough keeps the rule's side.
  JobSpec small = spec_of(1024, 512, 0, 0, 1, 64);
  small.task_seconds = 60;
  EXPECT_EQ(tile_side(small, 10.0), 16);
}

}  // namespace
}  // namespace dofarm::coordinator
