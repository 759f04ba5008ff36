// One coordinator per state folder. Two coordinators on one job store would
// both lease the same tasks and both write the SQLite file, each trusting its
// own memory (DESIGN.md: the memory is a cache of the store, built once), so
// the second one must not start. The lock is an flock(2) on STATE/dofarm.lock
// that holds the holder's pid as text (for the message): the kernel drops it
// when the process ends however it ends (kill -9 too), so a stale lock file
// never blocks a restart, and it is taken before the store is opened.
#pragma once

#include <filesystem>
#include <string>

namespace dofarm::coordinator {

class StateLock {
 public:
  // Takes the lock of `state_dir` (created if missing) or throws a
  // RuntimeError naming the folder and the pid that holds it.
  explicit StateLock(const std::filesystem::path& state_dir);
  ~StateLock();
  StateLock(const StateLock&) = delete;
  StateLock& operator=(const StateLock&) = delete;

  static std::filesystem::path file(const std::filesystem::path& state_dir) {
    return state_dir / "dofarm.lock";
  }

 private:
  int fd_ = -1;
};

}  // namespace dofarm::coordinator
