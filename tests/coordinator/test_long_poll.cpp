// Long poll: a worker's request with nothing to do is parked by the server
// and answered as soon as there is something to say. A real Server on
// loopback (port picked by the OS), raw DEALER sockets as workers, and a fake
// clock, so "as soon as" means "with the clock standing still" and the
// timeout is reached by advancing the clock, never by sleeping.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <optional>
#include <zmq.hpp>

#include "common/checksum.h"
#include "common/protocol.h"
#include "common/staging.h"
#include "coordinator/server.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

using protocol::Json;
using testing::TempDir;
using testing::tiny_spec;

// A worker's socket, driven by hand so a request can stay unanswered.
class RawWorker {
 public:
  RawWorker(zmq::context_t& ctx, const std::string& endpoint, std::string id)
      : socket_(ctx, zmq::socket_type::dealer), id_(std::move(id)) {
    socket_.set(zmq::sockopt::linger, 0);
    socket_.connect(endpoint);
  }
  void send(const std::string& type, Json fields = Json::object()) {
    fields["worker"] = id_;
    socket_.send(zmq::buffer(protocol::encode(type, fields)), zmq::send_flags::none);
  }
  std::optional<protocol::Message> receive() {
    zmq::message_t m;
    if (!socket_.recv(m, zmq::recv_flags::dontwait)) return std::nullopt;
    return protocol::parse(m.data(), m.size());
  }

 private:
  zmq::socket_t socket_;
  std::string id_;
};

class LongPollTest : public ::testing::Test {
 protected:
  void start(bool shutdown_when_idle, double wait_seconds, int frames = 1) {
    ServerOptions so;
    so.listen = "tcp://127.0.0.1:*";
    so.state_dir = dir_.path() / "state";
    so.shutdown_when_idle = shutdown_when_idle;
    so.wait_seconds = wait_seconds;
    server_ = std::make_unique<Server>(so, clock_);
    server_->scheduler().submit("/jobs/a.toml", {}, (dir_.path() / "out").string(),
                                tiny_spec(frames, frames), JobRef{std::string(32, '0'), ""});
  }
  std::unique_ptr<RawWorker> worker(const std::string& id) {
    return std::make_unique<RawWorker>(ctx_, server_->endpoint(), id);
  }
  // Serves until `w` has a reply (the clock stands still), or gives up.
  std::optional<protocol::Message> reply(RawWorker& w, int polls = 300) {
    for (int i = 0; i < polls; ++i) {
      if (auto m = w.receive()) return m;
      server_->poll_once(10);
    }
    return w.receive();
  }
  // Sends `type` and serves until the reply.
  protocol::Message call(RawWorker& w, const std::string& type, Json fields = Json::object()) {
    w.send(type, std::move(fields));
    std::optional<protocol::Message> m = reply(w);
    EXPECT_TRUE(m.has_value()) << "no reply to " << type;
    return m.value_or(protocol::Message{});
  }
  // Sends a request and serves until the server has parked it.
  void park(RawWorker& w, size_t parked_after) {
    w.send("request");
    for (int i = 0; i < 300 && server_->parked() < parked_after; ++i) server_->poll_once(10);
    ASSERT_EQ(server_->parked(), parked_after);
    for (int i = 0; i < 5; ++i) server_->poll_once(1);
    ASSERT_FALSE(w.receive().has_value()) << "a parked request was answered with nothing new";
  }
  // A true `done` for `task`: its output written where the coordinator
  // expects it (the claim is checked against the file).
  static Json result(const protocol::Message& task) {
    const Json& r = task.body.at("rect");
    const std::filesystem::path path =
        task.str("kind") == "pack_shard"
            ? std::filesystem::path(task.str("out_dir")) / task.str("shard_file")
            : staged_tile_path(task.str("out_dir"), task.str("batch"), int(task.integer("frame")),
                               Rect{r[0].get<int>(), r[1].get<int>(), r[2].get<int>(),
                                    r[3].get<int>()});
    std::filesystem::create_directories(path.parent_path());
    const std::string bytes = "output of task " + std::to_string(task.integer("task"));
    std::ofstream(path, std::ios::binary) << bytes;
    return {{"task", task.integer("task")},
            {"attempt", task.integer("attempt")},
            {"token", task.str("token")},
            {"staged_path", path.string()},
            {"size", bytes.size()},
            {"checksum", checksum_to_string(checksum64(bytes.data(), bytes.size()))},
            {"seconds", 0.0}};
  }

  TempDir dir_;
  FakeClock clock_;
  zmq::context_t ctx_{1};
  std::unique_ptr<Server> server_;
};

TEST_F(LongPollTest, ParkedRequestGetsATaskAsSoonAsOneBecomesRunnable) {
  start(false, 0.5);  // one tile, then its pack
  auto w1 = worker("w1"), w2 = worker("w2");
  const protocol::Message tile = call(*w1, "request");
  ASSERT_EQ(tile.type, "task");
  ASSERT_EQ(tile.str("kind"), "render_tile");
  park(*w2, 1);  // the pack waits for the tile
  ASSERT_EQ(call(*w1, "done", result(tile)).body.value("status", ""), "accepted");
  const std::optional<protocol::Message> pack = reply(*w2);
  ASSERT_TRUE(pack.has_value()) << "the parked request was not answered";
  EXPECT_EQ(pack->type, "task");
  EXPECT_EQ(pack->str("kind"), "pack_shard");
  EXPECT_EQ(server_->parked(), 0u);
}

TEST_F(LongPollTest, ParkedRequestGetsShutdownWhenTheBatchCompletes) {
  start(true, 0.5);
  auto w1 = worker("w1"), w2 = worker("w2");
  const protocol::Message tile = call(*w1, "request");
  ASSERT_EQ(tile.type, "task");
  call(*w1, "done", result(tile));
  const protocol::Message pack = call(*w1, "request");
  ASSERT_EQ(pack.str("kind"), "pack_shard");
  park(*w2, 1);
  call(*w1, "done", result(pack));
  const std::optional<protocol::Message> m = reply(*w2);
  ASSERT_TRUE(m.has_value()) << "the parked request was not answered";
  EXPECT_EQ(m->type, "shutdown");
}

TEST_F(LongPollTest, ParkedRequestGetsWaitAfterWaitSeconds) {
  start(false, 0.5);
  auto w1 = worker("w1"), w2 = worker("w2");
  ASSERT_EQ(call(*w1, "request").type, "task");
  park(*w2, 1);
  clock_.advance(0.4);
  for (int i = 0; i < 5; ++i) server_->poll_once(1);
  EXPECT_FALSE(w2->receive().has_value()) << "answered before wait_seconds";
  clock_.advance(0.2);
  const std::optional<protocol::Message> m = reply(*w2);
  ASSERT_TRUE(m.has_value()) << "not answered after wait_seconds";
  EXPECT_EQ(m->type, "wait");
  EXPECT_EQ(m->number("seconds"), 0.0);  // parked long enough: ask again at once
  EXPECT_EQ(server_->parked(), 0u);
}

TEST_F(LongPollTest, ParkedRequestGetsATaskWhenABackOffEnds) {
  start(false, 5);
  auto w1 = worker("w1");
  const protocol::Message tile = call(*w1, "request");
  Json failed = {{"task", tile.integer("task")},
                 {"attempt", tile.integer("attempt")},
                 {"token", tile.str("token")},
                 {"error", "flaky"}};
  ASSERT_EQ(call(*w1, "failed", failed).body.value("status", ""), "retry");  // back-off 2 s
  park(*w1, 1);  // a lone worker retries its task after the back-off
  clock_.advance(1.5);
  for (int i = 0; i < 5; ++i) server_->poll_once(1);
  EXPECT_FALSE(w1->receive().has_value()) << "answered during the back-off";
  clock_.advance(1);
  const std::optional<protocol::Message> m = reply(*w1);
  ASSERT_TRUE(m.has_value()) << "not answered when the back-off ended";
  EXPECT_EQ(m->type, "task");
  EXPECT_EQ(m->integer("task"), tile.integer("task"));
}

TEST_F(LongPollTest, ARequestFromANewSocketReplacesTheWorkersParkedOne) {
  start(false, 5);
  auto w1 = worker("w1"), old_socket = worker("w2"), new_socket = worker("w2");
  const protocol::Message tile = call(*w1, "request");
  park(*old_socket, 1);
  park(*new_socket, 1);  // still one: the same worker
  call(*w1, "done", result(tile));
  const std::optional<protocol::Message> m = reply(*new_socket);
  ASSERT_TRUE(m.has_value());
  EXPECT_EQ(m->type, "task");
  EXPECT_FALSE(old_socket->receive().has_value()) << "two leases for one worker";
}

}  // namespace
}  // namespace dofarm::coordinator
