// A `done` claim whose file is too large to read in one round of the
// receive loop is checksummed in slices over the next rounds, while every
// other message is served; its lease is kept alive meanwhile, and the answer
// (accepted or refused) goes out when the last slice is read. A real Server
// on loopback driven one poll_once() at a time, with a fake clock.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <optional>
#include <thread>
#include <zmq.hpp>

#include "common/checksum.h"
#include "common/protocol.h"
#include "common/staging.h"
#include "coordinator/server.h"
#include "coordinator_fixtures.h"

namespace dofarm::coordinator {
namespace {

namespace fs = std::filesystem;
using protocol::Json;
using testing::TempDir;

class ClaimsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ServerOptions so;
    so.listen = "tcp://127.0.0.1:*";
    so.state_dir = dir_.path() / "state";
    server_ = std::make_unique<Server>(so, clock_);
    JobSpec spec = testing::tiny_spec(1, 1);
    spec.width = spec.height = spec.tile = 512;  // a tile may be ~400 MB: bound far above 16 MiB
    server_->scheduler().submit("/jobs/a.toml", {}, (dir_.path() / "out").string(), spec,
                                JobRef{std::string(32, '0'), ""});
    worker_ = socket();
    client_ = socket();
  }
  std::unique_ptr<zmq::socket_t> socket() {
    auto s = std::make_unique<zmq::socket_t>(ctx_, zmq::socket_type::dealer);
    s->set(zmq::sockopt::linger, 0);
    s->connect(server_->endpoint());
    return s;
  }
  static void send(zmq::socket_t& s, const std::string& type, Json fields = Json::object()) {
    s.send(zmq::buffer(protocol::encode(type, std::move(fields))), zmq::send_flags::none);
  }
  static std::optional<protocol::Message> receive(zmq::socket_t& s) {
    zmq::message_t m;
    if (!s.recv(m, zmq::recv_flags::dontwait)) return std::nullopt;
    return protocol::parse(m.data(), m.size());
  }
  // Serves until `s` has a reply.
  std::optional<protocol::Message> reply(zmq::socket_t& s) {
    for (int i = 0; i < 300; ++i) {
      if (auto m = receive(s)) return m;
      server_->poll_once(10);
    }
    return receive(s);
  }
  // A task for the worker, and a file of `bytes` bytes where its output goes;
  // the `done` claim for it, with the file's true size and checksum.
  Json claim(size_t bytes) {
    send(*worker_, "request", {{"worker", "w1"}});
    std::optional<protocol::Message> t = reply(*worker_);
    EXPECT_TRUE(t && t->type == "task");
    if (!t || t->type != "task") return {};
    const Json& r = t->body.at("rect");
    const fs::path path =
        staged_tile_path(t->str("out_dir"), t->str("batch"), 0,
                         Rect{r[0].get<int>(), r[1].get<int>(), r[2].get<int>(), r[3].get<int>()});
    fs::create_directories(path.parent_path());
    const std::string data(bytes, 'd');
    std::ofstream(path, std::ios::binary) << data;
    return {{"worker", "w1"},
            {"task", t->integer("task")},
            {"attempt", t->integer("attempt")},
            {"token", t->str("token")},
            {"staged_path", path.string()},
            {"size", bytes},
            {"checksum", checksum_to_string(checksum64(data.data(), data.size()))},
            {"seconds", 1.0}};
  }
  // A message on `s` within `ms` milliseconds, the server not running
  // meanwhile: whatever arrives was sent in the rounds served so far (a
  // reply can take a while through the sockets on a loaded machine).
  static std::optional<protocol::Message> arrived(zmq::socket_t& s, int ms) {
    zmq::pollitem_t item{s.handle(), 0, ZMQ_POLLIN, 0};
    zmq::poll(&item, 1, std::chrono::milliseconds(ms));
    return receive(s);
  }
  // Sends the claim and a status request together; counts the server's
  // rounds until it has answered the claim, checking that a claim that
  // takes more than one round did not hold up the status request.
  std::string claim_answered_after_rounds(const Json& done, int& rounds) {
    send(*worker_, "done", done);
    send(*client_, "status");
    rounds = 0;
    int status_round = 0;
    std::optional<protocol::Message> status, answer;
    while (!answer && rounds < 100) {
      server_->poll_once(50);
      ++rounds;
      if (!status && (status = arrived(*client_, 200))) status_round = rounds;
      answer = arrived(*worker_, 200);
    }
    EXPECT_TRUE(answer.has_value());
    if (answer && rounds > 1) {
      EXPECT_TRUE(status.has_value()) << "status waited for the claim";
      EXPECT_LT(status_round, rounds) << "status answered in the claim's last round";
    }
    return answer ? answer->body.value("status", "") : "";
  }

  TempDir dir_;
  FakeClock clock_;
  zmq::context_t ctx_{1};
  std::unique_ptr<Server> server_;
  std::unique_ptr<zmq::socket_t> worker_, client_;
};

TEST_F(ClaimsTest, ALargeClaimIsReadInSlicesWhileOtherMessagesAreServed) {
  const Json done = claim(40u << 20);  // 16 MiB a round: three rounds
  int rounds = 0;
  EXPECT_EQ(claim_answered_after_rounds(done, rounds), "accepted");
  EXPECT_GE(rounds, 3);
  EXPECT_EQ(server_->scheduler().status().batches.at(0).tasks_done, 1);
}

TEST_F(ClaimsTest, ALargeClaimWithAnotherChecksumIsRefusedWhenRead) {
  Json done = claim(40u << 20);
  done["checksum"] = "xxh64:0123456789abcdef";
  int rounds = 0;
  EXPECT_EQ(claim_answered_after_rounds(done, rounds), "refused");
  EXPECT_EQ(server_->scheduler().status().batches.at(0).tasks_done, 0);
}

TEST_F(ClaimsTest, AClaimOfAnotherSizeThanTheFileIsRefusedAtOnce) {
  Json done = claim(1000);
  done["size"] = 999;
  int rounds = 0;
  EXPECT_EQ(claim_answered_after_rounds(done, rounds), "refused");
  EXPECT_LE(rounds, 2);
}

}  // namespace
}  // namespace dofarm::coordinator
