#include "worker/job_resolve.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <random>
#include <sstream>

#include "common/content_hash.h"
#include "common/error.h"
#include "worker/render/camera.h"
#include "worker/render/render_job.h"
#include "worker/render/scene.h"

namespace dofarm::worker {

namespace fs = std::filesystem;

namespace {

fs::path normal(const fs::path& p) { return fs::absolute(p).lexically_normal(); }

// The deepest folder holding every file.
fs::path common_folder(const std::vector<fs::path>& files) {
  fs::path base = files.front().parent_path();
  for (const fs::path& f : files) {
    fs::path dir = f.parent_path();
    while (!base.empty()) {
      auto [b, d] = std::mismatch(base.begin(), base.end(), dir.begin(), dir.end());
      if (b == base.end()) break;
      base = base.parent_path();
    }
  }
  return base;
}

struct Fd {
  int fd = -1;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

// Copies a regular file (never through a symlink, never a FIFO) to `to`,
// fsynced; returns the hash and size of the bytes copied.
FileHash copy_and_hash(const fs::path& from, const fs::path& to) {
  uint64_t size = 0;
  Fd in{open_regular_file(from, UINT64_MAX, &size)};
  fs::create_directories(to.parent_path());
  Fd out{::open(to.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644)};
  if (out.fd < 0)
    throw RuntimeError("cannot create \"" + to.string() + "\": " + std::strerror(errno));
  ContentHasher h;
  FileHash r;
  std::vector<char> buf(1 << 20);
  while (true) {
    ssize_t n = ::read(in.fd, buf.data(), buf.size());
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw RuntimeError("reading \"" + from.string() + "\": " + std::strerror(errno));
    if (n == 0) break;
    h.update(buf.data(), size_t(n));
    r.size += uint64_t(n);
    for (ssize_t done = 0; done < n;) {
      ssize_t w = ::write(out.fd, buf.data() + done, size_t(n - done));
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) throw RuntimeError("writing \"" + to.string() + "\": " + std::strerror(errno));
      done += w;
    }
  }
  if (::fsync(out.fd) != 0) throw RuntimeError("fsync \"" + to.string() + "\" failed");
  r.hash = h.hex();
  return r;
}

}  // namespace

// Where `key` ("scene" or "environment.map") is set in the spec file, for
// the message; line 0 when the file does not set it there (a --set did).
FileLoc key_location(const fs::path& spec_path, const std::string& key) {
  FileLoc loc{spec_path.string()};
  std::string text;
  try {
    text = read_regular_file(spec_path, kMaxSpecBytes);
  } catch (const std::exception&) {
    return loc;
  }
  const bool in_env = key == "environment.map";
  const std::string name = in_env ? "map" : key;
  std::istringstream lines(text);
  std::string line, section;
  for (int n = 1; std::getline(lines, line); ++n) {
    const size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos) continue;
    if (line[first] == '[') {
      const size_t close = line.find(']', first);
      section = line.substr(first + 1, close == std::string::npos ? 0 : close - first - 1);
      continue;
    }
    if (section != (in_env ? "environment" : "") || line.compare(first, name.size(), name) != 0)
      continue;
    const size_t eq = line.find_first_not_of(" \t", first + name.size());
    if (eq != std::string::npos && line[eq] == '=') {
      loc.line = n;
      loc.column = int(first) + 1;
      return loc;
    }
  }
  return loc;
}

std::shared_ptr<const render::Scene> load_scene_checked(const JobSpec& spec) {
  try {
    return render::load_scene(spec);
  } catch (const SpecError& e) {
    // The scene's own content errors (key "scene", located in the scene
    // file) are put at the job's scene key; an error at another key is a
    // job key checked against the scene ([[lights.lamp]]), already located
    // where the job sets it.
    if (e.key() != "scene") throw;
    throw SpecError(key_location(spec.spec_path, "scene"), "scene",
                    "\"" + spec.scene.string() + "\": " + e.message());
  } catch (const std::exception& e) {
    const bool env = spec.environment && !spec.environment->map.empty() &&
                     std::string(e.what()).find(spec.environment->map.string()) != std::string::npos;
    const std::string key = env ? "environment.map" : "scene";
    throw SpecError(key_location(spec.spec_path, key), key, e.what());
  }
}

void complete_spec_from_scene(JobSpec& spec, const render::Scene& scene) {
  const auto& track = scene.data().camera_track;
  if (spec.camera_from_scene) {
    const std::vector<std::string>& names = scene.data().camera_names;
    if (!spec.camera_name.empty() &&
        std::find(names.begin(), names.end(), spec.camera_name) == names.end()) {
      throw SpecError(spec.where("camera.name"), "camera.name",
                      names.empty()
                          ? fmt::format("the scene \"{}\" has no camera", spec.scene.string())
                          : fmt::format("the scene \"{}\" has no camera \"{}\"; its cameras: {}",
                                        spec.scene.string(), spec.camera_name, quoted_list(names)));
    }
    // A Blender file holds every camera of the scene, the active one not
    // marked (glTF has no such mark): say which one is taken.
    if (spec.camera_name.empty() && names.size() > 1)
      spdlog::warn(
          "{}: the scene has {} cameras ({}); rendering from \"{}\", the first, as camera.name "
          "is not set",
          spec.spec_path.string(), names.size(), quoted_list(names), names.front());
    if (track.empty()) {
      throw SpecError(spec.where("camera.from_scene"), "camera.from_scene",
                      render::no_scene_camera_message(scene.data(), spec.scene.string()));
    }
    const float aspect = track.front().aspect;
    const render::ImageSize size = render::image_size_for_aspect(
        aspect, spec.width_given ? spec.width : 0, spec.height_given ? spec.height : 0);
    for (auto [key, side, given] : {std::tuple{"image.width", size.width, spec.width_given},
                                    std::tuple{"image.height", size.height, spec.height_given}}) {
      if (side > kMaxImageSide) {
        const char* blame = given ? key : (spec.width_given ? "image.width" : "image.height");
        throw SpecError(spec.where(blame), blame,
                        fmt::format("the scene camera's aspect ratio {:.4g} makes the image {}x{}: "
                                    "{} would be above {}; give a smaller size",
                                    aspect, size.width, size.height, key, kMaxImageSide));
      }
    }
    spec.width = size.width;
    spec.height = size.height;
    spec.width_given = spec.height_given = true;
    check_batch_size(spec);
    if (std::string why = render::describe_aspect_mismatch(aspect, spec.width, spec.height,
                                                           track.front().ymag > 0);
        !why.empty())
      spdlog::warn("{}: {}", spec.spec_path.string(), why);
  }
  // Focus points and autofocus depend on each frame's camera, and a scene
  // camera is posed by the file's samplers at each frame's time: resolve
  // every frame now (one ray at most per frame) so that a bad one fails here.
  const bool per_frame_focus =
      std::any_of(spec.camera_keys.begin(), spec.camera_keys.end(), [](const CameraKey& k) {
        return k.focus == FocusMode::kPoint || k.focus == FocusMode::kAuto;
      });
  if (per_frame_focus || spec.camera_from_scene) {
    for (int64_t f = spec.frame_start; f <= spec.frame_end; ++f)
      render::frame_camera(scene, spec, int(f));
  }
}

ResolvedJob resolve_job(const fs::path& spec_path_in, const std::vector<std::string>& overrides) {
  const fs::path spec_path = normal(spec_path_in);
  std::string text;
  try {
    text = read_regular_file(spec_path, kMaxSpecBytes);
  } catch (const RuntimeError& e) {
    throw SpecError(FileLoc{spec_path.string()}, "", e.what());
  }
  ResolvedJob job;
  job.spec = parse_job_spec(text, spec_path, overrides);

  // Load what a worker loads, noting every file read.
  InputFileLog log;
  complete_spec_from_scene(job.spec, *load_scene_checked(job.spec));
  const JobSpec& spec = job.spec;
  std::vector<fs::path> files = log.files();
  const fs::path scene = normal(spec.scene);
  if (std::find(files.begin(), files.end(), scene) == files.end()) files.push_back(scene);
  fs::path env;
  if (spec.environment && !spec.environment->map.empty()) {
    env = normal(spec.environment->map);
    if (std::find(files.begin(), files.end(), env) == files.end()) files.push_back(env);
  }
  if (files.size() > kMaxJobInputs)
    throw SpecError(FileLoc{spec_path.string()}, "scene",
                    fmt::format("the scene reads {} files, more than the {} a job may have",
                                files.size(), kMaxJobInputs));

  // Inside the job folder the files keep their places relative to the
  // deepest folder that holds them all, so the scene's relative references
  // (buffers, textures) still resolve.
  const fs::path base = common_folder(files);
  std::string scene_rel, env_rel;
  for (const fs::path& f : files) {
    const std::string rel = "files/" + f.lexically_relative(base).generic_string();
    FileHash h;
    try {
      h = hash_regular_file(f);
    } catch (const RuntimeError& e) {
      throw SpecError(FileLoc{spec_path.string()}, f == env ? "environment.map" : "scene",
                      e.what());
    }
    job.snapshot.inputs.push_back({rel, h.size, h.hash});
    job.files.emplace_back(f, rel);
    if (f == scene) scene_rel = rel;
    if (f == env) env_rel = rel;
  }
  std::sort(job.snapshot.inputs.begin(), job.snapshot.inputs.end(),
            [](const JobInput& a, const JobInput& b) { return a.path < b.path; });
  job.snapshot.spec_toml = canonical_spec_toml(spec, scene_rel, env_rel);
  job.snapshot.source_spec = spec_path.string();
  job.snapshot.source_overrides = overrides;
  return job;
}

fs::path materialize_job(const ResolvedJob& job, const fs::path& out_dir) {
  const std::string hash = job.snapshot.hash();
  const fs::path dir = job_dir(out_dir, hash);
  std::error_code ec;
  if (fs::exists(fs::symlink_status(dir, ec))) {
    try {
      load_job(out_dir, hash);
      return dir;  // already there, every file as it should be
    } catch (const std::exception& e) {
      // A damaged copy is set aside (never deleted) and written again.
      fs::path aside = dir;
      aside += fmt::format(".damaged-{:08x}", std::random_device{}());
      fs::rename(dir, aside);
    }
  }
  fs::create_directories(jobs_dir(out_dir));
  fs::path tmp = jobs_dir(out_dir) / fmt::format(".tmp-{}-{:08x}", hash, std::random_device{}());
  fs::create_directory(tmp);
  try {
    for (const auto& [from, rel] : job.files) {
      FileHash copied = copy_and_hash(from, tmp / rel);
      auto it = std::find_if(job.snapshot.inputs.begin(), job.snapshot.inputs.end(),
                             [&](const JobInput& in) { return in.path == rel; });
      if (it == job.snapshot.inputs.end() || it->hash != copied.hash || it->size != copied.size)
        throw RuntimeError("\"" + from.string() +
                           "\" changed while the job was being submitted; submit it again");
    }
    write_new_file(tmp / "job.json", job.snapshot.to_json());
    write_new_file(tmp / "job.toml", job.snapshot.spec_toml);
    fs::rename(tmp, dir, ec);
    if (ec) {
      // Another process published the same job meanwhile: use theirs if whole.
      fs::remove_all(tmp, ec);
      load_job(out_dir, hash);
    }
  } catch (...) {
    fs::remove_all(tmp, ec);
    throw;
  }
  return dir;
}

}  // namespace dofarm::worker
