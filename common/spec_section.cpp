// Locations, ranges and the typed getters of one spec table
// (common/spec_section.h). Every problem is a SpecError located at
// file:line:col of the offending key or value (STYLE.md 2).
#include "common/spec_section.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <system_error>
#include <tuple>

#include "common/error.h"

namespace dofarm::spec_reading {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------
// Locations

void Origins::mark_override(const toml::node& node, const std::string& text) {
  overrides_[&node] = text;
  if (const auto* t = node.as_table()) {
    for (const auto& [k, child] : *t) mark_override(child, text);
  } else if (const auto* a = node.as_array()) {
    for (const auto& child : *a) mark_override(child, text);
  }
}

void Origins::forget(const toml::node& node) {
  overrides_.erase(&node);
  if (const auto* t = node.as_table()) {
    for (const auto& [k, child] : *t) forget(child);
  } else if (const auto* a = node.as_array()) {
    for (const auto& child : *a) forget(child);
  }
}

FileLoc Origins::of(const toml::node& node) const {
  if (auto it = overrides_.find(&node); it != overrides_.end()) return FileLoc{it->second};
  return from_region(node.source());
}

FileLoc Origins::of(const toml::key& key, const toml::node& value) const {
  if (!is_override(value) && key.source().begin.line > 0) return from_region(key.source());
  return of(value);
}

[[noreturn]] void fail(const FileLoc& loc, const std::string& key, const std::string& msg) {
  throw SpecError(loc, key, msg);
}

std::string join_key(const std::string& prefix, std::string_view key) {
  return prefix.empty() ? std::string(key) : prefix + "." + std::string(key);
}

std::string describe(const toml::node& node) {
  switch (node.type()) {
    case toml::node_type::integer:
      return std::to_string(node.as_integer()->get());
    case toml::node_type::floating_point:
      return fmt::format("{}", node.as_floating_point()->get());
    case toml::node_type::boolean:
      return node.as_boolean()->get() ? "true" : "false";
    case toml::node_type::string: {
      std::ostringstream os;
      os << "the string \"" << node.as_string()->get() << "\"";
      return os.str();
    }
    case toml::node_type::array:
      return "an array";
    case toml::node_type::table:
      return "a table";
    case toml::node_type::date:
      return "a date";
    case toml::node_type::time:
      return "a time";
    case toml::node_type::date_time:
      return "a date-time";
    default:
      return "nothing";
  }
}

// ---------------------------------------------------------------------------
// Ranges

IntRange IntRange::between(int64_t lo, int64_t hi) {
  return {lo, hi, fmt::format("an integer in [{}, {}]", lo, hi)};
}

Interval Interval::open(double lo, double hi) {
  return {lo, hi, true, true, fmt::format("a number in ({}, {})", lo, hi)};
}

// ---------------------------------------------------------------------------
// Section

FileLoc Section::loc() const {
  if (table_) {
    FileLoc l = origins_.of(*table_);
    if (l.line > 0 || origins_.is_override(*table_)) return l;
  }
  return fallback_;
}

void Section::check_keys(std::initializer_list<std::string_view> allowed) const {
  if (!table_) return;
  const toml::key* worst_key = nullptr;
  const toml::node* worst_node = nullptr;
  auto order = [&](const toml::key& k, const toml::node& n) {
    FileLoc l = origins_.of(k, n);
    // File positions first, then overrides (which have no line).
    return std::make_tuple(l.line == 0, l.line, l.column);
  };
  for (const auto& [k, node] : *table_) {
    if (std::find(allowed.begin(), allowed.end(), k.str()) != allowed.end()) continue;
    if (!worst_key || order(k, node) < order(*worst_key, *worst_node)) {
      worst_key = &k;
      worst_node = &node;
    }
  }
  if (!worst_key) return;
  std::string list;
  for (auto a : allowed) list += (list.empty() ? "" : ", ") + std::string(a);
  fail(origins_.of(*worst_key, *worst_node), key(worst_key->str()),
       "unknown key (allowed here: " + list + ")");
}

std::optional<int64_t> Section::integer(std::string_view k, const IntRange& range) const {
  const toml::node* n = find(k);
  if (!n) return std::nullopt;
  const auto* v = n->as_integer();
  if (!v) fail_at(k, "expected " + range.what + ", got " + describe(*n));
  int64_t x = v->get();
  if (x < range.lo || x > range.hi) {
    std::string extra = x > range.hi && range.hi == INT_MAX ? " (too large)" : "";
    fail_at(k, "expected " + range.what + ", got " + std::to_string(x) + extra);
  }
  return x;
}

std::optional<double> Section::number(std::string_view k, const Interval& range) const {
  const toml::node* n = find(k);
  if (!n) return std::nullopt;
  return number_of(*n, origins_.of(*n), key(k), "", range);
}

std::optional<bool> Section::boolean(std::string_view k) const {
  const toml::node* n = find(k);
  if (!n) return std::nullopt;
  const auto* v = n->as_boolean();
  if (!v) fail_at(k, "expected true or false, got " + describe(*n));
  return v->get();
}

std::optional<std::string> Section::string(std::string_view k) const {
  const toml::node* n = find(k);
  if (!n) return std::nullopt;
  const auto* v = n->as_string();
  if (!v) fail_at(k, "expected a string, got " + describe(*n));
  return v->get();
}

std::optional<Vec3> Section::vec3(std::string_view k, const Interval& range) const {
  const toml::node* n = find(k);
  if (!n) return std::nullopt;
  const auto* a = n->as_array();
  if (!a) fail_at(k, "expected an array of 3 numbers, got " + describe(*n));
  if (a->size() != 3) {
    fail_at(k, fmt::format("expected an array of 3 numbers, got {} element{}", a->size(),
                           a->size() == 1 ? "" : "s"));
  }
  Vec3 out;
  for (int i = 0; i < 3; ++i) {
    const toml::node& e = *a->get(i);
    out[i] = static_cast<float>(
        number_of(e, origins_.of(e), key(k), fmt::format("element [{}]: ", i), range));
  }
  return out;
}

std::optional<fs::path> Section::existing_file(std::string_view k, const fs::path& base) const {
  auto s = string(k);
  if (!s) return std::nullopt;
  if (s->empty()) fail_at(k, "expected a file path, got an empty string");
  fs::path p = fs::path(*s);
  if (p.is_relative()) p = base / p;
  p = p.lexically_normal();
  std::error_code ec;
  fs::file_status st = fs::status(p, ec);
  if (!fs::exists(st)) fail_at(k, "file not found: " + p.string());
  if (fs::is_directory(st)) fail_at(k, "expected a file, got a directory: " + p.string());
  return p;
}

Section Section::table(std::string_view k) const {
  const toml::node* n = find(k);
  const toml::table* t = nullptr;
  if (n) {
    t = n->as_table();
    if (!t) fail_at(k, "expected a table, got " + describe(*n));
  }
  return Section(origins_, t, key(k), fallback_);
}

const toml::array* Section::array_of_tables(std::string_view k) const {
  const toml::node* n = find(k);
  if (!n) return nullptr;
  const auto* a = n->as_array();
  // An empty array has no element type; it is an empty list of keys.
  if (!a || (!a->empty() && !a->is_array_of_tables())) {
    fail_at(k, "expected an array of tables ([[" + key(k) + "]]), got " +
                   (a ? std::string("an array of values") : describe(*n)));
  }
  return a;
}

void Section::exclusive(std::string_view a, std::string_view b) const {
  const toml::node* na = find(a);
  const toml::node* nb = find(b);
  if (!na || !nb) return;
  FileLoc la = origins_.of(*na), lb = origins_.of(*nb);
  bool b_later =
      lb.line == 0 || std::make_pair(lb.line, lb.column) > std::make_pair(la.line, la.column);
  std::string_view later = b_later ? b : a;
  fail_at(later, fmt::format("give either {} or {}, not both", a, b));
}

double Section::number_of(const toml::node& n, const FileLoc& loc, const std::string& key,
                          const std::string& prefix, const Interval& range) {
  double x;
  if (const auto* i = n.as_integer()) {
    x = static_cast<double>(i->get());
  } else if (const auto* f = n.as_floating_point()) {
    x = f->get();
  } else {
    fail(loc, key, prefix + "expected " + range.what + ", got " + describe(n));
  }
  // NaN and Inf are valid TOML but never a valid job parameter.
  if (!std::isfinite(x)) fail(loc, key, prefix + "expected a finite number, got " + describe(n));
  // Values must survive the conversion to float unchanged in kind.
  if (std::fabs(x) > std::numeric_limits<float>::max()) {
    fail(loc, key, prefix + "expected a number within float range, got " + describe(n));
  }
  if (!range.contains(x))
    fail(loc, key, prefix + "expected " + range.what + ", got " + describe(n));
  return x;
}

}  // namespace dofarm::spec_reading
