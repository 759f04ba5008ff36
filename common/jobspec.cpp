// Job spec parsing: TOML text (toml++) plus --set overrides -> a checked
// JobSpec. Every value is read at exactly one place below, every problem is a
// SpecError located at file:line:col of the offending key or value (STYLE.md 2),
// and unknown keys are errors so that a typo never falls back to a default.
// jobs/README.md documents the keys; keep it in step with this file. The
// located reading of a TOML table is common/spec_section.h, the overrides
// common/spec_overrides.cpp.
#include "common/jobspec.h"

#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <climits>
#include <fstream>
#include <map>
#include <sstream>
#include <string_view>
#include <system_error>

#include "common/error.h"
#include "common/spec_section.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;
using spec_reading::fail;
using spec_reading::Interval;
using spec_reading::IntRange;
using spec_reading::join_key;
using spec_reading::Origins;
using spec_reading::Section;

// The largest lens radius (`aperture`) a spec may give, in scene units.
constexpr double kMaxLensRadius = 1e6;

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
  s.check_keys({"from_scene", "name", "key"});
  if (auto v = s.boolean("from_scene")) spec.camera_from_scene = *v;
  if (auto v = s.string("name")) {
    if (!spec.camera_from_scene)
      s.fail_at("name", "names the scene camera to take: only with camera.from_scene = true");
    if (v->empty() || v->size() > 1024)
      s.fail_at("name", "must be a camera's name in the scene, 1 to 1024 bytes");
    spec.camera_name = *v;
  }
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

void read_lights(const Section& s, JobSpec& spec) {
  s.check_keys({"radius", "sun_angle", "lamp"});
  const Interval radius_range = Interval::closed(0, 1e6, "a radius in [0, 1e6] scene units");
  const Interval angle_range = Interval::closed(0, 180, "an angle in [0, 180] degrees");
  if (auto v = s.number("radius", radius_range)) spec.light_radius = float(*v);
  if (auto v = s.number("sun_angle", angle_range)) spec.sun_angle_deg = float(*v);
  const toml::array* lamps = s.array_of_tables("lamp");
  if (!lamps) return;
  for (size_t i = 0; i < lamps->size(); ++i) {
    Section ls(s.origins(), lamps->get(i)->as_table(), fmt::format("{}.lamp.{}", s.name(), i),
               s.loc());
    ls.check_keys({"name", "radius", "sun_angle"});
    JobSpec::LampSize size;
    size.index = int(i);
    auto name = ls.string("name");
    if (!name || name->empty())
      fail(ls.loc(), ls.key("name"), "required: the lamp's name in the scene");
    size.name = *name;
    if (auto v = ls.number("radius", radius_range)) size.radius = float(*v);
    if (auto v = ls.number("sun_angle", angle_range)) size.sun_angle_deg = float(*v);
    if (size.radius < 0 && size.sun_angle_deg < 0)
      fail(ls.loc(), ls.name(), "gives neither radius nor sun_angle");
    for (const JobSpec::LampSize& before : spec.lamp_sizes)
      if (before.name == size.name)
        ls.fail_at("name", fmt::format("lamp \"{}\" is sized already by lights.lamp.{}", size.name,
                                       before.index));
    spec.lamp_sizes.push_back(size);
  }
}

void read_buffers(const Section& s, JobSpec& spec) {
  s.check_keys({"versions", "reference_spp", "reference_error", "reference_max_spp",
                "reference_display_error", "reference_clamp", "albedo_ref_spp"});
  if (auto v = s.integer("versions", IntRange::between(1, 64))) spec.versions = int(*v);
  s.exclusive("reference_spp", "reference_error");
  if (auto v = s.integer("reference_spp", IntRange::positive())) spec.reference_spp = int(*v);
  if (auto v = s.number("reference_error", Interval::open(0, 1))) spec.reference_error = float(*v);
  if (s.find("reference_max_spp") && !s.find("reference_error")) {
    s.fail_at("reference_max_spp", "only applies with reference_error");
  }
  if (auto v = s.integer("reference_max_spp", IntRange::positive()))
    spec.reference_max_spp = int(*v);
  if (s.find("reference_display_error") && !s.find("reference_error")) {
    s.fail_at("reference_display_error", "only applies with reference_error");
  }
  if (auto v = s.number("reference_display_error", Interval::open(0, 1)))
    spec.reference_display_error = float(*v);
  if (auto v = s.integer("albedo_ref_spp", IntRange::positive())) spec.albedo_ref_spp = int(*v);
  if (auto v = s.number("reference_clamp", Interval::positive())) spec.reference_clamp = float(*v);
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
  top.check_keys({"scene", "seed", "image", "frames", "camera", "environment", "lights", "buffers",
                  "render", "farm"});
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
  read_lights(top.table("lights"), spec);
  read_buffers(top.table("buffers"), spec);
  read_render(top.table("render"), spec);
  read_farm(top.table("farm"), spec);
  record_locations(root, "", origins, spec.key_locations);
  // A size that follows the scene camera is checked once it is known.
  const bool size_from_scene = spec.camera_from_scene && !(spec.width_given && spec.height_given);
  if (!size_from_scene) check_batch_size(spec);
  return spec;
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
  for (const auto& o : overrides) spec_reading::apply_override(root, o, origins);
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
