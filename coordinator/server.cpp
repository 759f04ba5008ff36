#include "coordinator/server.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <zmq.hpp>

#include "common/checksum.h"
#include "common/jobspec.h"
#include "common/messages.h"
#include "common/transport.h"
#include "coordinator/roles.h"
#include "coordinator/state_lock.h"
#include "coordinator/verify.h"
#include "coordinator/zap_handler.h"

namespace dofarm::coordinator {

namespace fs = std::filesystem;

Server::Server(ServerOptions options, const Clock& clock)
    : options_(std::move(options)), clock_(clock) {
  if (options_.http) http_ = std::make_unique<HttpStatus>(*options_.http);
  fs::create_directories(options_.state_dir);
  // Before anything of the state is read or written: one coordinator per folder.
  lock_ = std::make_unique<StateLock>(options_.state_dir);
  tokens_ = std::make_unique<LeaseTokens>(options_.state_dir);
  store_ = std::make_unique<JobStore>(options_.state_dir / "dofarm.sqlite");
  scheduler_ = std::make_unique<Scheduler>(*store_, clock_, options_.scheduler);
  context_ = std::make_unique<zmq::context_t>(1);
  socket_ = std::make_unique<zmq::socket_t>(*context_, zmq::socket_type::router);
  socket_->set(zmq::sockopt::linger, 0);
  socket_->set(zmq::sockopt::maxmsgsize, int64_t(protocol::kMaxMessageBytes));
  socket_->set(zmq::sockopt::sndtimeo, 1000);
  // A restarted worker comes back with a fresh identity; an old identity that
  // reconnects takes over its route.
  socket_->set(zmq::sockopt::router_handover, 1);
  if (options_.curve_clients && !options_.curve_secret)
    throw SpecError(FileLoc{options_.curve_clients->string()}, "curve-clients",
                    "an allow-list needs CURVE: give --curve-secret too");
  if (options_.curve_secret) {
    const std::string secret = read_curve_secret_key(*options_.curve_secret, "curve-secret");
    std::vector<ClientKey> allowed;
    if (options_.curve_clients) allowed = load_client_keys(*options_.curve_clients);
    // Older key files list client public keys after the secret: operators.
    std::ifstream in(*options_.curve_secret);
    std::string line;
    std::getline(in, line);
    for (int n = 2; std::getline(in, line); ++n) {
      const std::string key = line.substr(0, 40);
      if (!is_z85_key(key)) continue;
      if (std::none_of(allowed.begin(), allowed.end(),
                       [&](const ClientKey& k) { return k.public_key == key; }))
        allowed.push_back({key, Role::kOperator, "line " + std::to_string(n), n});
    }
    if (allowed.empty())
      spdlog::warn("CURVE without a client allow-list (--curve-clients): every client that knows "
                   "the coordinator's public key may submit and cancel");
    zap_ = std::make_unique<ZapHandler>(*context_, std::move(allowed));
    socket_->set(zmq::sockopt::curve_server, 1);
    socket_->set(zmq::sockopt::curve_secretkey, secret);
    socket_->set(zmq::sockopt::zap_domain, "dofarm");
  }
  try {
    socket_->bind(options_.listen);
  } catch (const zmq::error_t& e) {
    // ZeroMQ says only "Address already in use": name the endpoint.
    throw RuntimeError("cannot listen on " + options_.listen + ": " + e.what() +
                       (e.num() == EADDRINUSE ? " (another coordinator, or another program, "
                                                "listens there; choose another --listen port)"
                                              : ""));
  }
  endpoint_ = socket_->get(zmq::sockopt::last_endpoint);
  // A restarted coordinator checks what the workers staged before it died.
  for (const std::string& b : scheduler_->running_batch_ids()) verify_staged_tiles(b);
  spdlog::info("coordinator listening on {} (state {})", endpoint_, options_.state_dir.string());
}

Server::~Server() = default;

bool Server::idle() { return scheduler_->running_batches() == 0; }

int Server::verify_staged_tiles(const std::string& batch_id) {
  const ResumeCheck r = verify_batch_outputs(*scheduler_, batch_id);
  if (r.total() > 0 || r.manifest_rebuilt)
    spdlog::warn("batch {}: {} staged tiles and {} shards to redo{}", batch_id, r.tiles_requeued,
                 r.shards_redone, r.manifest_rebuilt ? "; manifest.json rebuilt" : "");
  return r.total();
}

Server::JobSubmission Server::submit_job(const fs::path& out_dir_in, const JobSnapshot& snapshot,
                                         const std::vector<std::string>& overrides, int priority) {
  JobSubmission r;
  const fs::path out_dir = out_dir_in.lexically_normal();
  if (!out_dir.is_absolute()) {
    r.refusal = "the output folder must be an absolute path, got \"" + out_dir.string() + "\"";
    return r;
  }
  const std::string hash = snapshot.hash();
  JobSpec spec;
  try {
    // The folder must hold this very job (read bounded, regular file only),
    // and the spec must parse with its paths inside the job folder.
    read_job_snapshot(out_dir, hash);
    spec = parse_job_spec(snapshot.spec_toml, job_dir(out_dir, hash) / "job.toml");
  } catch (const std::exception& e) {
    r.refusal = "job " + hash + " in " + out_dir.string() + ": " + e.what();
    return r;
  }
  for (const BatchRow& b : scheduler_->batches_in(out_dir.string())) {
    if (b.job_hash == hash) {
      r.batch = b.id;
      r.existing = true;
      return r;
    }
    try {
      std::optional<JobSnapshot> other;
      if (!b.snapshot.empty()) other = JobSnapshot::from_json(b.snapshot, "batch " + b.id);
      r.refusal = conflict_message(out_dir, b.id, b.job_hash, other ? &*other : nullptr, "", snapshot);
    } catch (const std::exception& e) {
      r.refusal = conflict_message(out_dir, b.id, b.job_hash, nullptr, e.what(), snapshot);
    }
    return r;
  }
  try {
    r.refusal = ownership_conflict(out_dir, snapshot);
  } catch (const std::exception& e) {
    r.refusal = e.what();
  }
  if (!r.refusal.empty()) return r;
  r.batch = scheduler_->submit(snapshot.source_spec, overrides, out_dir.string(), spec,
                               JobRef{hash, snapshot.to_json()}, std::nullopt, priority);
  spdlog::info("batch {} submitted: job {} from {}, frames {}..{} -> {}, priority {}", r.batch,
               hash, snapshot.source_spec, spec.frame_start, spec.frame_end, out_dir.string(),
               priority);
  return r;
}

std::string Server::handle_submit(const protocol::Message& m) {
  auto refuse = [](std::string why) {
    // One line on the wire (messages carry no control characters).
    for (size_t p; (p = why.find("\n  ")) != std::string::npos;) why.replace(p, 3, "; ");
    std::replace(why.begin(), why.end(), '\n', ' ');
    return protocol::encode("error", {{"message", why}, {"bad_input", true}});
  };
  JobSnapshot snapshot;
  try {
    snapshot = JobSnapshot::from_json(m.str("snapshot"), "in the submit message");
  } catch (const RuntimeError& e) {
    return refuse(e.what());
  }
  const int priority = m.has("priority") ? int(m.integer("priority")) : kDefaultPriority;
  JobSubmission s = submit_job(m.str("out_dir"), snapshot, snapshot.source_overrides, priority);
  if (!s.refusal.empty()) return refuse(s.refusal);
  return protocol::encode("submitted",
                          {{"batch", s.batch}, {"job", snapshot.hash()}, {"existing", s.existing}});
}

std::string Server::handle_failed(const protocol::Message& m) {
  const std::string& worker = m.str("worker");
  int64_t task = m.integer("task");
  int attempt = int(m.integer("attempt"));
  // A pack task that found a bad staged tile is not the worker's fault: the
  // tile is rendered again and the pack waits for it.
  if (m.has("bad_tile") && m.body["bad_tile"].is_string()) {
    const std::string bad = m.body["bad_tile"].get<std::string>();
    if (std::optional<int64_t> tile = scheduler_->input_with_staged_path(task, bad)) {
      spdlog::warn("task {}: staged tile {} is bad ({}); rendering it again", task, bad,
                   m.str("error"));
      scheduler_->release(worker, task, attempt);
      scheduler_->invalidate(*tile);
      return protocol::encode("ack", {{"status", "tile_requeued"}});
    }
  }
  FailResult r = scheduler_->fail(worker, task, attempt, m.str("error"));
  if (r.status == FailStatus::kRetry || r.status == FailStatus::kFailedForGood)
    ++counters_.task_failures;
  counters_.blocklistings += r.worker_blocklisted;
  spdlog::warn("task {} attempt {} failed on {}: {} ({})", task, attempt, worker, m.str("error"),
               to_string(r.status));
  return protocol::encode("ack", {{"status", to_string(r.status)}});
}

std::optional<std::string> Server::answer_request(const protocol::Message& m) {
  const std::string& worker = m.str("worker");
  scheduler_->worker_seen(worker, m.body.value("host", ""), int(m.body.value("threads", 0)));
  if (auto a = scheduler_->assign(worker))
    return protocol::encode("task", assignment_json(*a, scheduler_->options().lease_seconds,
                                                    tokens_->token(a->task_id, a->attempt, worker)));
  if (options_.shutdown_when_idle && idle()) return protocol::encode("shutdown");
  return std::nullopt;
}

std::optional<std::string> Server::token_refusal(const protocol::Message& m) {
  const std::string& t = m.type;
  if (t != "heartbeat" && t != "done" && t != "failed" && t != "release") return std::nullopt;
  if (tokens_->valid(m.integer("task"), int(m.integer("attempt")), m.str("worker"),
                     m.str("token")))
    return std::nullopt;
  // Nothing changes: not the lease, not the worker's record, not its failures.
  spdlog::warn("{} for task {} attempt {} in the name of {} with a wrong lease token: ignored", t,
               m.integer("task"), m.integer("attempt"), m.str("worker"));
  const std::string why = "wrong lease token for task " + std::to_string(m.integer("task")) +
                          " attempt " + std::to_string(m.integer("attempt"));
  if (t == "heartbeat" || t == "release")
    return protocol::encode("ack", {{"ok", false}, {"message", why}});
  return protocol::encode("ack", {{"status", "refused"}, {"message", why}});
}

std::optional<std::string> Server::handle_done(const protocol::Message& m,
                                               const std::string* identity) {
  const std::string& worker = m.str("worker");
  const int64_t task = m.integer("task");
  const int attempt = int(m.integer("attempt"));
  const std::string& path = m.str("staged_path");
  const std::string& checksum = m.str("checksum");
  // A retry of a claim still being read waits for the same answer.
  for (PendingClaim& c : claims_) {
    if (c.task == task && c.attempt == attempt && c.worker == worker && c.path == path &&
        c.checksum == checksum) {
      if (!identity) return protocol::encode("ack", {{"status", "verifying"}});
      c.identities.push_back(*identity);
      return std::nullopt;
    }
  }
  const std::optional<ExpectedOutput> expected = scheduler_->expected_output(worker, task, attempt);
  // Not this worker's lease (any more): complete() says stale, duplicate or
  // unknown, and changes nothing; the file is not looked at.
  if (!expected) return settle_claim(worker, task, attempt, path, checksum, "");
  ClaimFile file;
  if (std::string why = file.open(*expected, path, uint64_t(m.integer("size"))); !why.empty())
    return settle_claim(worker, task, attempt, path, checksum, why);
  // Small files (every staged tile of a sane tiling) are read now, within
  // the round's budget; the rest in slices over the next rounds.
  if (!identity || round_claim_bytes_ + file.remaining() <= kClaimBytesPerRound) {
    round_claim_bytes_ += file.advance(file.remaining());
    return settle_claim(worker, task, attempt, path, checksum, file.verdict(checksum));
  }
  claims_.push_back({{*identity}, worker, task, attempt, path, checksum, std::move(file)});
  return std::nullopt;
}

std::string Server::settle_claim(const std::string& worker, int64_t task, int attempt,
                                 const std::string& path, const std::string& checksum,
                                 const std::string& refusal) {
  if (!refusal.empty()) {
    // The lease stays as it is: the holder may still send a true claim, and
    // otherwise it expires and the task is rendered again (not a failure).
    spdlog::warn("task {} attempt {}: refused the done claim of {}: {}", task, attempt, worker,
                 refusal);
    return protocol::encode("ack",
                            {{"status", "refused"}, {"message", protocol::clip_text(refusal)}});
  }
  CompleteStatus s = scheduler_->complete(worker, task, attempt, path, checksum);
  return protocol::encode("ack", {{"status", to_string(s)}});
}

void Server::advance_claims() {
  if (claims_.empty()) return;
  for (PendingClaim& c : claims_) {
    if (round_claim_bytes_ >= kClaimBytesPerRound) break;
    round_claim_bytes_ += c.file.advance(kClaimBytesPerRound - round_claim_bytes_);
  }
  std::erase_if(claims_, [&](PendingClaim& c) {
    if (!c.file.finished()) {
      // Reading a large shard must not cost its worker the lease.
      scheduler_->heartbeat(c.worker, c.task, c.attempt);
      return false;
    }
    std::string reply;
    try {
      reply = settle_claim(c.worker, c.task, c.attempt, c.path, c.checksum,
                           c.file.verdict(c.checksum));
    } catch (const std::exception& e) {
      reply = protocol::error_reply(std::string("coordinator error: ") + e.what());
    }
    for (const std::string& id : c.identities) send(id, reply);
    return true;
  });
}

std::string Server::handle(const protocol::Message& m) {
  const std::string& t = m.type;
  if (t == "request") {
    if (std::optional<std::string> reply = answer_request(m)) return *reply;
    return protocol::encode("wait", {{"seconds", options_.wait_seconds}});
  }
  if (std::optional<std::string> refused = token_refusal(m)) return *refused;
  if (t == "heartbeat")
    return protocol::encode("ack", {{"ok", scheduler_->heartbeat(m.str("worker"), m.integer("task"),
                                                                 int(m.integer("attempt")))}});
  if (t == "done") return *handle_done(m, nullptr);
  if (t == "failed") return handle_failed(m);
  if (t == "release")
    return protocol::encode("ack", {{"ok", scheduler_->release(m.str("worker"), m.integer("task"),
                                                               int(m.integer("attempt")))}});
  if (t == "submit") return handle_submit(m);
  if (t == "status")
    return protocol::encode("status_reply", status_to_json(scheduler_->status(status_query(m))));
  if (t == "events") {
    if (!scheduler_->has_batch(m.str("batch")))
      return protocol::encode("error",
                              {{"message", "no batch " + m.str("batch") + " on this coordinator"},
                               {"bad_input", true}});
    const int limit = m.has("limit") ? int(m.integer("limit")) : kDefaultEvents;
    // Asked for one more than listed: the reply says whether older ones exist.
    std::vector<EventRow> events = scheduler_->events(m.str("batch"), limit + 1);
    const bool older = int(events.size()) > limit;
    if (older) events.erase(events.begin());
    return protocol::encode("events_reply", events_to_json(m.str("batch"), events, older));
  }
  if (t == "resume") {
    int bad = verify_staged_tiles(m.str("batch"));
    OpResult r = scheduler_->resume(m.str("batch"));
    return protocol::encode("ack", {{"ok", r.ok}, {"message", r.message}, {"tiles_requeued", bad}});
  }
  auto op_ack = [](const OpResult& r) {
    return protocol::encode("ack", {{"ok", r.ok}, {"message", r.message}});
  };
  if (t == "cancel") return op_ack(scheduler_->cancel(m.str("batch")));
  if (t == "priority")
    return op_ack(scheduler_->set_priority(m.str("batch"), int(m.integer("priority"))));
  return protocol::error_reply("the coordinator does not take \"" + t + "\" messages");
}

void Server::send(const std::string& identity, const std::string& reply) {
  outbox_.emplace_back(identity, reply);
}

void Server::send_outbox() {
  for (const auto& [identity, reply] : outbox_) {
    try {
      socket_->send(zmq::buffer(identity), zmq::send_flags::sndmore);
      socket_->send(zmq::buffer(reply), zmq::send_flags::dontwait);
    } catch (const zmq::error_t& e) {
      spdlog::warn("could not reply: {}", e.what());
    }
  }
  outbox_.clear();
}

void Server::park(std::string identity, const std::string& worker) {
  // A worker asks from one socket at a time: an older parked request of the
  // same worker came from a socket it gave up on.
  std::erase_if(parked_, [&](const Parked& p) { return p.worker == worker; });
  parked_.push_back({std::move(identity), worker, clock_.now() + options_.wait_seconds});
}

void Server::serve_parked() {
  if (parked_.empty()) return;
  if (options_.shutdown_when_idle && idle()) {
    for (const Parked& p : parked_) send(p.identity, protocol::encode("shutdown"));
    parked_.clear();
    return;
  }
  const double now = clock_.now();
  // Only when something may have become runnable: a task joined the queue,
  // or a back-off ended.
  if (scheduler_->generation() != parked_generation_ || now >= scheduler_->next_due()) {
    std::erase_if(parked_, [&](const Parked& p) {
      try {
        if (std::optional<Assignment> a = scheduler_->assign(p.worker)) {
          send(p.identity,
               protocol::encode("task", assignment_json(*a, scheduler_->options().lease_seconds,
                                                        tokens_->token(a->task_id, a->attempt,
                                                                       p.worker))));
          return true;
        }
      } catch (const std::exception& e) {
        spdlog::error("assigning to parked {} failed: {}", p.worker, e.what());
        send(p.identity, protocol::error_reply(std::string("coordinator error: ") + e.what()));
        return true;
      }
      return false;
    });
    parked_generation_ = scheduler_->generation();
  }
  std::erase_if(parked_, [&](const Parked& p) {
    if (p.deadline > now) return false;
    send(p.identity, protocol::encode("wait", {{"seconds", 0.0}}));  // ask again at once
    return true;
  });
}

void Server::unpark_all() {
  for (const Parked& p : parked_)
    send(p.identity, protocol::encode("wait", {{"seconds", options_.wait_seconds}}));
  parked_.clear();
}

void Server::poll_once(int timeout_ms) {
  if (!claims_.empty()) timeout_ms = 0;  // a claim is being read: go on with it
  if (!parked_.empty()) {
    // Wake for the first parked deadline or the end of a back-off.
    double wake = scheduler_->next_due();
    for (const Parked& p : parked_) wake = std::min(wake, p.deadline);
    const double ms = std::ceil((wake - clock_.now()) * 1000.0);
    timeout_ms = int(std::clamp(ms, 0.0, double(timeout_ms)));
  }
  zmq::pollitem_t item{socket_->handle(), 0, ZMQ_POLLIN, 0};
  try {
    zmq::poll(&item, 1, std::chrono::milliseconds(timeout_ms));
  } catch (const zmq::error_t& e) {
    if (e.num() != EINTR) throw;
    return;  // a signal (SIGTERM to stop): the caller checks its stop flag
  }
  // Group commit: everything below is one store transaction, committed
  // before any reply leaves (JobStore "Group commit").
  store_->begin_group();
  // Drain what is there: identity frame, then one payload frame.
  for (int n = 0; n < 1000 && (item.revents & ZMQ_POLLIN); ++n) {
    zmq::message_t identity;
    try {
      if (!socket_->recv(identity, zmq::recv_flags::dontwait)) break;
    } catch (const zmq::error_t& e) {
      if (e.num() != EINTR) throw;
      break;
    }
    std::vector<zmq::message_t> payload;
    bool more = identity.more();
    while (more) {
      zmq::message_t part;
      if (!socket_->recv(part, zmq::recv_flags::none)) break;
      more = part.more();
      payload.push_back(std::move(part));
    }
    std::string reply;
    try {
      if (payload.size() != 1)
        throw protocol::ProtocolError("expected one payload frame, got " +
                                      std::to_string(payload.size()));
      const protocol::Message m = protocol::parse(payload[0].data(), payload[0].size());
      ++counters_.messages[m.type];
      // Roles under CURVE (coordinator/roles.h): the ZAP User-Id is the role.
      if (auto refused = refusal_for(zmq_msg_gets(payload[0].handle(), "User-Id"), m.type))
        throw protocol::ProtocolError(*refused);
      if (m.type == "request") {
        std::optional<std::string> answer = answer_request(m);
        if (!answer) {
          park(identity.to_string(), m.str("worker"));
          continue;
        }
        reply = std::move(*answer);
      } else if (m.type == "done") {
        if (std::optional<std::string> refused = token_refusal(m)) {
          reply = std::move(*refused);
        } else {
          const std::string id = identity.to_string();
          std::optional<std::string> answer = handle_done(m, &id);
          if (!answer) continue;  // answered when its file is read (advance_claims)
          reply = std::move(*answer);
        }
      } else {
        reply = handle(m);
      }
    } catch (const protocol::ProtocolError& e) {
      ++counters_.messages_refused;
      reply = protocol::error_reply(e.what());
    } catch (const std::exception& e) {
      spdlog::error("request failed: {}", e.what());
      reply = protocol::error_reply(std::string("coordinator error: ") + e.what());
    }
    send(identity.to_string(), reply);
  }
  try {
    advance_claims();
  } catch (const std::exception& e) {
    spdlog::error("checking done claims failed: {}", e.what());
  }
  round_claim_bytes_ = 0;
  try {
    for (int64_t id : scheduler_->expire_leases()) {
      spdlog::warn("task {}: lease expired, requeued", id);
      ++counters_.lease_expiries;
    }
    for (const std::string& b : scheduler_->fail_stalled_batches())
      spdlog::error("batch {} failed: no eligible worker for its stall timeout", b);
    scheduler_->flush_if_due();
  } catch (const std::exception& e) {
    spdlog::error("lease expiry or heartbeat flush failed: {}", e.what());
  }
  serve_parked();
  try {
    store_->commit_group();
  } catch (const std::exception& e) {
    // Nothing of this round reached the store: no reply may say it did.
    spdlog::error("job store commit failed: {}", e.what());
    try {
      scheduler_->rebuild();
    } catch (const std::exception& r) {
      spdlog::error("reloading the job store failed: {}", r.what());
    }
    for (auto& [identity, reply] : outbox_)
      reply = protocol::error_reply(std::string("coordinator error: ") + e.what());
  }
  send_outbox();
  if (http_) http_->tick(*scheduler_, counters_);  // after the replies: never delays one
}

void Server::run(const std::atomic<bool>& stop) {
  while (!stop) poll_once(100);
  unpark_all();  // nobody waits for a reply that will not come
  send_outbox();
}

}  // namespace dofarm::coordinator
