// A job as a value (DESIGN.md "The farm", STYLE rule 17). At `run` and
// `submit` the effective spec (the TOML file plus its --set overrides) is
// resolved once into a snapshot: the spec written out again in a canonical
// form, and every file rendering it reads (the scene, its buffers and
// textures, the environment map) with its size and content hash. The job
// hash is the content hash of that snapshot, so two jobs are the same job
// exactly when they render the same thing from the same bytes, whatever
// their files are called or wherever they are.
//
// The snapshot and copies of its files live in the output folder,
// OUT/.dofarm-jobs/HASH/ (job.json, job.toml, files/...), written once and
// never changed. Workers read the job from there and check every file
// against its hash before they use it; editing or replacing the original
// spec or scene after submit changes nothing in the batch.
//
// An output folder belongs to one job: OUT/.dofarm-owner.json names it.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "common/jobspec.h"

namespace dofarm {

inline constexpr const char* kJobSchema = "dofarm.job/1";
// Limits: a spec file, a snapshot (job.json), the ownership record.
inline constexpr uint64_t kMaxSpecBytes = 1 << 20;
inline constexpr uint64_t kMaxSnapshotBytes = 1 << 20;
inline constexpr size_t kMaxJobInputs = 4096;

struct JobInput {
  std::string path;  // relative to the job folder, '/'-separated: "files/..."
  uint64_t size = 0;
  std::string hash;  // content_hash()
  bool operator==(const JobInput&) const = default;
};

struct JobSnapshot {
  std::string spec_toml;          // canonical; paths relative to the job folder
  std::vector<JobInput> inputs;   // sorted by path
  // Where it came from: shown to people, not part of the hash.
  std::string source_spec;
  std::vector<std::string> source_overrides;

  std::string hash() const;     // content hash of schema, spec and inputs
  std::string to_json(int indent = 2) const;  // the text of job.json (-1: one line)
  // Parses job.json text; throws RuntimeError naming `where` on anything
  // malformed (unknown schema, bad paths, too many inputs, ...).
  static JobSnapshot from_json(const std::string& text, const std::string& where);
};

// The canonical TOML of a resolved spec: every key at its value (defaults
// included), sections in the order of jobs/README.md, numbers written so
// that reading them back gives the same values. `scene` and `environment_map`
// replace the spec's own paths (relative to where the TOML will live).
std::string canonical_spec_toml(const JobSpec& spec, const std::string& scene,
                                const std::string& environment_map);

// The differences between two canonical specs, one "key: A -> B" per line,
// keys in file order.
std::vector<std::string> spec_differences(const std::string& a_toml, const std::string& b_toml);

std::filesystem::path jobs_dir(const std::filesystem::path& out_dir);  // OUT/.dofarm-jobs
std::filesystem::path job_dir(const std::filesystem::path& out_dir, const std::string& hash);

// A job read back from its folder, every claim checked: job.json is a
// regular file whose snapshot hashes to `hash`, every input is a regular
// file (no symlink) of its size and hash, and the spec parses. `spec` has
// its paths inside the job folder. Throws RuntimeError saying what does not
// hold.
struct LoadedJob {
  JobSnapshot snapshot;
  JobSpec spec;
};
LoadedJob load_job(const std::filesystem::path& out_dir, const std::string& hash);

// The snapshot of `hash` as stored in job.json, checked against the hash but
// without reading its input files (the coordinator, which renders nothing).
JobSnapshot read_job_snapshot(const std::filesystem::path& out_dir, const std::string& hash);

// OUT/.dofarm-owner.json: which job an output folder belongs to.
struct OutputOwner {
  std::string job;    // job hash
  std::string batch;  // batch id, once known
  std::string spec;   // the source spec, for messages
};
std::filesystem::path owner_file(const std::filesystem::path& out_dir);
std::optional<OutputOwner> read_output_owner(const std::filesystem::path& out_dir);
// Writes the record atomically (temporary file, rename); an existing record
// of another job is never replaced (RuntimeError).
void write_output_owner(const std::filesystem::path& out_dir, const OutputOwner& owner);

// The refusal when `out_dir` belongs to another job: names the folder, the
// batch there and the keys (or input files) that differ. Empty when the
// folder is free or holds this same job.
std::string ownership_conflict(const std::filesystem::path& out_dir, const JobSnapshot& job);
// The same refusal for a batch `batch` of job `other_job` (empty: a batch
// from before snapshots) whose snapshot is `other` (null when unreadable,
// with `other_error` saying why).
std::string conflict_message(const std::filesystem::path& out_dir, const std::string& batch,
                             const std::string& other_job, const JobSnapshot* other,
                             const std::string& other_error, const JobSnapshot& job);

}  // namespace dofarm
