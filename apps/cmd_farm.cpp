// The farm's subcommands: run (embedded coordinator + local workers),
// coordinator, worker, submit, status, resume, cancel, inspect (keygen: cmd_keys.cpp).
#include <signal.h>
#include <spawn.h>
#include <spdlog/spdlog.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cctype>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <thread>

#include "apps/commands.h"
#include "common/error.h"
#include "common/inspect.h"
#include "common/job_snapshot.h"
#include "common/jobspec.h"
#include "common/messages.h"
#include "common/progress.h"
#include "common/stop_signals.h"
#include "common/transport.h"
#include "coordinator/server.h"
#include "farm/embedded_run.h"
#include "farm/status_view.h"
#include "worker/job_resolve.h"
#include "worker/worker.h"

extern char** environ;

namespace dofarm {

namespace fs = std::filesystem;
using protocol::Json;

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

// A ZeroMQ endpoint needs its transport: "127.0.0.1:5555" alone would reach
// ZeroMQ and come back as "Invalid argument".
const CLI::Validator kEndpoint(
    [](std::string& s) -> std::string {
      if (s.find("://") != std::string::npos) return "";
      return "expected an endpoint with its transport, e.g. tcp://" + s + " (got " + s + ")";
    },
    "ENDPOINT");

void add_coordinator_option(CLI::App* cmd, CoordinatorArgs& c) {
  cmd->add_option("--coordinator", c.endpoint, "the coordinator's endpoint")
      ->type_name("tcp://HOST:PORT")
      ->check(kEndpoint)
      ->required();
  cmd->add_option("--curve-public", c.curve_public,
                  "the coordinator's CURVE public key file, when it has one")
      ->type_name("FILE");
  add_curve_client_option(cmd, c.curve_client);
}

// --http and --http-token-file of `coordinator` and `run`.
struct HttpArgs {
  std::string address, token_file;
  std::optional<coordinator::HttpOptions> options() const {
    if (address.empty()) return std::nullopt;
    coordinator::HttpOptions o;
    o.address = address;
    if (!token_file.empty()) o.token_file = token_file;
    return o;
  }
};

void add_http_options(CLI::App* cmd, HttpArgs& h) {
  cmd->add_option("--http", h.address,
                  "serve a live web page, /api/status (JSON) and /metrics (Prometheus) on this "
                  "address, e.g. 127.0.0.1:8080 (port 0: any free port); a non-loopback address "
                  "needs --http-token-file")
      ->type_name("HOST:PORT");
  cmd->add_option("--http-token-file", h.token_file,
                  "access token for --http (first line, 16+ characters, file mode 600); requests "
                  "need \"Authorization: Bearer TOKEN\" or ?token=TOKEN")
      ->type_name("FILE");
}

Command add_run_impl(CLI::App& app) {
  auto a = std::make_shared<farm::EmbeddedRunOptions>();
  auto sets = std::make_shared<std::vector<std::string>>();
  auto job = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  auto http = std::make_shared<HttpArgs>();
  CLI::App* cmd = app.add_subcommand(
      "run", "Render a job on this machine: an embedded coordinator and N local workers");
  cmd->add_option("job", *job, "job spec")->type_name("JOB.toml")->required();
  cmd->add_option("--out", *out, "output folder: shards, manifest.json, farm state")
      ->type_name("DIR")
      ->required();
  cmd->add_option("--workers", a->workers, "local worker processes")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  cmd->add_option(
         "--threads", a->threads,
         "render threads per worker; 0 = the CPUs this process may use / workers (at least 1)")
      ->capture_default_str()
      ->check(CLI::Range(0, 4096));
  cmd->add_option("--lease", a->lease_seconds, "task lease in seconds")->capture_default_str();
  cmd->add_option("--stall-timeout", a->stall_timeout,
                  "fail the batch after this many seconds without a live local worker; 0 = never")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  add_set_option(cmd, *sets);
  add_http_options(cmd, *http);
  return {cmd, [a, sets, job, out, http, &app]() {
            a->http = http->options();
            a->spec = *job;
            a->out = *out;
            a->overrides = *sets;
            a->exe = fs::read_symlink("/proc/self/exe");
            std::string level = app.get_option("--log-level")->as<std::string>();
            a->worker_log_level = level == "info" ? "warn" : level;
            install_stop_signals(RepeatedSignal::kAsksAgain);
            farm::EmbeddedRunResult r = farm::run_embedded(*a, stop_requested());
            const auto& b = r.status;
            if (r.stranded)
              std::cerr << "every worker (" << a->workers << ") is blocklisted for batch "
                        << r.batch
                        << " after failing tasks; stopped. Fix the cause and run again to "
                           "resume.\n";
            std::cout << "batch " << r.batch << ": " << coordinator::to_string(b.batch.state)
                      << ", " << b.frames_packed << "/" << b.frames_total
                      << " frames in shards under " << fs::absolute(*out).lexically_normal().string()
                      << " (job " << r.job << ")\n";
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
    HttpArgs http;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand("coordinator", "Run the farm's coordinator");
  cmd->add_option("--listen", a->listen, "ZeroMQ endpoint to bind")
      ->capture_default_str()
      ->check(kEndpoint);
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
  add_http_options(cmd, a->http);
  return {cmd, [a]() {
            install_stop_signals(RepeatedSignal::kAsksAgain);
            coordinator::SystemClock clock;
            coordinator::ServerOptions so;
            so.listen = a->listen;
            so.state_dir = a->state;
            so.scheduler.lease_seconds = a->lease;
            so.scheduler.stall_timeout = a->stall_timeout;
            if (!a->curve.empty()) so.curve_secret = a->curve;
            if (!a->clients.empty()) so.curve_clients = a->clients;
            so.http = a->http.options();
            coordinator::Server server(so, clock);
            // Tests and scripts read the bound endpoint from here (and the
            // web page's address from the next line).
            std::cout << "listening " << server.endpoint() << std::endl;
            if (!server.http_url().empty()) std::cout << "web " << server.http_url() << std::endl;
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
      ->check(kEndpoint)
      ->type_name("tcp://HOST:PORT")
      ->required();
  cmd->add_option("--threads", o->threads, "render threads; 0 = the CPUs this process may use")
      ->capture_default_str()
      ->check(CLI::Range(0, 4096));
  cmd->add_option("--curve-public", *curve, "the coordinator's CURVE public key file")
      ->type_name("FILE");
  add_curve_client_option(cmd, *key_pair);
  cmd->add_option("--id", o->id, "worker id (default host-pid-random)")
      ->check(CLI::Validator(
          [](const std::string& id) -> std::string {
            // The `worker` field's limits (docs/protocol.md): refused here
            // rather than by every message the worker would send.
            if (id.size() > protocol::kMaxIdBytes)
              return "at most " + std::to_string(protocol::kMaxIdBytes) + " bytes";
            for (char c : id)
              if (!std::isalnum(static_cast<unsigned char>(c)) && !std::strchr("._:@+-", c))
                return "only A-Z a-z 0-9 . _ : @ + - allowed";
            return "";
          },
          "ID"));
  cmd->add_option("--heartbeat", o->heartbeat_seconds, "seconds between heartbeats")
      ->capture_default_str();
  cmd->add_option("--give-up", o->give_up_seconds,
                  "exit after this many seconds without a coordinator; 0 = never")
      ->capture_default_str();
  return {cmd, [o, curve, key_pair]() {
            if (!curve->empty()) o->curve_public = *curve;
            if (!key_pair->empty()) o->curve_client = *key_pair;
            install_stop_signals(RepeatedSignal::kAsksAgain);
            return worker::run_worker(*o, stop_requested());
          }};
}

Command add_submit(CLI::App& app) {
  struct Args {
    std::string job, out;
    CoordinatorArgs coordinator;
    std::vector<std::string> sets;
    int priority = coordinator::kDefaultPriority;
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
  cmd->add_option("--priority", a->priority,
                  "the new batch's priority: higher batches' tasks are handed out first, equal "
                  "ones oldest first; change it later with `dofarm priority`")
      ->check(CLI::Range(coordinator::kMinPriority, coordinator::kMaxPriority))
      ->capture_default_str();
  return {cmd, [a]() {
            // The job is resolved and checked here (located errors, exit 2,
            // nothing written), copied into the output folder, and sent as
            // its snapshot: the coordinator never reads the spec's path.
            worker::ResolvedJob job = worker::resolve_job(a->job, a->sets);
            const fs::path out = fs::absolute(a->out).lexically_normal();
            if (std::string why = ownership_conflict(out, job.snapshot); !why.empty())
              throw SpecError(FileLoc{}, "", why);
            fs::create_directories(out);
            worker::materialize_job(job, out);
            protocol::Json fields = {{"snapshot", job.snapshot.to_json(-1)},
                                     {"out_dir", out.string()}};
            // Sent only when asked for: a coordinator older than priorities
            // refuses fields it does not know, and serves the default anyway.
            if (a->priority != coordinator::kDefaultPriority) fields["priority"] = a->priority;
            auto r = checked(call_coordinator(a->coordinator.client(),
                                              protocol::encode("submit", std::move(fields))));
            const std::string batch = r.str("batch");
            write_output_owner(out, {job.snapshot.hash(), batch, job.snapshot.source_spec});
            if (r.body.value("existing", false))
              spdlog::info(
                  "{} already holds batch {} of this job (job {}); it keeps its priority "
                  "(`dofarm priority` changes it)",
                  out.string(), batch, job.snapshot.hash());
            std::cout << batch << std::endl;
            return kExitOk;
          }};
}

Command add_status(CLI::App& app) {
  struct Args {
    std::string batch;
    CoordinatorArgs coordinator;
    bool json = false, tasks = false;
    std::string state;
    int limit = 1000;
    std::string watch;  // seconds; empty with --watch alone
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "status", "Progress, rate, ETA, failures and workers; with --tasks the task table");
  cmd->add_option("batch", a->batch, "one batch (default: all)");
  add_coordinator_option(cmd, a->coordinator);
  cmd->add_flag("--json", a->json, "print JSON (the coordinator's status_reply, docs/protocol.md)");
  cmd->add_flag("--tasks", a->tasks,
                "list the batch's tasks: frame, tile, state, worker, attempts, last error, "
                "reproduce command (needs BATCH)");
  cmd->add_option("--state", a->state, "with --tasks: only tasks in this state")
      ->type_name("pending|running|done|failed")
      ->check(CLI::Validator(
          [](std::string& s) -> std::string {
            return farm::task_state_from_user(s) ? "" : "expected pending, running, done or failed";
          },
          "STATE"));
  cmd->add_option("--limit", a->limit, "with --tasks: at most this many tasks, by id")
      ->check(CLI::Range(1, 10000))
      ->capture_default_str();
  cmd->add_option("--watch", a->watch,
                  "refresh every S seconds (default 2) until Ctrl-C or the batch ends; on a "
                  "terminal it redraws in place. Put BATCH before --watch")
      ->type_name("[S]")
      ->expected(0, 1);
  return {
      cmd, [a, cmd]() {
        const bool watching = cmd->count("--watch") > 0;
        double interval = 2;
        if (watching && !a->watch.empty()) {
          char* end = nullptr;
          interval = std::strtod(a->watch.c_str(), &end);
          if (end == a->watch.c_str() || *end != '\0' || !(interval >= 0.1) || interval > 3600)
            throw SpecError(FileLoc{"--watch " + a->watch}, "",
                            "expected seconds between refreshes, 0.1 to 3600 (put BATCH "
                            "before --watch)");
        }
        if (a->tasks && a->batch.empty())
          throw SpecError(FileLoc{"--tasks"}, "", "--tasks lists one batch: give BATCH");
        if (!a->state.empty() && !a->tasks)
          throw SpecError(FileLoc{"--state " + a->state}, "", "--state needs --tasks");
        Json req = Json::object();
        if (!a->batch.empty()) req["batch"] = a->batch;
        if (a->tasks) {
          req["tasks"] = true;
          req["limit"] = a->limit;
          if (!a->state.empty()) req["state"] = *farm::task_state_from_user(a->state);
        }
        auto fetch = [&]() {
          auto r =
              checked(call_coordinator(a->coordinator.client(), protocol::encode("status", req)));
          r.body.erase("v");
          r.body.erase("type");
          // One batch asked for and none came back: it does not exist.
          if (!a->batch.empty() && r.body.value("batches", Json::array()).empty() &&
              r.body.value("batches_omitted", 0) == 0)
            throw SpecError(FileLoc{}, "batch", "no batch " + a->batch + " on this coordinator");
          return r.body;
        };
        if (!watching) {
          const Json st = fetch();
          std::cout << (a->json ? st.dump(2) + "\n" : farm::format_status(st)) << std::flush;
          return kExitOk;
        }
        install_stop_signals(RepeatedSignal::kAsksAgain);
        farm::WatchOptions wo;
        wo.interval_seconds = interval;
        wo.terminal = isatty(STDOUT_FILENO);
        wo.batch = a->batch;
        wo.json = a->json;
        try {
          farm::watch(fetch, wo, std::cout, stop_requested());
        } catch (const std::exception&) {
          if (!stop_requested()) throw;  // Ctrl-C during a call: a normal end
        }
        return kExitOk;
      }};
}

Command add_events(CLI::App& app) {
  struct Args {
    std::string batch;
    CoordinatorArgs coordinator;
    bool json = false;
    int limit = coordinator::kDefaultEvents;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "events",
      "A batch's events, oldest first: leases, expiries, retries, failures with their "
      "text, blocklisting with its reason");
  cmd->add_option("batch", a->batch, "batch id")->required();
  add_coordinator_option(cmd, a->coordinator);
  cmd->add_flag("--json", a->json, "print JSON (the coordinator's events_reply)");
  cmd->add_option("--limit", a->limit, "the newest N events")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  return {cmd, [a]() {
            auto r = checked(call_coordinator(
                a->coordinator.client(),
                protocol::encode("events", {{"batch", a->batch}, {"limit", a->limit}})));
            r.body.erase("v");
            r.body.erase("type");
            std::cout << (a->json ? r.body.dump(2) + "\n" : farm::format_events(r.body))
                      << std::flush;
            return kExitOk;
          }};
}

namespace {
// An operator command's `ack` {ok, message}: the message on stdout, or a
// refusal (no such batch, nothing to resume) as an error on stderr like
// every other, not a line on stdout.
int print_op_reply(const protocol::Message& r) {
  if (!r.body.value("ok", false))
    throw SpecError(FileLoc{}, "batch", r.body.value("message", std::string("refused")));
  std::cout << r.body.value("message", std::string()) << std::endl;
  return kExitOk;
}

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
            return print_op_reply(checked(call_coordinator(
                a->coordinator.client(), protocol::encode(type, {{"batch", a->batch}}))));
          }};
}
}  // namespace

Command add_resume(CLI::App& app) {
  return add_batch_op(app, "resume", "Resume a failed or cancelled batch");
}
Command add_cancel(CLI::App& app) { return add_batch_op(app, "cancel", "Cancel a batch"); }

Command add_priority(CLI::App& app) {
  struct Args {
    std::string batch;
    int priority = coordinator::kDefaultPriority;
    CoordinatorArgs coordinator;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "priority",
      "Give a batch another priority (0-100, default 50): the runnable tasks of higher "
      "batches are handed out first; leases already held are kept");
  cmd->add_option("batch", a->batch, "batch id")->required();
  cmd->add_option("priority", a->priority, "0 (last) .. 100 (first)")
      ->check(CLI::Range(coordinator::kMinPriority, coordinator::kMaxPriority))
      ->required();
  add_coordinator_option(cmd, a->coordinator);
  return {cmd, [a]() {
            return print_op_reply(checked(call_coordinator(
                a->coordinator.client(),
                protocol::encode("priority", {{"batch", a->batch}, {"priority", a->priority}}))));
          }};
}

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
