// Lease tokens: every `task` reply carries an unguessable token, and a
// worker's heartbeat, done, failed and release count only with the token of
// the attempt it names. A client that can connect but never got the lease
// (or guesses a worker's id) cannot complete, fail, release or keep alive a
// task it does not hold.
//
// The token is derived, not stored: keyed BLAKE2b-128 (libsodium
// crypto_generichash) of (task, attempt, worker) under a 32-byte random key
// kept in STATE/lease.key. Leases outlive a coordinator restart (their
// workers may still report), and so does the key, so a restarted coordinator
// recognises the tokens it handed out before without a job store column,
// without a schema migration, and without a write per assignment. An attempt
// number is never reused for a task, so every lease has its own token.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>

namespace dofarm::coordinator {

class LeaseTokens {
 public:
  // Reads STATE/lease.key, creating it when absent (O_CREAT|O_EXCL|O_NOFOLLOW,
  // mode 0600 from the start). Refuses a key file that is not a regular file
  // of 32 bytes, or that others may read. Throws RuntimeError naming the file.
  explicit LeaseTokens(const std::filesystem::path& state_dir);

  // 32 lowercase hex digits.
  std::string token(int64_t task, int attempt, const std::string& worker) const;
  // Constant-time comparison with the token of (task, attempt, worker).
  bool valid(int64_t task, int attempt, const std::string& worker, const std::string& token) const;

 private:
  std::array<unsigned char, 32> key_{};
};

}  // namespace dofarm::coordinator
