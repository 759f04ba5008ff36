// Shared by the farm tests: the real `dofarm` executable as child processes
// (stdout/stderr into files of the test's temporary folder), polling with a
// deadline instead of sleeping, tiny job specs, and the check every farm test
// ends with: the shards listed in OUT/manifest.json hold every frame exactly
// once, bit-identical to an in-process render_frame() of it.
#pragma once

#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "common/error.h"
#include "common/image.h"
#include "common/jobspec.h"
#include "common/manifest.h"
#include "common/protocol.h"
#include "common/shard.h"
#include "common/transport.h"
#include "worker/job_resolve.h"
#include "worker/render/render_job.h"

namespace dofarm::farm_testing {

namespace fs = std::filesystem;
using protocol::Json;
using Clock = std::chrono::steady_clock;

inline fs::path dofarm_exe() { return DOFARM_EXE; }
inline fs::path cornell_scene() { return fs::path(DOFARM_SOURCE_DIR) / "jobs/scenes/cornell.gltf"; }

// Deadlines are generous: two cores are shared by several builds and tests.
inline constexpr double kDeadlineSeconds = 90;

// A fresh folder per test; kept (and named) when the test failed, so the
// child processes' logs can be read.
class TempDir {
 public:
  TempDir() {
    static std::atomic<int> counter{0};
    path_ = fs::temp_directory_path() /
            ("dofarm_farm_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() {
    if (::testing::Test::HasFailure()) {
      std::fprintf(stderr, "[ farm    ] kept %s for inspection\n", path_.c_str());
      return;
    }
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const fs::path& path() const { return path_; }
  fs::path operator/(const std::string& name) const { return path_ / name; }

 private:
  fs::path path_;
};

inline std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

inline void write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

inline double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Calls `condition` every 50 ms until it holds; fails naming `what` (and the
// last `detail` the condition left) when the deadline passes first.
inline ::testing::AssertionResult poll_until(const std::string& what,
                                             const std::function<bool()>& condition,
                                             double deadline_seconds = kDeadlineSeconds) {
  const auto t0 = Clock::now();
  while (true) {
    if (condition()) return ::testing::AssertionSuccess();
    if (seconds_since(t0) > deadline_seconds)
      return ::testing::AssertionFailure()
             << "timed out after " << deadline_seconds << " s waiting for: " << what;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

// A child process running the dofarm executable. Killed (SIGKILL) and reaped
// by the destructor if still running, so no test leaves processes behind;
// the child also dies with the test process (PR_SET_PDEATHSIG).
class Child {
 public:
  Child() = default;
  Child(const std::vector<std::string>& args, const fs::path& stdout_file,
        const fs::path& stderr_file)
      : stdout_file_(stdout_file), stderr_file_(stderr_file) {
    std::vector<std::string> full = {dofarm_exe().string()};
    full.insert(full.end(), args.begin(), args.end());
    for (const auto& a : full) command_ += (command_.empty() ? "" : " ") + a;
    std::vector<char*> argv;
    for (auto& a : full) argv.push_back(a.data());
    argv.push_back(nullptr);
    const std::string out = stdout_file.string(), err = stderr_file.string();
    const pid_t parent = ::getpid();
    pid_ = ::fork();
    if (pid_ < 0) throw RuntimeError("fork: " + std::string(std::strerror(errno)));
    if (pid_ == 0) {
      // Only async-signal-safe calls between fork and exec.
      ::prctl(PR_SET_PDEATHSIG, SIGKILL);
      if (::getppid() != parent) ::_exit(127);
      int o = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      int e = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      if (o < 0 || e < 0) ::_exit(127);
      ::dup2(o, 1);
      ::dup2(e, 2);
      int in = ::open("/dev/null", O_RDONLY);
      if (in >= 0) ::dup2(in, 0);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
  }
  ~Child() {
    if (pid_ > 0 && !status_) {
      ::kill(pid_, SIGKILL);
      int st;
      ::waitpid(pid_, &st, 0);
    }
  }
  Child(Child&& o) noexcept { *this = std::move(o); }
  Child& operator=(Child&& o) noexcept {
    std::swap(pid_, o.pid_);
    std::swap(status_, o.status_);
    std::swap(command_, o.command_);
    std::swap(stdout_file_, o.stdout_file_);
    std::swap(stderr_file_, o.stderr_file_);
    return *this;
  }

  pid_t pid() const { return pid_; }
  const std::string& command() const { return command_; }
  std::string out() const { return read_text(stdout_file_); }
  std::string err() const { return read_text(stderr_file_); }

  // Reaps the child if it exited: its exit status, or 128 + signal.
  std::optional<int> poll() {
    if (status_ || pid_ <= 0) return status_;
    int st;
    pid_t r = ::waitpid(pid_, &st, WNOHANG);
    if (r == pid_) status_ = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    return status_;
  }
  bool running() { return !poll().has_value(); }
  // Waits for the child to exit; empty on timeout (it keeps running).
  std::optional<int> wait(double deadline_seconds = kDeadlineSeconds) {
    const auto t0 = Clock::now();
    while (!poll() && seconds_since(t0) < deadline_seconds)
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    return status_;
  }
  void signal(int sig) {
    if (pid_ > 0 && !status_) ::kill(pid_, sig);
  }
  // kill -9 and reap.
  void kill9() {
    signal(SIGKILL);
    wait(30);
  }
  std::string describe() const {
    return command_ + "\n--- stdout:\n" + out() + "\n--- stderr:\n" + err();
  }

 private:
  pid_t pid_ = -1;
  std::optional<int> status_;
  std::string command_;
  fs::path stdout_file_, stderr_file_;
};

// A dofarm command run to completion.
struct CliResult {
  int status = -1;  // -1: it did not finish in time (and was killed)
  std::string out, err;
};

inline CliResult run_cli(const fs::path& dir, const std::string& name,
                         const std::vector<std::string>& args,
                         double deadline_seconds = kDeadlineSeconds) {
  Child c(args, dir / (name + ".out"), dir / (name + ".err"));
  CliResult r;
  std::optional<int> st = c.wait(deadline_seconds);
  if (!st) c.kill9();
  r.status = st.value_or(-1);
  r.out = c.out();
  r.err = c.err();
  return r;
}

// The fields of a `submit` message for `spec` into `out`, as `dofarm submit`
// sends them: the job resolved, copied into out/.dofarm-jobs, and sent as
// its snapshot.
inline Json submit_fields(const fs::path& spec, const fs::path& out,
                          const std::vector<std::string>& sets = {}) {
  worker::ResolvedJob job = worker::resolve_job(spec, sets);
  fs::create_directories(out);
  worker::materialize_job(job, out);
  return {{"snapshot", job.snapshot.to_json(-1)}, {"out_dir", fs::absolute(out).string()}};
}

// `dofarm coordinator` on a port the OS picks, read back from its first line.
class CoordinatorProcess {
 public:
  CoordinatorProcess(const fs::path& dir, const std::string& name, const fs::path& state,
                     double lease_seconds, std::vector<std::string> extra = {}) {
    std::vector<std::string> args = {
        "coordinator",  "--listen", "tcp://127.0.0.1:*",          "--state",
        state.string(), "--lease",  std::to_string(lease_seconds)};
    args.insert(args.end(), extra.begin(), extra.end());
    child_ = Child(args, dir / (name + ".out"), dir / (name + ".err"));
    const std::string prefix = "listening ";
    const auto t0 = Clock::now();
    while (endpoint_.empty()) {
      std::string out = child_.out();
      size_t nl = out.find('\n');
      if (nl != std::string::npos) {
        std::string line = out.substr(0, nl);
        if (line.rfind(prefix, 0) != 0)
          throw RuntimeError("unexpected first line \"" + line + "\" from " + child_.describe());
        endpoint_ = line.substr(prefix.size());
        break;
      }
      if (!child_.running() || seconds_since(t0) > kDeadlineSeconds)
        throw RuntimeError("the coordinator did not say where it listens: " + child_.describe());
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
  const std::string& endpoint() const { return endpoint_; }
  Child& child() { return child_; }

 private:
  Child child_;
  std::string endpoint_;
};

// `dofarm worker` with a fixed id, one render thread (the cores are shared)
// and quick heartbeats.
inline Child start_worker(const fs::path& dir, const std::string& endpoint, const std::string& id,
                          std::vector<std::string> extra = {}) {
  std::vector<std::string> args = {"worker", "--connect",   endpoint, "--id",
                                   id,       "--heartbeat", "0.5",    "--threads",
                                   "1",      "--give-up",   "120"};
  args.insert(args.end(), extra.begin(), extra.end());
  return Child(args, dir / (id + ".out"), dir / (id + ".err"));
}

// The worker processes a `dofarm run` of process `run_pid` started
// ("local-RUNPID-N" in their command line), found in /proc.
inline std::vector<pid_t> local_worker_pids(pid_t run_pid) {
  const std::string tag = "local-" + std::to_string(run_pid) + "-";
  std::vector<pid_t> pids;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/proc", ec)) {
    std::string cmd = read_text(e.path() / "cmdline");
    std::replace(cmd.begin(), cmd.end(), '\0', ' ');
    if (cmd.find(tag) == std::string::npos || cmd.find(" worker ") == std::string::npos) continue;
    const pid_t pid = std::atoi(e.path().filename().c_str());
    if (pid > 0) pids.push_back(pid);
  }
  return pids;
}

// One request/reply on a fresh connection (the same wire messages the CLI
// sends); throws on a timeout or an "error" reply.
inline Json coordinator_call(const std::string& endpoint, const std::string& type,
                             Json fields = Json::object(), int timeout_ms = 10000,
                             std::optional<fs::path> curve_public = std::nullopt) {
  protocol::Message m =
      call_coordinator({endpoint, curve_public, timeout_ms}, protocol::encode(type, fields));
  if (m.type == "error") throw RuntimeError("coordinator error: " + m.str("message"));
  return m.body;
}

inline Json farm_status(const std::string& endpoint, const std::string& batch = "") {
  Json req = Json::object();
  if (!batch.empty()) req["batch"] = batch;
  return coordinator_call(endpoint, "status", req);
}

// The batch's entry of a status reply; null when absent.
inline Json batch_of(const Json& status, const std::string& batch) {
  for (const Json& b : status.at("batches"))
    if (b.at("batch") == batch) return b;
  return nullptr;
}

inline std::string batch_state(const std::string& endpoint, const std::string& batch) {
  Json b = batch_of(farm_status(endpoint, batch), batch);
  return b.is_null() ? "absent" : b.at("state").get<std::string>();
}

// Task ids a worker holds according to the coordinator's status.
inline std::vector<int64_t> leases_of(const Json& status, const std::string& worker) {
  for (const Json& w : status.at("workers"))
    if (w.at("worker") == worker) return w.at("tasks").get<std::vector<int64_t>>();
  return {};
}

// A small job: the Cornell box through a lens, tiny buffers.
struct TinyJob {
  fs::path scene = cornell_scene();
  int width = 32, height = 24;
  int frame_start = 0, frame_end = 3, per_shard = 2;
  int tile = 16;
  int versions = 2, reference_spp = 4, albedo_ref_spp = 2;
};

inline fs::path write_job(const fs::path& dir, const std::string& name, const TinyJob& j) {
  std::ostringstream s;
  s << "scene = \"" << j.scene.string() << "\"\n"
    << "seed = 7\n\n"
    << "[image]\nwidth = " << j.width << "\nheight = " << j.height << "\n\n"
    << "[frames]\nstart = " << j.frame_start << "\nend = " << j.frame_end
    << "\nper_shard = " << j.per_shard << "\n\n"
    << "[[camera.key]]\nframe = " << j.frame_start
    << "\nposition = [0.0, 1.0, 3.9]\nlook_at = [0.0, 1.0, 0.0]\nfov = 38.0\n"
    << "focal_distance = 3.55\naperture = 0.05\n\n"
    << "[[camera.key]]\nframe = " << j.frame_end + 1
    << "\nposition = [0.2, 1.05, 3.6]\nlook_at = [0.0, 1.0, 0.0]\nfov = 38.0\n"
    << "focal_distance = 4.9\naperture = 0.08\n\n"
    << "[buffers]\nversions = " << j.versions << "\nreference_spp = " << j.reference_spp
    << "\nalbedo_ref_spp = " << j.albedo_ref_spp << "\n\n"
    << "[farm]\ntile = " << j.tile << "\n";
  fs::path path = dir / name;
  write_text(path, s.str());
  return path;
}

// Frames by absolute number, read from every shard that OUT/manifest.json
// lists; fails when a frame appears twice or a shard disagrees with its entry.
inline ::testing::AssertionResult read_manifest_frames(const fs::path& out_dir,
                                                       std::map<int, FrameBuffers>& frames) {
  frames.clear();
  Manifest manifest;
  try {
    manifest = load_manifest(out_dir);
  } catch (const std::exception& e) {
    return ::testing::AssertionFailure() << "manifest: " << e.what();
  }
  if (manifest.shards.empty())
    return ::testing::AssertionFailure() << "no shards listed in " << out_dir / kManifestFile;
  if (auto problems = verify_manifest(out_dir); !problems.empty())
    return ::testing::AssertionFailure()
           << problems.front().file << ": " << problems.front().problem;
  for (const ManifestEntry& e : manifest.shards) {
    ShardReader reader(out_dir / e.file);
    const ShardInfo& info = reader.info();
    if (info.frame_start != e.frame_start || info.frame_end != e.frame_end)
      return ::testing::AssertionFailure()
             << e.file << " holds frames " << info.frame_start << ".." << info.frame_end
             << ", the manifest says " << e.frame_start << ".." << e.frame_end;
    for (int i = 0; i < reader.frame_count(); ++i) {
      const int frame = info.frame_start + i;
      if (frames.count(frame))
        return ::testing::AssertionFailure() << "frame " << frame << " is in two shards";
      frames[frame] = reader.read_frame(i);
    }
  }
  return ::testing::AssertionSuccess();
}

inline bool same_floats(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

// Every buffer and the camera, bit for bit.
inline ::testing::AssertionResult same_frame(const FrameBuffers& a, const FrameBuffers& b) {
  if (a.width != b.width || a.height != b.height || a.versions != b.versions)
    return ::testing::AssertionFailure()
           << "size " << a.width << "x" << a.height << " v" << a.versions << " vs " << b.width
           << "x" << b.height << " v" << b.versions;
  for (const BufferInfo& info : buffer_infos()) {
    const auto& x = buffer_data(a, info.name);
    const auto& y = buffer_data(b, info.name);
    if (x.size() != y.size())
      return ::testing::AssertionFailure()
             << info.name << ": " << x.size() << " vs " << y.size() << " values";
    for (size_t i = 0; i < x.size(); ++i)
      if (std::memcmp(&x[i], &y[i], sizeof(float)) != 0)
        return ::testing::AssertionFailure()
               << info.name << "[" << i << "]: " << x[i] << " vs " << y[i];
  }
  const CameraState &c = a.camera, &d = b.camera;
  auto same = [](const void* p, const void* q, size_t n) { return std::memcmp(p, q, n) == 0; };
  if (c.frame != d.frame || !same(&c.time, &d.time, 4) || !same(c.position, d.position, 12) ||
      !same(c.rotation, d.rotation, 16) || !same(&c.fov_deg, &d.fov_deg, 4) ||
      !same(&c.focal_distance, &d.focal_distance, 4) || !same(&c.aperture, &d.aperture, 4))
    return ::testing::AssertionFailure()
           << "camera of frame " << c.frame << " differs from that of frame " << d.frame;
  return ::testing::AssertionSuccess();
}

// The manifest of `out_dir` lists every frame of the job exactly once, and
// each is bit-identical to render_frame() of the job in this process.
inline ::testing::AssertionResult shards_match_render(const fs::path& out_dir,
                                                      const fs::path& spec_path,
                                                      const std::vector<std::string>& sets = {}) {
  std::map<int, FrameBuffers> frames;
  if (auto r = read_manifest_frames(out_dir, frames); !r) return r;
  const JobSpec spec = load_job_spec(spec_path, sets);
  for (int64_t f = spec.frame_start; f <= spec.frame_end; ++f)  // the last may be INT_MAX
    if (!frames.count(int(f)))
      return ::testing::AssertionFailure() << "frame " << f << " is missing";
  if (int(frames.size()) != spec.frame_count())
    return ::testing::AssertionFailure()
           << frames.size() << " frames in the shards, the job has " << spec.frame_count();
  for (const auto& [f, fb] : frames) {
    FrameBuffers expected = render::render_frame(spec, f);
    if (auto r = same_frame(fb, expected); !r) return r << " (frame " << f << ")";
    if (fb.camera.frame != f)
      return ::testing::AssertionFailure()
             << "frame " << f << " carries camera frame " << fb.camera.frame;
  }
  return ::testing::AssertionSuccess();
}

}  // namespace dofarm::farm_testing
