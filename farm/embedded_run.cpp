#include "farm/embedded_run.h"

#include <signal.h>
#include <spawn.h>
#include <spdlog/spdlog.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <optional>

#include "common/cpus.h"
#include "common/job_snapshot.h"
#include "common/progress.h"
#include "coordinator/clock.h"
#include "coordinator/server.h"
#include "worker/job_resolve.h"

extern char** environ;

namespace dofarm::farm {

namespace fs = std::filesystem;

namespace {

pid_t spawn_worker(const fs::path& exe, const std::string& endpoint, int threads,
                   const std::string& id, const std::string& log_level) {
  std::vector<std::string> args = {
      exe.string(), "worker", "--connect", endpoint, "--threads",   std::to_string(threads),
      "--id",       id,       "--give-up", "60",     "--log-level", log_level};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid;
  int rc = posix_spawn(&pid, exe.c_str(), nullptr, nullptr, argv.data(), environ);
  if (rc != 0) throw RuntimeError("cannot start a worker: " + std::string(strerror(rc)));
  return pid;
}

// A folder with shards but no ownership record or state was filled by
// something that did not record its job: it is not ours to write into.
std::string foreign_content(const fs::path& out) {
  std::error_code ec;
  if (fs::exists(owner_file(out), ec) || fs::exists(out / ".dofarm-state", ec)) return "";
  if (fs::exists(out / "manifest.json", ec))
    return "output folder " + out.string() +
           " holds a manifest.json but no record of the job that wrote it; nothing was changed; "
           "write this job to another --out folder";
  return "";
}

// How long workers get to leave after their batch ended, and to exit after
// SIGTERM (a worker hands its task back within about 2 s of it: worker.cpp,
// kStopGraceSeconds).
constexpr std::chrono::seconds kLeaveSeconds{5};
constexpr std::chrono::seconds kKillSeconds{10};

}  // namespace

EmbeddedRunResult run_embedded(const EmbeddedRunOptions& o, const std::atomic<bool>& stop) {
  // 1-2: resolve and check; bad input leaves no trace.
  if (o.http) coordinator::check_http_options(*o.http);
  worker::ResolvedJob job = worker::resolve_job(o.spec, o.overrides);
  const fs::path out = fs::absolute(o.out).lexically_normal();
  std::error_code ec;
  if (fs::exists(out, ec) && !fs::is_directory(out, ec))
    throw RunRefused("--out " + out.string() + " exists and is not a folder");
  if (std::string why = foreign_content(out); !why.empty()) throw RunRefused(why);
  if (std::string why = ownership_conflict(out, job.snapshot); !why.empty()) throw RunRefused(why);
  const fs::path state = out / ".dofarm-state";
  if (fs::exists(state / "dofarm.sqlite", ec)) {
    // The embedded store may know batches the ownership record does not (a
    // folder written before records existed).
    coordinator::JobStore store(state / "dofarm.sqlite");
    for (const coordinator::BatchRow& b : store.batches()) {
      if (b.job_hash == job.snapshot.hash()) continue;
      std::optional<JobSnapshot> other;
      std::string error;
      try {
        if (!b.snapshot.empty()) other = JobSnapshot::from_json(b.snapshot, "batch " + b.id);
      } catch (const std::exception& e) {
        error = e.what();
      }
      throw RunRefused(conflict_message(out, b.id, b.job_hash, other ? &*other : nullptr, error,
                                        job.snapshot));
    }
  }

  // 3: the job's folder, the coordinator, the batch.
  fs::create_directories(out);
  worker::materialize_job(job, out);
  coordinator::SystemClock clock;
  coordinator::ServerOptions so;
  so.listen = "tcp://127.0.0.1:*";
  so.state_dir = state;
  so.shutdown_when_idle = true;
  so.http = o.http;
  so.scheduler.lease_seconds = o.lease_seconds;
  so.scheduler.stall_timeout = o.stall_timeout;
  coordinator::Server server(so, clock);
  coordinator::Server::JobSubmission sub = server.submit_job(out, job.snapshot, o.overrides);
  if (!sub.refusal.empty()) throw RunRefused(sub.refusal);
  EmbeddedRunResult result;
  result.batch = sub.batch;
  result.job = job.snapshot.hash();
  result.resumed = sub.existing;
  write_output_owner(out, {result.job, result.batch, job.snapshot.source_spec});
  if (sub.existing) {
    int bad = server.verify_staged_tiles(result.batch);
    auto r = server.scheduler().resume(result.batch);
    spdlog::info("batch {}: resuming ({}; {} staged tiles to redo)", result.batch, r.message, bad);
  } else {
    spdlog::info("batch {}: {} frames of job {} into {}", result.batch, job.spec.frame_count(),
                 result.job, out.string());
  }

  // 4: workers, served until they all exit.
  const int threads = o.threads > 0 ? o.threads : std::max(1, cpus_available() / o.workers);
  std::vector<pid_t> children;
  for (int i = 0; i < o.workers; ++i)
    children.push_back(spawn_worker(o.exe, server.endpoint(), threads,
                                    "local-" + std::to_string(getpid()) + "-" + std::to_string(i),
                                    o.worker_log_level));
  // Progress counts finished tasks (render tiles and shard packs). Every
  // local worker blocklisted means nobody is left to render the batch: stop
  // rather than wait for a worker that never comes.
  bool running = true;  // the batch, as finished() last saw it
  auto finished = [&](int* total) {
    auto st = server.scheduler().status(result.batch);
    if (st.batches.empty()) return int64_t(0);
    const auto& b = st.batches[0];
    *total = b.tasks_total;
    running = b.batch.state == coordinator::BatchState::kRunning;
    result.stranded = running && int(b.blocklisted.size()) >= o.workers;
    return int64_t(b.tasks_done + b.tasks_failed);
  };
  int total = 0;
  int64_t done = finished(&total);
  ProgressOptions po;
  if (!o.progress) po.mode = ProgressOptions::Mode::kOff;
  // It counts tasks (render tiles and shard packs), and says so.
  Progress progress("batch " + result.batch, total, "tasks", po);
  progress.resume_from(done);  // a resumed batch: its rate is this run's
  // Workers leave by themselves: told "shutdown" once the batch has ended,
  // or handing their task back on SIGTERM. One that does neither (stopped by
  // SIGSTOP or a debugger, or hung) must not keep `run` waiting forever: it
  // gets SIGTERM kLeaveSeconds after the batch ended (at once on stop or
  // when stranded), with SIGCONT, without which a stopped process never
  // acts on it, and SIGKILL kKillSeconds later. Its lease, if it held one,
  // expires and the task is rendered again on the next run.
  using Steady = std::chrono::steady_clock;
  auto signal_workers = [&](int sig) {
    for (pid_t pid : children)
      if (pid > 0) kill(pid, sig);
  };
  std::optional<Steady::time_point> ended, terminated;
  bool killed = false;
  auto last = Steady::now();
  size_t alive = children.size();
  while (alive > 0) {
    server.poll_once(100);
    for (pid_t& pid : children) {
      int status;
      if (pid > 0 && waitpid(pid, &status, WNOHANG) == pid) {
        pid = -1;
        --alive;
      }
    }
    if (alive == 0) break;
    const auto now = Steady::now();
    if (now - last > std::chrono::seconds(1)) {
      last = now;
      int64_t now_done = finished(&total);
      progress.advance(now_done - done);
      done = now_done;
      if (!ended && !running) ended = now;
    }
    const bool overstayed = ended && now - *ended > kLeaveSeconds;
    if (!terminated && (stop || result.stranded || overstayed)) {
      if (overstayed)
        spdlog::warn("batch {} ended {} s ago and {} local worker(s) still run; stopping them",
                     result.batch, kLeaveSeconds.count(), alive);
      signal_workers(SIGTERM);
      signal_workers(SIGCONT);
      terminated = now;
    } else if (terminated && !killed && now - *terminated > kKillSeconds) {
      spdlog::warn("{} local worker(s) still run {} s after SIGTERM; killing them", alive,
                   kKillSeconds.count());
      signal_workers(SIGCONT);
      signal_workers(SIGKILL);
      killed = true;
    }
  }
  // Let the last results in before reading the final state.
  for (int i = 0; i < 5; ++i) server.poll_once(10);
  progress.advance(finished(&total) - done);
  result.status = server.scheduler().status(result.batch).batches.at(0);
  // "done" only for a batch that is done; a failed or interrupted one says
  // how it ended (its tasks may all have ended, so the count alone is full).
  const coordinator::BatchStatus& b = result.status;
  if (b.batch.state == coordinator::BatchState::kDone)
    progress.finish();
  else if (result.stranded)
    progress.fail("every worker is blocklisted");
  else if (b.tasks_failed > 0)
    progress.fail(std::to_string(b.tasks_failed) + " of them failed");
  else
    progress.fail(stop ? "stopped" : std::string("batch ") + coordinator::to_string(b.batch.state));
  return result;
}

}  // namespace dofarm::farm
