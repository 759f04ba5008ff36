// Coordinator throughput: many simulated workers on loopback against a real
// coordinator::Server (ZeroMQ ROUTER + SQLite job store) running on one
// thread. Each simulated worker is a DEALER that asks for work, heartbeats
// its lease a few times and completes the task, as a real worker does, with
// no rendering in between. Prints messages/s handled by the coordinator (wall
// clock, and per CPU-second of the coordinator's own thread, which is what
// one core sustains while the simulated workers share the machine), and the
// latency p50/p99 seen by the workers: of every message, and of the
// requests answered with a task (assignment latency). Never asserts.
//
// Every report carries the lease token of its task, and every `done` names a
// real file of `output_bytes` bytes at the path where the task's output
// belongs (written by the simulated worker), so the coordinator's claim
// checks (lstat, open, fstat, read and checksum) are part of what is timed.
//
//   build-farm/bench/farm_throughput [workers=32] [seconds=5] [heartbeats_per_task=8] [frames=4000]
//                                    [output_bytes=16384]
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "common/checksum.h"
#include "common/jobspec.h"
#include "common/staging.h"
#include "common/transport.h"
#include "coordinator/server.h"

using namespace dofarm;
using Clock = std::chrono::steady_clock;

namespace {

// Ids of this process's ZeroMQ I/O threads ("ZMQbg/IO/N").
std::set<int> zmq_io_threads() {
  std::set<int> out;
  for (const auto& e : std::filesystem::directory_iterator("/proc/self/task")) {
    std::ifstream comm(e.path() / "comm");
    std::string name;
    std::getline(comm, name);
    if (name.rfind("ZMQbg/IO", 0) == 0) out.insert(std::stoi(e.path().filename().string()));
  }
  return out;
}

// CPU seconds (user + system) of one thread of this process, from /proc.
double thread_cpu_seconds(int tid) {
  std::ifstream in("/proc/self/task/" + std::to_string(tid) + "/stat");
  std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::istringstream fields(stat.substr(stat.rfind(')') + 2));  // after "pid (comm) "
  std::string f;
  double ticks = 0;
  for (int i = 3; i <= 15 && fields >> f; ++i)
    if (i == 14 || i == 15) ticks += std::stod(f);  // utime, stime
  return ticks / double(sysconf(_SC_CLK_TCK));
}

}  // namespace

int main(int argc, char** argv) {
  const int workers = argc > 1 ? std::atoi(argv[1]) : 32;
  const double seconds = argc > 2 ? std::atof(argv[2]) : 5.0;
  const int heartbeats = argc > 3 ? std::atoi(argv[3]) : 8;
  const int frames = argc > 4 ? std::atoi(argv[4]) : 4000;
  const size_t output_bytes = argc > 5 ? size_t(std::atoll(argv[5])) : 16384;
  const std::string output(output_bytes, 'o');
  const std::string output_checksum = checksum_to_string(checksum64(output.data(), output.size()));
  namespace fs = std::filesystem;
  fs::path dir = fs::temp_directory_path() / ("dofarm-bench-farm-" + std::to_string(getpid()));
  fs::remove_all(dir);

  coordinator::SystemClock clock;
  coordinator::ServerOptions so;
  so.listen = "tcp://127.0.0.1:*";
  so.state_dir = dir / "state";
  const std::set<int> io_before = zmq_io_threads();
  coordinator::Server server(so, clock);
  // The server's own ZeroMQ I/O thread (the workers' contexts come later):
  // it moves every message in and out, so it counts as coordinator CPU too.
  // (A new thread names itself a moment after it starts.)
  int server_io = -1;
  for (int i = 0; i < 100 && server_io < 0; ++i) {
    for (int tid : zmq_io_threads())
      if (!io_before.count(tid)) server_io = tid;
    if (server_io < 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  if (server_io < 0) std::printf("(the server's ZeroMQ I/O thread was not found)\n");
  // A batch of `frames` frames of 2x2 tiles, 16 frames per shard.
  JobSpec spec = load_job_spec(
      fs::path(DOFARM_SOURCE_DIR) / "jobs/cornell.toml",
      {"image.width=128", "image.height=128", "farm.tile=64",
       "frames.end=" + std::to_string(std::max(16, frames) - 1), "frames.per_shard=16"});
  // A made-up job hash: the simulated workers never load the job.
  server.scheduler().submit(spec.spec_path.string(), {}, (dir / "out").string(), spec,
                            coordinator::JobRef{std::string(32, '0'), ""});

  std::atomic<bool> stop{false};
  // The coordinator's own CPU time: the simulated workers share the machine,
  // so messages per coordinator CPU-second is what one core would sustain.
  double serve_cpu_seconds = 0;
  std::thread serve([&] {
    auto cpu = [] {
      timespec ts;
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
      return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
    };
    double c0 = cpu();
    server.run(stop);
    serve_cpu_seconds = cpu() - c0;
  });

  std::atomic<bool> go{false}, done{false};
  std::vector<std::vector<double>> latencies(workers), assign_latencies(workers);
  std::vector<uint64_t> counts(workers, 0);
  std::vector<std::thread> threads;
  for (int w = 0; w < workers; ++w) {
    threads.emplace_back([&, w] {
      zmq::context_t ctx(1);
      CoordinatorClient client(ctx, {server.endpoint(), std::nullopt, 10000});
      const std::string id = "sim-" + std::to_string(w);
      while (!go) std::this_thread::yield();
      double last = 0;  // latency of the last call
      auto call = [&](const std::string& payload) {
        auto t0 = Clock::now();
        protocol::Message m = client.call(payload);
        last = std::chrono::duration<double>(Clock::now() - t0).count();
        latencies[w].push_back(last);
        ++counts[w];
        return m;
      };
      while (!done) {
        protocol::Message m = call(protocol::encode("request", {{"worker", id}}));
        if (m.type != "task") continue;
        assign_latencies[w].push_back(last);
        protocol::Json base = {{"worker", id},
                               {"task", m.integer("task")},
                               {"attempt", m.integer("attempt")},
                               {"token", m.str("token")}};
        for (int h = 0; h < heartbeats && !done; ++h) call(protocol::encode("heartbeat", base));
        // The output, where the coordinator expects it.
        const protocol::Json& r = m.body.at("rect");
        const fs::path out = m.str("kind") == "pack_shard"
                                 ? fs::path(m.str("out_dir")) / m.str("shard_file")
                                 : staged_tile_path(m.str("out_dir"), m.str("batch"),
                                                    int(m.integer("frame")),
                                                    Rect{r[0].get<int>(), r[1].get<int>(),
                                                         r[2].get<int>(), r[3].get<int>()});
        fs::create_directories(out.parent_path());
        std::ofstream(out, std::ios::binary) << output;
        protocol::Json d = base;
        d["staged_path"] = out.string();
        d["size"] = output.size();
        d["checksum"] = output_checksum;
        d["seconds"] = 0.0;
        call(protocol::encode("done", d));
      }
    });
  }
  const double io_cpu0 = server_io >= 0 ? thread_cpu_seconds(server_io) : 0;
  auto t0 = Clock::now();
  go = true;
  std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
  done = true;
  for (auto& t : threads) t.join();
  double elapsed = std::chrono::duration<double>(Clock::now() - t0).count();
  const double io_cpu_seconds = server_io >= 0 ? thread_cpu_seconds(server_io) - io_cpu0 : 0;
  stop = true;
  serve.join();

  std::vector<double> all, assigns;
  uint64_t total = 0;
  for (int w = 0; w < workers; ++w) {
    total += counts[w];
    all.insert(all.end(), latencies[w].begin(), latencies[w].end());
    assigns.insert(assigns.end(), assign_latencies[w].begin(), assign_latencies[w].end());
  }
  auto pct = [](std::vector<double>& v, double p) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[size_t(p * double(v.size() - 1))] * 1e3;
  };
  auto st = server.scheduler().status();
  std::printf("workers %d, heartbeats/task %d, batch of %d frames, outputs of %zu bytes, %.1f s\n",
              workers, heartbeats, frames, output_bytes, elapsed);
  std::printf("messages handled:          %llu\n", (unsigned long long)total);
  std::printf("wall:                      %.0f messages/s\n", double(total) / elapsed);
  std::printf("coordinator CPU:           loop thread %.2f s, its ZeroMQ I/O thread %.2f s\n",
              serve_cpu_seconds, io_cpu_seconds);
  std::printf("per coordinator CPU-second: %.0f messages (loop thread), %.0f (loop + I/O thread)\n",
              double(total) / std::max(serve_cpu_seconds, 1e-9),
              double(total) / std::max(serve_cpu_seconds + io_cpu_seconds, 1e-9));
  std::printf("tasks completed:           %d\n", st.batches.empty() ? 0 : st.batches[0].tasks_done);
  std::printf("latency ms, all messages:  p50 %.3f  p99 %.3f  max %.3f\n", pct(all, 0.5),
              pct(all, 0.99), pct(all, 1.0));
  std::printf(
      "latency ms, assignments:   p50 %.3f  p99 %.3f  max %.3f  (%zu requests got a task)\n",
      pct(assigns, 0.5), pct(assigns, 0.99), pct(assigns, 1.0), assigns.size());
  fs::remove_all(dir);
  return 0;
}
