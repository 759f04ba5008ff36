// Turning a job spec on disk into a job value (common/job_snapshot.h): done
// once, by `dofarm run` and `dofarm submit`, before anything is written.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "common/job_snapshot.h"

namespace dofarm::render {
class Scene;
}

namespace dofarm::worker {

struct ResolvedJob {
  JobSnapshot snapshot;
  JobSpec spec;  // as read from the user's files, completed from the scene
  // Each input: the user's file and its path in the job folder ("files/...").
  std::vector<std::pair<std::filesystem::path, std::string>> files;
};

// Loads the job's scene and environment map; anything wrong with them is a
// SpecError naming the spec file and the key ("scene" or "environment.map").
std::shared_ptr<const render::Scene> load_scene_checked(const JobSpec& spec);

// What the spec leaves to the scene, filled in and checked once the scene is
// loaded (`dofarm run`, `submit` and `render` call it; the canonical spec
// then holds the result, so workers and the coordinator never redo it):
// - camera.from_scene on a scene without a camera is a SpecError at the key;
// - an image size the spec does not give follows the scene camera's aspect
//   (longer side 512, or the other side from the one given), within
//   kMaxImageSide and the batch limits; a size whose ratio differs from the
//   camera's logs a warning saying what the image crops or adds;
// - every frame's focus (focus_point in front of the camera, autofocus
//   hitting something) is resolved once, so a bad one fails here, located.
void complete_spec_from_scene(JobSpec& spec, const render::Scene& scene);

// Reads the spec (a regular file of at most kMaxSpecBytes, never a FIFO or
// device), applies `overrides`, and loads the scene and environment map as
// a worker will, so a scene that is not a glTF, has no triangles or light,
// or an environment map that is not an image is a SpecError naming the spec
// file and the key, before anything exists. Every file that load read is
// hashed into the snapshot.
ResolvedJob resolve_job(const std::filesystem::path& spec_path,
                        const std::vector<std::string>& overrides);

// Copies the job into OUT/.dofarm-jobs/HASH/ (job.json, job.toml, files/)
// unless a complete, verified copy is there; each file's copied bytes are
// checked against the snapshot (a file changed since resolve_job is an
// error). Written to a temporary folder and renamed, so the job folder is
// either absent or complete. Returns the job folder.
std::filesystem::path materialize_job(const ResolvedJob& job, const std::filesystem::path& out_dir);

}  // namespace dofarm::worker
