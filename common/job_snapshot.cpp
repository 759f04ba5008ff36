#include "common/job_snapshot.h"

#include <fmt/format.h>

#include <algorithm>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <toml++/toml.h>

#include "common/content_hash.h"
#include "common/error.h"

namespace dofarm {

namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// A TOML basic string.
std::string quoted(const std::string& s) {
  std::string out = "\"";
  for (unsigned char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += char(c);
    } else if (c < 0x20 || c == 0x7f) {
      out += fmt::format("\\u{:04X}", unsigned(c));
    } else {
      out += char(c);
    }
  }
  return out + "\"";
}

// The shortest decimal that reads back as the same float, always with a
// point or an exponent so TOML takes it as a float.
std::string number(float v) {
  std::string s = fmt::format("{}", v);
  if (s.find_first_of(".e") == std::string::npos) s += ".0";
  return s;
}

std::string vec3(Vec3 v) {
  return "[" + number(v.x) + ", " + number(v.y) + ", " + number(v.z) + "]";
}

// A relative path inside the job folder: no root, no "..", no empty parts.
bool safe_relative(const std::string& p) {
  if (p.empty() || p.size() > 4096 || p.front() == '/') return false;
  if (p.find('\0') != std::string::npos || p.find('\\') != std::string::npos) return false;
  std::stringstream parts(p);
  std::string part;
  while (std::getline(parts, part, '/'))
    if (part.empty() || part == "." || part == "..") return false;
  return p.back() != '/';
}

Json hashed_part(const JobSnapshot& s) {
  Json inputs = Json::array();
  for (const JobInput& in : s.inputs)
    inputs.push_back({{"path", in.path}, {"size", in.size}, {"hash", in.hash}});
  return {{"schema", kJobSchema}, {"spec", s.spec_toml}, {"inputs", inputs}};
}

void flatten(const toml::node& node, const std::string& prefix,
             std::map<std::string, std::string>& out) {
  if (const toml::table* t = node.as_table()) {
    for (const auto& [k, v] : *t)
      flatten(v, prefix.empty() ? std::string(k.str()) : prefix + "." + std::string(k.str()), out);
  } else if (const toml::array* a = node.as_array(); a && a->is_array_of_tables()) {
    for (size_t i = 0; i < a->size(); ++i) flatten(*a->get(i), prefix + "." + std::to_string(i), out);
  } else {
    std::ostringstream s;
    if (const toml::array* arr = node.as_array())
      s << *arr;
    else if (auto v = node.value<std::string>())
      s << quoted(*v);
    else if (auto d = node.as_floating_point())
      s << number(float(d->get()));
    else if (auto i = node.as_integer())
      s << i->get();
    else if (auto b = node.as_boolean())
      s << (b->get() ? "true" : "false");
    out[prefix] = s.str();
  }
}

}  // namespace

std::string canonical_spec_toml(const JobSpec& spec, const std::string& scene,
                                const std::string& environment_map) {
  std::string t;
  auto line = [&](const std::string& s) { t += s + "\n"; };
  line("# dofarm job snapshot: the resolved spec, every key at its value");
  line("scene = " + quoted(scene));
  line("seed = " + std::to_string(spec.seed));
  line("\n[image]");
  line("width = " + std::to_string(spec.width));
  line("height = " + std::to_string(spec.height));
  line("\n[frames]");
  line("start = " + std::to_string(spec.frame_start));
  line("end = " + std::to_string(spec.frame_end));
  line("per_shard = " + std::to_string(spec.per_shard));
  line("fps = " + number(spec.fps));
  line("\n[camera]");
  line(std::string("from_scene = ") + (spec.camera_from_scene ? "true" : "false"));
  // Only when given, so that the jobs written before the key keep their hashes.
  if (!spec.camera_name.empty()) line("name = " + quoted(spec.camera_name));
  for (const CameraKey& k : spec.camera_keys) {
    line("\n[[camera.key]]");
    line("frame = " + std::to_string(k.frame));
    if (!spec.camera_from_scene) {
      line("position = " + vec3(k.position));
      if (k.look_at) {
        line("look_at = " + vec3(*k.look_at));
        line("up = " + vec3(k.up));
      } else if (k.rotation_deg) {
        line("rotation = " + vec3(*k.rotation_deg));
      }
      line("fov = " + number(k.fov_deg));
    }
    // The keys as given: an f-number without a focal length, a focus point
    // or autofocus depend on each frame's camera and are resolved there.
    switch (k.focus) {
      case FocusMode::kNone:  // a pinhole: records 1, as it always has
      case FocusMode::kDistance:
        line("focal_distance = " + number(k.focal_distance));
        break;
      case FocusMode::kPoint:
        line("focus_point = " + vec3(k.focus_point));
        break;
      case FocusMode::kAuto:
        line("focus = \"auto\"");
        break;
    }
    if (k.fstop > 0) {
      line("fstop = " + number(k.fstop));
      if (k.focal_length_mm > 0)
        line("focal_length = " + number(k.focal_length_mm));
      else
        line("sensor_width = " + number(k.sensor_width_mm));
    } else {
      line("aperture = " + number(k.aperture));
    }
  }
  if (spec.environment) {
    const EnvironmentSpec& e = *spec.environment;
    line("\n[environment]");
    if (e.color)
      line("color = " + vec3(*e.color));
    else
      line("map = " + quoted(environment_map));
    line("intensity = " + number(e.intensity));
    line("rotation = " + number(e.rotation_deg));
  }
  // Written only when set, so that the snapshots (and content hashes) of
  // jobs without lamp sizes stay what they were.
  if (spec.light_radius > 0 || spec.sun_angle_deg > 0 || !spec.lamp_sizes.empty()) {
    line("\n[lights]");
    if (spec.light_radius > 0) line("radius = " + number(spec.light_radius));
    if (spec.sun_angle_deg > 0) line("sun_angle = " + number(spec.sun_angle_deg));
    for (const JobSpec::LampSize& lamp : spec.lamp_sizes) {
      line("\n[[lights.lamp]]");
      line("name = " + quoted(lamp.name));
      if (lamp.radius >= 0) line("radius = " + number(lamp.radius));
      if (lamp.sun_angle_deg >= 0) line("sun_angle = " + number(lamp.sun_angle_deg));
    }
  }
  line("\n[buffers]");
  line("versions = " + std::to_string(spec.versions));
  if (spec.reference_error > 0) {
    line("reference_error = " + number(spec.reference_error));
    line("reference_max_spp = " + std::to_string(spec.reference_max_spp));
    // Only when set: older jobs keep their snapshots and content hashes.
    if (spec.reference_display_error > 0)
      line("reference_display_error = " + number(spec.reference_display_error));
  } else {
    line("reference_spp = " + std::to_string(spec.reference_spp));
  }
  line("albedo_ref_spp = " + std::to_string(spec.albedo_ref_spp));
  // Written only when set, so that the snapshots (and content hashes) of
  // jobs without it stay what they were.
  if (spec.reference_clamp > 0) line("reference_clamp = " + number(spec.reference_clamp));
  line("\n[render]");
  line("max_depth = " + std::to_string(spec.max_depth));
  line("rr_start_depth = " + std::to_string(spec.rr_start_depth));
  line(std::string("sampler = ") +
       (spec.sampler == SamplerKind::kSobol ? "\"sobol\"" : "\"independent\""));
  line("\n[farm]");
  if (spec.task_seconds > 0)
    line("task_seconds = " + number(spec.task_seconds));
  else
    line("tile = " + std::to_string(spec.tile));
  return t;
}

std::vector<std::string> spec_differences(const std::string& a_toml, const std::string& b_toml) {
  std::map<std::string, std::string> a, b;
  try {
    flatten(toml::parse(a_toml), "", a);
    flatten(toml::parse(b_toml), "", b);
  } catch (const toml::parse_error& e) {
    return {std::string("(cannot compare: ") + std::string(e.description()) + ")"};
  }
  std::vector<std::string> out;
  for (const auto& [k, v] : a) {
    auto it = b.find(k);
    if (it == b.end())
      out.push_back(k + ": " + v + " -> (absent)");
    else if (it->second != v)
      out.push_back(k + ": " + v + " -> " + it->second);
  }
  for (const auto& [k, v] : b)
    if (!a.count(k)) out.push_back(k + ": (absent) -> " + v);
  return out;
}

std::string JobSnapshot::hash() const { return content_hash(hashed_part(*this).dump()); }

std::string JobSnapshot::to_json(int indent) const {
  Json j = hashed_part(*this);
  j["job"] = hash();
  j["source"] = {{"spec", source_spec}, {"overrides", source_overrides}};
  return indent < 0 ? j.dump() : j.dump(indent) + "\n";
}

JobSnapshot JobSnapshot::from_json(const std::string& text, const std::string& where) {
  auto bad = [&](const std::string& why) -> RuntimeError {
    return RuntimeError("job snapshot " + where + ": " + why);
  };
  Json j = Json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (!j.is_object()) throw bad("not a JSON object");
  if (!j.contains("schema") || j["schema"] != kJobSchema)
    throw bad(std::string("schema is not \"") + kJobSchema + "\"");
  if (!j.contains("spec") || !j["spec"].is_string()) throw bad("\"spec\" must be a string");
  if (!j.contains("inputs") || !j["inputs"].is_array()) throw bad("\"inputs\" must be an array");
  if (j["inputs"].size() > kMaxJobInputs)
    throw bad("more than " + std::to_string(kMaxJobInputs) + " inputs");
  JobSnapshot s;
  s.spec_toml = j["spec"].get<std::string>();
  for (const Json& in : j["inputs"]) {
    if (!in.is_object() || !in.contains("path") || !in["path"].is_string() ||
        !in.contains("size") || !in["size"].is_number_unsigned() || !in.contains("hash") ||
        !in["hash"].is_string())
      throw bad("an input needs path (string), size (unsigned) and hash (string)");
    JobInput x{in["path"].get<std::string>(), in["size"].get<uint64_t>(),
               in["hash"].get<std::string>()};
    if (!safe_relative(x.path) || x.path.rfind("files/", 0) != 0)
      throw bad("input path \"" + x.path.substr(0, 200) + "\" is not inside files/");
    if (!is_content_hash(x.hash)) throw bad("input \"" + x.path + "\" has a malformed hash");
    if (!s.inputs.empty() && !(s.inputs.back().path < x.path))
      throw bad("inputs are not sorted by path without duplicates");
    s.inputs.push_back(std::move(x));
  }
  if (j.contains("source") && j["source"].is_object()) {
    const Json& src = j["source"];
    if (src.contains("spec") && src["spec"].is_string()) s.source_spec = src["spec"];
    if (src.contains("overrides") && src["overrides"].is_array())
      for (const Json& o : src["overrides"])
        if (o.is_string()) s.source_overrides.push_back(o);
  }
  return s;
}

fs::path jobs_dir(const fs::path& out_dir) { return out_dir / ".dofarm-jobs"; }
fs::path job_dir(const fs::path& out_dir, const std::string& hash) {
  return jobs_dir(out_dir) / hash;
}

JobSnapshot read_job_snapshot(const fs::path& out_dir, const std::string& hash) {
  if (!is_content_hash(hash)) throw RuntimeError("\"" + hash.substr(0, 64) + "\" is not a job hash");
  const fs::path file = job_dir(out_dir, hash) / "job.json";
  JobSnapshot s = JobSnapshot::from_json(read_regular_file(file, kMaxSnapshotBytes), file.string());
  if (s.hash() != hash)
    throw RuntimeError("job snapshot " + file.string() + " hashes to " + s.hash() +
                       ", not to its name " + hash);
  return s;
}

LoadedJob load_job(const fs::path& out_dir, const std::string& hash) {
  LoadedJob job;
  job.snapshot = read_job_snapshot(out_dir, hash);
  const fs::path dir = job_dir(out_dir, hash);
  for (const JobInput& in : job.snapshot.inputs) {
    // Every directory on the way is checked too: no symlink may lead out of
    // the job folder.
    fs::path p = dir;
    std::stringstream parts(in.path);
    std::string part;
    while (std::getline(parts, part, '/')) {
      p /= part;
      std::error_code ec;
      if (fs::is_symlink(fs::symlink_status(p, ec)))
        throw RuntimeError("job input " + p.string() + " is a symbolic link");
    }
    FileHash h = hash_regular_file(p, in.size);
    if (h.size != in.size || h.hash != in.hash)
      throw RuntimeError("job input " + p.string() + " does not match the job's snapshot (" +
                         std::to_string(h.size) + " bytes, hash " + h.hash + "; expected " +
                         std::to_string(in.size) + " bytes, hash " + in.hash + ")");
  }
  job.spec = parse_job_spec(job.snapshot.spec_toml, dir / "job.toml");
  return job;
}

fs::path owner_file(const fs::path& out_dir) { return out_dir / ".dofarm-owner.json"; }

std::optional<OutputOwner> read_output_owner(const fs::path& out_dir) {
  const fs::path file = owner_file(out_dir);
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(file, ec))) return std::nullopt;
  Json j = Json::parse(read_regular_file(file, 1 << 16), nullptr, false);
  if (!j.is_object() || !j.contains("job") || !j["job"].is_string() ||
      !is_content_hash(j["job"].get<std::string>()))
    throw RuntimeError(file.string() + ": not a dofarm ownership record (a \"job\" hash is needed)");
  OutputOwner o;
  o.job = j["job"];
  if (j.contains("batch") && j["batch"].is_string()) o.batch = j["batch"];
  if (j.contains("spec") && j["spec"].is_string()) o.spec = j["spec"];
  return o;
}

void write_output_owner(const fs::path& out_dir, const OutputOwner& owner) {
  if (auto existing = read_output_owner(out_dir); existing && existing->job != owner.job)
    throw RuntimeError(owner_file(out_dir).string() + " belongs to job " + existing->job);
  const std::string text =
      Json{{"job", owner.job}, {"batch", owner.batch}, {"spec", owner.spec}}.dump(2) + "\n";
  std::random_device rd;
  const fs::path tmp = out_dir / fmt::format(".dofarm-owner.json.tmp-{:08x}", rd());
  write_new_file(tmp, text);
  std::error_code ec;
  fs::rename(tmp, owner_file(out_dir), ec);
  if (ec) {
    fs::remove(tmp, ec);
    throw RuntimeError("cannot write " + owner_file(out_dir).string() + ": " + ec.message());
  }
}

std::string conflict_message(const fs::path& out_dir, const std::string& batch,
                             const std::string& other_job, const JobSnapshot* other,
                             const std::string& other_error, const JobSnapshot& job) {
  std::string msg = "output folder " + out_dir.string() + " holds batch " +
                    (batch.empty() ? "(unknown)" : batch) + " of another job" +
                    (other_job.empty() ? " (written before job snapshots)" : " (" + other_job + ")");
  if (other) {
    std::vector<std::string> diff = spec_differences(other->spec_toml, job.spec_toml);
    std::map<std::string, std::string> theirs, ours;
    for (const JobInput& in : other->inputs) theirs[in.path] = in.hash;
    for (const JobInput& in : job.inputs) ours[in.path] = in.hash;
    for (const auto& [p, h] : ours)
      if (!theirs.count(p) || theirs[p] != h) diff.push_back("input " + p + ": content differs");
    for (const auto& [p, h] : theirs)
      if (!ours.count(p)) diff.push_back("input " + p + ": not in this job");
    if (!diff.empty()) {
      msg += "; what differs (theirs -> this job's):";
      for (const std::string& d : diff) msg += "\n  " + d;
    }
  } else if (!other_error.empty()) {
    msg += " (its snapshot cannot be read: " + other_error + ")";
  }
  return msg + "\nnothing was changed; write this job to another --out folder";
}

std::string ownership_conflict(const fs::path& out_dir, const JobSnapshot& job) {
  std::optional<OutputOwner> owner = read_output_owner(out_dir);
  if (!owner || owner->job == job.hash()) return "";
  try {
    JobSnapshot other = read_job_snapshot(out_dir, owner->job);
    return conflict_message(out_dir, owner->batch, owner->job, &other, "", job);
  } catch (const std::exception& e) {
    return conflict_message(out_dir, owner->batch, owner->job, nullptr, e.what(), job);
  }
}

}  // namespace dofarm
