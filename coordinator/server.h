// The coordinator process: a ZeroMQ ROUTER socket in front of the scheduler.
// One receive loop (STYLE.md 4): every incoming frame goes through
// protocol::parse(); a bad one gets an "error" reply and the loop goes on.
// Workers are DEALERs; CLI clients (submit, status, resume, cancel) too.
#pragma once

#include <atomic>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include "common/protocol.h"
#include "coordinator/clock.h"
#include "coordinator/job_store.h"
#include "coordinator/scheduler.h"

namespace zmq {
class context_t;
class socket_t;
}  // namespace zmq

namespace dofarm::coordinator {

struct ServerOptions {
  std::string listen = "tcp://*:5555";
  std::filesystem::path state_dir;  // holds the job store, dofarm.sqlite
  // Z85 CURVE secret key of the coordinator (40 chars on the first line).
  // When set, only clients that know the coordinator's public key connect,
  // and, when the file has more lines, only the client public keys listed
  // there are let in (ZAP).
  std::optional<std::filesystem::path> curve_secret;
  SchedulerOptions scheduler;
  double wait_seconds = 0.5;        // how long an idle worker waits before asking again
  bool shutdown_when_idle = false;  // embedded run: tell workers to exit when nothing runs
};

class Server {
 public:
  Server(ServerOptions options, const Clock& clock);
  ~Server();

  // The bound endpoint with the real port (for tcp://127.0.0.1:*).
  const std::string& endpoint() const { return endpoint_; }
  // Serves until `stop` is set. Never throws for a bad message.
  void run(const std::atomic<bool>& stop);
  // One poll of at most `timeout_ms`, then lease expiry (for tests and run()).
  void poll_once(int timeout_ms);

  Scheduler& scheduler() { return *scheduler_; }
  // True when no batch is running (every batch done, failed or cancelled).
  bool idle();
  // Checks the staged tiles of unpacked shards and requeues missing or
  // corrupt ones (on start and on resume).
  int verify_staged_tiles(const std::string& batch_id);

  // Handles one decoded request; public for tests.
  std::string handle(const protocol::Message& m);

 private:
  std::string handle_submit(const protocol::Message& m);
  std::string handle_failed(const protocol::Message& m);

  ServerOptions options_;
  const Clock& clock_;
  std::unique_ptr<JobStore> store_;
  std::unique_ptr<Scheduler> scheduler_;
  std::unique_ptr<zmq::context_t> context_;
  std::unique_ptr<zmq::socket_t> socket_;
  std::unique_ptr<class ZapHandler> zap_;
  std::string endpoint_;
};

// The status report as JSON (the `status --json` output and the wire form).
protocol::Json status_to_json(const StatusReport& report);

}  // namespace dofarm::coordinator
