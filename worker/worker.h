// The worker process: asks the coordinator for work over a DEALER socket,
// runs render_tile and pack_shard tasks, heartbeats from its own thread while
// it works, and reconnects with back-off when the coordinator goes away.
//
// SIGTERM/SIGINT (Slurm's preemption and scancel): the worker stops the
// render at the next block, hands the task back ("release") and exits 0.
#pragma once

#include <atomic>
#include <filesystem>
#include <optional>
#include <string>

namespace dofarm::worker {

struct WorkerOptions {
  std::string endpoint;                               // tcp://HOST:PORT
  std::optional<std::filesystem::path> curve_public;  // coordinator public key file
  std::optional<std::filesystem::path> curve_client;  // this worker's key pair (NAME.key)
  int threads = 0;                                    // render threads; 0 = all cores
  std::string id;                                     // empty: host-pid-random
  double heartbeat_seconds = 5;
  int request_timeout_ms = 10000;
  double max_backoff_seconds = 30;  // reconnect back-off cap
  // Exit after this long without reaching the coordinator (0 = never).
  double give_up_seconds = 0;
};

// Runs until the coordinator says "shutdown", `stop` is set, or
// give_up_seconds pass without a coordinator. Returns the exit status.
int run_worker(const WorkerOptions& options, std::atomic<bool>& stop);

}  // namespace dofarm::worker
