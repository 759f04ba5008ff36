// --set KEY=VALUE: one override applied to the parsed TOML tree before the
// spec is read, so an overridden value is checked exactly like one of the
// file and its errors name "--set TEXT" as the place (jobs/README.md).
#include <fmt/format.h>

#include <algorithm>
#include <string_view>
#include <vector>

#include "common/spec_section.h"

namespace dofarm::spec_reading {
namespace {

// Keys that replace each other: an override of one removes the others from
// the same table, so `--set buffers.reference_spp=16` works whether the file
// uses reference_spp or reference_error. In the file itself both are errors.
struct Alternatives {
  std::string_view table;  // dotted, array indices written as '#'
  std::vector<std::vector<std::string_view>> groups;
};
const std::vector<Alternatives>& alternatives() {
  static const std::vector<Alternatives> kAlternatives = {
      {"buffers",
       {{"reference_spp"}, {"reference_error", "reference_max_spp", "reference_display_error"}}},
      {"camera.key.#", {{"look_at", "up"}, {"rotation"}}},
      {"camera.key.#", {{"aperture"}, {"fstop", "focal_length", "sensor_width"}}},
      {"camera.key.#", {{"focal_distance"}, {"focus_point"}, {"focus"}}},
      {"environment", {{"map"}, {"color"}}},
      {"farm", {{"tile"}, {"task_seconds"}}},
  };
  return kAlternatives;
}

bool is_index(std::string_view s) {
  return !s.empty() && s.size() < 10 &&
         std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

std::string toml_quote(std::string_view s) {
  std::string out = "\"";
  for (char c : s) {
    unsigned char u = static_cast<unsigned char>(c);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (u < 0x20 || u == 0x7f) {
      out += fmt::format("\\u{:04x}", u);
    } else {
      out += c;
    }
  }
  return out + "\"";
}

// VALUE as TOML (64, 0.5, true, "str", [1, 2, 3]); a bare word that is not
// valid TOML (scenes/a.gltf) is taken as a string.
toml::table parse_override_value(const std::string& value, const std::string& source) {
  try {
    toml::table t = toml::parse("v = " + value, source);
    if (t.size() == 1 && t.contains("v")) return t;
  } catch (const toml::parse_error&) {
  }
  return toml::parse("v = " + toml_quote(value), source);
}

}  // namespace

void apply_override(toml::table& root, const std::string& text, Origins& origins) {
  const FileLoc loc{"--set " + text};
  const size_t eq = text.find('=');
  if (eq == std::string::npos) fail(loc, "", "expected KEY=VALUE");
  std::string dotted = text.substr(0, eq);
  while (!dotted.empty() && dotted.back() == ' ') dotted.pop_back();
  while (!dotted.empty() && dotted.front() == ' ') dotted.erase(dotted.begin());
  if (dotted.empty()) fail(loc, "", "expected KEY=VALUE, got an empty key");

  std::vector<std::string> parts;
  for (size_t start = 0;;) {
    size_t dot = dotted.find('.', start);
    parts.push_back(dotted.substr(start, dot - start));
    if (parts.back().empty()) fail(loc, dotted, "empty part in dotted key");
    if (dot == std::string::npos) break;
    start = dot + 1;
  }

  toml::table parsed = parse_override_value(text.substr(eq + 1), loc.file);
  toml::node& value = *parsed.get("v");

  toml::node* cur = &root;
  std::string path, pattern;  // pattern: path with indices as '#'
  for (size_t i = 0; i < parts.size(); ++i) {
    const std::string& part = parts[i];
    const bool last = i + 1 == parts.size();
    const std::string here = join_key(path, part);
    if (toml::array* arr = cur->as_array()) {
      if (!is_index(part)) {
        fail(loc, here,
             fmt::format("\"{}\" is an array: expected an element index, got \"{}\"", path, part));
      }
      size_t idx = std::stoul(part);
      if (idx >= arr->size()) {
        fail(loc, here,
             fmt::format("index {} is out of range: \"{}\" has {} element{}", idx, path,
                         arr->size(), arr->size() == 1 ? "" : "s"));
      }
      if (last) {
        origins.forget(*arr->get(idx));
        arr->replace(arr->cbegin() + static_cast<ptrdiff_t>(idx), std::move(value));
        origins.mark_override(*arr->get(idx), loc.file);
        return;
      }
      cur = arr->get(idx);
      pattern = join_key(pattern, "#");
    } else if (toml::table* tbl = cur->as_table()) {
      if (last) {
        for (const auto& alt : alternatives()) {
          if (alt.table != pattern) continue;
          auto mine = std::find_if(alt.groups.begin(), alt.groups.end(), [&](const auto& g) {
            return std::find(g.begin(), g.end(), part) != g.end();
          });
          if (mine == alt.groups.end()) continue;
          for (auto g = alt.groups.begin(); g != alt.groups.end(); ++g) {
            if (g == mine) continue;
            for (std::string_view other : *g) {
              if (toml::node* n = tbl->get(other)) {
                origins.forget(*n);
                tbl->erase(other);
              }
            }
          }
        }
        if (toml::node* old = tbl->get(part)) origins.forget(*old);
        tbl->insert_or_assign(part, std::move(value));
        origins.mark_override(*tbl->get(part), loc.file);
        return;
      }
      toml::node* child = tbl->get(part);
      if (!child) {
        if (is_index(parts[i + 1])) {
          fail(loc, here, "no such array in the spec to index into");
        }
        tbl->insert(part, toml::table{});
        child = tbl->get(part);
        origins.mark_override(*child, loc.file);
      }
      cur = child;
      pattern = join_key(pattern, part);
    } else {
      fail(loc, path, "is a value, not a table: cannot set \"" + dotted + "\" inside it");
    }
    path = here;
  }
}

}  // namespace dofarm::spec_reading
