#pragma once

// Whole files read into memory: scene files whose JSON or binary chunks
// dofarm parses itself (glTF, FBX, Collada), their buffers and embedded
// images.

#include <filesystem>
#include <string>

namespace dofarm {

// The bytes of the regular file `path`, all of them. Throws RuntimeError
// naming the path and the reason (not found, a directory, a read error),
// so that a file that cannot be read is never taken for an empty one.
std::string read_file_bytes(const std::filesystem::path& path);

}  // namespace dofarm
