// The coordinator process: a ZeroMQ ROUTER socket in front of the scheduler.
// One receive loop (STYLE.md 4): every incoming frame goes through
// protocol::parse(); a bad one gets an "error" reply and the loop goes on.
// Workers are DEALERs; CLI clients (submit, status, resume, cancel) too.
//
// Long poll. A worker's `request` that finds nothing runnable is parked: the
// server keeps its ROUTER identity and answers it as soon as a task becomes
// runnable (a `task`), the embedded run has nothing left (`shutdown`), or
// after wait_seconds (`wait` with seconds 0: ask again at once). So an idle
// worker starts the moment work appears instead of sleeping through a poll
// interval, and the tail of a batch loses nothing to polling. wait_seconds
// must stay well below the workers' request timeout (10 s by default) so a
// parked request never times out; a worker that asks again from another
// socket replaces its parked request.
#pragma once

#include <atomic>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "common/protocol.h"
#include "coordinator/claims.h"
#include "coordinator/clock.h"
#include "coordinator/http_status.h"
#include "coordinator/job_store.h"
#include "coordinator/lease_tokens.h"
#include "common/job_snapshot.h"
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
  // When set, only clients that know the coordinator's public key connect.
  // Further lines of the file that hold client public keys (the older form
  // of an allow-list) are read as operator keys of curve_clients.
  std::optional<std::filesystem::path> curve_secret;
  // The client allow-list (coordinator/roles.h, load_client_keys()): only
  // these keys get in, each with its role (worker or operator). Needs
  // curve_secret.
  std::optional<std::filesystem::path> curve_clients;
  SchedulerOptions scheduler;
  double wait_seconds = 0.5;        // longest a request is parked before it gets `wait`
  bool shutdown_when_idle = false;  // embedded run: tell workers to exit when nothing runs
  // The web page, /api/status and /metrics (coordinator/http_status.h); off
  // when empty.
  std::optional<HttpOptions> http;
};

class Server {
 public:
  Server(ServerOptions options, const Clock& clock);
  ~Server();

  // The bound endpoint with the real port (for tcp://127.0.0.1:*).
  const std::string& endpoint() const { return endpoint_; }
  // Serves until `stop` is set. Never throws for a bad message.
  void run(const std::atomic<bool>& stop);
  // One poll of at most `timeout_ms` (less when a parked request or a
  // back-off is due sooner), the replies, lease expiry, the group commit of
  // heartbeats and the parked requests (for tests and run()).
  void poll_once(int timeout_ms);
  // Requests parked now (tests).
  size_t parked() const { return parked_.size(); }

  Scheduler& scheduler() { return *scheduler_; }
  // What the loop counted since it started (the counters of /metrics).
  const ServerCounters& counters() const { return counters_; }
  // The web page's address (http://HOST:PORT/); empty without --http.
  std::string http_url() const { return http_ ? http_->url() : ""; }
  // True when no batch is running (every batch done, failed or cancelled).
  bool idle();
  // The check of a resume (on start for running batches, the `resume`
  // message, `dofarm run` of the same job): staged tiles of unpacked shards
  // and every packed shard, requeuing what is missing or damaged
  // (verify_batch_outputs in coordinator/verify.h). Returns how many tiles
  // and shards are redone. It reads every shard of the batch, on the loop.
  int verify_staged_tiles(const std::string& batch_id);

  // A job into an output folder (the `submit` message and `dofarm run` both
  // come here). The job folder OUT/.dofarm-jobs/HASH must hold exactly
  // `snapshot`. An output folder belongs to one job: when it holds a batch
  // of another job, nothing changes and `refusal` says which batch and which
  // keys differ; when it holds a batch of this same job, that batch is
  // returned (`existing`), otherwise a new one is planned.
  struct JobSubmission {
    std::string batch;
    bool existing = false;
    std::string refusal;  // non-empty: refused, bad input
  };
  JobSubmission submit_job(const std::filesystem::path& out_dir, const JobSnapshot& snapshot,
                           const std::vector<std::string>& overrides,
                           int priority = kDefaultPriority);

  // Handles one decoded request; public for tests. A `request` with nothing
  // to do gets `wait` at once here (only the receive loop parks).
  std::string handle(const protocol::Message& m);

 private:
  struct Parked {
    std::string identity;  // the ROUTER routing id of the asking socket
    std::string worker;
    double deadline = 0;  // clock time of the `wait` answer
  };

  // A task or `shutdown` for a worker's request; nothing when it must wait.
  std::optional<std::string> answer_request(const protocol::Message& m);
  std::string handle_submit(const protocol::Message& m);
  std::string handle_failed(const protocol::Message& m);
  // heartbeat, done, failed, release: the reply when the message's lease
  // token is not the one of the attempt it names (nothing changes then).
  std::optional<std::string> token_refusal(const protocol::Message& m);
  // A `done` claim (coordinator/claims.h). With `identity` (the receive
  // loop) a claim too large for this round's read budget is checksummed in
  // slices over the next rounds and answered then (nothing returned now);
  // without (tests), it is read at once.
  std::optional<std::string> handle_done(const protocol::Message& m, const std::string* identity);
  // Reads the next slice of the pending claims and answers those finished.
  void advance_claims();
  // The `ack` a finished claim gets (completes the task when it holds).
  std::string settle_claim(const std::string& worker, int64_t task, int attempt,
                           const std::string& path, const std::string& checksum,
                           const std::string& refusal);
  void park(std::string identity, const std::string& worker);
  // Answers the parked requests that can be answered now.
  void serve_parked();
  // Answers every parked request with `wait` (the server stops).
  void unpark_all();
  // Queues a reply; send_outbox() sends the queue (after the group commit).
  void send(const std::string& identity, const std::string& reply);
  void send_outbox();

  ServerOptions options_;
  const Clock& clock_;
  std::unique_ptr<class StateLock> lock_;  // released after the store is closed
  std::unique_ptr<JobStore> store_;
  std::unique_ptr<Scheduler> scheduler_;
  std::unique_ptr<zmq::context_t> context_;
  std::unique_ptr<zmq::socket_t> socket_;
  std::unique_ptr<class ZapHandler> zap_;
  std::string endpoint_;
  ServerCounters counters_;
  std::unique_ptr<HttpStatus> http_;  // serves snapshots that poll_once() publishes
  std::vector<Parked> parked_;                               // oldest first
  std::vector<std::pair<std::string, std::string>> outbox_;  // (identity, reply)
  uint64_t parked_generation_ = 0;                           // scheduler generation they last tried
  std::unique_ptr<LeaseTokens> tokens_;
  struct PendingClaim {
    std::vector<std::string> identities;  // who waits for the answer (a retry adds itself)
    std::string worker;
    int64_t task = 0;
    int attempt = 0;
    std::string path, checksum;
    ClaimFile file;
  };
  std::vector<PendingClaim> claims_;
  uint64_t round_claim_bytes_ = 0;  // read for claims in this round of the loop
  // At most this many bytes of claimed files are read per round (about 5 ms
  // of page-cache reads and XXH64), however many or large the claims.
  static constexpr uint64_t kClaimBytesPerRound = 16u << 20;
};

// The JSON bodies of the replies (coordinator/server_replies.cpp).
// The `task` reply of an assignment, with the lease's length and token.
protocol::Json assignment_json(const Assignment& a, double lease_seconds, const std::string& token);
// The status report as JSON (the `status --json` output and the wire form),
// always below the message limit: what does not fit in its budget is counted
// (`batches_omitted`, `workers_omitted`, per batch `failed_omitted` and
// `blocklisted_omitted`), running batches and live workers listed first.
protocol::Json status_to_json(const StatusReport& report);
// What a `status` message asks for (its optional batch, tasks, state, limit).
StatusQuery status_query(const protocol::Message& m);
// The `events_reply` of `batch`: `events` oldest first (Scheduler::events),
// the newest that fit below the message limit (the others counted in
// `events_omitted`); `older`: the store holds older ones than those given.
protocol::Json events_to_json(const std::string& batch, const std::vector<EventRow>& events,
                              bool older);
// Events listed when an `events` message names no limit.
inline constexpr int kDefaultEvents = 100;

}  // namespace dofarm::coordinator
