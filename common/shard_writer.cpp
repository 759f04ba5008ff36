// ShardWriter: streams frames into a new shard, verifies it and publishes
// it atomically (see common/shard.h).
#include <hdf5_hl.h>

#include <cctype>
#include <cmath>
#include <map>

#include "common/checksum.h"
#include "common/shard.h"
#include "common/shard_hdf5.h"

namespace dofarm {

namespace fs = std::filesystem;
using namespace shard_detail;

// ---------------------------------------------------------------------------
// ShardWriter

struct ShardWriter::Impl {
  fs::path final_path, temp_path;
  ShardInfo info;
  Handle file;
  std::map<std::string, Handle> datasets;
  int next_frame = 0;
  bool failed = false, committed = false;
  Checksum64 sum;
  std::chrono::steady_clock::time_point started = std::chrono::steady_clock::now();

  Handle create_dataset(const std::string& name, const std::vector<hsize_t>& dims,
                        const std::vector<hsize_t>& chunk, const char* dim_names,
                        const char* channels_attr, const char* channels) {
    const fs::path& p = temp_path;
    Handle space = checked(H5Screate_simple(int(dims.size()), dims.data(), nullptr), H5Sclose, p,
                           "creating dataspace for '" + name + "'");
    Handle dcpl = checked(H5Pcreate(H5P_DATASET_CREATE), H5Pclose, p, "creating dcpl");
    // Shuffle groups the bytes of the floats so deflate sees runs of similar
    // exponents; Fletcher-32 last, so it covers the stored (compressed) bytes
    // and a damaged chunk fails the read instead of decoding to wrong values.
    if (H5Pset_chunk(dcpl.get(), int(chunk.size()), chunk.data()) < 0 ||
        H5Pset_shuffle(dcpl.get()) < 0 || H5Pset_deflate(dcpl.get(), 4) < 0 ||
        H5Pset_fletcher32(dcpl.get()) < 0 || H5Pset_fill_time(dcpl.get(), H5D_FILL_TIME_NEVER) < 0)
      h5_fail(p, "setting up chunking and filters for '" + name + "'");
    Handle ds = checked(H5Dcreate2(file.get(), name.c_str(), H5T_IEEE_F32LE, space.get(),
                                   H5P_DEFAULT, dcpl.get(), H5P_DEFAULT),
                        H5Dclose, p, "creating dataset '" + name + "'");
    write_attr_string(ds.get(), "dims", dim_names, p);
    write_attr_string(ds.get(), channels_attr, channels, p);
    return ds;
  }

  void write(const std::string& name, const BufferInfo* b, const float* data, size_t count) {
    const Handle& ds = datasets.at(name);
    Rect full{0, 0, info.width, info.height};
    std::vector<hsize_t> shape;
    Handle fspace = select_crop(ds.get(), b, next_frame, 1, ShardReader::kAllVersions, full,
                                info.versions, temp_path, &shape);
    // A memory space shaped like the file selection: with a flat one HDF5
    // maps every element through its general (slow) path.
    hsize_t elements = 1;
    for (hsize_t d : shape) elements *= d;
    if (elements != count)
      throw RuntimeError("shard " + temp_path.string() + ": '" + name + "' gets " +
                         std::to_string(count) + " values for " + std::to_string(elements) +
                         " places");
    Handle mspace = checked(H5Screate_simple(int(shape.size()), shape.data(), nullptr), H5Sclose,
                            temp_path, "memory space");
    if (H5Dwrite(ds.get(), H5T_NATIVE_FLOAT, mspace.get(), fspace.get(), H5P_DEFAULT, data) < 0)
      h5_fail(temp_path, "writing '" + name + "' of frame index " + std::to_string(next_frame));
  }

  // A 1-D dataset of `values` (int64) or `names` (UTF-8 strings) made an
  // HDF5 dimension scale (H5DS, the HDF5 Dimension Scale Specification) of
  // its own name: what netCDF-4, h5netcdf/xarray and h5py take for a
  // dimension's name and coordinates.
  Handle create_scale(const char* name, const std::vector<int64_t>& values,
                      const std::vector<std::string>& names = {}) {
    const fs::path& p = temp_path;
    const hsize_t n = names.empty() ? values.size() : names.size();
    Handle space = checked(H5Screate_simple(1, &n, nullptr), H5Sclose, p,
                           std::string("creating dataspace for scale '") + name + "'");
    Handle ds;
    if (names.empty()) {
      ds = checked(H5Dcreate2(file.get(), name, H5T_STD_I64LE, space.get(), H5P_DEFAULT,
                              H5P_DEFAULT, H5P_DEFAULT),
                   H5Dclose, p, std::string("creating scale '") + name + "'");
      if (H5Dwrite(ds.get(), H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()) < 0)
        h5_fail(p, std::string("writing scale '") + name + "'");
    } else {
      Handle type = checked(H5Tcopy(H5T_C_S1), H5Tclose, p, "creating string type");
      H5Tset_size(type.get(), H5T_VARIABLE);
      H5Tset_cset(type.get(), H5T_CSET_UTF8);
      ds = checked(H5Dcreate2(file.get(), name, type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT,
                              H5P_DEFAULT),
                   H5Dclose, p, std::string("creating scale '") + name + "'");
      std::vector<const char*> ptrs;
      for (const std::string& s : names) ptrs.push_back(s.c_str());
      if (H5Dwrite(ds.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, ptrs.data()) < 0)
        h5_fail(p, std::string("writing scale '") + name + "'");
    }
    if (H5DSset_scale(ds.get(), name) < 0)
      h5_fail(p, std::string("making '") + name + "' a dimension scale");
    return ds;
  }

  // Every dimension of every dataset gets a label (its part of `dims`) and
  // a dimension scale: frame numbers, version and pixel indices, channel
  // and camera column names (docs/shard_format.md, "Dimensions").
  void attach_dimension_scales() {
    const fs::path& p = temp_path;
    const ShardInfo& i = info;
    auto range = [](int64_t first, int64_t count) {
      std::vector<int64_t> v(static_cast<size_t>(count));
      for (int64_t k = 0; k < count; ++k) v[size_t(k)] = first + k;
      return v;
    };
    auto split = [](const std::string& csv) {
      std::vector<std::string> out;
      size_t start = 0;
      for (size_t comma; (comma = csv.find(',', start)) != std::string::npos; start = comma + 1)
        out.push_back(csv.substr(start, comma - start));
      out.push_back(csv.substr(start));
      return out;
    };
    std::map<std::string, Handle> scales;
    scales.emplace("frame", create_scale("frame", range(i.frame_start, i.frame_count())));
    scales.emplace("version", create_scale("version", range(0, i.versions)));
    scales.emplace("y", create_scale("y", range(0, i.height)));
    scales.emplace("x", create_scale("x", range(0, i.width)));
    std::vector<std::string> columns(camera_columns().begin(), camera_columns().end());
    scales.emplace("column", create_scale("column", {}, columns));
    auto attach = [&](const std::string& dataset, unsigned dim, const char* label,
                      const std::string& scale) {
      hid_t ds = datasets.at(dataset).get();
      if (H5DSset_label(ds, dim, label) < 0 ||
          H5DSattach_scale(ds, scales.at(scale).get(), dim) < 0)
        h5_fail(p, "attaching dimension scale '" + scale + "' to '" + dataset + "'");
    };
    for (const BufferInfo& b : buffer_infos()) {
      // One channel scale per channel set: its length must be the dimension's.
      const std::string channels = buffer_channel_names(b.name);
      std::string scale = "channel_";
      for (char c : channels)
        if (c != ',') scale += char(std::tolower(static_cast<unsigned char>(c)));
      if (!scales.count(scale))
        scales.emplace(scale, create_scale(scale.c_str(), {}, split(channels)));
      unsigned d = 0;
      attach(b.name, d++, "frame", "frame");
      if (b.per_version) attach(b.name, d++, "version", "version");
      attach(b.name, d++, "channel", scale);
      attach(b.name, d++, "y", "y");
      attach(b.name, d++, "x", "x");
    }
    attach("camera", 0, "frame", "frame");
    attach("camera", 1, "column", "column");
  }

  void write_root_attributes() {
    hid_t f = file.get();
    const fs::path& p = temp_path;
    write_attr_string(f, "schema", kShardSchema, p);
    write_attr_string(f, "batch_id", info.batch_id, p);
    write_attr_string(f, "scene_id", info.scene_id, p);
    write_attr_string(f, "scene_hash", info.scene_hash, p);
    write_attr_string(f, "job_hash", info.job_hash, p);
    write_attr_i64(f, "width", info.width, p);
    write_attr_i64(f, "height", info.height, p);
    write_attr_i64(f, "versions", info.versions, p);
    write_attr_i64(f, "spp_noisy", info.spp_noisy, p);
    write_attr_i64(f, "spp_reference", info.spp_reference, p);
    write_attr_f64(f, "reference_error", info.reference_error, p);
    write_attr_i64(f, "spp_albedo_ref", info.spp_albedo_ref, p);
    write_attr_u64(f, "seed", info.seed, p);
    write_attr_i64(f, "frame_start", info.frame_start, p);
    write_attr_i64(f, "frame_end", info.frame_end, p);
    write_attr_string(f, "renderer_version", info.renderer_version, p);
    write_attr_f64(f, "render_seconds", info.render_seconds, p);
    write_attr_f64(f, "pack_seconds", info.pack_seconds, p);
    write_attr_string(f, "created", info.created, p);
    write_attr_string(f, "data_checksum", checksum_to_string(info.data_checksum), p);
  }

  void close_all() {
    datasets.clear();
    file.reset();
  }

  void remove_temp() {
    close_all();
    std::error_code ec;
    fs::remove(temp_path, ec);  // best effort: we are already failing
  }
};

ShardWriter::ShardWriter(fs::path final_path, ShardInfo info) : impl_(std::make_unique<Impl>()) {
  DOFARM_CHECK_GE(info.width, 1);
  DOFARM_CHECK_GE(info.height, 1);
  DOFARM_CHECK_GE(info.versions, 1);
  DOFARM_CHECK_GE(info.frame_count(), 1);
  H5Lock lock;
  Impl& m = *impl_;
  m.final_path = std::move(final_path);
  m.temp_path = m.final_path;
  m.temp_path += ".tmp-" + std::to_string(::getpid());
  m.info = std::move(info);
  m.info.schema = kShardSchema;
  try {
    const fs::path& p = m.temp_path;
    Handle fapl = checked(H5Pcreate(H5P_FILE_ACCESS), H5Pclose, p, "creating fapl");
    // The 1.8 object format carries checksums on all metadata, so a damaged
    // header is reported instead of misread; h5py of any current version reads it.
    H5Pset_libver_bounds(fapl.get(), H5F_LIBVER_V18, H5F_LIBVER_LATEST);
    H5Pset_fclose_degree(fapl.get(), H5F_CLOSE_STRONG);
    m.file = checked(H5Fcreate(p.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl.get()), H5Fclose, p,
                     "cannot create file");
    const ShardInfo& i = m.info;
    hsize_t th = hsize_t(std::min(i.height, kShardTile));
    hsize_t tw = hsize_t(std::min(i.width, kShardTile));
    for (const BufferInfo& b : buffer_infos()) {
      // One chunk = one frame, one version, all channels, one 64x64 tile: the
      // unit the trainer's crops read.
      std::vector<hsize_t> chunk = {1};
      if (b.per_version) chunk.push_back(1);
      chunk.insert(chunk.end(), {hsize_t(b.channels), th, tw});
      const char* dims = b.per_version ? "frame,version,channel,y,x" : "frame,channel,y,x";
      m.datasets.emplace(b.name, m.create_dataset(b.name, dataset_dims(b, i), chunk, dims,
                                                  "channels", buffer_channel_names(b.name)));
    }
    std::string columns;
    for (const char* c : camera_columns()) {
      if (!columns.empty()) columns += ',';
      columns += c;
    }
    m.datasets.emplace("camera",
                       m.create_dataset("camera", {hsize_t(i.frame_count()), kCameraColumns},
                                        {hsize_t(i.frame_count()), kCameraColumns}, "frame,column",
                                        "columns", columns.c_str()));
    m.attach_dimension_scales();
  } catch (...) {
    m.remove_temp();
    throw;
  }
}

ShardWriter::~ShardWriter() {
  if (!impl_->committed) abort();
}

void ShardWriter::set_render_seconds(double seconds) {
  impl_->info.render_seconds = std::isfinite(seconds) && seconds > 0 ? seconds : 0;
}

const fs::path& ShardWriter::temp_path() const { return impl_->temp_path; }

void ShardWriter::abort() {
  H5Lock lock;
  impl_->failed = true;
  impl_->remove_temp();
}

void ShardWriter::add_frame(const FrameBuffers& fb) {
  H5Lock lock;
  Impl& m = *impl_;
  if (m.failed || m.committed)
    throw RuntimeError("shard " + m.final_path.string() + ": writer is no longer usable");
  try {
    const ShardInfo& i = m.info;
    if (m.next_frame >= i.frame_count())
      throw RuntimeError("shard " + m.final_path.string() + ": more frames than the " +
                         std::to_string(i.frame_count()) + " the shard was created for");
    if (fb.width != i.width || fb.height != i.height || fb.versions != i.versions)
      throw RuntimeError("shard " + m.final_path.string() + ": frame " +
                         std::to_string(fb.camera.frame) + " is " + std::to_string(fb.width) + "x" +
                         std::to_string(fb.height) + " with " + std::to_string(fb.versions) +
                         " versions; the shard is " + std::to_string(i.width) + "x" +
                         std::to_string(i.height) + " with " + std::to_string(i.versions));
    for (const BufferInfo& b : buffer_infos()) {
      size_t want = size_t(b.channels) * fb.plane() * (b.per_version ? i.versions : 1);
      if (buffer_data(fb, b.name).size() != want)
        throw RuntimeError("shard " + m.final_path.string() + ": frame " +
                           std::to_string(fb.camera.frame) + ", buffer '" + b.name + "' holds " +
                           std::to_string(buffer_data(fb, b.name).size()) + " values, expected " +
                           std::to_string(want));
    }
    check_finite(fb, m.final_path);
    for (const BufferInfo& b : buffer_infos()) {
      const std::vector<float>& data = buffer_data(fb, b.name);
      m.write(b.name, &b, data.data(), data.size());
      m.sum.update(data.data(), data.size() * sizeof(float));
    }
    auto row = camera_to_row(fb.camera);
    m.write("camera", nullptr, row.data(), row.size());
    m.sum.update(row.data(), sizeof row);
    ++m.next_frame;
  } catch (...) {
    m.failed = true;
    m.remove_temp();
    throw;
  }
}

ShardWriteResult ShardWriter::commit() {
  H5Lock lock;
  Impl& m = *impl_;
  const std::string where = "shard " + m.final_path.string();
  if (m.failed || m.committed) throw RuntimeError(where + ": writer is no longer usable");
  try {
    if (m.next_frame != m.info.frame_count())
      throw RuntimeError(where + ": commit after " + std::to_string(m.next_frame) + " of " +
                         std::to_string(m.info.frame_count()) + " frames");
    m.info.data_checksum = m.sum.digest();
    if (m.info.created.empty()) m.info.created = utc_now_iso8601();
    m.info.pack_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - m.started).count();
    m.write_root_attributes();
    if (H5Fflush(m.file.get(), H5F_SCOPE_GLOBAL) < 0) h5_fail(m.temp_path, "flushing");
    m.datasets.clear();
    if (m.file.reset() < 0) h5_fail(m.temp_path, "closing");
    fsync_path(m.temp_path, false);

    // Read everything back through the reader: the file must open as a shard,
    // carry what we meant to write and decode to the same bytes.
    ShardWriteResult result;
    {
      ShardReader check(m.temp_path);
      const ShardInfo& got = check.info();
      if (got.width != m.info.width || got.height != m.info.height ||
          got.versions != m.info.versions || got.frame_start != m.info.frame_start ||
          got.frame_end != m.info.frame_end || got.data_checksum != m.info.data_checksum)
        throw RuntimeError(where + ": verification failed: attributes read back differ");
      uint64_t back = check.compute_data_checksum();
      if (back != m.info.data_checksum)
        throw RuntimeError(where + ": verification failed: data read back has checksum " +
                           checksum_to_string(back) + ", written " +
                           checksum_to_string(m.info.data_checksum));
    }
    result.path = m.final_path;
    result.data_checksum = m.info.data_checksum;
    result.file_size = fs::file_size(m.temp_path);
    result.file_checksum = checksum_file(m.temp_path);
    std::error_code ec;
    fs::rename(m.temp_path, m.final_path, ec);
    if (ec) throw RuntimeError(where + ": rename from temporary failed: " + ec.message());
    m.committed = true;
    fs::path dir = m.final_path.parent_path();
    fsync_path(dir.empty() ? fs::path(".") : dir, true);
    return result;
  } catch (...) {
    if (!m.committed) {
      m.failed = true;
      m.remove_temp();
    }
    throw;
  }
}

ShardWriteResult write_shard(const fs::path& final_path, const ShardInfo& info,
                             const std::vector<FrameBuffers>& frames) {
  // Everything is checked before the file exists, so bad input leaves nothing.
  for (const FrameBuffers& fb : frames) check_finite(fb, final_path);
  if (int(frames.size()) != info.frame_count())
    throw RuntimeError("shard " + final_path.string() + ": " + std::to_string(frames.size()) +
                       " frames given for range " + std::to_string(info.frame_start) + ".." +
                       std::to_string(info.frame_end));
  ShardWriter w(final_path, info);
  for (const FrameBuffers& fb : frames) w.add_frame(fb);
  return w.commit();
}

}  // namespace dofarm
