// How the job spec parser (common/jobspec.cpp) reads a TOML tree: where each
// node came from (the file or a --set override), the ranges a value may take,
// and Section, the typed getters of one table that throw a located SpecError
// for a present key with a bad value (STYLE.md 2). Internal to the parser:
// common/jobspec.h is the interface; nothing outside common/ includes this.
#pragma once

#include <toml++/toml.h>

#include <climits>
#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>

#include "common/jobspec.h"

namespace dofarm::spec_reading {

// ---------------------------------------------------------------------------
// Locations

// Where each node came from. Nodes of the spec file carry their own
// toml::source_region; nodes inserted by a --set override do not (or carry one
// that points into the override text), so they are remembered by address. A
// toml::table owns its children through unique_ptr, so the addresses are
// stable for as long as the tree lives.
class Origins {
 public:
  explicit Origins(std::string file) : file_(std::move(file)) {}

  const std::string& file() const { return file_; }

  // `node` and everything below it came from the override `text`.
  void mark_override(const toml::node& node, const std::string& text);
  // `node` and everything below it are about to leave the tree.
  void forget(const toml::node& node);

  bool is_override(const toml::node& node) const { return overrides_.count(&node) > 0; }

  FileLoc of(const toml::node& node) const;
  // A key is located at its own text when it has one (the value may be on a
  // later line for inline tables), otherwise where its value is.
  FileLoc of(const toml::key& key, const toml::node& value) const;

 private:
  FileLoc from_region(const toml::source_region& r) const {
    return FileLoc{file_, static_cast<int>(r.begin.line), static_cast<int>(r.begin.column)};
  }

  std::string file_;
  std::unordered_map<const toml::node*, std::string> overrides_;
};

[[noreturn]] void fail(const FileLoc& loc, const std::string& key, const std::string& msg);

std::string join_key(const std::string& prefix, std::string_view key);

// How a value reads in an error message: scalars by value, the rest by kind.
std::string describe(const toml::node& node);

// ---------------------------------------------------------------------------
// Ranges, each with the words used in "expected ..., got ..."

struct IntRange {
  int64_t lo, hi;
  std::string what;
  static IntRange positive() { return {1, INT_MAX, "a positive integer"}; }
  static IntRange non_negative() { return {0, INT_MAX, "a non-negative integer"}; }
  static IntRange between(int64_t lo, int64_t hi);
};

struct Interval {
  double lo, hi;
  bool lo_open, hi_open;
  std::string what;
  bool contains(double v) const {
    return (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
  }
  static Interval any() {
    double inf = std::numeric_limits<double>::infinity();
    return {-inf, inf, true, true, "a finite number"};
  }
  static Interval positive() {
    return {0, std::numeric_limits<double>::infinity(), true, true, "a positive number"};
  }
  static Interval non_negative() {
    return {0, std::numeric_limits<double>::infinity(), false, true, "a non-negative number"};
  }
  static Interval closed(double lo, double hi, std::string what) {
    return {lo, hi, false, false, std::move(what)};
  }
  static Interval open(double lo, double hi);
};

// ---------------------------------------------------------------------------
// Reading one table of the spec

// A table of the spec with its dotted name. The typed getters return nullopt
// for an absent key (the caller keeps the struct's default) and throw a
// located SpecError for a present key with a bad value.
class Section {
 public:
  Section(const Origins& origins, const toml::table* table, std::string name, FileLoc fallback_loc)
      : origins_(origins),
        table_(table),
        name_(std::move(name)),
        fallback_(std::move(fallback_loc)) {}

  bool present() const { return table_ != nullptr; }
  const std::string& name() const { return name_; }
  std::string key(std::string_view k) const { return join_key(name_, k); }

  // Where the table itself is, for "missing key" errors. An implicit table
  // (e.g. `camera` made by [[camera.key]]) has no text of its own.
  FileLoc loc() const;

  const toml::node* find(std::string_view k) const { return table_ ? table_->get(k) : nullptr; }
  FileLoc loc_of(std::string_view k) const { return origins_.of(*find(k)); }

  [[noreturn]] void fail_at(std::string_view k, const std::string& msg) const {
    fail(loc_of(k), key(k), msg);
  }

  // Unknown keys are errors; the first one in the file is reported.
  void check_keys(std::initializer_list<std::string_view> allowed) const;

  std::optional<int64_t> integer(std::string_view k, const IntRange& range) const;
  // Integers are accepted where numbers are expected (`fov = 40`).
  std::optional<double> number(std::string_view k, const Interval& range) const;
  std::optional<bool> boolean(std::string_view k) const;
  std::optional<std::string> string(std::string_view k) const;
  // [x, y, z], each element checked against `range`.
  std::optional<Vec3> vec3(std::string_view k, const Interval& range = Interval::any()) const;
  // A path relative to `base` that must name an existing file.
  std::optional<std::filesystem::path> existing_file(std::string_view k,
                                                     const std::filesystem::path& base) const;

  // A sub-table (absent: a Section whose getters all return nullopt).
  Section table(std::string_view k) const;
  // [[k]] entries; nullptr when absent. An empty array is an empty list.
  const toml::array* array_of_tables(std::string_view k) const;

  // "give either a or b, not both": reported at whichever comes later.
  void exclusive(std::string_view a, std::string_view b) const;

  const Origins& origins() const { return origins_; }

 private:
  static double number_of(const toml::node& n, const FileLoc& loc, const std::string& key,
                          const std::string& prefix, const Interval& range);

  const Origins& origins_;
  const toml::table* table_;
  std::string name_;
  FileLoc fallback_;
};

// ---------------------------------------------------------------------------
// --set KEY=VALUE (common/spec_overrides.cpp)

// Applies one override to the tree, marking what it inserted in `origins`.
// Throws SpecError located at "--set TEXT" when it cannot be applied.
void apply_override(toml::table& root, const std::string& text, Origins& origins);

}  // namespace dofarm::spec_reading
