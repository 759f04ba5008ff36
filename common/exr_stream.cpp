// Reading and writing EXR bytes (common/exr_stream.h): OpenEXR streams over
// memory, the whole-file read and the atomic write.
#include "common/exr_stream.h"

#include <ImfOutputFile.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <exception>
#include <system_error>

#include "common/checksum.h"
#include "common/error.h"

namespace dofarm::exr_detail {
namespace {

std::string errno_text(int err) { return std::error_code(err, std::generic_category()).message(); }

// An Imf::OStream into memory. A frame is encoded whole before any byte
// reaches the disk, so its checksum is computed over the very bytes written
// and nobody has to read the file back for it. OutputFile writes its offset
// table from its destructor, which swallows exceptions, so the first failure
// (out of memory) is remembered: an incomplete encoding must not be written.
class MemOStream : public Imf::OStream {
 public:
  explicit MemOStream(const std::string& name) : Imf::OStream(name.c_str()) {}

  void write(const char c[], int n) override {
    try {
      if (pos_ + size_t(n) > bytes_.size()) bytes_.resize(pos_ + size_t(n));
    } catch (const std::exception& e) {
      error_ = std::string("out of memory encoding the image: ") + e.what();
      throw Iex::IoExc(error_);
    }
    std::memcpy(bytes_.data() + pos_, c, size_t(n));
    pos_ += size_t(n);
  }
  uint64_t tellp() override { return pos_; }
  void seekp(uint64_t pos) override { pos_ = pos; }

  const std::vector<char>& bytes() const { return bytes_; }
  const std::string& error() const { return error_; }

 private:
  std::vector<char> bytes_;
  size_t pos_ = 0;
  std::string error_;
};

}  // namespace

std::string quoted(const std::filesystem::path& path) { return "'" + path.string() + "'"; }

char* MemIStream::readMemoryMapped(int n) {
  if (n < 0 || pos_ + size_t(n) > bytes_.size()) throw Iex::InputExc("unexpected end of file");
  char* p = const_cast<char*>(bytes_.data()) + pos_;
  pos_ += size_t(n);
  return p;
}

bool MemIStream::read(char c[], int n) {
  std::memcpy(c, readMemoryMapped(n), size_t(n));
  return pos_ < bytes_.size();
}

std::vector<char> read_whole_file(const std::filesystem::path& path) {
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw RuntimeError("cannot open " + quoted(path) + ": " + errno_text(errno));
  std::vector<char> bytes;
  try {
    struct stat st {};
    if (::fstat(fd, &st) != 0)
      throw RuntimeError("cannot stat " + quoted(path) + ": " + errno_text(errno));
    bytes.resize(size_t(st.st_size));
    size_t done = 0;
    while (done < bytes.size()) {
      ssize_t k = ::pread(fd, bytes.data() + done, bytes.size() - done, off_t(done));
      if (k < 0 && errno == EINTR) continue;
      if (k < 0) throw RuntimeError("cannot read " + quoted(path) + ": " + errno_text(errno));
      if (k == 0) break;  // shrank meanwhile: decode what is there, the reader reports it
      done += size_t(k);
    }
    bytes.resize(done);
  } catch (...) {
    ::close(fd);
    throw;
  }
  ::close(fd);
  return bytes;
}

namespace {

// Writes all of `bytes` to `fd`. Throws RuntimeError.
void write_all(int fd, const std::vector<char>& bytes) {
  size_t done = 0;
  while (done < bytes.size()) {
    ssize_t k = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) throw RuntimeError("write failed: " + errno_text(k < 0 ? errno : EIO));
    done += size_t(k);
  }
}

// Makes a rename durable: the directory entry itself must reach the disk.
void fsync_directory(const std::filesystem::path& dir) {
  int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) throw RuntimeError("cannot open directory " + quoted(dir) + ": " + errno_text(errno));
  int rc = ::fsync(fd);
  int err = errno;
  ::close(fd);
  if (rc != 0) throw RuntimeError("cannot fsync directory " + quoted(dir) + ": " + errno_text(err));
}

}  // namespace

uint64_t write_exr_atomically(const std::filesystem::path& path, const Imf::Header& header,
                              const Imf::FrameBuffer& frame_buffer) {
  // The counter keeps two threads of one process writing the same path from
  // sharing a temporary file.
  static std::atomic<unsigned> counter{0};
  const std::filesystem::path tmp = path.string() + ".tmp-" + std::to_string(::getpid()) + "-" +
                                    std::to_string(counter.fetch_add(1));
  const std::filesystem::path dir = path.has_parent_path() ? path.parent_path() : ".";
  int fd = -1;
  try {
    MemOStream stream(tmp.string());
    {
      Imf::OutputFile file(stream, header, 1);
      file.setFrameBuffer(frame_buffer);
      file.writePixels(header.dataWindow().max.y - header.dataWindow().min.y + 1);
    }  // the destructor writes the line offset table
    if (!stream.error().empty()) throw RuntimeError(stream.error());
    const uint64_t sum = checksum64(stream.bytes().data(), stream.bytes().size());
    std::filesystem::create_directories(dir);
    fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) throw RuntimeError("cannot create " + quoted(tmp) + ": " + errno_text(errno));
    write_all(fd, stream.bytes());
    if (::fsync(fd) != 0) throw RuntimeError("fsync failed: " + errno_text(errno));
    int rc = ::close(fd);
    fd = -1;
    if (rc != 0) throw RuntimeError("close failed: " + errno_text(errno));
    std::filesystem::rename(tmp, path);
    fsync_directory(dir);
    return sum;
  } catch (const std::exception& e) {
    if (fd >= 0) ::close(fd);
    std::error_code ignored;
    std::filesystem::remove(tmp, ignored);
    throw RuntimeError("cannot write EXR " + quoted(path) + ": " + e.what());
  }
}

}  // namespace dofarm::exr_detail
