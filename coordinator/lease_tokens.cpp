#include "coordinator/lease_tokens.h"

#include <fcntl.h>
#include <sodium.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "common/error.h"

namespace dofarm::coordinator {

namespace fs = std::filesystem;

namespace {

std::string errno_text() { return std::strerror(errno); }

// Reads exactly key.size() bytes of a regular, owner-only file.
bool read_key(const fs::path& path, std::array<unsigned char, 32>& key) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return false;
    throw RuntimeError("lease key " + path.string() + ": " + errno_text());
  }
  struct stat st {};
  std::string why;
  if (::fstat(fd, &st) != 0) {
    why = errno_text();
  } else if (!S_ISREG(st.st_mode)) {
    why = "not a regular file";
  } else if (st.st_mode & 077) {
    why = "readable by others (mode " + std::to_string(st.st_mode & 0777) + "); chmod 600 it";
  } else if (st.st_size != off_t(key.size())) {
    why = "holds " + std::to_string(st.st_size) + " bytes, expected " + std::to_string(key.size());
  } else if (::read(fd, key.data(), key.size()) != ssize_t(key.size())) {
    why = "short read";
  }
  ::close(fd);
  if (!why.empty()) throw RuntimeError("lease key " + path.string() + ": " + why);
  return true;
}

}  // namespace

LeaseTokens::LeaseTokens(const fs::path& state_dir) {
  if (sodium_init() < 0) throw RuntimeError("libsodium could not be initialised");
  const fs::path path = state_dir / "lease.key";
  if (read_key(path, key_)) return;
  randombytes_buf(key_.data(), key_.size());
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0600);
  if (fd < 0) {
    // Another coordinator on the same state folder made it first: use theirs.
    if (errno == EEXIST && read_key(path, key_)) return;
    throw RuntimeError("lease key " + path.string() + ": " + errno_text());
  }
  const bool ok = ::write(fd, key_.data(), key_.size()) == ssize_t(key_.size()) && ::fsync(fd) == 0;
  ::close(fd);
  if (!ok) {
    ::unlink(path.c_str());
    throw RuntimeError("lease key " + path.string() + ": could not write it");
  }
}

std::string LeaseTokens::token(int64_t task, int attempt, const std::string& worker) const {
  // Fixed-width task and attempt, then the worker id: no two inputs collide.
  unsigned char head[12];
  for (int i = 0; i < 8; ++i) head[i] = static_cast<unsigned char>(uint64_t(task) >> (8 * i));
  for (int i = 0; i < 4; ++i)
    head[8 + i] = static_cast<unsigned char>(uint32_t(attempt) >> (8 * i));
  crypto_generichash_state state;
  crypto_generichash_init(&state, key_.data(), key_.size(), 16);
  crypto_generichash_update(&state, head, sizeof(head));
  crypto_generichash_update(&state, reinterpret_cast<const unsigned char*>(worker.data()),
                            worker.size());
  unsigned char out[16];
  crypto_generichash_final(&state, out, sizeof(out));
  char hex[33];
  sodium_bin2hex(hex, sizeof(hex), out, sizeof(out));
  return std::string(hex, 32);
}

bool LeaseTokens::valid(int64_t task, int attempt, const std::string& worker,
                        const std::string& token) const {
  if (token.size() != 32) return false;
  const std::string expected = this->token(task, attempt, worker);
  return sodium_memcmp(expected.data(), token.data(), 32) == 0;
}

}  // namespace dofarm::coordinator
