#include "worker/tasks.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "common/checksum.h"
#include "common/content_hash.h"
#include "common/exr_io.h"
#include "common/shard.h"
#include "worker/render/render_job.h"
#include "worker/render/scene.h"

namespace dofarm::worker {

namespace fs = std::filesystem;

std::shared_ptr<const LoadedJob> JobCache::get(const fs::path& out_dir, const std::string& hash) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (auto it = jobs_.find(hash); it != jobs_.end()) return it->second;
  auto job = std::make_shared<const LoadedJob>(load_job(out_dir, hash));
  if (jobs_.size() >= 8) jobs_.clear();  // a worker moves between few jobs
  jobs_.emplace(hash, job);
  return job;
}

std::shared_ptr<const render::Scene> SceneCache::get(const JobSpec& spec, const std::string& key) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!scene_ || key != key_) {
    scene_.reset();  // free the old BVH before building the new one
    scene_ = render::load_scene(spec);
    key_ = key;
  }
  return scene_;
}

void SceneCache::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  scene_.reset();
  key_.clear();
}

StagedTile render_tile(const JobSpec& spec, const render::Scene& scene, const std::string& batch,
                       const fs::path& out_dir, int frame, Rect rect,
                       const render::RenderOptions& options) {
  auto t0 = std::chrono::steady_clock::now();
  FrameBuffers fb = render::render_frame(scene, spec, frame, rect, options);
  StagedTile t;
  t.frame = frame;
  t.rect = rect;
  t.path = staged_tile_path(out_dir, batch, frame, rect);
  t.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  t.checksum = write_frame_exr(
      t.path, fb, {{"dofarm.batch", batch}, {"dofarm.render_seconds", std::to_string(t.seconds)}},
      FrameExtent{spec.width, spec.height});
  return t;
}

std::string scene_id(const JobSpec& spec) { return spec.scene.stem().string(); }

std::string scene_hash(const JobSpec& spec) {
  uint64_t h = checksum_file(spec.scene);
  if (spec.environment && !spec.environment->map.empty())
    h ^= checksum_file(spec.environment->map) * 0x9E3779B97F4A7C15ull;
  return checksum_to_string(h);
}

std::string scene_hash(const JobSnapshot& job) {
  ContentHasher h;
  for (const JobInput& in : job.inputs) {
    h.update(in.path);
    h.update("\n", 1);
    h.update(in.hash);
    h.update("\n", 1);
  }
  return h.hex();
}

// Reads one staged tile once: the bytes are checksummed and decoded together.
// Anything wrong with it is a StagedTileError, which the coordinator answers
// by rendering the tile again.
ExrFrame read_staged_tile(const StagedTile& t, int versions) {
  uint64_t sum = 0;
  ExrFrame tile;
  try {
    tile = read_frame_exr(t.path, &sum);
  } catch (const RuntimeError& e) {
    throw StagedTileError(t.path, e.what());
  }
  if (sum != t.checksum)
    throw StagedTileError(t.path, "checksum " + checksum_to_string(sum) + ", expected " +
                                      checksum_to_string(t.checksum));
  if (!(tile.buffers.rect == t.rect) || tile.buffers.versions != versions)
    throw StagedTileError(t.path, "holds another tile than its name says");
  return tile;
}

ManifestEntry pack_shard(const JobSpec& spec, const fs::path& out_dir, const ShardJob& job) {
  // Every staged tile must exist before the shard's temporary file is
  // created; their contents are checked as they are read, once each. A bad
  // tile aborts the writer, which removes its temporary file: nothing is
  // published and nothing already published is touched.
  for (const StagedTile& t : job.tiles) {
    std::error_code ec;
    if (!fs::exists(t.path, ec)) throw StagedTileError(t.path, "missing");
  }

  ShardInfo info;
  info.batch_id = job.batch;
  info.scene_id = scene_id(spec);
  info.scene_hash = job.scene_hash.empty() ? scene_hash(spec) : job.scene_hash;
  info.job_hash = job.job_hash;
  info.width = spec.width;
  info.height = spec.height;
  info.versions = spec.versions;
  info.spp_reference = spec.reference_error > 0 ? spec.reference_max_spp : spec.reference_spp;
  info.reference_error = spec.reference_error;
  info.spp_albedo_ref = spec.albedo_ref_spp;
  info.seed = spec.seed;
  info.frame_start = job.frame_start;
  info.frame_end = job.frame_end;
  info.renderer_version = DOFARM_VERSION;

  ShardWriter writer(out_dir / job.file, info);
  double render_seconds = 0;
  // 64-bit counter: the last frame may be INT_MAX (jobs/README.md, "Limits").
  for (int64_t number = job.frame_start; number <= job.frame_end; ++number) {
    const int f = int(number);
    FrameBuffers frame;
    frame.allocate(spec.width, spec.height, spec.versions);
    frame.rect = Rect{0, 0, spec.width, spec.height};
    int64_t covered = 0;
    for (const StagedTile& t : job.tiles) {
      if (t.frame != f) continue;
      ExrFrame tile = read_staged_tile(t, spec.versions);
      frame.paste(tile.buffers);
      frame.camera = tile.buffers.camera;
      covered += int64_t(t.rect.w) * t.rect.h;
      // The render time of each tile travels in its staged file's header.
      double seconds = t.seconds;
      if (seconds <= 0) {
        auto it = tile.attributes.find("dofarm.render_seconds");
        if (it != tile.attributes.end()) seconds = std::strtod(it->second.c_str(), nullptr);
      }
      if (std::isfinite(seconds) && seconds > 0) render_seconds += seconds;
    }
    if (covered != int64_t(spec.width) * spec.height)
      throw RuntimeError("shard " + job.file + ": the staged tiles of frame " + std::to_string(f) +
                         " cover " + std::to_string(covered) + " of " +
                         std::to_string(int64_t(spec.width) * spec.height) + " pixels");
    writer.add_frame(frame);
  }
  writer.set_render_seconds(render_seconds);
  ShardWriteResult written = writer.commit();
  ManifestEntry entry = manifest_entry(info, written);
  add_to_manifest(out_dir, entry);
  // The shard is published: its staged tiles are no longer needed.
  for (const StagedTile& t : job.tiles) {
    std::error_code ec;
    fs::remove(t.path, ec);
  }
  return entry;
}

}  // namespace dofarm::worker
