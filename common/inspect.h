// `dofarm inspect SHARD.h5 [--json]`: what a shard holds and whether it is
// sound. Prints the schema and root attributes, the frame range, each
// dataset's shape, chunking, filters and compression ratio, per-channel
// statistics (min, max, mean, std over all frames and versions, finite
// values only) with the count of NaN/Inf values, and recomputes the data
// checksum stored in the file (this reads the whole shard).
#pragma once

#include <filesystem>
#include <iostream>
#include <ostream>

namespace dofarm {

// Returns the exit code: 0 the shard is sound; 2 not a shard or an unknown
// schema (kExitBadInput); 1 an IO error, a damaged file, a data checksum
// mismatch or non-finite values (kExitRuntime). The report goes to `out`
// (one JSON document when `json`, also on failure: {"file", "error"}); in
// text mode the failure goes to `err`.
int inspect_shard(const std::filesystem::path& path, bool json, std::ostream& out,
                  std::ostream& err = std::cerr);

}  // namespace dofarm
