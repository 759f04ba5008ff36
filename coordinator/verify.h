// Checking an output folder against its record (`dofarm verify DIR`, and the
// shard checks of a resume): every shard a record lists must be a regular
// file in the folder with the size and checksum recorded when it was packed,
// and be listed in manifest.json with them.
//
// The record is the job store of the batch that writes the folder
// (DIR/.dofarm-state/dofarm.sqlite for `dofarm run`, or the store of a
// standalone coordinator given with --state), when there is one; otherwise
// manifest.json alone. Files are opened without following symlinks and
// without blocking (a FIFO in place of a shard is reported, never read).
#pragma once

#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

namespace dofarm::coordinator {

// `path` must be a regular file (not a symlink, FIFO or device) of `size`
// bytes when given, whose checksum_file() is `checksum`. Returns what is
// wrong in words, empty when it holds; `actual_size` gets the size found.
std::string check_output_file(const std::filesystem::path& path, uint64_t checksum,
                              std::optional<uint64_t> size = std::nullopt,
                              uint64_t* actual_size = nullptr);

class Scheduler;

// What a resume found and requeued (verify_batch_outputs).
struct ResumeCheck {
  int tiles_requeued = 0;  // staged tiles of unpacked shards missing or damaged
  int shards_redone = 0;   // packed shards missing, damaged or unlisted: packed again
  bool manifest_rebuilt = false;
  int total() const { return tiles_requeued + shards_redone; }
};

// The check of a resume (`dofarm run` of the same job, the `resume` message,
// a coordinator restart): every done tile of an unpacked shard has its staged
// file with its checksum, every shard of a done pack is a regular file with
// the checksum recorded at pack time and is listed in manifest.json with its
// size and checksum. A damaged or missing shard leaves the manifest and is
// packed again: from its staged tiles where they still verify, else its
// tiles are rendered again (Scheduler::invalidate; a done batch runs again).
// A sound shard the manifest lacks, or a manifest that is missing or
// unreadable, is listed again (the entry rebuilt from the shard's own
// attributes). Reads every shard of the batch once: the cost is the
// checksum of its bytes (XXH64, a few GB/s).
ResumeCheck verify_batch_outputs(Scheduler& scheduler, const std::string& batch_id);

struct ShardVerdict {
  std::string file;  // relative to the folder
  int frame_start = 0;
  int frame_end = -1;   // inclusive
  std::string problem;  // empty: it holds
};

struct StagedVerdict {
  std::string file;     // relative to the folder
  std::string status;   // "awaiting pack", "left over", ...
  std::string problem;  // empty: it holds
};

struct FolderReport {
  std::filesystem::path dir;
  std::string record;  // what the folder was checked against, in words
  std::string batch_id;
  std::string batch_state;            // of the batch in the job store; empty without
  std::vector<ShardVerdict> shards;   // every shard the record lists, by file
  std::vector<std::string> unlisted;  // shard files in the folder that no record lists
  std::vector<StagedVerdict> staged;  // files under DIR/.staging
  std::vector<std::string> problems;  // of the folder itself (manifest unreadable, ...)
  // Every shard holds, nothing unlisted, no staged tile damaged, no problem.
  bool ok() const;
};

struct VerifyOptions {
  // Job store to check against; empty: DIR/.dofarm-state/dofarm.sqlite when
  // it exists, else manifest.json alone.
  std::filesystem::path state_dir;
  std::string batch_id;  // empty: the one DIR/.dofarm-owner.json names, else the newest for DIR
};

// Throws RuntimeError when `dir` is not a folder or the store cannot be read.
FolderReport verify_folder(const std::filesystem::path& dir, const VerifyOptions& options = {});

nlohmann::json folder_report_json(const FolderReport& report);
// One line per shard ("shard-00000.h5  frames 0..1  OK"), then unlisted
// files, staged tiles and a summary.
void print_folder_report(const FolderReport& report, std::ostream& out);

}  // namespace dofarm::coordinator
