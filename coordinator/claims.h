// Checking a worker's `done` claim against the file it names, without ever
// letting one message stall the coordinator's loop.
//
// The claimed path must be exactly where the task's output belongs
// (Scheduler::expected_output), a regular file (lstat: a symlink, FIFO,
// device or directory is refused before anything is opened), opened with
// O_NOFOLLOW|O_NONBLOCK and checked again with fstat (same inode), of the
// reported size, and no larger than the task's bound. Only then are its
// bytes read, at most `budget` per call, so a large shard is checksummed in
// slices across rounds of the receive loop (Server::advance_claims) while
// every other message is still served.
#pragma once

#include <cstdint>
#include <string>

#include "common/checksum.h"
#include "coordinator/scheduler.h"

namespace dofarm::coordinator {

class ClaimFile {
 public:
  ClaimFile() = default;
  ~ClaimFile();
  ClaimFile(ClaimFile&& o) noexcept;
  ClaimFile& operator=(ClaimFile&& o) noexcept;
  ClaimFile(const ClaimFile&) = delete;
  ClaimFile& operator=(const ClaimFile&) = delete;

  // Checks the claim's path, type and size and opens the file; returns why
  // it is refused, or empty.
  std::string open(const ExpectedOutput& expected, const std::string& path, uint64_t size);
  // Reads and checksums up to `budget` more bytes; returns how many it read.
  uint64_t advance(uint64_t budget);
  bool finished() const { return fd_ < 0 || read_ == size_ || !error_.empty(); }
  uint64_t remaining() const { return size_ - read_; }
  // Once finished: why the claim is refused (a read error, a file that
  // shrank, another checksum), or empty when `checksum` is right.
  std::string verdict(const std::string& checksum) const;

 private:
  int fd_ = -1;
  uint64_t size_ = 0, read_ = 0;
  Checksum64 sum_;
  std::string error_;
};

}  // namespace dofarm::coordinator
