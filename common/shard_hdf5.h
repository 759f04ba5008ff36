// Internal to the shard reader and writer (common/shard.cpp,
// common/shard_writer.cpp): the HDF5 boundary (STYLE.md 4) and the helpers
// both sides use. Automatic error printing is switched off and every failed
// call turns the error stack into the text of one RuntimeError. Not part of
// the public API: include common/shard.h.
#pragma once

#include <fcntl.h>
#include <hdf5.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "common/shard.h"

namespace dofarm::shard_detail {

namespace fs = std::filesystem;

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
inline std::string take_error_stack() {
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

[[noreturn]] inline void h5_fail(const fs::path& path, const std::string& what) {
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

inline Handle checked(hid_t id, herr_t (*close)(hid_t), const fs::path& path,
                      const std::string& what) {
  if (id < 0) h5_fail(path, what);
  return Handle(id, close);
}

// Shape of a dataset for F frames: (F, V, C, H, W) or (F, C, H, W); camera (F, K).
inline std::vector<hsize_t> dataset_dims(const BufferInfo& b, const ShardInfo& info) {
  std::vector<hsize_t> d = {hsize_t(info.frame_count())};
  if (b.per_version) d.push_back(hsize_t(info.versions));
  d.push_back(hsize_t(b.channels));
  d.push_back(hsize_t(info.height));
  d.push_back(hsize_t(info.width));
  return d;
}

inline std::string dims_to_string(const std::vector<hsize_t>& d) {
  std::string s = "(";
  for (size_t i = 0; i < d.size(); ++i) s += (i ? ", " : "") + std::to_string(d[i]);
  return s + ")";
}

// --- attributes -------------------------------------------------------------

inline void write_attr(hid_t obj, const char* name, hid_t file_type, hid_t mem_type,
                       const void* value, const fs::path& path) {
  Handle space = checked(H5Screate(H5S_SCALAR), H5Sclose, path, "creating attribute space");
  Handle attr = checked(H5Acreate2(obj, name, file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT),
                        H5Aclose, path, std::string("creating attribute '") + name + "'");
  if (H5Awrite(attr.get(), mem_type, value) < 0)
    h5_fail(path, std::string("writing attribute '") + name + "'");
}

// Variable-length UTF-8 strings: h5py returns them as str, not bytes.
inline void write_attr_string(hid_t obj, const char* name, const std::string& value,
                              const fs::path& path) {
  Handle type = checked(H5Tcopy(H5T_C_S1), H5Tclose, path, "creating string type");
  H5Tset_size(type.get(), H5T_VARIABLE);
  H5Tset_cset(type.get(), H5T_CSET_UTF8);
  const char* p = value.c_str();
  write_attr(obj, name, type.get(), type.get(), &p, path);
}
inline void write_attr_i64(hid_t obj, const char* name, int64_t v, const fs::path& path) {
  write_attr(obj, name, H5T_STD_I64LE, H5T_NATIVE_INT64, &v, path);
}
inline void write_attr_u64(hid_t obj, const char* name, uint64_t v, const fs::path& path) {
  write_attr(obj, name, H5T_STD_U64LE, H5T_NATIVE_UINT64, &v, path);
}
inline void write_attr_f64(hid_t obj, const char* name, double v, const fs::path& path) {
  write_attr(obj, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &v, path);
}

inline Handle open_attr(hid_t obj, const char* name, const fs::path& path) {
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
inline std::string read_attr_string(hid_t obj, const char* name, const fs::path& path) {
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
inline T read_attr_number(hid_t obj, const char* name, hid_t mem_type, const fs::path& path) {
  Handle attr = open_attr(obj, name, path);
  T v{};
  if (H5Aread(attr.get(), mem_type, &v) < 0)
    h5_fail(path, std::string("reading attribute '") + name + "'");
  return v;
}

inline std::string utc_now_iso8601() {
  std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

inline void fsync_path(const fs::path& p, bool directory) {
  int fd = ::open(p.c_str(), directory ? (O_RDONLY | O_DIRECTORY) : O_RDWR);
  if (fd < 0) throw RuntimeError(p.string() + ": cannot open to fsync: " + std::strerror(errno));
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) throw RuntimeError(p.string() + ": fsync failed: " + std::strerror(err));
}

// Throws naming the frame, buffer and first offending element.
inline void check_finite(const FrameBuffers& fb, const fs::path& path) {
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
// `count_out`, when given, receives the selection's shape: a memory space of
// that shape lets HDF5 map the selection chunk by chunk (a flat 1-D memory
// space sends it down an element-by-element path several times slower).
inline Handle select_crop(hid_t dataset, const BufferInfo* b, int f0, int n, int version, Rect r,
                          int versions, const fs::path& path,
                          std::vector<hsize_t>* count_out = nullptr) {
  Handle space = checked(H5Dget_space(dataset), H5Sclose, path, "getting dataspace");
  std::vector<hsize_t> start, count;
  if (!b) {  // camera: all its columns (12 before version 3)
    hsize_t dims[2] = {0, 0};
    if (H5Sget_simple_extent_ndims(space.get()) != 2) h5_fail(path, "camera is not 2-D");
    H5Sget_simple_extent_dims(space.get(), dims, nullptr);
    start = {hsize_t(f0), 0};
    count = {hsize_t(n), dims[1]};
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
  if (count_out) *count_out = count;
  return space;
}

inline const BufferInfo& find_buffer(const std::string& name) {
  for (const BufferInfo& b : buffer_infos())
    if (name == b.name) return b;
  throw RuntimeError("unknown buffer name '" + name + "'");
}

}  // namespace dofarm::shard_detail
