#include "common/content_hash.h"

#include <fcntl.h>
#include <sodium.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "common/error.h"

namespace dofarm {

namespace fs = std::filesystem;

namespace {

constexpr size_t kDigestBytes = kContentHashHexDigits / 2;
static_assert(sizeof(crypto_generichash_state) <= 384);

std::string to_hex(const unsigned char* d, size_t n) {
  static const char* digits = "0123456789abcdef";
  std::string s(2 * n, '0');
  for (size_t i = 0; i < n; ++i) {
    s[2 * i] = digits[d[i] >> 4];
    s[2 * i + 1] = digits[d[i] & 15];
  }
  return s;
}

}  // namespace

int open_regular_file(const fs::path& path, uint64_t max_bytes, uint64_t* size) {
  int fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ELOOP)
      throw RuntimeError("\"" + path.string() + "\": is a symbolic link, not a regular file");
    throw RuntimeError("\"" + path.string() + "\": cannot open: " + std::strerror(errno));
  }
  struct stat st;
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    throw RuntimeError("\"" + path.string() + "\": not a regular file");
  }
  if (uint64_t(st.st_size) > max_bytes) {
    ::close(fd);
    throw RuntimeError("\"" + path.string() + "\": " + std::to_string(st.st_size) +
                       " bytes, more than the " + std::to_string(max_bytes) + " allowed");
  }
  *size = uint64_t(st.st_size);
  return fd;
}

void write_new_file(const fs::path& path, std::string_view bytes, unsigned mode) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, mode);
  if (fd < 0)
    throw RuntimeError("cannot create \"" + path.string() + "\": " + std::strerror(errno));
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    done += size_t(n);
  }
  const bool ok = done == bytes.size() && ::fsync(fd) == 0;
  ::close(fd);
  if (!ok) throw RuntimeError("cannot write \"" + path.string() + "\"");
}

namespace {

// Reads up to `size` bytes (the size fstat gave), calling `sink` per block;
// a file that grows or shrinks meanwhile is an error.
template <typename Sink>
void read_all(int fd, const fs::path& path, uint64_t size, Sink&& sink) {
  std::vector<unsigned char> buf(1 << 20);
  uint64_t total = 0;
  while (true) {
    ssize_t n = ::read(fd, buf.data(), buf.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      throw RuntimeError("\"" + path.string() + "\": read failed: " + std::strerror(errno));
    }
    if (n == 0) break;
    total += uint64_t(n);
    if (total > size) break;
    sink(buf.data(), size_t(n));
  }
  if (total != size)
    throw RuntimeError("\"" + path.string() + "\": changed while it was read");
}

struct Fd {
  int fd;
  ~Fd() { ::close(fd); }
};

thread_local InputFileLog* t_log = nullptr;

}  // namespace

ContentHasher::ContentHasher() {
  if (sodium_init() < 0) throw RuntimeError("libsodium could not be initialised");
  crypto_generichash_init(reinterpret_cast<crypto_generichash_state*>(state_), nullptr, 0,
                          kDigestBytes);
}

void ContentHasher::update(const void* data, size_t size) {
  crypto_generichash_update(reinterpret_cast<crypto_generichash_state*>(state_),
                            static_cast<const unsigned char*>(data), size);
}

std::string ContentHasher::hex() {
  unsigned char out[kDigestBytes];
  crypto_generichash_final(reinterpret_cast<crypto_generichash_state*>(state_), out, kDigestBytes);
  return to_hex(out, kDigestBytes);
}

std::string content_hash(std::string_view bytes) {
  ContentHasher h;
  h.update(bytes);
  return h.hex();
}

FileHash hash_regular_file(const fs::path& path, uint64_t max_bytes) {
  FileHash out;
  Fd fd{open_regular_file(path, max_bytes, &out.size)};
  ContentHasher h;
  read_all(fd.fd, path, out.size, [&](const unsigned char* d, size_t n) { h.update(d, n); });
  out.hash = h.hex();
  return out;
}

std::string read_regular_file(const fs::path& path, uint64_t max_bytes) {
  uint64_t size = 0;
  Fd fd{open_regular_file(path, max_bytes, &size)};
  std::string bytes;
  bytes.reserve(size);
  read_all(fd.fd, path, size,
           [&](const unsigned char* d, size_t n) { bytes.append(reinterpret_cast<const char*>(d), n); });
  return bytes;
}

bool is_content_hash(std::string_view s) {
  return s.size() == kContentHashHexDigits &&
         std::all_of(s.begin(), s.end(),
                     [](char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'); });
}

InputFileLog::InputFileLog() : previous_(t_log) { t_log = this; }
InputFileLog::~InputFileLog() { t_log = previous_; }

void InputFileLog::add(const fs::path& path) {
  fs::path p = fs::absolute(path).lexically_normal();
  if (std::find(files_.begin(), files_.end(), p) == files_.end()) files_.push_back(p);
}

void note_input_file(const fs::path& path) {
  if (t_log) t_log->add(path);
}

}  // namespace dofarm
