// `dofarm run`: the embedded farm. A coordinator in this process (state in
// OUT/.dofarm-state, a loopback port the OS picks) and N local worker
// processes render one job into one output folder.
//
// In order, and nothing is written before the first two hold:
//  1. the job is resolved (worker/job_resolve.h): spec read, scene and
//     environment map loaded and hashed; bad input is a SpecError;
//  2. the folder must be free or hold this same job (OUT/.dofarm-owner.json,
//     the embedded store): another job's folder is refused (RunRefused)
//     naming the batch and the keys that differ, and nothing is touched;
//  3. the job is copied into OUT/.dofarm-jobs/HASH, the coordinator starts,
//     and the batch of this job resumes (its staged tiles and shards checked)
//     or a new one is planned;
//  4. workers are started and served until they exit: when the batch ends,
//     on stop, or when every worker is blocklisted (stranded). A worker that
//     does not leave (stopped, hung) gets SIGTERM 5 s after the batch ended,
//     SIGKILL 10 s after that, so `run` always returns.
#pragma once

#include <atomic>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "common/error.h"
#include "coordinator/http_status.h"
#include "coordinator/scheduler.h"

namespace dofarm::farm {

struct EmbeddedRunOptions {
  std::filesystem::path spec;
  std::vector<std::string> overrides;
  std::filesystem::path out;
  int workers = 2;
  int threads = 0;  // per worker; 0 = cores / workers, at least 1
  double lease_seconds = 30;
  // Fail the batch after this long without an eligible worker (0 = never);
  // the coordinator's --stall-timeout.
  double stall_timeout = coordinator::SchedulerOptions{}.stall_timeout;
  std::filesystem::path exe;         // the dofarm executable the workers run
  std::string worker_log_level = "warn";
  bool progress = true;              // draw a progress bar on stderr
  std::optional<coordinator::HttpOptions> http;  // the coordinator's web page (--http)
};

// The folder belongs to another job (bad input: exit 2, nothing changed).
class RunRefused : public SpecError {
 public:
  explicit RunRefused(const std::string& why) : SpecError(FileLoc{}, "", why) {}
};

struct EmbeddedRunResult {
  std::string batch;
  std::string job;       // job hash
  bool resumed = false;  // the folder held this job's batch already
  coordinator::BatchStatus status;  // at the end
  bool stranded = false;            // every worker was blocklisted
};

// Runs the job (see above); `stop` ends it early (workers hand their tasks
// back; running again resumes).
EmbeddedRunResult run_embedded(const EmbeddedRunOptions& options, const std::atomic<bool>& stop);

}  // namespace dofarm::farm
