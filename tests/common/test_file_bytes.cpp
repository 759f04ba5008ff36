// read_file_bytes (common/file_bytes.h): every byte of a file, and an error
// that names the path and the reason for what cannot be read, never an
// empty string in its place.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fstream>
#include <string>

#include "common/error.h"
#include "common/file_bytes.h"
#include "shard_fixtures.h"

namespace dofarm {
namespace {

using shard_testing::TempDir;

void write(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

// The message of the RuntimeError that reading `p` throws ("" if none).
std::string read_error(const std::filesystem::path& p) {
  try {
    read_file_bytes(p);
  } catch (const RuntimeError& e) {
    return e.what();
  }
  return "";
}

TEST(FileBytes, ReadsEveryByteOfABinaryFile) {
  TempDir dir;
  // NUL bytes, a CR LF pair and bytes above 127, past several stream buffers.
  std::string bytes;
  for (int i = 0; i < 70000; ++i) bytes += char((i * 131 + 7) % 256);
  bytes += "\r\n";
  bytes += std::string(3, '\0');
  write(dir.path() / "scene.glb", bytes);
  EXPECT_EQ(read_file_bytes(dir.path() / "scene.glb"), bytes);
  write(dir.path() / "empty.bin", "");
  EXPECT_EQ(read_file_bytes(dir.path() / "empty.bin"), "");
}

TEST(FileBytes, WhatCannotBeReadIsAnErrorNamingThePathAndWhy) {
  TempDir dir;
  const std::string missing = read_error(dir.path() / "missing.bin");
  EXPECT_NE(missing.find((dir.path() / "missing.bin").string()), std::string::npos) << missing;
  EXPECT_NE(missing.find("no such file"), std::string::npos) << missing;

  // A buffer uri naming a folder: an ifstream opens it and reads nothing.
  std::filesystem::create_directories(dir.path() / "textures");
  const std::string folder = read_error(dir.path() / "textures");
  EXPECT_NE(folder.find("textures: cannot read: it is a directory"), std::string::npos) << folder;

  if (::geteuid() != 0) {  // root reads a file of mode 000 all the same
    write(dir.path() / "locked.bin", "bytes");
    ::chmod((dir.path() / "locked.bin").c_str(), 0);
    const std::string locked = read_error(dir.path() / "locked.bin");
    EXPECT_NE(locked.find("locked.bin: cannot read: Permission denied"), std::string::npos)
        << locked;
    // A file that exists in a folder that may not be entered is not "missing".
    std::filesystem::create_directories(dir.path() / "closed");
    write(dir.path() / "closed" / "a.bin", "bytes");
    ::chmod((dir.path() / "closed").c_str(), 0);
    const std::string closed = read_error(dir.path() / "closed" / "a.bin");
    ::chmod((dir.path() / "closed").c_str(), 0700);  // so that TempDir can remove it
    EXPECT_NE(closed.find("a.bin: cannot read: Permission denied"), std::string::npos) << closed;
  }
}

}  // namespace
}  // namespace dofarm
