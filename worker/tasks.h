// What a worker does for each kind of task, independent of how the task
// arrived (ZeroMQ, a test, the embedded farm).
//
// render_tile: renders one tile of one frame and writes it to a staging file
// (a tile EXR, written atomically) on the shared output filesystem, returning
// its checksum for the coordinator to keep.
// pack_shard: verifies every staged tile of a shard's frames against its
// checksum, pastes them into full frames, writes the shard atomically, adds
// it to the manifest and removes the staged tiles.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "common/error.h"
#include "common/image.h"
#include "common/job_snapshot.h"
#include "common/jobspec.h"
#include "common/manifest.h"
#include "common/staging.h"
#include "worker/render/render_job.h"

namespace dofarm::render {
class Scene;
}

namespace dofarm::worker {

// Where a batch's staged tiles live (common/staging.h: the coordinator checks
// `done` claims against the same paths).
using dofarm::staged_tile_path;
using dofarm::staging_dir;

// Jobs read from their folders (common/job_snapshot.h load_job: every file
// checked against the snapshot), kept by job hash: a worker checks a job's
// files once, not per task.
class JobCache {
 public:
  std::shared_ptr<const LoadedJob> get(const std::filesystem::path& out_dir,
                                       const std::string& hash);

 private:
  std::mutex mutex_;
  std::map<std::string, std::shared_ptr<const LoadedJob>> jobs_;
};

// Keeps loaded scenes (and their BVH) across tasks of the same job, keyed by
// the job hash: the same key is the same bytes.
class SceneCache {
 public:
  std::shared_ptr<const render::Scene> get(const JobSpec& spec, const std::string& key);
  void clear();

 private:
  std::mutex mutex_;
  std::string key_;
  std::shared_ptr<const render::Scene> scene_;
};

struct StagedTile {
  int frame = 0;
  Rect rect;
  std::filesystem::path path;
  uint64_t checksum = 0;
  double seconds = 0;
};

// Renders and stages one tile.
StagedTile render_tile(const JobSpec& spec, const render::Scene& scene, const std::string& batch,
                       const std::filesystem::path& out_dir, int frame, Rect rect,
                       const render::RenderOptions& options = {});

// A staged tile that is missing, truncated or does not match its checksum.
// The coordinator answers by rendering that tile again.
class StagedTileError : public RuntimeError {
 public:
  StagedTileError(std::filesystem::path path, const std::string& why)
      : RuntimeError("staged tile " + path.string() + ": " + why), path_(std::move(path)) {}
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};


struct ShardJob {
  std::string batch;
  int shard_index = 0;
  int frame_start = 0, frame_end = 0;  // inclusive
  std::string file;                    // shard file name in out_dir
  std::vector<StagedTile> tiles;       // every tile of every frame of the shard
  // The job's hash and the content hash of its scene files (scene_hash of
  // the snapshot); empty: the shard says scene_hash(spec) and no job.
  std::string job_hash;
  std::string scene_hash;
};

// Packs a shard (see above); returns its manifest entry. Throws
// StagedTileError for a bad tile, RuntimeError for IO failures.
ManifestEntry pack_shard(const JobSpec& spec, const std::filesystem::path& out_dir,
                         const ShardJob& job);

// A stable id and content hash for a job's scene (file and environment map).
std::string scene_id(const JobSpec& spec);
std::string scene_hash(const JobSpec& spec);
// The content hash over every input file of a snapshot (the scene, its
// buffers and textures, the environment map), by path and hash.
std::string scene_hash(const JobSnapshot& job);

}  // namespace dofarm::worker
