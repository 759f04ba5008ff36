// The file side of EXR IO (common/exr_io.h): a frame is decoded from bytes
// read in one go and encoded whole in memory before it is written to a
// temporary name, fsynced and renamed (LevelDB-style; STYLE.md 6), so its
// checksum is computed over the very bytes written. Internal to common/'s EXR
// and image code; common/exr_io.h is the interface.
#pragma once

#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfIO.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace dofarm::exr_detail {

// 'PATH', as file names appear in error messages.
std::string quoted(const std::filesystem::path& path);

// An Imf::IStream over bytes already in memory (memory-mapped in OpenEXR's
// sense: the decoder reads them in place). `bytes` must outlive it.
class MemIStream : public Imf::IStream {
 public:
  MemIStream(const std::string& name, const std::vector<char>& bytes)
      : Imf::IStream(name.c_str()), bytes_(bytes) {}

  bool isMemoryMapped() const override { return true; }
  char* readMemoryMapped(int n) override;
  bool read(char c[], int n) override;
  uint64_t tellg() override { return pos_; }
  void seekg(uint64_t pos) override { pos_ = pos; }
  void clear() override {}

 private:
  const std::vector<char>& bytes_;
  size_t pos_ = 0;
};

// The whole file in one read. Throws RuntimeError naming it.
std::vector<char> read_whole_file(const std::filesystem::path& path);

// Writes `header` and `frame_buffer` to `path` so that a reader sees either
// the old file or the complete new one (temp, fsync, rename); creates the
// parent directories. Returns the XXH64 of the bytes written. This is the
// one boundary where OpenEXR exceptions of a write become RuntimeError.
uint64_t write_exr_atomically(const std::filesystem::path& path, const Imf::Header& header,
                              const Imf::FrameBuffer& frame_buffer);

}  // namespace dofarm::exr_detail
