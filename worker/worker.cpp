#include "worker/worker.h"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <optional>
#include <random>
#include <thread>

#include "common/checksum.h"
#include "common/cpus.h"
#include "common/jobspec.h"
#include "common/messages.h"
#include "common/transport.h"
#include "worker/render/render_job.h"
#include "worker/render/scene.h"
#include "worker/tasks.h"

namespace dofarm::worker {

namespace fs = std::filesystem;
using protocol::Json;

namespace {

// The host name as the `host` and `worker` fields allow it (docs/protocol.md):
// other characters become '_', and it is cut to `max` bytes.
std::string host_name(size_t max) {
  char host[256] = "host";
  gethostname(host, sizeof(host) - 1);
  std::string out(host, std::min(std::strlen(host), max));
  for (char& c : out)
    if (!std::isalnum(static_cast<unsigned char>(c)) && !std::strchr("._:@+-", c)) c = '_';
  return out;
}

std::string default_id() {
  std::random_device rd;
  char buf[320];
  std::snprintf(buf, sizeof(buf), "%s-%d-%04x", host_name(100).c_str(), int(getpid()),
                unsigned(rd() & 0xffff));
  return buf;
}

Rect rect_of(const Json& j) {
  return Rect{j.at(0).get<int>(), j.at(1).get<int>(), j.at(2).get<int>(), j.at(3).get<int>()};
}

// Sleeps up to `seconds`, waking early when `stop` is set.
void nap(double seconds, const std::atomic<bool>& stop) {
  auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (!stop && std::chrono::steady_clock::now() < end)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
}

// Heartbeats for one task from its own thread and socket (a ZeroMQ socket
// belongs to one thread). Tells the task when the lease is lost.
class Heartbeat {
 public:
  Heartbeat(zmq::context_t& ctx, const WorkerOptions& o, const std::string& worker, int64_t task,
            int attempt, const std::string& token)
      : thread_([&ctx, o, worker, task, attempt, token, this] {
          ClientOptions co{o.endpoint, o.curve_public, o.request_timeout_ms, o.curve_client};
          CoordinatorClient client(ctx, co);
          std::unique_lock<std::mutex> lock(mutex_);
          while (!done_) {
            cv_.wait_for(lock, std::chrono::duration<double>(o.heartbeat_seconds));
            if (done_) break;
            lock.unlock();
            try {
              // Gives up when the task ends, so a coordinator that does not
              // answer never holds up the worker's exit.
              protocol::Message r = client.call(
                  protocol::encode("heartbeat",
                                   {{"worker", worker},
                                    {"task", task},
                                    {"attempt", attempt},
                                    {"token", token}}),
                  [this] { return done_.load(); });
              if (r.type == "ack" && r.body.value("ok", true) == false) lost_ = true;
            } catch (const std::exception& e) {
              spdlog::warn("heartbeat for task {}: {}", task, e.what());
            }
            lock.lock();
          }
        }) {}
  ~Heartbeat() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      done_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  bool lost() const { return lost_; }
  // Set when the coordinator says the lease is no longer this worker's
  // (expired and given to another, or its batch cancelled).
  const std::atomic<bool>& lost_flag() const { return lost_; }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::atomic<bool> done_{false};  // written under mutex_, read by the call's give_up
  std::atomic<bool> lost_{false};
  std::thread thread_;
};

class Worker {
 public:
  Worker(const WorkerOptions& o, std::atomic<bool>& stop)
      : options_(o), stop_(stop), id_(o.id.empty() ? default_id() : o.id), ctx_(1) {
    // Resolved once, so the coordinator's status shows the count it renders with.
    if (options_.threads <= 0) options_.threads = cpus_available();
  }

  int run() {
    ClientOptions co{options_.endpoint, options_.curve_public, options_.request_timeout_ms,
                     options_.curve_client};
    CoordinatorClient client(ctx_, co);
    spdlog::info("worker {} connecting to {} ({} render threads)", id_, options_.endpoint,
                 options_.threads);
    double backoff = 0.5;
    auto last_contact = std::chrono::steady_clock::now();
    const std::string host = host_name(protocol::kMaxHostBytes);
    while (!stop_) {
      protocol::Message reply;
      try {
        reply = client.call(
            protocol::encode("request", {{"worker", id_},
                                         {"host", host},
                                         {"threads", std::clamp(options_.threads, 0, 4096)}}),
            [this] { return stop_.load(); });  // nothing to hand back yet: stop at once
      } catch (const std::exception& e) {
        double since =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - last_contact).count();
        if (options_.give_up_seconds > 0 && since > options_.give_up_seconds) {
          spdlog::error("no coordinator for {:.0f} s, giving up: {}", since, e.what());
          return 1;
        }
        spdlog::warn("{}; retrying in {:.1f} s", e.what(), backoff);
        nap(backoff, stop_);
        backoff = std::min(backoff * 2, options_.max_backoff_seconds);
        continue;
      }
      last_contact = std::chrono::steady_clock::now();
      backoff = 0.5;
      if (reply.type == "task") {
        execute(client, reply);
      } else if (reply.type == "wait") {
        nap(reply.number("seconds"), stop_);
      } else if (reply.type == "shutdown") {
        spdlog::info("worker {}: the coordinator has no more work; exiting", id_);
        return 0;
      } else if (reply.type == "error") {
        spdlog::error("coordinator: {}", reply.str("message"));
        nap(1.0, stop_);
      }
    }
    spdlog::info("worker {} stopping", id_);
    return 0;
  }

 private:
  // After SIGTERM the coordinator gets this long, all calls together, to take
  // the worker's last result or release; then the worker exits regardless
  // (Slurm's grace is 30 s; docs/farm.md "Failure policy").
  static constexpr double kStopGraceSeconds = 2;

  // True once stop was requested more than kStopGraceSeconds ago.
  bool past_stop_grace() {
    if (!stop_) return false;
    const auto now = std::chrono::steady_clock::now();
    if (!stop_seen_) stop_seen_ = now;
    return std::chrono::duration<double>(now - *stop_seen_).count() > kStopGraceSeconds;
  }

  void send_result(CoordinatorClient& client, const std::string& payload) {
    // A result is worth retrying: losing it costs a whole task. Once stopping,
    // the attempts share kStopGraceSeconds: an unanswered release only means
    // the lease expires and the task is requeued then.
    for (int i = 0; i < 5 && !past_stop_grace(); ++i) {
      try {
        client.call(payload, [this] { return past_stop_grace(); });
        return;
      } catch (const std::exception& e) {
        spdlog::warn("reporting a result: {}", e.what());
        nap(1.0 * (i + 1), stop_);
      }
    }
  }

  void execute(CoordinatorClient& client, const protocol::Message& m) {
    const int64_t task = m.integer("task");
    const int attempt = int(m.integer("attempt"));
    const std::string kind = m.str("kind");
    // The lease token goes with every report about this lease.
    const std::string token = m.str("token");
    const Json base = {{"worker", id_}, {"task", task}, {"attempt", attempt}, {"token", token}};
    Heartbeat heartbeat(ctx_, options_, id_, task, attempt, token);
    try {
      // The job is a value: read from its content-addressed folder and every
      // file checked against its hash, once per job (JobCache).
      const fs::path out_dir = m.body.at("out_dir").get<std::string>();
      const std::string batch = m.body.at("batch").get<std::string>();
      std::shared_ptr<const LoadedJob> job = jobs_.get(out_dir, m.body.at("job").get<std::string>());
      const JobSpec& spec = job->spec;
      if (kind == "render_tile") {
        auto scene = scenes_.get(spec, job->snapshot.hash());
        const int frame = m.body.at("frame").get<int>();
        const Rect rect = rect_of(m.body.at("rect"));
        spdlog::info("task {}: frame {} tile {},{} {}x{}", task, frame, rect.x, rect.y, rect.w,
                     rect.h);
        render::RenderOptions opt;
        opt.threads = options_.threads;
        opt.cancel = &stop_;
        // A tile whose lease was taken away is someone else's now, or
        // nobody's: rendering on would only be refused (it could be minutes).
        opt.cancel_also = &heartbeat.lost_flag();
        StagedTile t = render_tile(spec, *scene, batch, out_dir, frame, rect, opt);
        Json done = base;
        done["staged_path"] = t.path.string();
        done["checksum"] = checksum_to_string(t.checksum);
        done["size"] = fs::file_size(t.path);
        done["seconds"] = t.seconds;
        send_result(client, protocol::encode("done", done));
      } else if (kind == "pack_shard") {
        ShardJob shard_job;
        shard_job.batch = batch;
        shard_job.shard_index = m.body.at("shard").get<int>();
        shard_job.frame_start = m.body.at("frame_start").get<int>();
        shard_job.frame_end = m.body.at("frame_end").get<int>();
        shard_job.file = m.body.at("shard_file").get<std::string>();
        for (const Json& in : m.body.at("inputs")) {
          StagedTile t;
          t.frame = in.at("frame").get<int>();
          t.rect = rect_of(in.at("rect"));
          t.path = in.at("path").get<std::string>();
          t.checksum = parse_checksum(in.at("checksum").get<std::string>()).value_or(0);
          shard_job.tiles.push_back(t);
        }
        spdlog::info("task {}: packing {} (frames {}..{})", task, shard_job.file, shard_job.frame_start,
                     shard_job.frame_end);
        shard_job.job_hash = job->snapshot.hash();
        shard_job.scene_hash = scene_hash(job->snapshot);
        ManifestEntry e = pack_shard(spec, out_dir, shard_job);
        Json done = base;
        done["staged_path"] = (out_dir / e.file).string();
        done["checksum"] = checksum_to_string(e.checksum);
        done["size"] = e.size;
        done["seconds"] = 0.0;
        send_result(client, protocol::encode("done", done));
      } else {
        throw RuntimeError("unknown task kind \"" + kind + "\"");
      }
    } catch (const render::Cancelled&) {
      if (heartbeat.lost() && !stop_) {
        spdlog::warn("task {}: the lease was taken away; abandoning the task", task);
        return;
      }
      spdlog::info("task {}: stopping; handing the task back", task);
      send_result(client, protocol::encode("release", base));
    } catch (const StagedTileError& e) {
      Json failed = base;
      failed["error"] = protocol::clip_text(e.what());
      failed["bad_tile"] = e.path().string();
      send_result(client, protocol::encode("failed", failed));
    } catch (const std::exception& e) {
      spdlog::error("task {} failed: {}", task, e.what());
      Json failed = base;
      failed["error"] = protocol::clip_text(e.what());
      send_result(client, protocol::encode("failed", failed));
    }
    if (heartbeat.lost()) spdlog::warn("task {}: the lease was taken away meanwhile", task);
  }

  WorkerOptions options_;
  std::atomic<bool>& stop_;
  std::optional<std::chrono::steady_clock::time_point> stop_seen_;  // see past_stop_grace()
  std::string id_;
  zmq::context_t ctx_;
  JobCache jobs_;
  SceneCache scenes_;
};

}  // namespace

int run_worker(const WorkerOptions& options, std::atomic<bool>& stop) {
  Worker w(options, stop);
  return w.run();
}

}  // namespace dofarm::worker
