#include "common/manifest.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/checksum.h"

namespace dofarm {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// Holds an exclusive flock() on the folder's lock file for its lifetime. The
// lock file is never removed: removing it would let two writers lock two
// different inodes.
class ManifestLock {
 public:
  explicit ManifestLock(const fs::path& dir) {
    fs::path p = dir / (std::string(kManifestFile) + ".lock");
    fd_ = ::open(p.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd_ < 0) throw RuntimeError(p.string() + ": cannot open lock: " + std::strerror(errno));
    while (::flock(fd_, LOCK_EX) != 0) {
      if (errno == EINTR) continue;
      int err = errno;
      ::close(fd_);
      throw RuntimeError(p.string() + ": cannot lock: " + std::strerror(err));
    }
  }
  ~ManifestLock() { ::close(fd_); }  // closing releases the lock
  ManifestLock(const ManifestLock&) = delete;
  ManifestLock& operator=(const ManifestLock&) = delete;

 private:
  int fd_ = -1;
};

void fsync_fd_or_throw(int fd, const fs::path& p) {
  if (::fsync(fd) != 0) throw RuntimeError(p.string() + ": fsync failed: " + std::strerror(errno));
}

// Reads one key of a manifest entry, naming it on failure.
template <typename T>
T field(const json& e, const char* key, size_t index, const fs::path& file) {
  std::string where = file.string() + ": shards[" + std::to_string(index) + "]." + key;
  if (!e.contains(key)) throw RuntimeError(where + ": missing");
  try {
    return e.at(key).get<T>();
  } catch (const json::exception&) {
    throw RuntimeError(where + ": wrong type (" + e.at(key).dump() + ")");
  }
}

}  // namespace

ManifestEntry manifest_entry(const ShardInfo& info, const ShardWriteResult& written) {
  ManifestEntry e;
  e.file = written.path.filename().string();
  e.batch_id = info.batch_id;
  e.scene_id = info.scene_id;
  e.frame_start = info.frame_start;
  e.frame_end = info.frame_end;
  e.size = written.file_size;
  e.checksum = written.file_checksum;
  return e;
}

Manifest load_manifest(const fs::path& dir) {
  fs::path p = dir / kManifestFile;
  Manifest m;
  std::ifstream in(p);
  if (!in) {
    std::error_code ec;
    if (!fs::exists(p, ec)) return m;
    throw RuntimeError(p.string() + ": cannot read");
  }
  json j;
  try {
    j = json::parse(in);
  } catch (const json::parse_error& e) {
    throw RuntimeError(p.string() + ": not valid JSON: " + e.what());
  }
  if (!j.is_object() || !j.contains("schema") || !j["schema"].is_string())
    throw RuntimeError(p.string() + ": no \"schema\"; not a dofarm manifest");
  std::string schema = j["schema"];
  if (schema != kManifestSchema)
    throw RuntimeError(p.string() + ": schema '" + schema +
                       "' is not supported (this build reads " + kManifestSchema + ")");
  if (!j.contains("shards") || !j["shards"].is_array())
    throw RuntimeError(p.string() + ": \"shards\" must be an array");
  size_t i = 0;
  for (const json& e : j["shards"]) {
    ManifestEntry s;
    s.file = field<std::string>(e, "file", i, p);
    s.batch_id = field<std::string>(e, "batch_id", i, p);
    s.scene_id = field<std::string>(e, "scene_id", i, p);
    s.frame_start = field<int>(e, "frame_start", i, p);
    s.frame_end = field<int>(e, "frame_end", i, p);
    s.size = field<uint64_t>(e, "size", i, p);
    std::string sum = field<std::string>(e, "checksum", i, p);
    auto parsed = parse_checksum(sum);
    if (!parsed)
      throw RuntimeError(p.string() + ": shards[" + std::to_string(i) +
                         "].checksum: expected \"xxh64:\" and 16 hex digits, got \"" + sum + "\"");
    s.checksum = *parsed;
    // A path would let a manifest point outside its folder.
    if (s.file.empty() || s.file.find('/') != std::string::npos || s.file == "." || s.file == "..")
      throw RuntimeError(p.string() + ": shards[" + std::to_string(i) +
                         "].file: must be a plain file name, got \"" + s.file + "\"");
    m.shards.push_back(std::move(s));
    ++i;
  }
  return m;
}

void save_manifest(const fs::path& dir, const Manifest& manifest) {
  json shards = json::array();
  std::vector<ManifestEntry> sorted = manifest.shards;
  std::sort(sorted.begin(), sorted.end(),
            [](const ManifestEntry& a, const ManifestEntry& b) { return a.file < b.file; });
  for (const ManifestEntry& e : sorted)
    shards.push_back({{"file", e.file},
                      {"batch_id", e.batch_id},
                      {"scene_id", e.scene_id},
                      {"frame_start", e.frame_start},
                      {"frame_end", e.frame_end},
                      {"size", e.size},
                      {"checksum", checksum_to_string(e.checksum)}});
  json j = {{"schema", kManifestSchema}, {"shards", shards}};
  std::string text = j.dump(2) + "\n";

  fs::path final_path = dir / kManifestFile;
  fs::path temp = final_path;
  temp += ".tmp-" + std::to_string(::getpid());
  int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw RuntimeError(temp.string() + ": cannot create: " + std::strerror(errno));
  try {
    for (size_t done = 0; done < text.size();) {
      ssize_t n = ::write(fd, text.data() + done, text.size() - done);
      if (n < 0 && errno == EINTR) continue;
      if (n < 0) throw RuntimeError(temp.string() + ": write failed: " + std::strerror(errno));
      done += size_t(n);
    }
    fsync_fd_or_throw(fd, temp);
    ::close(fd);
    fd = -1;
    if (::rename(temp.c_str(), final_path.c_str()) != 0)
      throw RuntimeError(final_path.string() + ": rename failed: " + std::strerror(errno));
  } catch (...) {
    if (fd >= 0) ::close(fd);
    ::unlink(temp.c_str());
    throw;
  }
  int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0) throw RuntimeError(dir.string() + ": cannot open to fsync: " + std::strerror(errno));
  int rc = ::fsync(dfd);
  ::close(dfd);
  if (rc != 0) throw RuntimeError(dir.string() + ": fsync failed");
}

void add_to_manifest(const fs::path& dir, const ManifestEntry& entry) {
  ManifestLock lock(dir);
  Manifest m = load_manifest(dir);
  auto it = std::find_if(m.shards.begin(), m.shards.end(),
                         [&](const ManifestEntry& e) { return e.file == entry.file; });
  if (it != m.shards.end())
    *it = entry;
  else
    m.shards.push_back(entry);
  save_manifest(dir, m);
}

void rewrite_manifest(const fs::path& dir,
                      const std::function<void(Manifest& manifest, bool readable)>& edit) {
  ManifestLock lock(dir);
  Manifest m;
  bool readable = true;
  try {
    m = load_manifest(dir);
  } catch (const RuntimeError&) {
    readable = false;  // the caller rebuilds it from what it knows
  }
  edit(m, readable);
  save_manifest(dir, m);
}

std::vector<ManifestProblem> verify_manifest(const fs::path& dir, bool checksums) {
  std::vector<ManifestProblem> problems;
  for (const ManifestEntry& e : load_manifest(dir).shards) {
    fs::path p = dir / e.file;
    std::error_code ec;
    uint64_t size = fs::file_size(p, ec);
    if (ec) {
      problems.push_back({e.file, "missing (" + ec.message() + ")"});
      continue;
    }
    if (size != e.size) {
      problems.push_back(
          {e.file, "size " + std::to_string(size) + ", manifest says " + std::to_string(e.size)});
      continue;
    }
    if (!checksums) continue;
    try {
      uint64_t sum = checksum_file(p);
      if (sum != e.checksum)
        problems.push_back({e.file, "checksum " + checksum_to_string(sum) + ", manifest says " +
                                        checksum_to_string(e.checksum)});
    } catch (const RuntimeError& err) {
      problems.push_back({e.file, err.what()});
    }
  }
  return problems;
}

}  // namespace dofarm
