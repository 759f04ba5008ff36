#include "coordinator/planner.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "common/error.h"

namespace dofarm::coordinator {

const char* to_string(TaskKind kind) {
  switch (kind) {
    case TaskKind::kRenderTile:
      return "render_tile";
    case TaskKind::kPackShard:
      return "pack_shard";
  }
  return "?";
}

void check_plan_limits(const JobSpec& spec, int side) {
  const FileLoc loc{spec.spec_path.string()};
  if (spec.frame_count() <= 0 || spec.frame_count() > kMaxFramesPerBatch)
    throw SpecError(loc, "frames",
                    "frames " + std::to_string(spec.frame_start) + ".." +
                        std::to_string(spec.frame_end) + ": " + std::to_string(spec.frame_count()) +
                        " frames, a batch has at least 1 " + "and at most the " +
                        std::to_string(kMaxFramesPerBatch) + " one batch may have");
  const int64_t tasks = batch_task_count(spec, side);
  if (tasks > kMaxTasksPerBatch)
    throw SpecError(loc, "farm.tile",
                    "the plan has " + std::to_string(tasks) + " tasks (tile side " +
                        std::to_string(side) + "), more than the " +
                        std::to_string(kMaxTasksPerBatch) + " one batch may have");
  const int64_t shard_tiles = shard_tile_count(spec, side);
  if (shard_tiles > kMaxTilesPerShard)
    throw SpecError(loc, "farm.tile",
                    "a shard has " + std::to_string(shard_tiles) + " tiles (tile side " +
                        std::to_string(side) + "), more than the " +
                        std::to_string(kMaxTilesPerShard) + " one pack task may take");
}

Plan plan_batch(const JobSpec& spec, std::optional<double> seconds_per_pixel) {
  DOFARM_CHECK_OP(spec.per_shard, >, 0);
  Plan plan;
  plan.tile_side = tile_side(spec, seconds_per_pixel);
  // Before anything is allocated: a plan's size is known from the spec.
  check_plan_limits(spec, plan.tile_side);
  plan.shards = shard_ranges(spec.frame_start, spec.frame_end, spec.per_shard);
  const std::vector<Rect> rects = tile_rects(spec.width, spec.height, plan.tile_side);
  plan.tasks.reserve(size_t(batch_task_count(spec, plan.tile_side)));
  for (const ShardRange& shard : plan.shards) {
    PlannedTask pack;
    pack.kind = TaskKind::kPackShard;
    pack.shard = shard.index;
    // 64-bit frame counter: the last frame may be INT_MAX.
    for (int64_t frame = shard.frame_start; frame <= shard.frame_end; ++frame) {
      for (const Rect& r : rects) {
        pack.depends_on.push_back(static_cast<int>(plan.tasks.size()));
        plan.tasks.push_back({TaskKind::kRenderTile, int(frame), r, shard.index, {}});
      }
    }
    plan.tasks.push_back(std::move(pack));
  }
  return plan;
}

int tile_side(const JobSpec& spec, std::optional<double> seconds_per_pixel) {
  if (spec.task_seconds <= 0) return spec.tile;
  const double spp = seconds_per_pixel.value_or(estimate_seconds_per_pixel(spec));
  DOFARM_CHECK_OP(spp, >, 0.0);
  const int largest = std::max(spec.width, spec.height);
  const double side = std::sqrt(spec.task_seconds / spp);
  // Multiples of 8 keep tiles aligned with the renderer's pixel blocks. At
  // least 16 so that per-task overhead (scene load, staging file) never
  // dominates; at most the larger image side, where one tile is the frame.
  const double rounded = std::round(std::min(side, 1e6) / 8.0) * 8.0;
  int chosen = std::clamp(static_cast<int>(rounded), std::min(16, largest), largest);
  // Larger tiles where the batch would exceed kMaxTasksPerBatch or a shard
  // kMaxTilesPerShard: one tile per frame always fits the first, and the
  // second whenever per_shard <= kMaxTilesPerShard.
  while (chosen < largest && (batch_task_count(spec, chosen) > kMaxTasksPerBatch ||
                              shard_tile_count(spec, chosen) > kMaxTilesPerShard))
    chosen = std::min(largest, chosen * 2);
  return chosen;
}

std::vector<Rect> tile_rects(int width, int height, int side) {
  DOFARM_CHECK_OP(side, >, 0);
  std::vector<Rect> rects;
  // 64-bit positions: y + side must not overflow for any int size.
  for (int64_t y = 0; y < height; y += side) {
    for (int64_t x = 0; x < width; x += side) {
      rects.push_back({int(x), int(y), int(std::min<int64_t>(side, width - x)),
                       int(std::min<int64_t>(side, height - y))});
    }
  }
  return rects;
}

std::vector<ShardRange> shard_ranges(int frame_start, int frame_end, int per_shard) {
  DOFARM_CHECK_OP(per_shard, >, 0);
  std::vector<ShardRange> shards;
  // 64-bit: first + per_shard passes INT_MAX after the last shard of a range
  // that ends there.
  int k = 0;
  for (int64_t first = frame_start; first <= frame_end; first += per_shard, ++k) {
    const int64_t last = std::min<int64_t>(first + per_shard - 1, frame_end);
    shards.push_back({k, int(first), int(last), shard_file_name(k)});
  }
  return shards;
}

std::string shard_file_name(int shard_index) {
  char name[32];
  std::snprintf(name, sizeof name, "shard-%05d.h5", shard_index);
  return name;
}

double estimate_seconds_per_pixel(const JobSpec& spec) {
  // One worker (all its threads) traces on the order of 2 million camera
  // paths per second on a mid-range node and a small interior scene. This is
  // only a first guess: a caller with measured tile times passes those.
  constexpr double kSecondsPerPath = 5e-7;
  // With an error target the reference stops somewhere below its cap; assume
  // a quarter of it.
  const double reference =
      spec.reference_error > 0 ? spec.reference_max_spp / 4.0 : spec.reference_spp;
  const double paths = spec.versions + reference + spec.albedo_ref_spp;
  return paths * kSecondsPerPath;
}

}  // namespace dofarm::coordinator
