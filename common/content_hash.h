// Content hashes: what identifies an input (a scene file, a texture, a job)
// by its bytes rather than its name. BLAKE2b (RFC 7693, libsodium's
// crypto_generichash) with a 128-bit digest, written as 32 lowercase hex
// digits. Unlike the XXH64 checksums of common/checksum.h, which catch
// accidents in staged files, a content hash is meant to stay unique when
// someone picks the inputs on purpose.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace dofarm {

inline constexpr size_t kContentHashHexDigits = 32;

// Incremental hashing.
class ContentHasher {
 public:
  ContentHasher();
  void update(const void* data, size_t size);
  void update(std::string_view s) { update(s.data(), s.size()); }
  std::string hex();  // ends the hash

 private:
  alignas(64) unsigned char state_[384];
};

std::string content_hash(std::string_view bytes);

// The hash and size of a regular file. Never follows a symlink in the last
// component and never opens anything but a regular file (no FIFO, device or
// socket); throws RuntimeError naming the file otherwise. `max_bytes` bounds
// what is read: a larger file is an error.
struct FileHash {
  std::string hash;
  uint64_t size = 0;
};
FileHash hash_regular_file(const std::filesystem::path& path, uint64_t max_bytes = UINT64_MAX);

// Reads a whole regular file under the same rules (for small files: specs,
// job snapshots, ownership records).
std::string read_regular_file(const std::filesystem::path& path, uint64_t max_bytes);

// Opens a regular file for reading under the same rules; returns the file
// descriptor (the caller closes it) and sets `size`.
int open_regular_file(const std::filesystem::path& path, uint64_t max_bytes, uint64_t* size);

// Creates `path` (never replacing a file, never through a symlink) with
// `mode` from the start, writes `bytes` and fsyncs it; throws RuntimeError.
void write_new_file(const std::filesystem::path& path, std::string_view bytes, unsigned mode = 0644);

bool is_content_hash(std::string_view s);  // 32 lowercase hex digits

// Files read while an InputFileLog is alive on this thread are recorded in
// it (the scene loader, its textures and the environment map call
// note_input_file), so that a job's snapshot holds exactly what rendering it
// reads.
class InputFileLog {
 public:
  InputFileLog();
  ~InputFileLog();
  InputFileLog(const InputFileLog&) = delete;
  InputFileLog& operator=(const InputFileLog&) = delete;
  const std::vector<std::filesystem::path>& files() const { return files_; }
  void add(const std::filesystem::path& path);

 private:
  InputFileLog* previous_;
  std::vector<std::filesystem::path> files_;
};
void note_input_file(const std::filesystem::path& path);

}  // namespace dofarm
