#include "common/shard.h"

#include <fcntl.h>
#include <hdf5.h>
#include <unistd.h>

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
      "frame",      "time",       "position_x", "position_y", "position_z",     "rotation_w",
      "rotation_x", "rotation_y", "rotation_z", "fov_deg",    "focal_distance", "aperture"};
  return names;
}

std::array<float, kCameraColumns> camera_to_row(const CameraState& c) {
  return {float(c.frame), c.time,        c.position[0],    c.position[1],
          c.position[2],  c.rotation[0], c.rotation[1],    c.rotation[2],
          c.rotation[3],  c.fov_deg,     c.focal_distance, c.aperture};
}

CameraState camera_from_row(const float* r) {
  CameraState c;
  c.frame = int(std::lround(r[0]));
  c.time = r[1];
  for (int i = 0; i < 3; ++i) c.position[i] = r[2 + i];
  for (int i = 0; i < 4; ++i) c.rotation[i] = r[5 + i];
  c.fov_deg = r[9];
  c.focal_distance = r[10];
  c.aperture = r[11];
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

struct ShardReader::Impl {
  fs::path path;
  ShardInfo info;
  Handle file;
  std::map<std::string, Handle> datasets;  // buffers and "camera"

  void open(const fs::path& path);

  // Reads a hyperslab of one dataset into `out` (exactly its element count).
  void read(const std::string& name, const BufferInfo* b, int f0, int n, int version, Rect r,
            float* out, size_t count) const {
    const Handle& ds = datasets.at(name);
    Handle fspace = select_crop(ds.get(), b, f0, n, version, r, info.versions, path);
    hsize_t dim = count;
    Handle mspace = checked(H5Screate_simple(1, &dim, nullptr), H5Sclose, path, "memory space");
    if (H5Dread(ds.get(), H5T_NATIVE_FLOAT, mspace.get(), fspace.get(), H5P_DEFAULT, out) < 0) {
      std::ostringstream os;
      os << "reading '" << name << "' frames " << f0 << ".." << f0 + n - 1;
      if (b) os << " rect " << r.x << "," << r.y << "," << r.w << "," << r.h;
      os << " failed (damaged file?)";
      h5_fail(path, os.str());
    }
  }
};

ShardReader::ShardReader(const fs::path& path) : impl_(std::make_unique<Impl>()) {
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
  if (i.schema != kShardSchema)
    throw ShardFormatError(where + ": schema '" + i.schema +
                           "' is not supported (this build reads " + kShardSchema + ")");
  i.batch_id = read_attr_string(f, "batch_id", path);
  i.scene_id = read_attr_string(f, "scene_id", path);
  i.scene_hash = read_attr_string(f, "scene_hash", path);
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

  auto open_checked = [&](const std::string& name, const std::vector<hsize_t>& expect) {
    if (H5Lexists(f, name.c_str(), H5P_DEFAULT) <= 0)
      throw ShardFormatError(where + ": dataset '" + name + "' is missing");
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
  for (const BufferInfo& b : buffer_infos()) open_checked(b.name, dataset_dims(b, i));
  open_checked("camera", {hsize_t(i.frame_count()), hsize_t(kCameraColumns)});
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
  H5Lock lock;
  impl_->read(buffer, &b, frame_begin, frame_count, version, crop, out,
              crop_size(buffer, frame_count, version, crop));
}

std::vector<float> ShardReader::read_crop(const std::string& buffer, int frame_begin,
                                          int frame_count, int version, Rect crop) const {
  std::vector<float> out(crop_size(buffer, frame_count, version, crop));
  read_crop_into(buffer, frame_begin, frame_count, version, crop, out.data());
  return out;
}

std::vector<CameraState> ShardReader::cameras() const {
  H5Lock lock;
  int n = frame_count();
  std::vector<float> rows(size_t(n) * kCameraColumns);
  impl_->read("camera", nullptr, 0, n, 0, {}, rows.data(), rows.size());
  std::vector<CameraState> out;
  for (int f = 0; f < n; ++f) out.push_back(camera_from_row(&rows[size_t(f) * kCameraColumns]));
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
  impl_->read("camera", nullptr, frame, 1, 0, {}, row, kCameraColumns);
  fb.camera = camera_from_row(row);
  for (const BufferInfo& b : buffer_infos()) {
    bool wanted = buffers.empty();
    for (const std::string& name : buffers) wanted |= name == b.name;
    if (!wanted) continue;
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
  for (const BufferInfo& b : buffer_infos()) names.push_back(b.name);
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
    auto row = camera_to_row(fb.camera);
    sum.update(row.data(), sizeof row);
  }
  return sum.digest();
}

}  // namespace dofarm
