#include "common/shard.h"

#include <fcntl.h>
#include <hdf5.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <map>
#include <sstream>

#include "common/checksum.h"
#include "common/shard_hdf5.h"

namespace dofarm {
namespace fs = std::filesystem;

// ---------------------------------------------------------------------------
// Camera columns and channel names

const std::array<const char*, kCameraColumns>& camera_columns() {
  static const std::array<const char*, kCameraColumns> names = {
      "frame",          "time",       "position_x",  "position_y", "position_z",
      "rotation_w",     "rotation_x", "rotation_y",  "rotation_z", "fov_deg",
      "focal_distance", "aperture",   "ortho_height"};
  return names;
}

int camera_columns_of(const std::string& schema) {
  return schema == kShardSchemaV2 || schema == kShardSchemaV1 ? kCameraColumnsV2 : kCameraColumns;
}

std::array<float, kCameraColumns> camera_to_row(const CameraState& c) {
  return {float(c.frame),   c.time,        c.position[0], c.position[1], c.position[2],
          c.rotation[0],    c.rotation[1], c.rotation[2], c.rotation[3], c.fov_deg,
          c.focal_distance, c.aperture,    c.ortho_height};
}

CameraState camera_from_row(const float* r, int columns) {
  CameraState c;
  c.frame = int(std::lround(r[0]));
  c.time = r[1];
  for (int i = 0; i < 3; ++i) c.position[i] = r[2 + i];
  for (int i = 0; i < 4; ++i) c.rotation[i] = r[5 + i];
  c.fov_deg = r[9];
  c.focal_distance = r[10];
  c.aperture = r[11];
  c.ortho_height = columns > kCameraColumnsV2 ? r[12] : 0.0f;
  return c;
}

const char* buffer_channel_names(const std::string& buffer) {
  if (buffer == "normal") return "X,Y,Z";
  for (const BufferInfo& b : buffer_infos())
    if (buffer == b.name) return b.channels == 3 ? "R,G,B" : "Y";
  throw RuntimeError("unknown buffer name '" + buffer + "'");
}

// ---------------------------------------------------------------------------
// The HDF5 boundary (STYLE.md 4) lives in common/shard_hdf5.h; the writer in
// common/shard_writer.cpp.

std::recursive_mutex& hdf5_mutex() {
  static std::recursive_mutex m;
  return m;
}

using namespace shard_detail;

// ---------------------------------------------------------------------------
// ShardReader

// Reading chunks without HDF5's filter pipeline. HDF5 decompresses inside
// H5Dread, under the process-wide lock (see hdf5_mutex()), so several reader
// threads decode one chunk at a time. For the layout the writer makes
// (docs/shard_format.md: one chunk per frame, version and tile; shuffle ->
// deflate -> Fletcher-32) the reader instead fetches the stored bytes with
// H5Dread_chunk under the lock and verifies, inflates and unshuffles them
// outside it, so reader threads decode in parallel. A dataset stored any other
// way is read with H5Dread. zlib is HDF5's own deflate library (hdf5::hdf5
// links it).
namespace {

// Filter order of the shard format; bit i of H5Dread_chunk's filter mask set
// means filter i was skipped for that chunk.
constexpr int kShuffleFilter = 0, kDeflateFilter = 1, kFletcherFilter = 2;

// HDF5's Fletcher-32 (H5checksum.c): 16-bit big-endian words, sums folded
// every 360 words.
uint32_t fletcher32(const uint8_t* data, size_t bytes) {
  size_t len = bytes / 2;
  uint32_t sum1 = 0, sum2 = 0;
  while (len) {
    size_t t = len > 360 ? 360 : len;
    len -= t;
    do {
      sum1 += (uint32_t(data[0]) << 8) | uint32_t(data[1]);
      data += 2;
      sum2 += sum1;
    } while (--t);
    sum1 = (sum1 & 0xffff) + (sum1 >> 16);
    sum2 = (sum2 & 0xffff) + (sum2 >> 16);
  }
  if (bytes % 2) {
    sum1 += uint32_t(*data) << 8;
    sum2 += sum1;
    sum1 = (sum1 & 0xffff) + (sum1 >> 16);
    sum2 = (sum2 & 0xffff) + (sum2 >> 16);
  }
  sum1 = (sum1 & 0xffff) + (sum1 >> 16);
  sum2 = (sum2 & 0xffff) + (sum2 >> 16);
  return (sum2 << 16) | sum1;
}

// Two zlib streams per thread, reset per chunk (no allocation per chunk).
// When Fletcher-32 has verified the stored bytes, the zlib wrapper's adler32
// of the inflated bytes cannot tell anything more (inflate is deterministic),
// so the deflate body is inflated raw and the adler32 skipped (~10% of the
// decoding time); a chunk without the checksum is inflated with it.
struct Inflater {
  z_stream wrapped{}, raw{};
  bool ok = false;
  Inflater() { ok = inflateInit(&wrapped) == Z_OK && inflateInit2(&raw, -MAX_WBITS) == Z_OK; }
  ~Inflater() {
    inflateEnd(&wrapped);
    inflateEnd(&raw);
  }
  // True when `in` (a zlib stream) inflates to exactly `out_bytes` bytes.
  bool run(const uint8_t* in, size_t in_bytes, uint8_t* out, size_t out_bytes, bool verified) {
    z_stream* z = &wrapped;
    if (verified) {
      // RFC 1950 header: CM 8 (deflate), no preset dictionary, FCHECK.
      if (in_bytes < 2 || (in[0] & 0x0f) != 8 || (in[1] & 0x20) || (in[0] * 256 + in[1]) % 31)
        return false;
      in += 2;
      in_bytes -= 2;
      z = &raw;
    }
    if (!ok || inflateReset(z) != Z_OK) return false;
    z->next_in = const_cast<Bytef*>(in);
    z->avail_in = uInt(in_bytes);
    z->next_out = out;
    z->avail_out = uInt(out_bytes);
    return inflate(z, Z_FINISH) == Z_STREAM_END && z->avail_out == 0;
  }
};

}  // namespace

struct ShardReader::Impl {
  fs::path path;
  ShardInfo info;
  ShardReaderOptions options;
  Handle file;
  std::map<std::string, Handle> datasets;  // buffers and "camera"
  int camera_columns = kCameraColumns;     // of the "camera" dataset (by schema)
  // Image datasets stored as the writer stores them: chunk shape (rank of the
  // dataset) per name; absent = read through H5Dread.
  std::map<std::string, std::vector<hsize_t>> direct;

  void open(const fs::path& path);
  void probe_direct(const std::string& name, const BufferInfo& b);

  // Reads a hyperslab of one dataset into `out` (exactly its element count).
  void read(const std::string& name, const BufferInfo* b, int f0, int n, int version, Rect r,
            float* out, size_t count) const {
    if (b && options.direct_chunks) {
      auto it = direct.find(name);
      if (it != direct.end()) return read_direct(name, *b, it->second, f0, n, version, r, out);
    }
    H5Lock lock;
    const Handle& ds = datasets.at(name);
    std::vector<hsize_t> shape;
    Handle fspace = select_crop(ds.get(), b, f0, n, version, r, info.versions, path, &shape);
    hsize_t elements = 1;
    for (hsize_t d : shape) elements *= d;
    DOFARM_CHECK_EQ(elements, hsize_t(count));
    Handle mspace = checked(H5Screate_simple(int(shape.size()), shape.data(), nullptr), H5Sclose,
                            path, "memory space");
    if (H5Dread(ds.get(), H5T_NATIVE_FLOAT, mspace.get(), fspace.get(), H5P_DEFAULT, out) < 0)
      h5_fail(path, describe(name, b, f0, n, r) + " failed (damaged file?)");
  }

  std::string describe(const std::string& name, const BufferInfo* b, int f0, int n, Rect r) const {
    std::ostringstream os;
    os << "reading '" << name << "' frames " << f0 << ".." << f0 + n - 1;
    if (b) os << " rect " << r.x << "," << r.y << "," << r.w << "," << r.h;
    return os.str();
  }

  void read_direct(const std::string& name, const BufferInfo& b, const std::vector<hsize_t>& chunk,
                   int f0, int n, int version, Rect r, float* out) const;
};

void ShardReader::Impl::probe_direct(const std::string& name, const BufferInfo& b) {
  hid_t ds = datasets.at(name).get();
  Handle dcpl = checked(H5Dget_create_plist(ds), H5Pclose, path, "creation properties of " + name);
  if (H5Pget_layout(dcpl.get()) != H5D_CHUNKED) return;
  const std::vector<hsize_t> dims = dataset_dims(b, info);
  std::vector<hsize_t> chunk(dims.size());
  if (H5Pget_chunk(dcpl.get(), int(chunk.size()), chunk.data()) != int(chunk.size())) return;
  // One frame (and version) per chunk, all channels: the layout read_direct decodes.
  const size_t lead = b.per_version ? 2 : 1;
  for (size_t k = 0; k < lead; ++k)
    if (chunk[k] != 1) return;
  if (chunk[lead] != hsize_t(b.channels) || chunk[lead + 1] == 0 || chunk[lead + 2] == 0) return;
  // Decoded bytes are used as floats as they are: float32 little-endian only.
  if constexpr (std::endian::native != std::endian::little) return;
  Handle type = checked(H5Dget_type(ds), H5Tclose, path, "type of " + name);
  if (H5Tequal(type.get(), H5T_IEEE_F32LE) <= 0) return;
  if (H5Pget_nfilters(dcpl.get()) != 3) return;
  const H5Z_filter_t expect[3] = {H5Z_FILTER_SHUFFLE, H5Z_FILTER_DEFLATE, H5Z_FILTER_FLETCHER32};
  for (unsigned k = 0; k < 3; ++k) {
    unsigned flags = 0, values[8] = {0};
    size_t nvalues = 8;
    H5Z_filter_t id = H5Pget_filter2(dcpl.get(), k, &flags, &nvalues, values, 0, nullptr, nullptr);
    if (id != expect[k]) return;
    // HDF5 fills in the shuffle element size when the dataset is created.
    if (id == H5Z_FILTER_SHUFFLE && nvalues >= 1 && values[0] != sizeof(float)) return;
  }
  direct.emplace(name, chunk);
}

void ShardReader::Impl::read_direct(const std::string& name, const BufferInfo& b,
                                    const std::vector<hsize_t>& chunk, int f0, int n, int version,
                                    Rect r, float* out) const {
  const size_t rank = chunk.size();
  const int th = int(chunk[rank - 2]), tw = int(chunk[rank - 1]);
  const int channels = b.channels;
  const bool all = b.per_version && version == ShardReader::kAllVersions;
  const int v0 = b.per_version && !all ? version : 0;
  const int nv = all ? info.versions : 1;
  const int ty0 = r.y / th, ty1 = (r.y + r.h - 1) / th;
  const int tx0 = r.x / tw, tx1 = (r.x + r.w - 1) / tw;
  const size_t chunk_floats = size_t(channels) * th * tw;
  const size_t chunk_bytes = chunk_floats * sizeof(float);

  struct Stored {
    int f, v, ty, tx;
    size_t at, bytes;
    uint32_t mask;
  };
  thread_local std::vector<uint8_t> stored_bytes;
  thread_local std::vector<uint8_t> inflated, floats;
  std::vector<Stored> stored;
  stored.reserve(size_t(n) * nv * (ty1 - ty0 + 1) * (tx1 - tx0 + 1));
  stored_bytes.clear();
  {
    // Only the file reads hold the lock; decoding below runs in parallel.
    H5Lock lock;
    hid_t ds = datasets.at(name).get();
    for (int f = f0; f < f0 + n; ++f)
      for (int v = v0; v < v0 + nv; ++v)
        for (int ty = ty0; ty <= ty1; ++ty)
          for (int tx = tx0; tx <= tx1; ++tx) {
            std::vector<hsize_t> offset = {hsize_t(f)};
            if (b.per_version) offset.push_back(hsize_t(v));
            offset.insert(offset.end(), {0, hsize_t(ty) * th, hsize_t(tx) * tw});
            hsize_t bytes = 0;
            if (H5Dget_chunk_storage_size(ds, offset.data(), &bytes) < 0 || bytes == 0)
              h5_fail(path, describe(name, &b, f0, n, r) + ": chunk of frame " + std::to_string(f) +
                                " is missing (damaged file?)");
            Stored s{f, v, ty, tx, stored_bytes.size(), size_t(bytes), 0};
            stored_bytes.resize(s.at + s.bytes);
            if (H5Dread_chunk(ds, H5P_DEFAULT, offset.data(), &s.mask, &stored_bytes[s.at]) < 0)
              h5_fail(path, describe(name, &b, f0, n, r) + " failed (damaged file?)");
            stored.push_back(s);
          }
  }
  thread_local Inflater inflater;
  inflated.resize(chunk_bytes);
  floats.resize(chunk_bytes);
  const size_t plane = size_t(r.w) * r.h;
  for (const Stored& s : stored) {
    auto damaged = [&](const std::string& why) {
      throw RuntimeError("shard " + path.string() + ": " + describe(name, &b, f0, n, r) +
                         ": chunk of frame " + std::to_string(s.f) + " at x " +
                         std::to_string(s.tx * tw) + ", y " + std::to_string(s.ty * th) + ": " +
                         why + " (damaged file?)");
    };
    const uint8_t* p = &stored_bytes[s.at];
    size_t bytes = s.bytes;
    const bool verified = !(s.mask & (1u << kFletcherFilter));
    if (verified) {
      if (bytes < 4) damaged("shorter than its checksum");
      bytes -= 4;
      const uint32_t want = uint32_t(p[bytes]) | uint32_t(p[bytes + 1]) << 8 |
                            uint32_t(p[bytes + 2]) << 16 | uint32_t(p[bytes + 3]) << 24;
      if (fletcher32(p, bytes) != want) damaged("data error detected by Fletcher32 checksum");
    }
    const uint8_t* plain = p;
    if (!(s.mask & (1u << kDeflateFilter))) {
      if (!inflater.run(p, bytes, inflated.data(), chunk_bytes, verified))
        damaged("inflate failed");
      plain = inflated.data();
    } else if (bytes != chunk_bytes) {
      damaged("stored size " + std::to_string(bytes) + " is not the chunk size");
    }
    const float* values = reinterpret_cast<const float*>(plain);
    if (!(s.mask & (1u << kShuffleFilter))) {
      // Shuffle stored byte k of every float together: undo it.
      uint8_t* dst = floats.data();
      const uint8_t* b0 = plain;
      const uint8_t* b1 = b0 + chunk_floats;
      const uint8_t* b2 = b1 + chunk_floats;
      const uint8_t* b3 = b2 + chunk_floats;
      for (size_t i = 0; i < chunk_floats; ++i) {
        dst[4 * i] = b0[i];
        dst[4 * i + 1] = b1[i];
        dst[4 * i + 2] = b2[i];
        dst[4 * i + 3] = b3[i];
      }
      values = reinterpret_cast<const float*>(floats.data());
    }
    // The part of this tile inside the crop, into (frame, version, channel, y, x).
    const int y_begin = std::max(r.y, s.ty * th), y_end = std::min(r.y + r.h, (s.ty + 1) * th);
    const int x_begin = std::max(r.x, s.tx * tw), x_end = std::min(r.x + r.w, (s.tx + 1) * tw);
    for (int c = 0; c < channels; ++c) {
      float* dst = out + ((size_t(s.f - f0) * nv + (s.v - v0)) * channels + c) * plane;
      const float* src = values + size_t(c) * th * tw;
      for (int y = y_begin; y < y_end; ++y)
        std::memcpy(dst + size_t(y - r.y) * r.w + (x_begin - r.x),
                    src + size_t(y - s.ty * th) * tw + (x_begin - s.tx * tw),
                    size_t(x_end - x_begin) * sizeof(float));
    }
  }
}

ShardReader::ShardReader(const fs::path& path, ShardReaderOptions options)
    : impl_(std::make_unique<Impl>()) {
  impl_->options = options;
  H5Lock lock;
  try {
    impl_->open(path);
  } catch (...) {
    impl_.reset();  // close what was opened while still holding the lock
    throw;
  }
}

void ShardReader::Impl::open(const fs::path& path_in) {
  Impl& m = *this;
  const fs::path& path = path_in;
  m.path = path;
  const std::string where = "shard " + path.string();
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw RuntimeError(where + ": no such file");
  htri_t is_h5 = H5Fis_hdf5(path.c_str());
  if (is_h5 < 0) h5_fail(path, "cannot read the file");
  if (is_h5 == 0) throw ShardFormatError(where + ": not an HDF5 file");
  m.file = checked(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose, path,
                   "cannot open (truncated or damaged file?)");
  hid_t f = m.file.get();

  ShardInfo& i = m.info;
  if (H5Aexists(f, "schema") <= 0)
    throw ShardFormatError(where + ": no 'schema' attribute; not a dofarm shard");
  i.schema = read_attr_string(f, "schema", path);
  if (i.schema != kShardSchema && i.schema != kShardSchemaV2 && i.schema != kShardSchemaV1)
    throw ShardFormatError(where + ": schema '" + i.schema +
                           "' is not supported (this build reads " + kShardSchema + ", " +
                           kShardSchemaV2 + " and " + kShardSchemaV1 + ")");
  i.batch_id = read_attr_string(f, "batch_id", path);
  i.scene_id = read_attr_string(f, "scene_id", path);
  i.scene_hash = read_attr_string(f, "scene_hash", path);
  if (i.schema != kShardSchemaV1) i.job_hash = read_attr_string(f, "job_hash", path);
  auto i64 = [&](const char* n) { return read_attr_number<int64_t>(f, n, H5T_NATIVE_INT64, path); };
  auto f64 = [&](const char* n) { return read_attr_number<double>(f, n, H5T_NATIVE_DOUBLE, path); };
  i.width = int(i64("width"));
  i.height = int(i64("height"));
  i.versions = int(i64("versions"));
  i.spp_noisy = int(i64("spp_noisy"));
  i.spp_reference = int(i64("spp_reference"));
  i.reference_error = float(f64("reference_error"));
  i.spp_albedo_ref = int(i64("spp_albedo_ref"));
  i.seed = read_attr_number<uint64_t>(f, "seed", H5T_NATIVE_UINT64, path);
  i.frame_start = int(i64("frame_start"));
  i.frame_end = int(i64("frame_end"));
  i.renderer_version = read_attr_string(f, "renderer_version", path);
  i.render_seconds = f64("render_seconds");
  i.pack_seconds = f64("pack_seconds");
  i.created = read_attr_string(f, "created", path);
  std::string sum = read_attr_string(f, "data_checksum", path);
  auto parsed = parse_checksum(sum);
  if (!parsed)
    throw ShardFormatError(where + ": attribute 'data_checksum' is not a checksum: '" + sum + "'");
  i.data_checksum = *parsed;
  if (i.width <= 0 || i.height <= 0 || i.versions <= 0 || i.frame_count() <= 0)
    throw ShardFormatError(
        where + ": attributes give an empty shard (width " + std::to_string(i.width) + ", height " +
        std::to_string(i.height) + ", versions " + std::to_string(i.versions) + ", frames " +
        std::to_string(i.frame_start) + ".." + std::to_string(i.frame_end) + ")");

  auto open_checked = [&](const std::string& name, const std::vector<hsize_t>& expect,
                          bool optional = false) {
    if (H5Lexists(f, name.c_str(), H5P_DEFAULT) <= 0) {
      if (optional) return;  // an older shard: the buffer reads as empty
      throw ShardFormatError(where + ": dataset '" + name + "' is missing");
    }
    Handle ds = checked(H5Dopen2(f, name.c_str(), H5P_DEFAULT), H5Dclose, path,
                        "opening dataset '" + name + "'");
    Handle space = checked(H5Dget_space(ds.get()), H5Sclose, path, "dataspace of " + name);
    int rank = H5Sget_simple_extent_ndims(space.get());
    std::vector<hsize_t> dims(rank > 0 ? rank : 0);
    if (rank > 0) H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
    if (dims != expect)
      throw ShardFormatError(where + ": dataset '" + name + "' has shape " + dims_to_string(dims) +
                             " but the attributes say " + dims_to_string(expect));
    m.datasets.emplace(name, std::move(ds));
  };
  for (const BufferInfo& b : buffer_infos())
    open_checked(b.name, dataset_dims(b, i), b.optional_in_shards);
  m.camera_columns = camera_columns_of(i.schema);
  open_checked("camera", {hsize_t(i.frame_count()), hsize_t(m.camera_columns)});
  for (const BufferInfo& b : buffer_infos())
    if (m.datasets.count(b.name)) probe_direct(b.name, b);
}

ShardReader::~ShardReader() {
  H5Lock lock;
  impl_.reset();  // closes the HDF5 handles under the lock
}

const fs::path& ShardReader::path() const { return impl_->path; }
const ShardInfo& ShardReader::info() const { return impl_->info; }

size_t ShardReader::crop_size(const std::string& buffer, int frame_count, int version,
                              Rect crop) const {
  const BufferInfo& b = find_buffer(buffer);
  size_t v = b.per_version && version == kAllVersions ? size_t(info().versions) : 1;
  return size_t(frame_count) * v * b.channels * crop.h * crop.w;
}

void ShardReader::read_crop_into(const std::string& buffer, int frame_begin, int frame_count,
                                 int version, Rect crop, float* out) const {
  const BufferInfo& b = find_buffer(buffer);
  const ShardInfo& i = info();
  // Out-of-range requests are caller bugs, not file problems.
  DOFARM_CHECK_GE(frame_begin, 0);
  DOFARM_CHECK_LE(frame_begin + frame_count, i.frame_count());
  DOFARM_CHECK_GE(frame_count, 1);
  DOFARM_CHECK_GE(crop.x, 0);
  DOFARM_CHECK_GE(crop.y, 0);
  DOFARM_CHECK_GE(crop.w, 1);
  DOFARM_CHECK_GE(crop.h, 1);
  DOFARM_CHECK_LE(crop.x + crop.w, i.width);
  DOFARM_CHECK_LE(crop.y + crop.h, i.height);
  if (b.per_version && version != kAllVersions) {
    DOFARM_CHECK_GE(version, 0);
    DOFARM_CHECK_LT(version, i.versions);
  }
  // No lock here: read() holds it for the HDF5 calls only, so chunk decoding
  // of several reader threads overlaps.
  impl_->read(buffer, &b, frame_begin, frame_count, version, crop, out,
              crop_size(buffer, frame_count, version, crop));
}

std::vector<float> ShardReader::read_crop(const std::string& buffer, int frame_begin,
                                          int frame_count, int version, Rect crop) const {
  std::vector<float> out(crop_size(buffer, frame_count, version, crop));
  read_crop_into(buffer, frame_begin, frame_count, version, crop, out.data());
  return out;
}

bool ShardReader::decodes_chunks(const std::string& buffer) const {
  return impl_->options.direct_chunks && impl_->direct.count(buffer) > 0;
}

std::vector<CameraState> ShardReader::cameras() const {
  H5Lock lock;
  int n = frame_count();
  const int k = impl_->camera_columns;
  std::vector<float> rows(size_t(n) * k);
  impl_->read("camera", nullptr, 0, n, 0, {}, rows.data(), rows.size());
  std::vector<CameraState> out;
  for (int f = 0; f < n; ++f) out.push_back(camera_from_row(&rows[size_t(f) * k], k));
  return out;
}

FrameBuffers ShardReader::read_frame(int frame, const std::vector<std::string>& buffers) const {
  const ShardInfo& i = info();
  DOFARM_CHECK_GE(frame, 0);
  DOFARM_CHECK_LT(frame, i.frame_count());
  for (const std::string& name : buffers) find_buffer(name);  // unknown names throw
  H5Lock lock;
  FrameBuffers fb;
  fb.width = i.width;
  fb.height = i.height;
  fb.versions = i.versions;
  fb.rect = {0, 0, i.width, i.height};
  float row[kCameraColumns];
  impl_->read("camera", nullptr, frame, 1, 0, {}, row, size_t(impl_->camera_columns));
  fb.camera = camera_from_row(row, impl_->camera_columns);
  for (const BufferInfo& b : buffer_infos()) {
    bool wanted = buffers.empty();
    for (const std::string& name : buffers) wanted |= name == b.name;
    if (!wanted || !impl_->datasets.count(b.name)) continue;  // absent: an older shard
    std::vector<float>& data = buffer_data(fb, b.name);
    data.resize(crop_size(b.name, 1, kAllVersions, fb.rect));
    impl_->read(b.name, &b, frame, 1, kAllVersions, fb.rect, data.data(), data.size());
  }
  return fb;
}

std::vector<ShardReader::DatasetLayout> ShardReader::layout() const {
  H5Lock lock;
  const fs::path& p = impl_->path;
  std::vector<DatasetLayout> out;
  std::vector<std::string> names;
  for (const BufferInfo& b : buffer_infos())
    if (impl_->datasets.count(b.name)) names.push_back(b.name);
  names.push_back("camera");
  for (const std::string& name : names) {
    hid_t ds = impl_->datasets.at(name).get();
    DatasetLayout l;
    l.name = name;
    Handle space = checked(H5Dget_space(ds), H5Sclose, p, "dataspace of " + name);
    int rank = H5Sget_simple_extent_ndims(space.get());
    std::vector<hsize_t> dims(rank > 0 ? rank : 0), chunk(dims.size());
    H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
    l.shape.assign(dims.begin(), dims.end());
    Handle dcpl = checked(H5Dget_create_plist(ds), H5Pclose, p, "creation properties of " + name);
    if (H5Pget_layout(dcpl.get()) == H5D_CHUNKED &&
        H5Pget_chunk(dcpl.get(), int(chunk.size()), chunk.data()) == int(chunk.size()))
      l.chunk.assign(chunk.begin(), chunk.end());
    for (int k = 0, n = H5Pget_nfilters(dcpl.get()); k < n; ++k) {
      unsigned flags = 0, values[8] = {0};
      size_t nvalues = 8;
      char fname[64] = {0};
      H5Z_filter_t id = H5Pget_filter2(dcpl.get(), unsigned(k), &flags, &nvalues, values,
                                       sizeof fname, fname, nullptr);
      if (id == H5Z_FILTER_DEFLATE)
        l.filters.push_back("deflate(" + std::to_string(nvalues > 0 ? values[0] : 0) + ")");
      else if (id == H5Z_FILTER_SHUFFLE)
        l.filters.push_back("shuffle");
      else if (id == H5Z_FILTER_FLETCHER32)
        l.filters.push_back("fletcher32");
      else
        l.filters.push_back("filter " + std::to_string(id));
    }
    const char* attr = name == "camera" ? "columns" : "channels";
    if (H5Aexists(ds, attr) > 0) l.channels = read_attr_string(ds, attr, p);
    l.stored_bytes = H5Dget_storage_size(ds);
    l.logical_bytes = sizeof(float);
    for (hsize_t d : dims) l.logical_bytes *= d;
    out.push_back(std::move(l));
  }
  return out;
}

// The checksum walk (docs/shard_format.md): per frame, each buffer in schema
// order, then the camera row, as float32 little-endian bytes.
uint64_t ShardReader::compute_data_checksum() const {
  H5Lock lock;
  Checksum64 sum;
  for (int f = 0; f < frame_count(); ++f) {
    FrameBuffers fb = read_frame(f);
    for (const BufferInfo& b : buffer_infos()) {
      const std::vector<float>& data = buffer_data(fb, b.name);
      sum.update(data.data(), data.size() * sizeof(float));
    }
    // The row as the shard's schema stores it (12 columns before version 3).
    auto row = camera_to_row(fb.camera);
    sum.update(row.data(), size_t(impl_->camera_columns) * sizeof(float));
  }
  return sum.digest();
}

}  // namespace dofarm
