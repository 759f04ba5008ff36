#include "common/staging.h"

#include <algorithm>
#include <cstdio>

namespace dofarm {

namespace fs = std::filesystem;

fs::path staging_dir(const fs::path& out_dir, const std::string& batch) {
  return out_dir / ".staging" / batch;
}

fs::path staged_tile_path(const fs::path& out_dir, const std::string& batch, int frame, Rect r) {
  char name[96];
  std::snprintf(name, sizeof(name), "f%05d_x%d_y%d_w%d_h%d.exr", frame, r.x, r.y, r.w, r.h);
  return staging_dir(out_dir, batch) / name;
}

uint64_t staged_tile_max_bytes(Rect r, int versions) {
  uint64_t floats = 1;  // the root A (docs/exr_format.md)
  for (const BufferInfo& b : buffer_infos())
    floats += uint64_t(b.channels) * uint64_t(b.per_version ? versions : 1);
  const uint64_t raw = uint64_t(std::max(r.w, 0)) * uint64_t(std::max(r.h, 0)) * floats * 4;
  return raw + raw / 64 + (uint64_t(1) << 20);
}

}  // namespace dofarm
