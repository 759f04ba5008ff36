// manifest.json: the list of complete shards in an output folder.
//
// A shard is added only after its writer renamed it into place (ShardWriter
// commit), so every listed shard is complete; the trainer streams exactly the
// listed ones while the farm is still adding more. The manifest itself is
// replaced atomically (temp + fsync + rename + directory fsync), so a reader
// sees the old list or the new one, never half of one.
//
//   {"schema": "dofarm.manifest/1",
//    "shards": [{"file": "shard-00000.h5", "batch_id": "...", "scene_id": "...",
//                "frame_start": 0, "frame_end": 15, "size": 123456,
//                "checksum": "xxh64:0123456789abcdef"}, ...]}
//
// Entries are sorted by file name. Writers in several processes (local
// workers, or workers on nodes sharing the folder) are serialized by an
// flock() on "manifest.json.lock" next to it.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "common/shard.h"

namespace dofarm {

inline constexpr const char* kManifestSchema = "dofarm.manifest/1";
inline constexpr const char* kManifestFile = "manifest.json";

struct ManifestEntry {
  std::string file;  // shard file name, relative to the manifest's folder
  std::string batch_id;
  std::string scene_id;
  int frame_start = 0;
  int frame_end = -1;     // inclusive
  uint64_t size = 0;      // bytes
  uint64_t checksum = 0;  // checksum_file() of the shard
  bool operator==(const ManifestEntry&) const = default;
};

struct Manifest {
  std::vector<ManifestEntry> shards;  // sorted by file
};

// The entry for a shard just committed into `dir`.
ManifestEntry manifest_entry(const ShardInfo& info, const ShardWriteResult& written);

// Loads dir/manifest.json; an absent file is an empty manifest. Throws
// RuntimeError naming the file and the offending key when it is malformed
// or of an unknown schema.
Manifest load_manifest(const std::filesystem::path& dir);
// Replaces dir/manifest.json atomically.
void save_manifest(const std::filesystem::path& dir, const Manifest& manifest);
// Adds `entry`, replacing an entry of the same file (a retried pack job is
// harmless), under the folder's manifest lock.
void add_to_manifest(const std::filesystem::path& dir, const ManifestEntry& entry);
// Edits the manifest under the folder's lock and replaces it atomically:
// `edit` gets the entries (none when the file is missing or unreadable, which
// `readable` tells, so the caller can rebuild it) and changes them in place.
void rewrite_manifest(const std::filesystem::path& dir,
                      const std::function<void(Manifest& manifest, bool readable)>& edit);

struct ManifestProblem {
  std::string file;
  std::string problem;  // "missing", "size 100, manifest says 120", ...
};
// Checks that every listed shard exists with the listed size and, when
// `checksums` is set, the listed checksum (reads every file). Empty = all good.
std::vector<ManifestProblem> verify_manifest(const std::filesystem::path& dir,
                                             bool checksums = true);

}  // namespace dofarm
