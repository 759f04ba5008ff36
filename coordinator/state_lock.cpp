#include "coordinator/state_lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "common/error.h"

namespace dofarm::coordinator {

StateLock::StateLock(const std::filesystem::path& state_dir) {
  const std::filesystem::path path = file(state_dir);
  // O_NOFOLLOW: a planted symlink does not make us lock (or truncate) its target.
  fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0644);
  if (fd_ < 0)
    throw RuntimeError("cannot open the state lock " + path.string() + ": " + std::strerror(errno));
  struct stat st;
  if (::fstat(fd_, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd_);
    throw RuntimeError("the state lock " + path.string() + " is not a regular file");
  }
  if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    // The holder wrote its pid; a short read bounded by the buffer.
    char buf[32] = {};
    const ssize_t n = ::pread(fd_, buf, sizeof(buf) - 1, 0);
    std::string pid = n > 0 ? std::string(buf, size_t(n)) : "";
    while (!pid.empty() && (pid.back() == '\n' || pid.back() == ' ')) pid.pop_back();
    ::close(fd_);
    fd_ = -1;
    if (err == EWOULDBLOCK)
      throw RuntimeError("another coordinator" + (pid.empty() ? "" : " (pid " + pid + ")") +
                         " is running on the state folder " + state_dir.string() + " (it holds " +
                         path.string() +
                         "); stop it first, or give --state "
                         "another folder");
    throw RuntimeError("cannot lock " + path.string() + ": " + std::strerror(err));
  }
  const std::string pid = std::to_string(::getpid()) + "\n";
  // Only for the message a second coordinator gives: a failed write costs
  // nothing but the pid in it.
  if (::ftruncate(fd_, 0) == 0) (void)!::pwrite(fd_, pid.data(), pid.size(), 0);
}

StateLock::~StateLock() {
  if (fd_ >= 0) ::close(fd_);  // releases the lock; the file stays (it is harmless)
}

}  // namespace dofarm::coordinator
