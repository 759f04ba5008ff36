// Where a batch's outputs live in its output folder. The worker writes there
// and the coordinator checks a `done` claim against exactly these paths, so
// both call these functions.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include "common/image.h"

namespace dofarm {

// OUT/.staging/BATCH/: the staged tiles of one batch.
std::filesystem::path staging_dir(const std::filesystem::path& out_dir, const std::string& batch);
// OUT/.staging/BATCH/fFFFFF_xX_yY_wW_hH.exr: one render tile's staged EXR.
std::filesystem::path staged_tile_path(const std::filesystem::path& out_dir,
                                       const std::string& batch, int frame, Rect rect);

// The largest a staged tile of `rect` can honestly be: every buffer's float
// channels and the constant A at the most versions a job may have (64),
// ZIP's worst-case growth, and room for the header. The coordinator reads no more than this for one
// `done` claim.
uint64_t staged_tile_max_bytes(Rect rect, int versions = 64);

}  // namespace dofarm
