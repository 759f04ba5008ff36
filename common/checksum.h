// A fast 64-bit checksum for shards, staging tiles and manifests.
//
// The function is XXH64 (Collet, xxHash spec), seed 0, written here from the
// specification so the farm needs no extra library; `xxhsum -H64` and
// Python's `xxhash.xxh64` give the same values. It detects corruption
// (flipped bits, truncation, torn writes), not tampering: it is not a
// cryptographic hash.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

namespace dofarm {

// Streaming form: update() any number of times, digest() at any point.
class Checksum64 {
 public:
  explicit Checksum64(uint64_t seed = 0);
  void update(const void* data, size_t size);
  uint64_t digest() const;

 private:
  uint64_t seed_;
  uint64_t acc_[4];
  uint64_t total_ = 0;
  unsigned char buffer_[32];  // input not yet folded into acc_ (< 32 bytes)
  size_t buffered_ = 0;
};

uint64_t checksum64(const void* data, size_t size, uint64_t seed = 0);
// Checksum of a file's whole contents. Throws RuntimeError naming the file.
uint64_t checksum_file(const std::filesystem::path& path);

// Text form used in JSON and HDF5 attributes: "xxh64:" + 16 lower-case hex
// digits. parse_checksum() returns nullopt for anything else.
std::string checksum_to_string(uint64_t sum);
std::optional<uint64_t> parse_checksum(const std::string& text);

}  // namespace dofarm
