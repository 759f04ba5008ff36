// The planner: a batch (one job spec) -> frames -> render_tile tasks, plus one
// pack_shard task per shard that depends on every tile of the shard's frames.
//
// Tiles. With spec.task_seconds == 0 the tile side is spec.tile. With
// task_seconds > 0 it is sized so that one tile takes about that long:
//   side = sqrt(task_seconds / seconds_per_pixel), rounded to a multiple of 8,
//   clamped to [16, max(width, height)],
// where seconds_per_pixel is a measurement (from earlier tiles of the scene)
// or, without one, estimate_seconds_per_pixel(spec). Tiles are side x side
// squares in row-major order from the top-left; the last column and row are
// narrower where the image is not a multiple of the side. They cover every
// pixel of every frame exactly once.
//
// Shards. Shard k covers frames [start + k*per_shard, start + (k+1)*per_shard - 1]
// clipped to the batch's last frame (the last shard may be shorter); its file
// is shard_file_name(k), "shard-00007.h5", in the batch's output folder.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "common/image.h"
#include "common/jobspec.h"

namespace dofarm::coordinator {

enum class TaskKind { kRenderTile, kPackShard };
const char* to_string(TaskKind kind);  // "render_tile", "pack_shard"

struct ShardRange {
  int index = 0;
  int frame_start = 0;
  int frame_end = 0;  // inclusive
  std::string file;   // shard_file_name(index)
};

struct PlannedTask {
  TaskKind kind = TaskKind::kRenderTile;
  int frame = -1;               // render_tile: absolute frame; pack_shard: -1
  Rect rect;                    // render_tile: the pixels to render; pack_shard: empty
  int shard = 0;                // the shard the task belongs to (or packs)
  std::vector<int> depends_on;  // indices into Plan::tasks
};

struct Plan {
  int tile_side = 0;
  std::vector<ShardRange> shards;
  // Per shard: its render tiles (frame-major, then row-major), then its pack
  // task, which depends on exactly those tiles.
  std::vector<PlannedTask> tasks;
};

// Throws SpecError (nothing allocated) for a spec beyond the limits of
// jobs/README.md, "Limits": more than kMaxFramesPerBatch frames, or more than
// kMaxTasksPerBatch tasks with the chosen tile side. Specs that
// load_job_spec() accepted are always within them.
Plan plan_batch(const JobSpec& spec, std::optional<double> seconds_per_pixel = std::nullopt);
// The check plan_batch() makes first: tasks counted, not made.
void check_plan_limits(const JobSpec& spec, int tile_side);

// The tile side plan_batch() uses (see the rule above; with task_seconds it
// is doubled, up to the larger image side, while the batch would have more
// than kMaxTasksPerBatch tasks).
int tile_side(const JobSpec& spec, std::optional<double> seconds_per_pixel = std::nullopt);
// Row-major side x side tiles covering a width x height image exactly once.
std::vector<Rect> tile_rects(int width, int height, int side);
std::vector<ShardRange> shard_ranges(int frame_start, int frame_end, int per_shard);
std::string shard_file_name(int shard_index);
// A rough cost model for a first plan, before any tile has been measured:
// seconds of one worker per pixel for all the buffers a tile renders.
double estimate_seconds_per_pixel(const JobSpec& spec);

}  // namespace dofarm::coordinator
