// The three kinds of failure (STYLE.md 3): bad user input is a located
// SpecError (exit 2); runtime failures are RuntimeError (exit 1); programmer
// errors are DOFARM_CHECK, which prints both operands and aborts.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace dofarm {

// Names for a message, each in double quotes, joined by ", ":
// "a", "b", "c" ("" for none).
inline std::string quoted_list(const std::vector<std::string>& names) {
  std::string list;
  for (const std::string& n : names) list += (list.empty() ? "\"" : ", \"") + n + "\"";
  return list;
}

inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntime = 1;
inline constexpr int kExitBadInput = 2;

// Where a piece of user input came from: "jobs/cornell.toml:42:7".
struct FileLoc {
  std::string file;
  int line = 0;    // 1-based; 0 = unknown (e.g. a --set override)
  int column = 0;  // 1-based; 0 = unknown
  std::string str() const {
    std::string s = file;
    if (line > 0) s.append(":").append(std::to_string(line));
    if (column > 0) s.append(":").append(std::to_string(column));
    return s;
  }
};

// Bad user input. what() is the full located message:
//   jobs/cornell.toml:42:7: "reference_spp": expected a positive integer, got -3
class SpecError : public std::runtime_error {
 public:
  SpecError(const FileLoc& loc, const std::string& key, const std::string& msg)
      : std::runtime_error(format(loc, key, msg)), loc_(loc), key_(key), message_(msg) {}
  const FileLoc& loc() const { return loc_; }
  const std::string& key() const { return key_; }
  const std::string& message() const { return message_; }  // without place and key

 private:
  static std::string format(const FileLoc& loc, const std::string& key, const std::string& msg) {
    std::string s = loc.str();
    if (!s.empty()) s.append(": ");
    if (!key.empty()) s.append("\"").append(key).append("\": ");
    return s.append(msg);
  }
  FileLoc loc_;
  std::string key_;
  std::string message_;
};

// A runtime failure (IO, library error) carrying its cause.
class RuntimeError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

namespace detail {
template <typename A, typename B>
[[noreturn]] void check_failed(const char* file, int line, const char* expr, const A& a,
                               const B& b) {
  std::ostringstream os;
  os << file << ":" << line << ": check failed: " << expr << " (" << a << " vs " << b << ")";
  std::fprintf(stderr, "%s\n", os.str().c_str());
  std::abort();
}
}  // namespace detail

}  // namespace dofarm

#define DOFARM_CHECK_OP(a, op, b)                                                                  \
  do {                                                                                             \
    const auto& dofarm_a_ = (a);                                                                   \
    const auto& dofarm_b_ = (b);                                                                   \
    if (!(dofarm_a_ op dofarm_b_))                                                                 \
      ::dofarm::detail::check_failed(__FILE__, __LINE__, #a " " #op " " #b, dofarm_a_, dofarm_b_); \
  } while (0)
#define DOFARM_CHECK_EQ(a, b) DOFARM_CHECK_OP(a, ==, b)
#define DOFARM_CHECK_LT(a, b) DOFARM_CHECK_OP(a, <, b)
#define DOFARM_CHECK_LE(a, b) DOFARM_CHECK_OP(a, <=, b)
#define DOFARM_CHECK_GE(a, b) DOFARM_CHECK_OP(a, >=, b)
#define DOFARM_CHECK(cond) DOFARM_CHECK_OP(static_cast<bool>(cond), ==, true)
