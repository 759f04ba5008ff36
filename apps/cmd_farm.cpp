// The farm's subcommands: run (embedded coordinator + local workers),
// coordinator, worker, submit, status, resume, cancel, inspect (keygen: cmd_keys.cpp).
#include <signal.h>
#include <spawn.h>
#include <spdlog/spdlog.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <thread>

#include "apps/commands.h"
#include "common/error.h"
#include "common/inspect.h"
#include "common/jobspec.h"
#include "common/progress.h"
#include "common/transport.h"
#include "coordinator/server.h"
#include "worker/worker.h"

extern char** environ;

namespace dofarm {

namespace fs = std::filesystem;
using protocol::Json;

std::atomic<bool>& stop_requested() {
  static std::atomic<bool> flag{false};
  return flag;
}

namespace {
extern "C" void on_stop_signal(int) { stop_requested().store(true); }
}  // namespace

void install_stop_signals() {
  struct sigaction sa = {};
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

namespace {

// A reply of type "error" becomes an exception: bad input (exit 2) when the
// coordinator says so, a runtime failure otherwise.
protocol::Message checked(protocol::Message m) {
  if (m.type == "error") {
    if (m.body.value("bad_input", false)) throw SpecError(FileLoc{}, "", m.str("message"));
    throw RuntimeError("coordinator: " + m.str("message"));
  }
  return m;
}

// --coordinator, --curve-public and --curve-client, for every command that
// talks to one.
struct CoordinatorArgs {
  std::string endpoint;
  std::string curve_public, curve_client;
  ClientOptions client() const {
    ClientOptions o{endpoint, std::nullopt, 10000};
    if (!curve_public.empty()) o.curve_public = curve_public;
    if (!curve_client.empty()) o.curve_client = curve_client;
    return o;
  }
};

void add_curve_client_option(CLI::App* cmd, std::string& file) {
  cmd->add_option("--curve-client", file,
                  "this client's CURVE key pair (keygen --client NAME: NAME.key), needed where "
                  "the coordinator has an allow-list (--curve-clients)")
      ->type_name("FILE");
}

void add_coordinator_option(CLI::App* cmd, CoordinatorArgs& c) {
  cmd->add_option("--coordinator", c.endpoint, "the coordinator's endpoint")
      ->type_name("tcp://HOST:PORT")
      ->required();
  cmd->add_option("--curve-public", c.curve_public,
                  "the coordinator's CURVE public key file, when it has one")
      ->type_name("FILE");
  add_curve_client_option(cmd, c.curve_client);
}

std::string format_eta(const Json& eta) {
  if (eta.is_null()) return "-";
  int s = int(eta.get<double>());
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%d:%02d:%02d", s / 3600, (s / 60) % 60, s % 60);
  return buf;
}

void print_status_table(const Json& st, std::ostream& out) {
  for (const Json& b : st["batches"]) {
    out << b["batch"].get<std::string>() << "  " << b["state"].get<std::string>() << "  "
        << b["spec_path"].get<std::string>() << "\n";
    char line[256];
    std::snprintf(line, sizeof(line),
                  "  frames %d/%d rendered, %d packed | tasks %d done, %d running, %d pending, "
                  "%d failed | %.1f frames/h | ETA %s\n",
                  b["frames_rendered"].get<int>(), b["frames_total"].get<int>(),
                  b["frames_packed"].get<int>(), b["tasks_done"].get<int>(),
                  b["tasks_leased"].get<int>(), b["tasks_pending"].get<int>(),
                  b["tasks_failed"].get<int>(), b["frames_per_hour"].get<double>(),
                  format_eta(b["eta_seconds"]).c_str());
    out << line;
    for (const Json& f : b["failed"]) {
      out << "  FAILED task " << f["task"] << " (" << f["kind"].get<std::string>() << ", frame "
          << f["frame"] << "): " << f["error"].get<std::string>() << "\n";
      if (!f["reproduce"].get<std::string>().empty())
        out << "    reproduce: " << f["reproduce"].get<std::string>() << "\n";
    }
    if (!b["blocklisted"].empty())
      out << "  blocklisted workers: " << b["blocklisted"].dump() << "\n";
    if (!b.value("reason", std::string()).empty())
      out << "  reason: " << b["reason"].get<std::string>() << "\n";
    if (b.contains("stalled_seconds") && !b["stalled_seconds"].is_null())
      out << "  stalled: no eligible worker for " << int(b["stalled_seconds"].get<double>())
          << " s\n";
  }
  int live = 0;
  for (const Json& w : st["workers"]) live += w["live"].get<bool>();
  out << "workers: " << live << " live\n";
  for (const Json& w : st["workers"])
    if (w["live"].get<bool>())
      out << "  " << w["worker"].get<std::string>() << "  tasks " << w["tasks"].dump() << "\n";
}

// Starts `dofarm worker` as a child process of this executable.
pid_t spawn_worker(const std::string& endpoint, int threads, const std::string& id,
                   const std::string& log_level) {
  std::string exe = fs::read_symlink("/proc/self/exe").string();
  std::vector<std::string> args = {
      exe,    "worker", "--connect", endpoint, "--threads",   std::to_string(threads),
      "--id", id,       "--give-up", "60",     "--log-level", log_level};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid;
  int rc = posix_spawn(&pid, exe.c_str(), nullptr, nullptr, argv.data(), environ);
  if (rc != 0) throw RuntimeError("cannot start a worker: " + std::string(strerror(rc)));
  return pid;
}

Command add_run_impl(CLI::App& app) {
  struct Args {
    std::string job, out;
    int workers = 2, threads = 0;
    double lease = 30;
    std::vector<std::string> sets;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "run", "Render a job on this machine: an embedded coordinator and N local workers");
  cmd->add_option("job", a->job, "job spec")->type_name("JOB.toml")->required();
  cmd->add_option("--out", a->out, "output folder: shards, manifest.json, farm state")
      ->type_name("DIR")
      ->required();
  cmd->add_option("--workers", a->workers, "local worker processes")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  cmd->add_option("--threads", a->threads,
                  "render threads per worker; 0 = cores / workers (at least 1)")
      ->capture_default_str();
  cmd->add_option("--lease", a->lease, "task lease in seconds")->capture_default_str();
  add_set_option(cmd, a->sets);
  return {cmd, [a, &app]() {
            fs::path spec_path = fs::absolute(a->job);
            JobSpec spec = load_job_spec(spec_path, a->sets);  // bad input: exit 2, nothing written
            fs::path out = fs::absolute(a->out);
            fs::create_directories(out);
            install_stop_signals();
            coordinator::SystemClock clock;
            coordinator::ServerOptions so;
            so.listen = "tcp://127.0.0.1:*";
            so.state_dir = out / ".dofarm-state";
            so.shutdown_when_idle = true;
            so.scheduler.lease_seconds = a->lease;
            coordinator::Server server(so, clock);

            // The same job into the same folder resumes the batch that is there.
            std::string batch;
            for (const auto& b : server.scheduler().status().batches)
              if (b.batch.spec_path == spec_path.string() && b.batch.overrides == a->sets)
                batch = b.batch.id;
            if (batch.empty()) {
              batch = server.scheduler().submit(spec_path.string(), a->sets, out.string(), spec);
              spdlog::info("batch {}: {} frames into {}", batch, spec.frame_count(), out.string());
            } else {
              int bad = server.verify_staged_tiles(batch);
              auto r = server.scheduler().resume(batch);
              spdlog::info("batch {}: resuming ({}; {} staged tiles to redo)", batch, r.message,
                           bad);
            }
            int threads = a->threads > 0
                              ? a->threads
                              : std::max(1, int(std::thread::hardware_concurrency()) / a->workers);
            std::vector<pid_t> children;
            std::string level = app.get_option("--log-level")->as<std::string>();
            for (int i = 0; i < a->workers; ++i)
              children.push_back(
                  spawn_worker(server.endpoint(), threads,
                               "local-" + std::to_string(getpid()) + "-" + std::to_string(i),
                               level == "info" ? "warn" : level));
            // Progress counts finished tasks (tiles and packs) against the total.
            // Every local worker blocklisted for the batch means nobody is left
            // to render it: stop rather than wait for a worker that never comes.
            int64_t finished = 0;
            bool stranded = false;
            auto tasks_finished = [&](int* total) {
              auto st = server.scheduler().status(batch);
              if (st.batches.empty()) return int64_t(0);
              const auto& b = st.batches[0];
              *total = b.tasks_total;
              stranded = b.batch.state == coordinator::BatchState::kRunning &&
                         int(b.blocklisted.size()) >= a->workers;
              return int64_t(b.tasks_done + b.tasks_failed);
            };
            int total = 0;
            finished = tasks_finished(&total);
            Progress progress("batch " + batch, total);
            progress.advance(finished);
            auto last = std::chrono::steady_clock::now();
            size_t alive = children.size();
            while (alive > 0) {
              server.poll_once(100);
              for (pid_t& pid : children) {
                if (pid <= 0) continue;
                int status;
                if (waitpid(pid, &status, WNOHANG) == pid) {
                  pid = -1;
                  --alive;
                }
              }
              if (stop_requested() || stranded) {
                for (pid_t pid : children)
                  if (pid > 0) kill(pid, SIGTERM);
              }
              if (std::chrono::steady_clock::now() - last > std::chrono::seconds(1)) {
                last = std::chrono::steady_clock::now();
                int64_t now_finished = tasks_finished(&total);
                progress.advance(now_finished - finished);
                finished = now_finished;
              }
            }
            // Let the last results in before reading the final state.
            for (int i = 0; i < 5; ++i) server.poll_once(10);
            progress.advance(tasks_finished(&total) - finished);
            progress.finish();
            auto st = server.scheduler().status(batch);
            const auto& b = st.batches.at(0);
            if (stranded)
              std::cerr << "every worker (" << a->workers << ") is blocklisted for batch " << batch
                        << " after failing tasks; stopped. Fix the cause and run again to "
                           "resume.\n";
            std::cout << "batch " << batch << ": " << coordinator::to_string(b.batch.state) << ", "
                      << b.frames_packed << "/" << b.frames_total << " frames in shards under "
                      << out.string() << "\n";
            if (b.batch.state == coordinator::BatchState::kDone) return kExitOk;
            for (const auto& f : b.failed)
              std::cerr << "failed task " << f.task_id << ": " << f.error << "\n";
            return kExitRuntime;
          }};
}

}  // namespace

Command add_run(CLI::App& app) { return add_run_impl(app); }

Command add_coordinator(CLI::App& app) {
  struct Args {
    std::string listen = "tcp://*:5555", state, curve, clients;
    double lease = 30;
    double stall_timeout = coordinator::SchedulerOptions{}.stall_timeout;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand("coordinator", "Run the farm's coordinator");
  cmd->add_option("--listen", a->listen, "ZeroMQ endpoint to bind")->capture_default_str();
  cmd->add_option("--state", a->state, "folder of the job store (resumes what is there)")
      ->type_name("DIR")
      ->required();
  cmd->add_option("--curve-secret", a->curve, "CURVE secret key file (see keygen)")
      ->type_name("FILE");
  cmd->add_option("--curve-clients", a->clients,
                  "CURVE allow-list: lines PUBLIC_KEY ROLE [NAME], ROLE worker or operator "
                  "(docs/farm.md); only these keys get in. Needs --curve-secret")
      ->type_name("FILE");
  cmd->add_option("--lease", a->lease, "task lease in seconds")->capture_default_str();
  cmd->add_option("--stall-timeout", a->stall_timeout,
                  "fail a batch that has had no eligible worker (live, not blocklisted) for "
                  "this many seconds; 0 = never")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  return {cmd, [a]() {
            install_stop_signals();
            coordinator::SystemClock clock;
            coordinator::ServerOptions so;
            so.listen = a->listen;
            so.state_dir = a->state;
            so.scheduler.lease_seconds = a->lease;
            so.scheduler.stall_timeout = a->stall_timeout;
            if (!a->curve.empty()) so.curve_secret = a->curve;
            if (!a->clients.empty()) so.curve_clients = a->clients;
            coordinator::Server server(so, clock);
            // Tests and scripts read the bound endpoint from here.
            std::cout << "listening " << server.endpoint() << std::endl;
            server.run(stop_requested());
            spdlog::info("coordinator stopping");
            return kExitOk;
          }};
}

Command add_worker(CLI::App& app) {
  auto o = std::make_shared<worker::WorkerOptions>();
  auto curve = std::make_shared<std::string>();
  auto key_pair = std::make_shared<std::string>();
  CLI::App* cmd = app.add_subcommand("worker", "Run a render worker");
  cmd->add_option("--connect", o->endpoint, "the coordinator's endpoint")
      ->type_name("tcp://HOST:PORT")
      ->required();
  cmd->add_option("--threads", o->threads, "render threads; 0 = all cores")->capture_default_str();
  cmd->add_option("--curve-public", *curve, "the coordinator's CURVE public key file")
      ->type_name("FILE");
  add_curve_client_option(cmd, *key_pair);
  cmd->add_option("--id", o->id, "worker id (default host-pid-random)");
  cmd->add_option("--heartbeat", o->heartbeat_seconds, "seconds between heartbeats")
      ->capture_default_str();
  cmd->add_option("--give-up", o->give_up_seconds,
                  "exit after this many seconds without a coordinator; 0 = never")
      ->capture_default_str();
  return {cmd, [o, curve, key_pair]() {
            if (!curve->empty()) o->curve_public = *curve;
            if (!key_pair->empty()) o->curve_client = *key_pair;
            install_stop_signals();
            return worker::run_worker(*o, stop_requested());
          }};
}

Command add_submit(CLI::App& app) {
  struct Args {
    std::string job, out;
    CoordinatorArgs coordinator;
    std::vector<std::string> sets;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd =
      app.add_subcommand("submit", "Submit a job to a coordinator; prints the batch id");
  cmd->add_option("job", a->job, "job spec")->type_name("JOB.toml")->required();
  add_coordinator_option(cmd, a->coordinator);
  cmd->add_option("--out", a->out, "output folder (on a filesystem every node shares)")
      ->type_name("DIR")
      ->required();
  add_set_option(cmd, a->sets);
  return {cmd, [a]() {
            load_job_spec(a->job, a->sets);  // located errors before anything is sent
            auto r = checked(call_coordinator(
                a->coordinator.client(),
                protocol::encode("submit", {{"spec_path", fs::absolute(a->job).string()},
                                            {"overrides", a->sets},
                                            {"out_dir", fs::absolute(a->out).string()}})));
            std::cout << r.str("batch") << std::endl;
            return kExitOk;
          }};
}

Command add_status(CLI::App& app) {
  struct Args {
    std::string batch;
    CoordinatorArgs coordinator;
    bool json = false;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand("status", "Progress, rate, ETA, failures and workers");
  cmd->add_option("batch", a->batch, "one batch (default: all)");
  add_coordinator_option(cmd, a->coordinator);
  cmd->add_flag("--json", a->json, "print JSON");
  return {cmd, [a]() {
            Json req = Json::object();
            if (!a->batch.empty()) req["batch"] = a->batch;
            auto r =
                checked(call_coordinator(a->coordinator.client(), protocol::encode("status", req)));
            r.body.erase("v");
            r.body.erase("type");
            if (a->json)
              std::cout << r.body.dump(2) << std::endl;
            else
              print_status_table(r.body, std::cout);
            return kExitOk;
          }};
}

namespace {
Command add_batch_op(CLI::App& app, const char* name, const char* help) {
  struct Args {
    std::string batch;
    CoordinatorArgs coordinator;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(name, help);
  cmd->add_option("batch", a->batch, "batch id")->required();
  add_coordinator_option(cmd, a->coordinator);
  std::string type = name;
  return {cmd, [a, type]() {
            auto r = checked(call_coordinator(a->coordinator.client(),
                                              protocol::encode(type, {{"batch", a->batch}})));
            std::cout << r.body.value("message", std::string()) << std::endl;
            return r.body.value("ok", false) ? kExitOk : kExitBadInput;
          }};
}
}  // namespace

Command add_resume(CLI::App& app) {
  return add_batch_op(app, "resume", "Resume a failed or cancelled batch");
}
Command add_cancel(CLI::App& app) { return add_batch_op(app, "cancel", "Cancel a batch"); }

Command add_inspect(CLI::App& app) {
  struct Args {
    std::string shard;
    bool json = false;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd =
      app.add_subcommand("inspect", "Show a shard: schema, frames, channel statistics, NaN count");
  cmd->add_option("shard", a->shard, "shard file")->type_name("SHARD.h5")->required();
  cmd->add_flag("--json", a->json, "print JSON");
  return {cmd, [a]() { return inspect_shard(a->shard, a->json, std::cout); }};
}

}  // namespace dofarm
