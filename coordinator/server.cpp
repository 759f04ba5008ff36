#include "coordinator/server.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <set>
#include <thread>
#include <zmq.hpp>

#include "common/checksum.h"
#include "common/jobspec.h"
#include "common/transport.h"
#include "coordinator/roles.h"
#include "coordinator/verify.h"

namespace dofarm::coordinator {

namespace fs = std::filesystem;
using protocol::Json;

// ZAP (ZeroMQ RFC 27) handler for CURVE: lets in the client public keys of
// the allow-list and names their role as the connection's User-Id, which the
// receive loop checks every message against (coordinator/roles.h). Without
// an allow-list every client that completed the CURVE handshake (i.e. knew
// the coordinator's public key) is let in as an operator.
class ZapHandler {
 public:
  ZapHandler(zmq::context_t& ctx, std::vector<ClientKey> allowed)
      : socket_(ctx, zmq::socket_type::rep), any_key_(allowed.empty()) {
    for (ClientKey& k : allowed) allowed_.emplace(k.public_key, std::move(k));
    socket_.bind("inproc://zeromq.zap.01");
    thread_ = std::thread([this] { loop(); });
  }
  ~ZapHandler() {
    stop_ = true;
    thread_.join();
  }

 private:
  void loop() {
    while (!stop_) {
      zmq::pollitem_t item{socket_.handle(), 0, ZMQ_POLLIN, 0};
      try {
        zmq::poll(&item, 1, std::chrono::milliseconds(100));
      } catch (const zmq::error_t&) {
        continue;  // EINTR; anything else shows again on the next poll
      }
      if (!(item.revents & ZMQ_POLLIN)) continue;
      std::vector<zmq::message_t> parts;
      while (true) {
        zmq::message_t m;
        if (!socket_.recv(m, zmq::recv_flags::none)) break;
        bool more = m.more();
        parts.push_back(std::move(m));
        if (!more) break;
      }
      // version, request id, domain, address, identity, mechanism, credentials...
      std::string request_id = parts.size() > 1 ? parts[1].to_string() : "";
      std::string role;
      if (parts.size() >= 7 && parts[5].to_string() == "CURVE" && parts[6].size() == 32) {
        char z85[41];
        zmq_z85_encode(z85, static_cast<const uint8_t*>(parts[6].data()), 32);
        const std::string address = parts[3].to_string();
        if (any_key_) {
          role = to_string(Role::kOperator);
        } else if (auto it = allowed_.find(z85); it != allowed_.end()) {
          role = to_string(it->second.role);
          spdlog::debug("client {} ({} key {}) from {}", it->second.name, role, z85, address);
        } else {
          spdlog::warn("refused a client with a CURVE key not on the allow-list: {} from {}", z85,
                       address);
        }
      }
      const bool ok = !role.empty();
      socket_.send(zmq::str_buffer("1.0"), zmq::send_flags::sndmore);
      socket_.send(zmq::buffer(request_id), zmq::send_flags::sndmore);
      socket_.send(zmq::buffer(std::string(ok ? "200" : "400")), zmq::send_flags::sndmore);
      socket_.send(zmq::buffer(std::string(ok ? "OK" : "unknown key")), zmq::send_flags::sndmore);
      socket_.send(zmq::buffer(role), zmq::send_flags::sndmore);  // User-Id: the role
      socket_.send(zmq::str_buffer(""), zmq::send_flags::none);
    }
  }
  zmq::socket_t socket_;
  bool any_key_;  // no allow-list: every key, as an operator
  std::map<std::string, ClientKey> allowed_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

namespace {

Json rect_json(Rect r) { return Json::array({r.x, r.y, r.w, r.h}); }

Json assignment_json(const Assignment& a, double lease_seconds) {
  Json j = {{"task", a.task_id},
            {"attempt", a.attempt},
            {"kind", to_string(a.kind)},
            {"batch", a.batch_id},
            {"spec_path", a.spec_path},
            {"overrides", a.overrides},
            {"out_dir", a.out_dir},
            {"frame", a.frame},
            {"rect", rect_json(a.rect)},
            {"shard", a.shard},
            {"shard_file", a.shard_range.file},
            {"frame_start", a.shard_range.frame_start},
            {"frame_end", a.shard_range.frame_end},
            {"lease_seconds", lease_seconds}};
  Json inputs = Json::array();
  for (const StagedTile& t : a.inputs)
    inputs.push_back({{"task", t.task_id},
                      {"frame", t.frame},
                      {"rect", rect_json(t.rect)},
                      {"path", t.staged_path},
                      {"checksum", t.checksum}});
  j["inputs"] = inputs;
  return j;
}

std::vector<std::string> string_list(const Json& j) {
  std::vector<std::string> out;
  for (const Json& v : j) {
    if (!v.is_string()) throw protocol::ProtocolError("\"overrides\" must hold strings");
    out.push_back(v.get<std::string>());
  }
  return out;
}

}  // namespace

Json status_to_json(const StatusReport& r) {
  Json batches = Json::array();
  for (const BatchStatus& b : r.batches) {
    Json failed = Json::array();
    for (const FailedTask& f : b.failed)
      failed.push_back({{"task", f.task_id},
                        {"kind", to_string(f.kind)},
                        {"frame", f.frame},
                        {"rect", rect_json(f.rect)},
                        {"shard", f.shard},
                        {"error", f.error},
                        {"reproduce", f.reproduce}});
    batches.push_back({{"batch", b.batch.id},
                       {"state", to_string(b.batch.state)},
                       {"spec_path", b.batch.spec_path},
                       {"out_dir", b.batch.out_dir},
                       {"created", b.batch.created},
                       {"tasks_total", b.tasks_total},
                       {"tasks_done", b.tasks_done},
                       {"tasks_failed", b.tasks_failed},
                       {"tasks_leased", b.tasks_leased},
                       {"tasks_pending", b.tasks_pending},
                       {"frames_total", b.frames_total},
                       {"frames_rendered", b.frames_rendered},
                       {"frames_packed", b.frames_packed},
                       {"frames_per_hour", b.frames_per_hour},
                       {"eta_seconds", b.eta_seconds ? Json(*b.eta_seconds) : Json(nullptr)},
                       {"failed", failed},
                       {"blocklisted", b.blocklisted},
                       {"reason", b.reason},
                       {"stalled_seconds",
                        b.stalled_seconds ? Json(*b.stalled_seconds) : Json(nullptr)}});
  }
  Json workers = Json::array();
  for (const WorkerStatus& w : r.workers)
    workers.push_back({{"worker", w.worker.id},
                       {"host", w.worker.host},
                       {"threads", w.worker.threads},
                       {"last_seen", w.worker.last_seen},
                       {"live", w.live},
                       {"tasks", w.leased_tasks}});
  return {{"now", r.now}, {"batches", batches}, {"workers", workers}};
}

Server::Server(ServerOptions options, const Clock& clock)
    : options_(std::move(options)), clock_(clock) {
  fs::create_directories(options_.state_dir);
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
  socket_->bind(options_.listen);
  endpoint_ = socket_->get(zmq::sockopt::last_endpoint);
  // A restarted coordinator checks what the workers staged before it died.
  for (const BatchRow& b : store_->batches())
    if (b.state == BatchState::kRunning) verify_staged_tiles(b.id);
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

std::string Server::handle_submit(const protocol::Message& m) {
  std::vector<std::string> overrides = string_list(m.body["overrides"]);
  fs::path spec_path = fs::absolute(m.str("spec_path"));
  JobSpec spec;
  try {
    spec = load_job_spec(spec_path, overrides);
  } catch (const SpecError& e) {
    return protocol::encode("error", {{"message", e.what()}, {"bad_input", true}});
  }
  std::string out_dir = fs::absolute(m.str("out_dir")).string();
  std::string id = scheduler_->submit(spec_path.string(), overrides, out_dir, spec);
  spdlog::info("batch {} submitted: {} frames {}..{} -> {}", id, spec_path.string(),
               spec.frame_start, spec.frame_end, out_dir);
  return protocol::encode("submitted", {{"batch", id}});
}

std::string Server::handle_failed(const protocol::Message& m) {
  const std::string& worker = m.str("worker");
  int64_t task = m.integer("task");
  int attempt = int(m.integer("attempt"));
  // A pack task that found a bad staged tile is not the worker's fault: the
  // tile is rendered again and the pack waits for it.
  if (m.has("bad_tile") && m.body["bad_tile"].is_string()) {
    const std::string bad = m.body["bad_tile"].get<std::string>();
    if (std::optional<int64_t> tile = store_->input_with_staged_path(task, bad)) {
      spdlog::warn("task {}: staged tile {} is bad ({}); rendering it again", task, bad,
                   m.str("error"));
      scheduler_->release(worker, task, attempt);
      scheduler_->invalidate(*tile);
      return protocol::encode("ack", {{"status", "tile_requeued"}});
    }
  }
  FailResult r = scheduler_->fail(worker, task, attempt, m.str("error"));
  spdlog::warn("task {} attempt {} failed on {}: {} ({})", task, attempt, worker, m.str("error"),
               to_string(r.status));
  return protocol::encode("ack", {{"status", to_string(r.status)}});
}

std::optional<std::string> Server::answer_request(const protocol::Message& m) {
  const std::string& worker = m.str("worker");
  scheduler_->worker_seen(worker, m.body.value("host", ""), int(m.body.value("threads", 0)));
  if (auto a = scheduler_->assign(worker))
    return protocol::encode("task", assignment_json(*a, scheduler_->options().lease_seconds));
  if (options_.shutdown_when_idle && idle()) return protocol::encode("shutdown");
  return std::nullopt;
}

std::string Server::handle(const protocol::Message& m) {
  const std::string& t = m.type;
  if (t == "request") {
    if (std::optional<std::string> reply = answer_request(m)) return *reply;
    return protocol::encode("wait", {{"seconds", options_.wait_seconds}});
  }
  if (t == "heartbeat")
    return protocol::encode("ack", {{"ok", scheduler_->heartbeat(m.str("worker"), m.integer("task"),
                                                                 int(m.integer("attempt")))}});
  if (t == "done") {
    CompleteStatus s =
        scheduler_->complete(m.str("worker"), m.integer("task"), int(m.integer("attempt")),
                             m.str("staged_path"), m.str("checksum"));
    return protocol::encode("ack", {{"status", to_string(s)}});
  }
  if (t == "failed") return handle_failed(m);
  if (t == "release")
    return protocol::encode("ack", {{"ok", scheduler_->release(m.str("worker"), m.integer("task"),
                                                               int(m.integer("attempt")))}});
  if (t == "submit") return handle_submit(m);
  if (t == "status") {
    std::string batch = m.has("batch") && m.body["batch"].is_string() ? m.str("batch") : "";
    return protocol::encode("status_reply", status_to_json(scheduler_->status(batch)));
  }
  if (t == "resume") {
    int bad = verify_staged_tiles(m.str("batch"));
    OpResult r = scheduler_->resume(m.str("batch"));
    return protocol::encode("ack", {{"ok", r.ok}, {"message", r.message}, {"tiles_requeued", bad}});
  }
  if (t == "cancel") {
    OpResult r = scheduler_->cancel(m.str("batch"));
    return protocol::encode("ack", {{"ok", r.ok}, {"message", r.message}});
  }
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
               protocol::encode("task", assignment_json(*a, scheduler_->options().lease_seconds)));
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
      } else {
        reply = handle(m);
      }
    } catch (const protocol::ProtocolError& e) {
      reply = protocol::error_reply(e.what());
    } catch (const std::exception& e) {
      spdlog::error("request failed: {}", e.what());
      reply = protocol::error_reply(std::string("coordinator error: ") + e.what());
    }
    send(identity.to_string(), reply);
  }
  try {
    for (int64_t id : scheduler_->expire_leases())
      spdlog::warn("task {}: lease expired, requeued", id);
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
}

void Server::run(const std::atomic<bool>& stop) {
  while (!stop) poll_once(100);
  unpark_all();  // nobody waits for a reply that will not come
  send_outbox();
}

}  // namespace dofarm::coordinator
