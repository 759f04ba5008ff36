// The coordinator checks every claim (issue 10, defects 5 and 6): lease
// tokens, `done` only for the file where the task's output belongs (a regular
// file of the reported size and checksum), bounded status replies, and a
// seeded protocol fuzzer against a live coordinator with a batch running.
// Real processes on loopback: `dofarm coordinator`, `dofarm worker`, the
// CLI, and raw clients speaking the wire protocol.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <random>
#include <regex>
#include <zmq.hpp>

#include "common/messages.h"
#include "common/staging.h"
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

// Two 16x16 frames of one tile each, a shard per frame: 4 tasks, fast.
TinyJob tiny_job() {
  TinyJob j;
  j.width = 16;
  j.height = 16;
  j.tile = 16;
  j.frame_start = 0;
  j.frame_end = 1;
  j.per_shard = 1;
  return j;
}

std::string submit(const TempDir& tmp, const std::string& endpoint, const fs::path& job,
                   const fs::path& out) {
  CliResult r = run_cli(tmp.path(), "submit-" + out.filename().string(),
                        {"submit", job.string(), "--coordinator", endpoint, "--out", out.string()});
  EXPECT_EQ(r.status, 0) << r.out << r.err;
  std::string batch = r.out.substr(0, r.out.find('\n'));
  EXPECT_TRUE(std::regex_match(batch, std::regex("b-[0-9a-f]{8}"))) << r.out << r.err;
  return batch;
}

// A client that speaks the protocol by hand (no rendering), with replies
// parsed by the same decoder as everyone's.
class RawClient {
 public:
  explicit RawClient(const std::string& endpoint, int timeout_ms = 10000)
      : client_(ctx_, {endpoint, std::nullopt, timeout_ms}) {}
  protocol::Message call(const std::string& type, Json fields) {
    return client_.call(protocol::encode(type, std::move(fields)));
  }
  // Bytes that need not be a valid message (they are not encoded).
  protocol::Message call_raw(const std::string& payload) { return client_.call(payload); }
  // The next task for `worker`, or nothing within `seconds`.
  std::optional<protocol::Message> next_task(const std::string& worker, double seconds = 10) {
    const auto t0 = Clock::now();
    while (seconds_since(t0) < seconds) {
      protocol::Message m = call("request", {{"worker", worker}});
      if (m.type == "task") return m;
    }
    return std::nullopt;
  }

 private:
  zmq::context_t ctx_{1};
  CoordinatorClient client_;
};

Json report(const protocol::Message& task, const std::string& worker) {
  return {{"worker", worker},
          {"task", task.integer("task")},
          {"attempt", task.integer("attempt")},
          {"token", task.str("token")}};
}

fs::path expected_path(const protocol::Message& t) {
  if (t.str("kind") == "pack_shard") return fs::path(t.str("out_dir")) / t.str("shard_file");
  const Json& r = t.body.at("rect");
  return staged_tile_path(t.str("out_dir"), t.str("batch"), int(t.integer("frame")),
                          Rect{r[0].get<int>(), r[1].get<int>(), r[2].get<int>(), r[3].get<int>()});
}

TEST(FarmClaims, MadeUpDoneClaimsNeverFinishABatch) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", tiny_job());
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 2);
  const std::string ep = coord.endpoint();
  const std::string batch = submit(tmp, ep, job, tmp / "out");

  // A liar holds real leases (with their tokens) and answers each `done`
  // without rendering: a made-up path, then the right path with no file.
  RawClient liar(ep);
  int claims = 0;
  const auto t0 = Clock::now();
  while (seconds_since(t0) < 3) {
    std::optional<protocol::Message> t = liar.next_task("liar", 1);
    if (!t) continue;
    for (const fs::path& path : {tmp / "out" / "made-up.exr", expected_path(*t)}) {
      Json d = report(*t, "liar");
      d["staged_path"] = path.string();
      d["size"] = 1234;
      d["checksum"] = "xxh64:0123456789abcdef";
      d["seconds"] = 0.1;
      protocol::Message r = liar.call("done", d);
      EXPECT_EQ(r.body.value("status", ""), "refused") << r.body.dump();
      ++claims;
    }
  }
  ASSERT_GE(claims, 2);
  Json b = batch_of(farm_status(ep, batch), batch);
  EXPECT_EQ(b.at("state"), "running") << b.dump();
  EXPECT_EQ(b.at("tasks_done"), 0) << b.dump();

  // A real worker then renders everything, bit-identical.
  Child w = start_worker(tmp.path(), ep, "w1");
  ASSERT_TRUE(poll_until("the batch done", [&] { return batch_state(ep, batch) == "done"; }));
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

TEST(FarmClaims, FailedInARealWorkersNameWithoutItsTokenBlocklistsNobody) {
  TempDir tmp;
  TinyJob j = tiny_job();
  j.reference_spp = 256;  // tasks long enough to be aimed at
  const fs::path job = write_job(tmp.path(), "job.toml", j);
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 10);
  const std::string ep = coord.endpoint();
  const std::string batch = submit(tmp, ep, job, tmp / "out");
  Child w = start_worker(tmp.path(), ep, "real");

  // Every task the real worker holds gets `failed` in its name, for every
  // attempt it might be at, with a made-up token: enough to blocklist it
  // three times over if they counted.
  RawClient liar(ep);
  int sent = 0;
  const auto t0 = Clock::now();
  while (batch_state(ep, batch) == "running" && seconds_since(t0) < kDeadlineSeconds) {
    for (int64_t task : leases_of(farm_status(ep, batch), "real")) {
      for (int attempt = 1; attempt <= 3; ++attempt) {
        protocol::Message r = liar.call("failed", {{"worker", "real"},
                                                   {"task", task},
                                                   {"attempt", attempt},
                                                   {"token", std::string(32, '0')},
                                                   {"error", "made up"}});
        EXPECT_EQ(r.body.value("status", ""), "refused") << r.body.dump();
        ++sent;
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_GT(sent, 0);
  Json b = batch_of(farm_status(ep, batch), batch);
  EXPECT_EQ(b.at("state"), "done") << b.dump();
  EXPECT_TRUE(b.at("blocklisted").empty()) << b.dump();
  EXPECT_EQ(b.at("tasks_failed"), 0) << b.dump();
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

TEST(FarmClaims, DoneNamingDevZeroAFifoOrASymlinkIsRefusedAtOnceAlsoAfterARestart) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", tiny_job());
  auto coord = std::make_unique<CoordinatorProcess>(tmp.path(), "coordinator", tmp / "state", 30);
  std::string ep = coord->endpoint();
  const std::string batch = submit(tmp, ep, job, tmp / "out");

  RawClient liar(ep, 3000);
  std::optional<protocol::Message> t = liar.next_task("liar");
  ASSERT_TRUE(t);
  const fs::path where = expected_path(*t);
  fs::create_directories(where.parent_path());
  auto claim = [&](const fs::path& path) {
    Json d = report(*t, "liar");
    d["staged_path"] = path.string();
    d["size"] = 4096;
    d["checksum"] = "xxh64:0123456789abcdef";
    d["seconds"] = 0.1;
    const auto c0 = Clock::now();
    protocol::Message r = liar.call("done", d);
    EXPECT_LT(seconds_since(c0), 1.0) << path;
    return r.body.value("status", "") + ": " + r.body.value("message", "");
  };
  // /dev/zero itself, and at the very path the tile belongs: a FIFO (no
  // writer: opening it would block), then a symlink to /dev/zero.
  EXPECT_EQ(claim("/dev/zero").rfind("refused: staged_path \"/dev/zero\" is not where", 0), 0u);
  ASSERT_EQ(::mkfifo(where.c_str(), 0600), 0);
  EXPECT_NE(claim(where).find("is a FIFO"), std::string::npos);
  fs::remove(where);
  fs::create_symlink("/dev/zero", where);
  EXPECT_NE(claim(where).find("is a symbolic link"), std::string::npos);
  fs::remove(where);
  EXPECT_EQ(batch_of(farm_status(ep, batch), batch).at("tasks_done"), 0);

  // Restarted (kill -9): it comes up, answers, and the liar's lease token
  // still works for its heartbeat (the key is in STATE/lease.key) while a
  // made-up one does not.
  coord->child().kill9();
  coord = std::make_unique<CoordinatorProcess>(tmp.path(), "coordinator2", tmp / "state", 30);
  ep = coord->endpoint();
  RawClient again(ep, 3000);
  EXPECT_EQ(again.call("heartbeat", report(*t, "liar")).body.value("ok", false), true);
  Json forged = report(*t, "liar");
  forged["token"] = std::string(32, 'f');
  EXPECT_EQ(again.call("heartbeat", forged).body.value("ok", true), false);
  struct stat st {};
  ASSERT_EQ(::lstat((tmp / "state" / "lease.key").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  // Give the lease back so a real worker finishes the batch now.
  EXPECT_EQ(again.call("release", report(*t, "liar")).body.value("ok", false), true);
  Child w = start_worker(tmp.path(), ep, "w1");
  ASSERT_TRUE(poll_until("the batch done", [&] { return batch_state(ep, batch) == "done"; }));
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

// `dofarm status` (the real CLI) answers after workers whose ids total over
// 1 MiB registered through real `request` messages, and after a restart.
TEST(FarmClaims, StatusAnswersAfterWorkerIdsTotallingOverOneMebibyte) {
  TempDir tmp;
  auto coord = std::make_unique<CoordinatorProcess>(tmp.path(), "coordinator", tmp / "state", 30);
  std::string ep = coord->endpoint();
  {
    // Pipelined on 10 DEALERs of 900 requests each (below ZeroMQ's default
    // high-water mark of 1000, past which a ROUTER drops replies): every
    // request is parked, then answered `wait`.
    zmq::context_t ctx(1);
    std::vector<zmq::socket_t> sockets;
    size_t total = 0;
    int n = 0;
    for (int k = 0; k < 10; ++k) {
      zmq::socket_t& s = sockets.emplace_back(ctx, zmq::socket_type::dealer);
      s.set(zmq::sockopt::linger, 0);
      s.set(zmq::sockopt::rcvtimeo, 30000);
      s.connect(ep);
      for (int i = 0; i < 900; ++i, ++n) {
        std::string id = std::to_string(n);  // (not "w" + ...: GCC 12's -Wrestrict false positive)
        id.insert(0, 1, 'w');
        id += '-';
        id += std::string(protocol::kMaxIdBytes - id.size(), 'x');
        total += id.size();
        const std::string m = protocol::encode("request", {{"worker", id}, {"host", "h"}});
        s.send(zmq::buffer(m), zmq::send_flags::none);
      }
    }
    ASSERT_GT(total, size_t(1) << 20);
    for (zmq::socket_t& s : sockets) {
      for (int i = 0; i < 900; ++i) {
        zmq::message_t reply;
        ASSERT_TRUE(s.recv(reply)) << "reply " << i;
      }
    }
  }
  auto check = [&](const std::string& name) {
    CliResult r = run_cli(tmp.path(), name, {"status", "--coordinator", ep}, 20);
    EXPECT_EQ(r.status, 0) << r.out << r.err;
    CliResult j =
        run_cli(tmp.path(), name + "-json", {"status", "--coordinator", ep, "--json"}, 20);
    ASSERT_EQ(j.status, 0) << j.err;
    Json st = Json::parse(j.out);
    EXPECT_GT(st.at("workers_omitted").get<int64_t>(), 0);
    // Remembered at most max_workers (4096): the oldest were forgotten.
    EXPECT_LE(st.at("workers").size() + st.at("workers_omitted").get<size_t>(), 4096u);
    EXPECT_GT(st.at("workers").size(), 0u);
    EXPECT_LT(j.out.size(), protocol::kMaxMessageBytes);
  };
  check("status");
  coord->child().kill9();
  coord = std::make_unique<CoordinatorProcess>(tmp.path(), "coordinator2", tmp / "state", 30);
  ep = coord->endpoint();
  check("status-after-restart");
}

// --- The fuzzer ---------------------------------------------------------------

// Random values for a field of a definition: mostly valid, sometimes wrong in
// one of the ways a parser must survive.
class Fuzzer {
 public:
  Fuzzer(uint32_t seed, std::vector<fs::path> paths, std::vector<std::string> workers)
      : rng_(seed), paths_(std::move(paths)), workers_(std::move(workers)) {}

  std::string message() {
    const auto& defs = protocol::message_defs();
    // Mostly the worker's reports, which reach the claim checks.
    static const char* kReports[] = {"done", "failed", "heartbeat", "release", "status"};
    const std::string type = pick(4) ? defs[rng_() % defs.size()].type : kReports[rng_() % 5];
    type_ = type;
    Json j = Json::object();
    if (const protocol::MessageDef* d = protocol::find_message(type))
      for (const protocol::Field& f : d->fields)
        if (f.required || pick(2)) j[f.name] = value(f, 0);
    switch (rng_() % 12) {
      case 0:
        j["surprise"] = 1;  // unknown field
        break;
      case 1:
        if (!j.empty()) j.erase(j.begin());  // missing field
        break;
      case 2:
        if (!j.empty()) j.begin().value() = std::string(200000, 'z');  // huge string
        break;
      default:
        break;
    }
    j["v"] = pick(30) ? 2 : 1;
    j["type"] = type;
    if (pick(40)) return std::string(rng_() % 64, char(rng_()));
    return j.dump(-1, ' ', false, Json::error_handler_t::replace);
  }

 private:
  bool pick(int one_in) { return rng_() % uint32_t(one_in) == 0; }

  Json value(const protocol::Field& f, int depth) {
    using protocol::FieldType;
    if (pick(25)) return Json::array({1, "x"});  // wrong type
    // Requests come in the fuzzer's own names (one in the real worker's
    // would take over its parked request: slower, not wronger); reports in
    // any name.
    if (f.name == "worker")
      return type_ == "request" ? "fuzz-" + std::to_string(rng_() % 2)
                                : workers_[rng_() % workers_.size()];
    if (f.name == "task") return int64_t(rng_() % 8) + 1;
    if (f.name == "attempt") return int64_t(rng_() % 3) + 1;
    if (f.name == "staged_path" || f.name == "bad_tile" || f.name == "path")
      return paths_[rng_() % paths_.size()].string();
    if (f.name == "batch" && pick(2)) return "b-" + std::to_string(rng_() % 100000000);
    switch (f.type) {
      case FieldType::kString: {
        std::string s(pick(10) ? f.max_len + 1 : rng_() % (std::min<size_t>(f.max_len, 40) + 1),
                      'a');
        if (f.charset == protocol::Charset::kChecksum) s = "xxh64:" + std::string(16, 'a');
        if (f.charset == protocol::Charset::kHex32) s = std::string(32, "0a"[rng_() % 2]);
        return s;
      }
      case FieldType::kInt:
        return pick(8) ? int64_t(-5) : int64_t(rng_() % 100);
      case FieldType::kNumber:
      case FieldType::kNullableNumber:
        return pick(8) ? -1.0 : double(rng_() % 1000) / 10;
      case FieldType::kBool:
        return pick(2);
      case FieldType::kArray: {
        Json a = Json::array();
        // One past the limit only at the top: nested, the limits multiply
        // (a status_reply's 100001 batches of 10001 tasks each filled 24 GB).
        const size_t n = depth == 0 && pick(20) ? f.max_len + 1 : rng_() % 4;
        for (size_t i = 0; i < n && depth < 3; ++i) a.push_back(value(f.children.at(0), depth + 1));
        return a;
      }
      case FieldType::kObject: {
        Json o = Json::object();
        for (const protocol::Field& c : f.children) o[c.name] = value(c, depth + 1);
        return o;
      }
    }
    return nullptr;
  }

  std::mt19937 rng_;
  std::string type_;
  std::vector<fs::path> paths_;
  std::vector<std::string> workers_;
};

TEST(FarmClaims, FuzzedMessagesDuringABatchLeaveItRespondingAndBitIdentical) {
  TempDir tmp;
  TinyJob j = tiny_job();
  j.frame_end = 3;
  const fs::path job = write_job(tmp.path(), "job.toml", j);
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 3);
  const std::string ep = coord.endpoint();
  const std::string batch = submit(tmp, ep, job, tmp / "out");

  // Paths a liar might name: devices, a FIFO, a symlink out of the folder,
  // the staging folder itself, a shard that is not there.
  fs::create_directories(tmp / "traps");
  ASSERT_EQ(::mkfifo((tmp / "traps" / "fifo").c_str(), 0600), 0);
  fs::create_symlink("/etc/passwd", tmp / "traps" / "link");
  const std::vector<fs::path> paths = {"/dev/zero",
                                       "/dev/urandom",
                                       tmp / "traps" / "fifo",
                                       tmp / "traps" / "link",
                                       tmp / "out" / ".staging" / batch,
                                       tmp / "out" / "shard-00000.h5",
                                       staged_tile_path(tmp / "out", batch, 0, Rect{0, 0, 16, 16}),
                                       "relative/path.exr"};
  Child w = start_worker(tmp.path(), ep, "w1");

  Fuzzer fuzz(20261130, paths, {"w1", "fuzz-0", "fuzz-1"});
  RawClient client(ep, 5000);
  int errors = 0, answered = 0, oversize = 0;
  const int n = 1000;
  const auto t0 = Clock::now();
  for (int i = 0; i < n; ++i) {
    const std::string m = fuzz.message();
    // Over the frame limit ZeroMQ drops the frame and the connection
    // (FarmProtocol covers that): nothing to wait for.
    if (m.size() > protocol::kMaxMessageBytes) {
      ++oversize;
      continue;
    }
    protocol::Message r;
    try {
      r = client.call_raw(m);
    } catch (const std::exception& e) {
      FAIL() << "message " << i << " got no reply: " << e.what() << "\n" << m.substr(0, 300);
    }
    ++answered;
    if (r.type == "error") ++errors;
    // A fuzzer lease would only delay the batch (until it expires): hand it back.
    if (r.type == "task")
      client.call("release", {{"worker", Json::parse(m).at("worker")},
                              {"task", r.integer("task")},
                              {"attempt", r.integer("attempt")},
                              {"token", r.str("token")}});
  }
  const double seconds = seconds_since(t0);
  EXPECT_EQ(answered + oversize, n);
  EXPECT_LT(oversize, n / 10);
  EXPECT_GT(errors, n / 10);  // the malformed ones
  std::printf("fuzzer: %d messages in %.2f s, %d error replies\n", n, seconds, errors);
  ASSERT_TRUE(poll_until("the batch done", [&] { return batch_state(ep, batch) == "done"; }));
  Json b = batch_of(farm_status(ep, batch), batch);
  EXPECT_TRUE(b.at("blocklisted").empty()) << b.dump();
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

}  // namespace
}  // namespace dofarm::farm_testing
