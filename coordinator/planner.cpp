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

Plan plan_batch(const JobSpec& spec, std::optional<double> seconds_per_pixel) {
  Plan plan;
  plan.tile_side = tile_side(spec, seconds_per_pixel);
  plan.shards = shard_ranges(spec.frame_start, spec.frame_end, spec.per_shard);
  const std::vector<Rect> rects = tile_rects(spec.width, spec.height, plan.tile_side);
  for (const ShardRange& shard : plan.shards) {
    PlannedTask pack;
    pack.kind = TaskKind::kPackShard;
    pack.shard = shard.index;
    for (int frame = shard.frame_start; frame <= shard.frame_end; ++frame) {
      for (const Rect& r : rects) {
        pack.depends_on.push_back(static_cast<int>(plan.tasks.size()));
        plan.tasks.push_back({TaskKind::kRenderTile, frame, r, shard.index, {}});
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
  return std::clamp(static_cast<int>(rounded), std::min(16, largest), largest);
}

std::vector<Rect> tile_rects(int width, int height, int side) {
  DOFARM_CHECK_OP(side, >, 0);
  std::vector<Rect> rects;
  for (int y = 0; y < height; y += side) {
    for (int x = 0; x < width; x += side) {
      rects.push_back({x, y, std::min(side, width - x), std::min(side, height - y)});
    }
  }
  return rects;
}

std::vector<ShardRange> shard_ranges(int frame_start, int frame_end, int per_shard) {
  DOFARM_CHECK_OP(per_shard, >, 0);
  std::vector<ShardRange> shards;
  for (int first = frame_start, k = 0; first <= frame_end; first += per_shard, ++k) {
    shards.push_back({k, first, std::min(first + per_shard - 1, frame_end), shard_file_name(k)});
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
