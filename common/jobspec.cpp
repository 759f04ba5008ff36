// Job spec parsing: TOML text (toml++) plus --set overrides -> a checked
// JobSpec. Every value is read at exactly one place below, every problem is a
// SpecError located at file:line:col of the offending key or value (STYLE.md 2),
// and unknown keys are errors so that a typo never falls back to a default.
// jobs/README.md documents the keys; keep it in step with this file.
#include "common/jobspec.h"

#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <string_view>
#include <system_error>
#include <unordered_map>

#include "common/error.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;

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

  void mark_override(const toml::node& node, const std::string& text) {
    overrides_[&node] = text;
    if (const auto* t = node.as_table()) {
      for (const auto& [k, child] : *t) mark_override(child, text);
    } else if (const auto* a = node.as_array()) {
      for (const auto& child : *a) mark_override(child, text);
    }
  }

  void forget(const toml::node& node) {
    overrides_.erase(&node);
    if (const auto* t = node.as_table()) {
      for (const auto& [k, child] : *t) forget(child);
    } else if (const auto* a = node.as_array()) {
      for (const auto& child : *a) forget(child);
    }
  }

  bool is_override(const toml::node& node) const { return overrides_.count(&node) > 0; }

  FileLoc of(const toml::node& node) const {
    if (auto it = overrides_.find(&node); it != overrides_.end()) return FileLoc{it->second};
    return from_region(node.source());
  }

  // A key is located at its own text when it has one (the value may be on a
  // later line for inline tables), otherwise where its value is.
  FileLoc of(const toml::key& key, const toml::node& value) const {
    if (!is_override(value) && key.source().begin.line > 0) return from_region(key.source());
    return of(value);
  }

 private:
  FileLoc from_region(const toml::source_region& r) const {
    return FileLoc{file_, static_cast<int>(r.begin.line), static_cast<int>(r.begin.column)};
  }

  std::string file_;
  std::unordered_map<const toml::node*, std::string> overrides_;
};

[[noreturn]] void fail(const FileLoc& loc, const std::string& key, const std::string& msg) {
  throw SpecError(loc, key, msg);
}

std::string join_key(const std::string& prefix, std::string_view key) {
  return prefix.empty() ? std::string(key) : prefix + "." + std::string(key);
}

// How a value reads in an error message: scalars by value, the rest by kind.
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
// Ranges, each with the words used in "expected ..., got ..."

struct IntRange {
  int64_t lo, hi;
  std::string what;
  static IntRange positive() { return {1, INT_MAX, "a positive integer"}; }
  static IntRange non_negative() { return {0, INT_MAX, "a non-negative integer"}; }
  static IntRange between(int64_t lo, int64_t hi) {
    return {lo, hi, fmt::format("an integer in [{}, {}]", lo, hi)};
  }
};

// The largest lens radius (`aperture`) a spec may give, in scene units.
constexpr double kMaxLensRadius = 1e6;

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
  static Interval open(double lo, double hi) {
    return {lo, hi, true, true, fmt::format("a number in ({}, {})", lo, hi)};
  }
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
  FileLoc loc() const {
    if (table_) {
      FileLoc l = origins_.of(*table_);
      if (l.line > 0 || origins_.is_override(*table_)) return l;
    }
    return fallback_;
  }

  const toml::node* find(std::string_view k) const { return table_ ? table_->get(k) : nullptr; }
  FileLoc loc_of(std::string_view k) const { return origins_.of(*find(k)); }

  [[noreturn]] void fail_at(std::string_view k, const std::string& msg) const {
    fail(loc_of(k), key(k), msg);
  }

  // Unknown keys are errors; the first one in the file is reported.
  void check_keys(std::initializer_list<std::string_view> allowed) const {
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

  std::optional<int64_t> integer(std::string_view k, const IntRange& range) const {
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

  // Integers are accepted where numbers are expected (`fov = 40`).
  std::optional<double> number(std::string_view k, const Interval& range) const {
    const toml::node* n = find(k);
    if (!n) return std::nullopt;
    return number_of(*n, origins_.of(*n), key(k), "", range);
  }

  std::optional<bool> boolean(std::string_view k) const {
    const toml::node* n = find(k);
    if (!n) return std::nullopt;
    const auto* v = n->as_boolean();
    if (!v) fail_at(k, "expected true or false, got " + describe(*n));
    return v->get();
  }

  std::optional<std::string> string(std::string_view k) const {
    const toml::node* n = find(k);
    if (!n) return std::nullopt;
    const auto* v = n->as_string();
    if (!v) fail_at(k, "expected a string, got " + describe(*n));
    return v->get();
  }

  // [x, y, z], each element checked against `range`.
  std::optional<Vec3> vec3(std::string_view k, const Interval& range = Interval::any()) const {
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

  // A path relative to `base` that must name an existing file.
  std::optional<fs::path> existing_file(std::string_view k, const fs::path& base) const {
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

  // A sub-table (absent: a Section whose getters all return nullopt).
  Section table(std::string_view k) const {
    const toml::node* n = find(k);
    const toml::table* t = nullptr;
    if (n) {
      t = n->as_table();
      if (!t) fail_at(k, "expected a table, got " + describe(*n));
    }
    return Section(origins_, t, key(k), fallback_);
  }

  const toml::array* array_of_tables(std::string_view k) const {
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

  // "give either a or b, not both": reported at whichever comes later.
  void exclusive(std::string_view a, std::string_view b) const {
    const toml::node* na = find(a);
    const toml::node* nb = find(b);
    if (!na || !nb) return;
    FileLoc la = origins_.of(*na), lb = origins_.of(*nb);
    bool b_later =
        lb.line == 0 || std::make_pair(lb.line, lb.column) > std::make_pair(la.line, la.column);
    std::string_view later = b_later ? b : a;
    fail_at(later, fmt::format("give either {} or {}, not both", a, b));
  }

  const Origins& origins() const { return origins_; }

 private:
  static double number_of(const toml::node& n, const FileLoc& loc, const std::string& key,
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

  const Origins& origins_;
  const toml::table* table_;
  std::string name_;
  FileLoc fallback_;
};

// ---------------------------------------------------------------------------
// The spec, section by section, in the order of jobs/README.md

void read_image(const Section& s, JobSpec& spec) {
  s.check_keys({"width", "height"});
  if (auto v = s.integer("width", IntRange::between(1, kMaxImageSide))) {
    spec.width = int(*v);
    spec.width_given = true;
  }
  if (auto v = s.integer("height", IntRange::between(1, kMaxImageSide))) {
    spec.height = int(*v);
    spec.height_given = true;
  }
}

void read_frames(const Section& s, JobSpec& spec) {
  s.check_keys({"start", "end", "per_shard", "fps"});
  // Frame numbers stay exact in the shard's float32 camera table.
  const IntRange frame_number{0, kMaxFrameNumber,
                              fmt::format("a frame number in [0, {}] (2^24 - 1: shards store it "
                                          "as a 32-bit float)",
                                          kMaxFrameNumber)};
  if (auto v = s.integer("start", frame_number)) spec.frame_start = int(*v);
  if (auto v = s.integer("end", frame_number)) spec.frame_end = int(*v);
  if (auto v = s.integer("per_shard", IntRange::between(1, kMaxTilesPerShard)))
    spec.per_shard = int(*v);
  if (auto v = s.number("fps", Interval::positive())) spec.fps = float(*v);
  auto fail_range = [&](const std::string& msg) {
    if (s.find("end")) s.fail_at("end", msg);
    if (s.find("start")) s.fail_at("start", msg);
    fail(s.loc(), s.name(), msg);
  };
  if (spec.frame_end < spec.frame_start)
    fail_range(fmt::format("frame range is reversed: end {} < start {} (end is inclusive)",
                           spec.frame_end, spec.frame_start));
  if (spec.frame_count() > kMaxFramesPerBatch)
    fail_range(
        fmt::format("{} frames ({}..{}) are more than the {} one batch may have; split "
                    "the range into several jobs",
                    spec.frame_count(), spec.frame_start, spec.frame_end, kMaxFramesPerBatch));
}

// The lens and focus keys of one camera key (jobs/README.md, "Lens and focus").
void read_lens(const Section& s, CameraKey& key) {
  s.exclusive("aperture", "fstop");
  // At most 1e6 scene units (1000 km in metres): a radius near float's limit
  // would push lens-ray origins to Inf.
  if (auto v = s.number("aperture", Interval::closed(0, kMaxLensRadius,
                                                     "a lens radius in [0, 1e6] scene units")))
    key.aperture = float(*v);
  if (auto v = s.number("fstop", Interval::positive())) key.fstop = float(*v);
  for (std::string_view k : {"focal_length", "sensor_width"}) {
    if (s.find(k) && !s.find("fstop")) {
      s.fail_at(k, "only applies with fstop (the lens radius is focal_length / (2 fstop))");
    }
  }
  if (s.find("sensor_width") && s.find("focal_length")) {
    s.fail_at("sensor_width",
              "only applies when focal_length is not given (it derives the focal length from "
              "the field of view); give one of them");
  }
  if (auto v = s.number("focal_length", Interval::positive())) key.focal_length_mm = float(*v);
  if (auto v = s.number("sensor_width", Interval::positive())) key.sensor_width_mm = float(*v);

  s.exclusive("focal_distance", "focus_point");
  s.exclusive("focal_distance", "focus");
  s.exclusive("focus_point", "focus");
  if (auto v = s.number("focal_distance", Interval::positive())) {
    key.focal_distance = float(*v);
    key.focus = FocusMode::kDistance;
  }
  if (auto v = s.vec3("focus_point")) {
    key.focus_point = *v;
    key.focus = FocusMode::kPoint;
  }
  if (auto v = s.string("focus")) {
    if (*v != "auto") {
      s.fail_at("focus", "expected \"auto\" (focus on the surface at the image centre), got \"" +
                             *v + "\"; a distance is focal_distance, a point focus_point");
    }
    key.focus = FocusMode::kAuto;
  }
  if (key.has_lens() && key.focus == FocusMode::kNone) {
    const char* lens = key.fstop > 0 ? "fstop" : "aperture";
    s.fail_at(lens, fmt::format("a lens ({} = {}) needs a focus: set focal_distance, "
                                "focus_point = [x, y, z] or focus = \"auto\"",
                                lens, key.fstop > 0 ? key.fstop : key.aperture));
  }
}

CameraKey read_camera_key(const Section& s, bool from_scene) {
  s.check_keys({"frame", "position", "look_at", "rotation", "up", "fov", "aperture", "fstop",
                "focal_length", "sensor_width", "focal_distance", "focus_point", "focus"});
  CameraKey key;
  if (from_scene) {
    // Pose and fov come from the scene's camera; only the lens is keyed here.
    for (std::string_view k : {"position", "look_at", "rotation", "up", "fov"}) {
      if (s.find(k)) {
        s.fail_at(k,
                  "not allowed with camera.from_scene = true (pose and fov come from the "
                  "scene; keys may only set frame and the lens: aperture or fstop, "
                  "focal_length, sensor_width, focal_distance, focus_point, focus)");
      }
    }
  }
  if (auto v = s.integer("frame", IntRange::non_negative())) key.frame = int(*v);
  if (!from_scene) {
    if (auto v = s.vec3("position")) key.position = *v;
    s.exclusive("look_at", "rotation");
    key.look_at = s.vec3("look_at");
    key.rotation_deg = s.vec3("rotation");
    if (!key.look_at && !key.rotation_deg) {
      fail(s.loc(), s.name(), "needs look_at or rotation (Euler XYZ degrees)");
    }
    if (key.rotation_deg && s.find("up")) {
      s.fail_at("up", "up only applies with look_at (rotation already fixes the roll)");
    }
    if (auto v = s.vec3("up")) key.up = *v;
    if (key.look_at) {
      Vec3 dir = *key.look_at - key.position;
      if (!(length(dir) > 0.0f)) s.fail_at("look_at", "look_at equals position: no view direction");
      if (!(length(key.up) > 0.0f)) s.fail_at("up", "up must not be the zero vector");
      // Parallel up and view direction leave the camera's roll undefined.
      float sin_angle = length(cross(normalize(dir), normalize(key.up)));
      if (sin_angle < 1e-6f) {
        std::string_view where = s.find("up") ? "up" : "look_at";
        s.fail_at(where, "up is parallel to the view direction (look_at - position)");
      }
    }
    if (auto v = s.number("fov", Interval::open(0, 180))) key.fov_deg = float(*v);
  }
  read_lens(s, key);
  return key;
}

void read_camera(const Section& s, JobSpec& spec) {
  s.check_keys({"from_scene", "key"});
  if (auto v = s.boolean("from_scene")) spec.camera_from_scene = *v;
  const toml::array* keys = s.array_of_tables("key");

  struct Keyed {
    CameraKey key;
    size_t index;  // in the file, for messages
  };
  std::vector<Keyed> read;
  if (keys) {
    for (size_t i = 0; i < keys->size(); ++i) {
      Section ks(s.origins(), keys->get(i)->as_table(), fmt::format("{}.key.{}", s.name(), i),
                 s.loc());
      read.push_back({read_camera_key(ks, spec.camera_from_scene), i});
      read.back().key.index = int(i);
    }
  }
  if (read.empty() && !spec.camera_from_scene) {
    fail(s.loc(), s.key("key"),
         "at least one [[camera.key]] is required (or set camera.from_scene = true)");
  }
  std::stable_sort(read.begin(), read.end(),
                   [](const Keyed& a, const Keyed& b) { return a.key.frame < b.key.frame; });
  for (size_t i = 1; i < read.size(); ++i) {
    if (read[i].key.frame != read[i - 1].key.frame) continue;
    // Blame the later key in the file, or the one a --set just changed.
    size_t first = std::min(read[i].index, read[i - 1].index);
    size_t second = std::max(read[i].index, read[i - 1].index);
    const toml::node* first_frame = keys->get(first)->as_table()->get("frame");
    if (first_frame && s.origins().is_override(*first_frame)) std::swap(first, second);
    Section ks(s.origins(), keys->get(second)->as_table(),
               fmt::format("{}.key.{}", s.name(), second), s.loc());
    std::string msg = fmt::format("duplicate camera key for frame {} (camera.key.{} has it too)",
                                  read[i].key.frame, first);
    if (ks.find("frame")) ks.fail_at("frame", msg);
    fail(ks.loc(), ks.name(), msg);
  }
  // The lens interpolates between keys, so a pinhole key next to a lens key
  // needs a focus too (else the frames between would focus at a made-up 1).
  auto lens_key =
      std::find_if(read.begin(), read.end(), [](const Keyed& k) { return k.key.has_lens(); });
  if (lens_key != read.end()) {
    for (const Keyed& k : read) {
      if (k.key.focus != FocusMode::kNone) continue;
      Section ks(s.origins(), keys->get(k.index)->as_table(),
                 fmt::format("{}.key.{}", s.name(), k.index), s.loc());
      fail(ks.loc(), ks.name(),
           fmt::format("needs a focus (focal_distance, focus_point or focus = \"auto\"): "
                       "{}.key.{} has a lens, and the lens interpolates between keys",
                       s.name(), lens_key->index));
    }
  }
  for (auto& k : read) spec.camera_keys.push_back(k.key);
}

void read_environment(const Section& s, const fs::path& base, JobSpec& spec) {
  s.check_keys({"map", "color", "intensity", "rotation"});
  EnvironmentSpec env;
  s.exclusive("map", "color");
  if (auto v = s.existing_file("map", base)) env.map = *v;
  env.color = s.vec3("color", Interval::non_negative());
  if (env.map.empty() && !env.color) fail(s.loc(), s.name(), "needs map or color");
  if (auto v = s.number("intensity", Interval::non_negative())) env.intensity = float(*v);
  if (auto v = s.number("rotation", Interval::any())) env.rotation_deg = float(*v);
  if (env.color) {
    const double brightest =
        double(std::max({env.color->x, env.color->y, env.color->z})) * env.intensity;
    if (brightest > kMaxRadiance) {
      s.fail_at(s.find("intensity") ? "intensity" : "color",
                fmt::format("color times intensity is {:g}, above the {:g} a radiance may be "
                            "(keeps every buffer finite)",
                            brightest, kMaxRadiance));
    }
  }
  spec.environment = env;
}

void read_buffers(const Section& s, JobSpec& spec) {
  s.check_keys(
      {"versions", "reference_spp", "reference_error", "reference_max_spp", "albedo_ref_spp"});
  if (auto v = s.integer("versions", IntRange::between(1, 64))) spec.versions = int(*v);
  s.exclusive("reference_spp", "reference_error");
  if (auto v = s.integer("reference_spp", IntRange::positive())) spec.reference_spp = int(*v);
  if (auto v = s.number("reference_error", Interval::open(0, 1))) spec.reference_error = float(*v);
  if (s.find("reference_max_spp") && !s.find("reference_error")) {
    s.fail_at("reference_max_spp", "only applies with reference_error");
  }
  if (auto v = s.integer("reference_max_spp", IntRange::positive()))
    spec.reference_max_spp = int(*v);
  if (auto v = s.integer("albedo_ref_spp", IntRange::positive())) spec.albedo_ref_spp = int(*v);
}

void read_render(const Section& s, JobSpec& spec) {
  s.check_keys({"max_depth", "rr_start_depth", "sampler"});
  if (auto v = s.integer("max_depth", IntRange::between(1, 1024))) spec.max_depth = int(*v);
  if (auto v = s.integer("rr_start_depth", IntRange::between(1, 1024)))
    spec.rr_start_depth = int(*v);
  if (auto v = s.string("sampler")) {
    if (*v == "sobol") {
      spec.sampler = SamplerKind::kSobol;
    } else if (*v == "independent") {
      spec.sampler = SamplerKind::kIndependent;
    } else {
      s.fail_at("sampler", "expected \"sobol\" or \"independent\", got \"" + *v + "\"");
    }
  }
}

void read_farm(const Section& s, JobSpec& spec) {
  s.check_keys({"tile", "task_seconds"});
  s.exclusive("tile", "task_seconds");
  if (auto v = s.integer("tile", IntRange::between(8, 4096))) spec.tile = int(*v);
  if (auto v = s.number("task_seconds", Interval::positive())) spec.task_seconds = float(*v);
}

// Every key of the spec with the place of its value, dotted as the
// spec's messages name them ("camera.key.0.focus").
void record_locations(const toml::node& node, const std::string& prefix, const Origins& origins,
                      std::map<std::string, FileLoc>& out) {
  if (!prefix.empty()) out[prefix] = origins.of(node);
  if (const toml::table* t = node.as_table()) {
    for (const auto& [k, child] : *t)
      record_locations(child, join_key(prefix, k.str()), origins, out);
  } else if (const toml::array* a = node.as_array(); a && a->is_array_of_tables()) {
    for (size_t i = 0; i < a->size(); ++i)
      record_locations(*a->get(i), prefix + "." + std::to_string(i), origins, out);
  }
}

JobSpec read_spec(const toml::table& root, const Origins& origins, const fs::path& spec_path) {
  JobSpec spec;
  spec.spec_path = spec_path;
  const fs::path base = spec_path.parent_path();
  Section top(origins, &root, "", FileLoc{origins.file()});
  top.check_keys(
      {"scene", "seed", "image", "frames", "camera", "environment", "buffers", "render", "farm"});
  auto scene = top.existing_file("scene", base);
  if (!scene) fail(FileLoc{origins.file()}, "scene", "required key is missing");
  spec.scene = *scene;
  if (auto v = top.integer("seed", {0, INT64_MAX, "a non-negative integer"})) {
    spec.seed = static_cast<uint64_t>(*v);
  }
  read_image(top.table("image"), spec);
  read_frames(top.table("frames"), spec);
  read_camera(top.table("camera"), spec);
  if (Section env = top.table("environment"); env.present()) read_environment(env, base, spec);
  read_buffers(top.table("buffers"), spec);
  read_render(top.table("render"), spec);
  read_farm(top.table("farm"), spec);
  record_locations(root, "", origins, spec.key_locations);
  // A size that follows the scene camera is checked once it is known.
  const bool size_from_scene = spec.camera_from_scene && !(spec.width_given && spec.height_given);
  if (!size_from_scene) check_batch_size(spec);
  return spec;
}

// ---------------------------------------------------------------------------
// --set KEY=VALUE

// Keys that replace each other: an override of one removes the others from
// the same table, so `--set buffers.reference_spp=16` works whether the file
// uses reference_spp or reference_error. In the file itself both are errors.
struct Alternatives {
  std::string_view table;  // dotted, array indices written as '#'
  std::vector<std::vector<std::string_view>> groups;
};
const std::vector<Alternatives>& alternatives() {
  static const std::vector<Alternatives> kAlternatives = {
      {"buffers", {{"reference_spp"}, {"reference_error", "reference_max_spp"}}},
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

}  // namespace

FileLoc JobSpec::where(const std::string& key) const {
  auto it = key_locations.find(key);
  return it != key_locations.end() ? it->second : FileLoc{spec_path.string()};
}

// With task_seconds the planner picks the tile side and keeps under the
// limits by itself (one tile per frame always fits).
void check_batch_size(const JobSpec& spec) {
  if (spec.task_seconds > 0) return;
  const int64_t tasks = batch_task_count(spec, spec.tile);
  const int64_t shard_tiles = shard_tile_count(spec, spec.tile);
  if (tasks <= kMaxTasksPerBatch && shard_tiles <= kMaxTilesPerShard) return;
  const int64_t per_frame = (int64_t(spec.width) + spec.tile - 1) / spec.tile *
                            ((int64_t(spec.height) + spec.tile - 1) / spec.tile);
  const std::string tiles = fmt::format("{} tiles of {}x{} px of a {}x{} image", per_frame,
                                        spec.tile, spec.tile, spec.width, spec.height);
  std::string msg;
  std::vector<const char*> blame;
  if (tasks > kMaxTasksPerBatch) {
    msg = fmt::format(
        "the batch would have {} tasks ({} frames x {}, plus the packs), more than the {} one "
        "batch may have; use a larger farm.tile, fewer frames or a smaller image",
        tasks, spec.frame_count(), tiles, kMaxTasksPerBatch);
    blame = {"farm.tile", "frames.end", "image.width", "image.height"};
  } else {
    msg = fmt::format(
        "a shard would have {} tiles ({} frames x {}), more than the {} one pack task may "
        "take; use a larger farm.tile or a smaller frames.per_shard",
        shard_tiles, std::min<int64_t>(spec.per_shard, spec.frame_count()), tiles,
        kMaxTilesPerShard);
    blame = {"farm.tile", "frames.per_shard", "image.width", "image.height"};
  }
  // Blame the key that made it too large, as far as the file says.
  for (const char* key : blame) {
    if (spec.key_locations.count(key)) throw SpecError(spec.where(key), key, msg);
  }
  throw SpecError(FileLoc{spec.spec_path.string()}, "farm.tile", msg);
}

int64_t batch_task_count(const JobSpec& spec, int tile_side) {
  DOFARM_CHECK_OP(tile_side, >, 0);
  DOFARM_CHECK_OP(spec.per_shard, >, 0);
  const int64_t frames = std::max<int64_t>(0, spec.frame_count());
  const int64_t columns = (int64_t(spec.width) + tile_side - 1) / tile_side;
  const int64_t rows = (int64_t(spec.height) + tile_side - 1) / tile_side;
  const int64_t shards = (frames + spec.per_shard - 1) / spec.per_shard;
  // Each factor is below 2^32, so the product of the first two is exact; the
  // third multiplication saturates instead of overflowing.
  const int64_t per_frame = columns * rows;
  if (per_frame != 0 && frames > (INT64_MAX - shards) / per_frame) return INT64_MAX;
  return frames * per_frame + shards;
}

int64_t shard_tile_count(const JobSpec& spec, int tile_side) {
  DOFARM_CHECK_OP(tile_side, >, 0);
  DOFARM_CHECK_OP(spec.per_shard, >, 0);
  const int64_t frames =
      std::min<int64_t>(spec.per_shard, std::max<int64_t>(0, spec.frame_count()));
  const int64_t per_frame = ((int64_t(spec.width) + tile_side - 1) / tile_side) *
                            ((int64_t(spec.height) + tile_side - 1) / tile_side);
  if (per_frame != 0 && frames > INT64_MAX / per_frame) return INT64_MAX;
  return frames * per_frame;
}

JobSpec parse_job_spec(const std::string& toml_text, const fs::path& virtual_path,
                       const std::vector<std::string>& overrides) {
  const std::string display = virtual_path.string();
  toml::table root;
  try {
    root = toml::parse(toml_text, display);
  } catch (const toml::parse_error& e) {
    const auto& b = e.source().begin;
    throw SpecError(FileLoc{display, static_cast<int>(b.line), static_cast<int>(b.column)}, "",
                    std::string(e.description()));
  }
  Origins origins(display);
  for (const auto& o : overrides) apply_override(root, o, origins);
  return read_spec(root, origins, fs::absolute(virtual_path).lexically_normal());
}

JobSpec load_job_spec(const fs::path& path, const std::vector<std::string>& overrides) {
  std::error_code dir_ec;
  if (fs::is_directory(path, dir_ec)) {
    throw SpecError(FileLoc{path.string()}, "", "expected a job spec file, got a directory");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    std::error_code ec;
    std::string why = fs::exists(path, ec) ? "cannot read the file" : "file not found";
    throw SpecError(FileLoc{path.string()}, "", "cannot open job spec: " + why);
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw SpecError(FileLoc{path.string()}, "", "cannot read job spec");
  return parse_job_spec(text.str(), path, overrides);
}

}  // namespace dofarm
