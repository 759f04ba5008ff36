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
// The HDF5 boundary (STYLE.md 4): automatic error printing is switched off and
// every failed call turns the error stack into the text of one RuntimeError.

std::recursive_mutex& hdf5_mutex() {
  static std::recursive_mutex m;
  return m;
}

namespace {

// Held for the whole of every public call. Switching auto-printing off here
// rather than once keeps it off even if other code turned it back on.
class H5Lock {
 public:
  H5Lock() : lock_(hdf5_mutex()) { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

 private:
  std::lock_guard<std::recursive_mutex> lock_;
};

// The innermost entries carry the cause ("truncated file", "Fletcher32
// checksum failed"); the outer ones only repeat "unable to open file".
std::string take_error_stack() {
  std::vector<std::string> lines;
  H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_UPWARD,
      [](unsigned, const H5E_error2_t* e, void* data) -> herr_t {
        auto* out = static_cast<std::vector<std::string>*>(data);
        std::string line = e->desc ? e->desc : "";
        char minor[256] = {0};
        if (H5Eget_msg(e->min_num, nullptr, minor, sizeof minor) > 0 && minor[0] != '\0')
          line += line.empty() ? minor : std::string(" (") + minor + ")";
        if (!line.empty()) out->push_back(line);
        return 0;
      },
      &lines);
  H5Eclear2(H5E_DEFAULT);
  std::string s;
  for (size_t i = 0; i < lines.size() && i < 3; ++i) s += (i ? "; " : "") + lines[i];
  return s.empty() ? "HDF5 reported no detail" : s;
}

[[noreturn]] void h5_fail(const fs::path& path, const std::string& what) {
  throw RuntimeError("shard " + path.string() + ": " + what + ": " + take_error_stack());
}

// Owns one HDF5 identifier; the closer matches its kind.
class Handle {
 public:
  Handle() = default;
  Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  Handle(Handle&& o) noexcept : id_(o.id_), close_(o.close_) { o.id_ = -1; }
  Handle& operator=(Handle&& o) noexcept {
    reset();
    std::swap(id_, o.id_);
    close_ = o.close_;
    return *this;
  }
  ~Handle() { reset(); }
  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  // Returns the close status, so the writer can tell a failed final flush.
  herr_t reset() {
    herr_t rc = 0;
    if (id_ >= 0) rc = close_(id_);
    id_ = -1;
    return rc;
  }

 private:
  hid_t id_ = -1;
  herr_t (*close_)(hid_t) = nullptr;
};

Handle checked(hid_t id, herr_t (*close)(hid_t), const fs::path& path, const std::string& what) {
  if (id < 0) h5_fail(path, what);
  return Handle(id, close);
}

// Shape of a dataset for F frames: (F, V, C, H, W) or (F, C, H, W); camera (F, K).
std::vector<hsize_t> dataset_dims(const BufferInfo& b, const ShardInfo& info) {
  std::vector<hsize_t> d = {hsize_t(info.frame_count())};
  if (b.per_version) d.push_back(hsize_t(info.versions));
  d.push_back(hsize_t(b.channels));
  d.push_back(hsize_t(info.height));
  d.push_back(hsize_t(info.width));
  return d;
}

std::string dims_to_string(const std::vector<hsize_t>& d) {
  std::string s = "(";
  for (size_t i = 0; i < d.size(); ++i) s += (i ? ", " : "") + std::to_string(d[i]);
  return s + ")";
}

// --- attributes -------------------------------------------------------------

void write_attr(hid_t obj, const char* name, hid_t file_type, hid_t mem_type, const void* value,
                const fs::path& path) {
  Handle space = checked(H5Screate(H5S_SCALAR), H5Sclose, path, "creating attribute space");
  Handle attr = checked(H5Acreate2(obj, name, file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT),
                        H5Aclose, path, std::string("creating attribute '") + name + "'");
  if (H5Awrite(attr.get(), mem_type, value) < 0)
    h5_fail(path, std::string("writing attribute '") + name + "'");
}

// Variable-length UTF-8 strings: h5py returns them as str, not bytes.
void write_attr_string(hid_t obj, const char* name, const std::string& value,
                       const fs::path& path) {
  Handle type = checked(H5Tcopy(H5T_C_S1), H5Tclose, path, "creating string type");
  H5Tset_size(type.get(), H5T_VARIABLE);
  H5Tset_cset(type.get(), H5T_CSET_UTF8);
  const char* p = value.c_str();
  write_attr(obj, name, type.get(), type.get(), &p, path);
}
void write_attr_i64(hid_t obj, const char* name, int64_t v, const fs::path& path) {
  write_attr(obj, name, H5T_STD_I64LE, H5T_NATIVE_INT64, &v, path);
}
void write_attr_u64(hid_t obj, const char* name, uint64_t v, const fs::path& path) {
  write_attr(obj, name, H5T_STD_U64LE, H5T_NATIVE_UINT64, &v, path);
}
void write_attr_f64(hid_t obj, const char* name, double v, const fs::path& path) {
  write_attr(obj, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &v, path);
}

Handle open_attr(hid_t obj, const char* name, const fs::path& path) {
  htri_t exists = H5Aexists(obj, name);
  if (exists < 0) h5_fail(path, std::string("looking up attribute '") + name + "'");
  if (exists == 0)
    throw ShardFormatError("shard " + path.string() + ": attribute '" + name +
                           "' is missing; not a complete dofarm shard");
  return checked(H5Aopen(obj, name, H5P_DEFAULT), H5Aclose, path,
                 std::string("opening attribute '") + name + "'");
}

// Reads fixed-length as well as variable-length strings, so files written by
// other tools (h5py writes either) are accepted.
std::string read_attr_string(hid_t obj, const char* name, const fs::path& path) {
  Handle attr = open_attr(obj, name, path);
  Handle type = checked(H5Aget_type(attr.get()), H5Tclose, path, "reading attribute type");
  if (H5Tget_class(type.get()) != H5T_STRING)
    throw ShardFormatError("shard " + path.string() + ": attribute '" + name + "' is not a string");
  if (H5Tis_variable_str(type.get()) > 0) {
    Handle mem = checked(H5Tcopy(H5T_C_S1), H5Tclose, path, "creating string type");
    H5Tset_size(mem.get(), H5T_VARIABLE);
    H5Tset_cset(mem.get(), H5Tget_cset(type.get()));
    char* p = nullptr;
    if (H5Aread(attr.get(), mem.get(), &p) < 0)
      h5_fail(path, std::string("reading attribute '") + name + "'");
    std::string s = p ? p : "";
    H5free_memory(p);
    return s;
  }
  size_t n = H5Tget_size(type.get());
  std::string s(n, '\0');
  if (H5Aread(attr.get(), type.get(), s.data()) < 0)
    h5_fail(path, std::string("reading attribute '") + name + "'");
  s.resize(std::strlen(s.c_str()));  // fixed-length strings are NUL-padded
  return s;
}

template <typename T>
T read_attr_number(hid_t obj, const char* name, hid_t mem_type, const fs::path& path) {
  Handle attr = open_attr(obj, name, path);
  T v{};
  if (H5Aread(attr.get(), mem_type, &v) < 0)
    h5_fail(path, std::string("reading attribute '") + name + "'");
  return v;
}

std::string utc_now_iso8601() {
  std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

void fsync_path(const fs::path& p, bool directory) {
  int fd = ::open(p.c_str(), directory ? (O_RDONLY | O_DIRECTORY) : O_RDWR);
  if (fd < 0) throw RuntimeError(p.string() + ": cannot open to fsync: " + std::strerror(errno));
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) throw RuntimeError(p.string() + ": fsync failed: " + std::strerror(err));
}

// Throws naming the frame, buffer and first offending element.
void check_finite(const FrameBuffers& fb, const fs::path& path) {
  for (const BufferInfo& b : buffer_infos()) {
    const std::vector<float>& data = buffer_data(fb, b.name);
    size_t bad = 0, first = 0;
    for (size_t i = 0; i < data.size(); ++i)
      if (!std::isfinite(data[i]) && bad++ == 0) first = i;
    if (bad == 0) continue;
    size_t plane = fb.plane();
    size_t p = first / plane, pix = first % plane;
    std::ostringstream os;
    os << "shard " << path.string() << ": frame " << fb.camera.frame << ", buffer '" << b.name
       << "': " << bad << " non-finite value(s), first " << data[first] << " at ";
    if (b.per_version) os << "version " << p / b.channels << ", ";
    os << "channel " << p % b.channels << ", x " << pix % fb.width << ", y " << pix / fb.width
       << "; refusing to write it";
    throw RuntimeError(os.str());
  }
  auto row = camera_to_row(fb.camera);
  for (int i = 0; i < kCameraColumns; ++i)
    if (!std::isfinite(row[i]))
      throw RuntimeError("shard " + path.string() + ": frame " + std::to_string(fb.camera.frame) +
                         ", camera column '" + camera_columns()[i] +
                         "' is not finite; refusing to write it");
}

// Selects frames [f0, f0+n), the given version (or all) and rect of a dataset.
Handle select_crop(hid_t dataset, const BufferInfo* b, int f0, int n, int version, Rect r,
                   int versions, const fs::path& path) {
  Handle space = checked(H5Dget_space(dataset), H5Sclose, path, "getting dataspace");
  std::vector<hsize_t> start, count;
  if (!b) {  // camera
    start = {hsize_t(f0), 0};
    count = {hsize_t(n), hsize_t(kCameraColumns)};
  } else {
    start = {hsize_t(f0)};
    count = {hsize_t(n)};
    if (b->per_version) {
      bool all = version == ShardReader::kAllVersions;
      start.push_back(all ? 0 : hsize_t(version));
      count.push_back(all ? hsize_t(versions) : 1);
    }
    start.insert(start.end(), {0, hsize_t(r.y), hsize_t(r.x)});
    count.insert(count.end(), {hsize_t(b->channels), hsize_t(r.h), hsize_t(r.w)});
  }
  if (H5Sselect_hyperslab(space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(),
                          nullptr) < 0)
    h5_fail(path, "selecting hyperslab");
  return space;
}

const BufferInfo& find_buffer(const std::string& name) {
  for (const BufferInfo& b : buffer_infos())
    if (name == b.name) return b;
  throw RuntimeError("unknown buffer name '" + name + "'");
}

}  // namespace

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
    Handle fspace = select_crop(ds.get(), b, next_frame, 1, ShardReader::kAllVersions, full,
                                info.versions, temp_path);
    hsize_t dim = count;
    Handle mspace =
        checked(H5Screate_simple(1, &dim, nullptr), H5Sclose, temp_path, "memory space");
    if (H5Dwrite(ds.get(), H5T_NATIVE_FLOAT, mspace.get(), fspace.get(), H5P_DEFAULT, data) < 0)
      h5_fail(temp_path, "writing '" + name + "' of frame index " + std::to_string(next_frame));
  }

  void write_root_attributes() {
    hid_t f = file.get();
    const fs::path& p = temp_path;
    write_attr_string(f, "schema", kShardSchema, p);
    write_attr_string(f, "batch_id", info.batch_id, p);
    write_attr_string(f, "scene_id", info.scene_id, p);
    write_attr_string(f, "scene_hash", info.scene_hash, p);
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
    for (const char* c : camera_columns()) columns += (columns.empty() ? "" : ",") + std::string(c);
    m.datasets.emplace("camera",
                       m.create_dataset("camera", {hsize_t(i.frame_count()), kCameraColumns},
                                        {hsize_t(i.frame_count()), kCameraColumns}, "frame,column",
                                        "columns", columns.c_str()));
  } catch (...) {
    m.remove_temp();
    throw;
  }
}

ShardWriter::~ShardWriter() {
  if (!impl_->committed) abort();
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
