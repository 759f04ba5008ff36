#include "coordinator/claims.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <utility>
#include <vector>

namespace dofarm::coordinator {

namespace {

const char* file_type(mode_t m) {
  if (S_ISLNK(m)) return "a symbolic link";
  if (S_ISDIR(m)) return "a directory";
  if (S_ISFIFO(m)) return "a FIFO";
  if (S_ISCHR(m)) return "a character device";
  if (S_ISBLK(m)) return "a block device";
  if (S_ISSOCK(m)) return "a socket";
  return "not a regular file";
}

}  // namespace

ClaimFile::~ClaimFile() {
  if (fd_ >= 0) ::close(fd_);
}

ClaimFile::ClaimFile(ClaimFile&& o) noexcept
    : fd_(std::exchange(o.fd_, -1)),
      size_(o.size_),
      read_(o.read_),
      sum_(o.sum_),
      error_(std::move(o.error_)) {}

ClaimFile& ClaimFile::operator=(ClaimFile&& o) noexcept {
  if (this != &o) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(o.fd_, -1);
    size_ = o.size_;
    read_ = o.read_;
    sum_ = o.sum_;
    error_ = std::move(o.error_);
  }
  return *this;
}

std::string ClaimFile::open(const ExpectedOutput& expected, const std::string& path,
                            uint64_t size) {
  if (path != expected.path)
    return "staged_path \"" + path.substr(0, 512) + "\" is not where this task's output belongs (" +
           expected.path + ")";
  if (size > expected.max_bytes)
    return "size " + std::to_string(size) + " exceeds the bound of " +
           std::to_string(expected.max_bytes) + " bytes for this task";
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) return path + ": " + std::strerror(errno);
  if (!S_ISREG(st.st_mode)) return path + " is " + file_type(st.st_mode);
  // Opened only now, and so that a file swapped for a FIFO or a symlink in
  // between still cannot block us or lead elsewhere.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return path + ": " + std::strerror(errno);
  struct stat fst {};
  std::string why;
  if (::fstat(fd, &fst) != 0) {
    why = path + ": " + std::strerror(errno);
  } else if (!S_ISREG(fst.st_mode) || fst.st_ino != st.st_ino || fst.st_dev != st.st_dev) {
    why = path + " changed while it was being opened";
  } else if (uint64_t(fst.st_size) != size) {
    why = path + " holds " + std::to_string(fst.st_size) + " bytes, the claim says " +
          std::to_string(size);
  }
  if (!why.empty()) {
    ::close(fd);
    return why;
  }
  if (fd_ >= 0) ::close(fd_);
  fd_ = fd;
  size_ = size;
  read_ = 0;
  sum_ = Checksum64();
  error_.clear();
  return "";
}

uint64_t ClaimFile::advance(uint64_t budget) {
  if (finished()) return 0;
  static thread_local std::vector<unsigned char> buffer(1 << 20);
  uint64_t done = 0;
  while (done < budget && read_ < size_) {
    const size_t want = size_t(std::min<uint64_t>({budget - done, size_ - read_, buffer.size()}));
    const ssize_t n = ::read(fd_, buffer.data(), want);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      error_ = std::string("read: ") + std::strerror(errno);
      break;
    }
    if (n == 0) {
      error_ = "the file shrank to " + std::to_string(read_) + " bytes while it was read";
      break;
    }
    sum_.update(buffer.data(), size_t(n));
    read_ += uint64_t(n);
    done += uint64_t(n);
  }
  if (finished() && fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
  return done;
}

std::string ClaimFile::verdict(const std::string& checksum) const {
  if (!error_.empty()) return error_;
  if (read_ != size_) return "not read";
  const std::string got = checksum_to_string(sum_.digest());
  if (got != checksum) return "checksum " + got + ", the claim says " + checksum;
  return "";
}

}  // namespace dofarm::coordinator
