#include "common/file_bytes.h"

#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>

#include "common/error.h"

namespace dofarm {

std::string read_file_bytes(const std::filesystem::path& path) {
  std::error_code ec;
  const std::filesystem::file_status st = std::filesystem::status(path, ec);
  if (st.type() == std::filesystem::file_type::not_found)
    throw RuntimeError(path.string() + ": cannot read: no such file");
  // Any other failure to stat (a folder on the way that may not be entered).
  if (ec) throw RuntimeError(path.string() + ": cannot read: " + ec.message());
  // An ifstream opens a directory and then reads nothing from it.
  if (std::filesystem::is_directory(st))
    throw RuntimeError(path.string() + ": cannot read: it is a directory");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw RuntimeError(path.string() + ": cannot read: " + std::strerror(errno));
  std::ostringstream bytes;
  // An empty file sets failbit on operator<<; only badbit is a read error.
  if (in.peek() != std::ifstream::traits_type::eof()) bytes << in.rdbuf();
  if (in.bad() || !bytes) throw RuntimeError(path.string() + ": cannot read: a read error");
  return std::move(bytes).str();
}

}  // namespace dofarm
