// The `dofarm.shard/2` HDF5 format (docs/shard_format.md is the full spec).
//
// One shard holds F consecutive frames of one scene of one batch:
//   noisy, albedo                       F, V, 3, H, W
//   albedo_ref, reference, normal       F, 3, H, W
//   reference_var, depth, roughness,coc F, 1, H, W
//   camera                              F, K   (columns: camera_columns())
// float32 little-endian, chunked one chunk per (frame, version, 64x64 tile),
// shuffle + deflate + Fletcher-32 per chunk.
//
// Writing is atomic: ShardWriter writes "<final>.tmp-<pid>", flushes, fsyncs,
// re-opens and verifies what it wrote against a checksum of what it was
// given, renames and fsyncs the directory. On any failure (or when the writer
// is destroyed without commit()) the temporary file is removed, so the final
// name either does not exist or names a complete, verified shard.
//
// Thread safety: Debian's HDF5 is built without --enable-threadsafe, so every
// HDF5 call in the process must be serialized. ShardWriter and ShardReader take
// hdf5_mutex() around their HDF5 calls; they may be used from any thread. The
// reader decodes crop chunks outside the lock (ShardReaderOptions). Any other
// code in the process that calls HDF5 directly must take it too.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "common/error.h"
#include "common/image.h"

namespace dofarm {

inline constexpr const char* kShardSchema = "dofarm.shard/3";
// Version 2 lacks the camera's ortho_height column (its frames are all
// perspective); readers still take it.
inline constexpr const char* kShardSchemaV2 = "dofarm.shard/2";
// Version 1 lacks job_hash as well (and its scene_hash covers only the scene file
// and environment map); readers still take it.
inline constexpr const char* kShardSchemaV1 = "dofarm.shard/1";
// Spatial chunk edge; chunks are clipped to the image when it is smaller.
inline constexpr int kShardTile = 64;

// The shard is not one this build can read: not HDF5, no schema attribute, an
// unknown schema version, or datasets whose shapes contradict the attributes.
// (Distinct from a plain RuntimeError, which is an IO failure: `inspect`
// exits 2 for this and 1 for that.)
class ShardFormatError : public RuntimeError {
 public:
  using RuntimeError::RuntimeError;
};

// Root attributes of a shard. Frame numbers are absolute (as in the job
// spec); the shard holds frames frame_start..frame_end inclusive, and frame
// index i of the datasets is absolute frame frame_start + i.
struct ShardInfo {
  std::string schema = kShardSchema;  // set by the writer; read back as stored
  std::string batch_id;
  std::string scene_id;
  std::string scene_hash;  // content hash of the scene and every file it reads
  std::string job_hash;    // the job (common/job_snapshot.h); empty in version 1
  int width = 0;
  int height = 0;
  int versions = 0;  // V: noisy 1-spp versions per frame
  int spp_noisy = 1;
  int spp_reference = 0;      // fixed spp, or the cap when reference_error > 0
  float reference_error = 0;  // relative std. error target; 0 = fixed spp
  int spp_albedo_ref = 0;
  uint64_t seed = 0;
  int frame_start = 0;
  int frame_end = -1;  // inclusive
  std::string renderer_version;
  double render_seconds = 0;   // sum of tile render times over the shard's frames
  double pack_seconds = 0;     // time to assemble and write the shard (writer fills it)
  std::string created;         // ISO 8601 UTC; the writer fills it when empty
  uint64_t data_checksum = 0;  // checksum64 of the data (writer fills it; see docs)

  int frame_count() const { return frame_end - frame_start + 1; }
};

// Columns of the `camera` dataset, in order (also stored as its "columns"
// attribute): frame, time, position_x/y/z, rotation_w/x/y/z, fov_deg,
// focal_distance, aperture, ortho_height. The frame number is stored as
// float32, exact below 2^24. Versions 1 and 2 have the first 12.
inline constexpr int kCameraColumns = 13;
inline constexpr int kCameraColumnsV2 = 12;
const std::array<const char*, kCameraColumns>& camera_columns();
std::array<float, kCameraColumns> camera_to_row(const CameraState& c);
// A row of `columns` values (kCameraColumns, or kCameraColumnsV2 for a
// version 1 or 2 shard: ortho_height 0).
CameraState camera_from_row(const float* row, int columns = kCameraColumns);
// The camera columns a shard of `schema` has.
int camera_columns_of(const std::string& schema);

// Comma-separated channel names of a buffer ("R,G,B", "X,Y,Z", "Y").
const char* buffer_channel_names(const std::string& buffer);

// The mutex every HDF5 call in the process goes through (see above).
std::recursive_mutex& hdf5_mutex();

struct ShardWriteResult {
  std::filesystem::path path;  // the final name
  uint64_t file_size = 0;
  uint64_t file_checksum = 0;  // checksum64 of the whole file, for the manifest
  uint64_t data_checksum = 0;  // as stored in the root attribute
};

// Streams frames into a new shard, one at a time, so packing a shard needs
// memory for one frame only.
//   ShardWriter w(dir / "shard-00000.h5", info);
//   for (...) w.add_frame(frame);   // frames in order, full frames
//   ShardWriteResult r = w.commit();
class ShardWriter {
 public:
  // Creates the temporary file. Throws RuntimeError on IO failure;
  // DOFARM_CHECKs programmer errors (empty frame range, zero size).
  ShardWriter(std::filesystem::path final_path, ShardInfo info);
  ~ShardWriter();  // removes the temporary file unless commit() succeeded
  ShardWriter(const ShardWriter&) = delete;
  ShardWriter& operator=(const ShardWriter&) = delete;

  // Appends the next frame. It must be a full frame of info's size and
  // versions. Throws RuntimeError naming the frame and buffer if any value is
  // NaN or Inf (and the shard is then abandoned: commit() will refuse).
  void add_frame(const FrameBuffers& frame);
  // After exactly info.frame_count() frames: flush, fsync, verify, rename.
  ShardWriteResult commit();
  // Sets the root attribute render_seconds, which commit() writes; a pack
  // learns the tiles' render times while it reads them.
  void set_render_seconds(double seconds);
  // Drops the temporary file now (the destructor does it too).
  void abort();

  const std::filesystem::path& temp_path() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Writes all frames in one call. Checks every frame for NaN/Inf before
// creating anything.
ShardWriteResult write_shard(const std::filesystem::path& final_path, const ShardInfo& info,
                             const std::vector<FrameBuffers>& frames);

struct ShardReaderOptions {
  // Image datasets stored in the writer's layout are read chunk by chunk with
  // H5Dread_chunk under hdf5_mutex() and decoded (Fletcher-32 check, inflate,
  // unshuffle) outside it, so several threads reading crops decode in
  // parallel. false: everything through H5Dread (HDF5 decodes under the lock).
  // Both give the same values and the same damaged-chunk errors.
  bool direct_chunks = true;
};

// Read access to one shard. Frame indices are 0-based within the shard.
class ShardReader {
 public:
  static constexpr int kAllVersions = -1;

  // Opens and checks schema, attributes and dataset shapes. Throws
  // ShardFormatError (not a shard, unknown schema) or RuntimeError (IO,
  // truncated or damaged file), naming the file.
  explicit ShardReader(const std::filesystem::path& path, ShardReaderOptions options = {});
  ~ShardReader();
  ShardReader(const ShardReader&) = delete;
  ShardReader& operator=(const ShardReader&) = delete;

  const std::filesystem::path& path() const;
  const ShardInfo& info() const;
  int frame_count() const { return info().frame_count(); }

  // One full frame; `buffers` selects buffers by name (empty = all; the
  // others stay empty). The camera is always read.
  FrameBuffers read_frame(int frame, const std::vector<std::string>& buffers = {}) const;

  // A crop of `frame_count` consecutive frames of one buffer, laid out
  // (frame, version, channel, y, x) with version only for per-version buffers
  // and only the one asked for unless kAllVersions:
  //   noisy, version 3:      frame_count * 1 * 3 * h * w floats
  //   noisy, kAllVersions:   frame_count * V * 3 * h * w
  //   depth (version ignored): frame_count * 1 * h * w
  // Reads only the chunks the crop touches (the trainer's 7-frame 64x64
  // crops touch at most 4 chunks per frame). A crop, frame range or version
  // outside the shard is a caller bug (DOFARM_CHECK); an unknown buffer name
  // throws RuntimeError.
  std::vector<float> read_crop(const std::string& buffer, int frame_begin, int frame_count,
                               int version, Rect crop) const;
  // As read_crop(), into caller memory of crop_size() floats.
  void read_crop_into(const std::string& buffer, int frame_begin, int frame_count, int version,
                      Rect crop, float* out) const;
  size_t crop_size(const std::string& buffer, int frame_count, int version, Rect crop) const;

  std::vector<CameraState> cameras() const;

  // Whether crops of `buffer` are decoded by the reader itself
  // (ShardReaderOptions::direct_chunks and a dataset in the writer's layout).
  bool decodes_chunks(const std::string& buffer) const;

  // How each dataset is stored (for `dofarm inspect`), in schema order,
  // camera last.
  struct DatasetLayout {
    std::string name;
    std::vector<uint64_t> shape, chunk;
    std::vector<std::string> filters;  // pipeline order: "shuffle", "deflate(4)", ...
    std::string channels;              // the "channels" (or camera "columns") attribute
    uint64_t stored_bytes = 0;         // on disk, after compression
    uint64_t logical_bytes = 0;        // float32 values * 4
  };
  std::vector<DatasetLayout> layout() const;

  // Reads everything back and recomputes the data checksum the writer stored
  // (the same walk the writer's own verification does). Slow: whole shard.
  uint64_t compute_data_checksum() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dofarm
