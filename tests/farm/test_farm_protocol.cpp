// The coordinator's wire boundary: thousands of malformed messages each get
// an "error" reply and never stop it; CURVE keeps clients without the
// coordinator's public key out.
#include <gtest/gtest.h>

#include <random>
#include <thread>
#include <zmq.hpp>

#include "coordinator/server.h"
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

using coordinator::Server;
using coordinator::ServerOptions;
using coordinator::SystemClock;

// A Server on its own thread, stopped and joined by the destructor.
class ServerThread {
 public:
  explicit ServerThread(ServerOptions so) : server_(std::move(so), clock_) {
    thread_ = std::thread([this] { server_.run(stop_); });
  }
  ~ServerThread() {
    stop_ = true;
    thread_.join();
  }
  const std::string& endpoint() const { return server_.endpoint(); }

 private:
  SystemClock clock_;
  Server server_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

// A raw DEALER: sends exactly the frames it is given.
std::unique_ptr<zmq::socket_t> raw_dealer(zmq::context_t& ctx, const std::string& endpoint) {
  auto s = std::make_unique<zmq::socket_t>(ctx, zmq::socket_type::dealer);
  s->set(zmq::sockopt::linger, 0);
  s->set(zmq::sockopt::rcvtimeo, 10000);
  s->set(zmq::sockopt::sndtimeo, 10000);
  s->connect(endpoint);
  return s;
}

// Sends `frames` as one message; the reply, or empty on a timeout.
std::optional<std::string> exchange(zmq::socket_t& s, const std::vector<std::string>& frames) {
  for (size_t i = 0; i < frames.size(); ++i)
    s.send(zmq::buffer(frames[i]),
           i + 1 < frames.size() ? zmq::send_flags::sndmore : zmq::send_flags::none);
  zmq::message_t reply;
  if (!s.recv(reply)) return std::nullopt;
  EXPECT_FALSE(reply.more()) << "a reply is one frame";
  return reply.to_string();
}

// A message built without the definitions' check, so it can break them.
std::string unchecked(const std::string& type, Json fields = Json::object()) {
  fields["v"] = protocol::kVersion;
  fields["type"] = type;
  return fields.dump(-1, ' ', false, Json::error_handler_t::replace);
}

const std::string kToken(32, '0');  // well-formed, and no lease's token

// Messages that are each wrong in one way. None may get anything but an error.
std::vector<std::vector<std::string>> malformed_messages() {
  std::vector<std::vector<std::string>> out;
  auto one = [&](const std::string& s) { out.push_back({s}); };
  std::mt19937 rng(20240611);
  // Random bytes, empty included.
  for (int i = 0; i < 1200; ++i) {
    std::string s(rng() % 300, '\0');
    for (char& c : s) c = char(rng());
    one(s);
  }
  // Not JSON, or not an object.
  for (const char* s : {"",
                        " ",
                        "hello",
                        "{",
                        "}",
                        "{\"v\":1",
                        "{\"v\":1,}",
                        "{'v':1}",
                        "null",
                        "true",
                        "42",
                        "-1e999",
                        "\"status\"",
                        "[]",
                        "[{\"v\":1,\"type\":\"status\"}]",
                        "[1,2,3]",
                        "{\"v\":1,\"type\":\"status\"}{}",
                        "\xff\xfe\xfd",
                        "{\"v\":1,\"type\":\"\xc3\x28\"}",
                        "{\"v\":1,\"type\":\"st\\ud800atus\"}"})
    one(s);
  one(std::string(200000, '['));
  one(std::string(100000, '[') + std::string(100000, ']'));
  std::string nested;
  for (int i = 0; i < 20000; ++i) nested += "{\"a\":";
  one(nested);
  // Every strict prefix of valid messages is invalid JSON.
  for (const std::string& valid :
       {unchecked("status"),
        unchecked("request", {{"worker", "w"}, {"host", "h"}, {"threads", 1}}),
        unchecked("heartbeat", {{"worker", "w"}, {"task", 1}, {"attempt", 1}}),
        unchecked("submit", {{"snapshot", "{}"}, {"out_dir", "/tmp/x"}})})
    for (size_t n = 0; n < valid.size(); ++n) one(valid.substr(0, n));
  // Wrong or missing protocol version.
  for (const char* v : {"2", "0", "-1", "1.0", "1.5", "\"1\"", "null", "true", "[1]", "{}",
                        "99999999999999999999", "1e0"})
    one(std::string("{\"v\":") + v + ",\"type\":\"status\"}");
  one("{\"type\":\"status\"}");
  // Missing, mistyped or unknown type.
  one("{\"v\":1}");
  for (const char* t : {"5", "null", "[\"status\"]", "{\"a\":1}", "true"})
    one(std::string("{\"v\":1,\"type\":") + t + "}");
  for (const char* t : {"", "STATUS", "status ", "hello", "rm -rf /", "request\t", "\u00e9"})
    one(unchecked(t));
  // Types the coordinator sends but never takes.
  one(unchecked("task", {{"task", 1}, {"attempt", 1}, {"kind", "render_tile"}}));
  one(unchecked("wait", {{"seconds", 1.0}}));
  one(unchecked("ack"));
  one(unchecked("submitted", {{"batch", "b-00000000"}}));
  one(unchecked("status_reply", {{"batches", Json::array()}}));
  one(unchecked("error", {{"message", "x"}}));
  one(unchecked("shutdown"));
  // Each required field of each worker/client message missing or mistyped.
  const std::vector<std::pair<std::string, Json>> good = {
      {"request", {{"worker", "w"}}},
      {"heartbeat", {{"worker", "w"}, {"task", 1}, {"attempt", 1}, {"token", kToken}}},
      {"done",
       {{"worker", "w"},
        {"task", 1},
        {"attempt", 1},
        {"token", kToken},
        {"staged_path", "/x"},
        {"size", 1},
        {"checksum", "xxh64:0123456789abcdef"},
        {"seconds", 1.0}}},
      {"failed", {{"worker", "w"}, {"task", 1}, {"attempt", 1}, {"token", kToken}, {"error", "e"}}},
      {"release", {{"worker", "w"}, {"task", 1}, {"attempt", 1}, {"token", kToken}}},
      {"submit", {{"snapshot", "{}"}, {"out_dir", "/tmp"}}},
      {"resume", {{"batch", "b-00000000"}}},
      {"cancel", {{"batch", "b-00000000"}}},
  };
  const std::vector<Json> wrong = {
      nullptr, true, 1.5, -3, "text", Json::array(), Json::object(), Json::array({1, 2})};
  for (const auto& [type, fields] : good) {
    for (const auto& [key, value] : fields.items()) {
      Json missing = fields;
      missing.erase(key);
      one(unchecked(type, missing));
      for (const Json& w : wrong) {
        if (w.type() == value.type()) continue;                  // same type: not wrong
        if (value.is_number_float() && w.is_number()) continue;  // an int is a number
        Json bad = fields;
        bad[key] = w;
        one(unchecked(type, bad));
      }
    }
  }
  // Optional fields of the wrong type.
  one(unchecked("request", {{"worker", "w"}, {"host", 5}}));
  one(unchecked("request", {{"worker", "w"}, {"threads", "many"}}));
  one(unchecked("submit", {{"snapshot", Json::array({1, 2})}, {"out_dir", "/tmp"}}));
  // Non-finite numbers.
  one("{\"v\":1,\"type\":\"done\",\"worker\":\"w\",\"task\":1,\"attempt\":1,"
      "\"staged_path\":\"/x\",\"checksum\":\"c\",\"seconds\":1e999}");
  // Multi-frame messages.
  out.push_back({unchecked("status"), unchecked("status")});
  out.push_back({unchecked("status"), ""});
  out.push_back({"", unchecked("status")});
  out.push_back({"a", "b", "c"});
  // Exactly at the size limit: delivered, and not JSON.
  one(std::string(protocol::kMaxMessageBytes, 'x'));
  // Fill up to ~3000 with random printable JSON-ish text.
  const std::string alphabet = "{}[]\":,0123456789.-eEtruefalsnvyp ";
  while (out.size() < 3000) {
    std::string s(1 + rng() % 80, ' ');
    for (char& c : s) c = alphabet[rng() % alphabet.size()];
    if (s.find("\"v\"") != std::string::npos) continue;  // cannot be valid without "v"
    one(s);
  }
  return out;
}

TEST(FarmProtocol, ThousandsOfMalformedMessagesEachGetAnErrorAndTheCoordinatorGoesOn) {
  TempDir tmp;
  ServerOptions so;
  so.listen = "tcp://127.0.0.1:*";
  so.state_dir = tmp / "state";
  ServerThread server(so);
  zmq::context_t ctx(1);

  const auto messages = malformed_messages();
  ASSERT_GE(messages.size(), 3000u);
  auto socket = raw_dealer(ctx, server.endpoint());
  for (size_t i = 0; i < messages.size(); ++i) {
    std::optional<std::string> reply = exchange(*socket, messages[i]);
    ASSERT_TRUE(reply.has_value())
        << "no reply to message " << i << " (" << messages[i][0].substr(0, 80) << ")";
    protocol::Message m;
    ASSERT_NO_THROW(m = protocol::parse(reply->data(), reply->size())) << *reply;
    ASSERT_EQ(m.type, "error") << "message " << i << ": " << messages[i][0].substr(0, 200)
                               << "\n -> " << *reply;
    EXPECT_FALSE(m.str("message").empty());
  }
  // Nothing of that became state.
  Json st = farm_status(server.endpoint());
  EXPECT_TRUE(st.at("batches").empty()) << st.dump();

  // An oversized message: ZeroMQ drops the connection instead of delivering
  // it. The coordinator serves on.
  auto big = raw_dealer(ctx, server.endpoint());
  big->set(zmq::sockopt::rcvtimeo, 2000);
  EXPECT_FALSE(exchange(*big, {std::string(protocol::kMaxMessageBytes + 1, ' ')}).has_value());
  EXPECT_NO_THROW(farm_status(server.endpoint()));
  // And the old connection still works too.
  auto r = exchange(*socket, {protocol::encode("status")});
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(protocol::parse(r->data(), r->size()).type, "status_reply") << *r;
}

TEST(FarmCurve, ClientsWithoutTheCoordinatorsPublicKeyGetNothing) {
  TempDir tmp;
  CliResult k = run_cli(tmp.path(), "keygen", {"keygen", "--out", (tmp / "keys").string()});
  ASSERT_EQ(k.status, 0) << k.err;
  CliResult k2 = run_cli(tmp.path(), "keygen2", {"keygen", "--out", (tmp / "other").string()});
  ASSERT_EQ(k2.status, 0) << k2.err;
  const fs::path pub = tmp / "keys" / "coordinator.pub";
  ASSERT_TRUE(fs::exists(pub));
  EXPECT_EQ(fs::status(tmp / "keys" / "coordinator.key").permissions() & fs::perms::others_read,
            fs::perms::none)
      << "the secret key must not be world-readable";

  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 2,
                           {"--curve-secret", (tmp / "keys" / "coordinator.key").string()});
  const std::string ep = coord.endpoint();
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});
  Json submitted = coordinator_call(ep, "submit", submit_fields(job, tmp / "out"), 10000, pub);
  const std::string batch = submitted.at("batch");

  zmq::context_t ctx(1);
  const std::string request = protocol::encode("request", {{"worker", "intruder"}});
  CoordinatorClient plain(ctx, {ep, std::nullopt, 1500});
  EXPECT_THROW(plain.call(request), RuntimeError) << "a client without CURVE got a reply";
  CoordinatorClient wrong_key(ctx, {ep, tmp / "other" / "coordinator.pub", 1500});
  EXPECT_THROW(wrong_key.call(request), RuntimeError) << "a client with another key got a reply";

  CoordinatorClient keyed(ctx, {ep, pub, 10000});
  protocol::Message m = keyed.call(protocol::encode("request", {{"worker", "friend"}}));
  ASSERT_EQ(m.type, "task") << m.body.dump();
  EXPECT_EQ(m.str("batch"), batch);
  EXPECT_TRUE(keyed
                  .call(protocol::encode("release", {{"worker", "friend"},
                                                     {"task", m.integer("task")},
                                                     {"attempt", m.integer("attempt")},
                                                     {"token", m.str("token")}}))
                  .body.value("ok", false));

  // A real worker with the key finishes the batch; the intruder never got work.
  Child w = start_worker(tmp.path(), ep, "w1", {"--curve-public", pub.string()});
  ASSERT_TRUE(poll_until("the batch to be done", [&] {
    Json b = batch_of(coordinator_call(ep, "status", {{"batch", batch}}, 10000, pub), batch);
    return b.at("state") == "done";
  })) << w.describe();
  Json st = coordinator_call(ep, "status", Json::object(), 10000, pub);
  for (const Json& wk : st.at("workers")) EXPECT_NE(wk.at("worker"), "intruder");
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

// The CLI's client commands must be able to talk to a CURVE coordinator too:
// without a --curve-public option nobody can submit to or watch such a farm.
TEST(FarmCurve, StatusCommandReachesACurveCoordinator) {
  TempDir tmp;
  ASSERT_EQ(run_cli(tmp.path(), "keygen", {"keygen", "--out", (tmp / "keys").string()}).status, 0);
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 2,
                           {"--curve-secret", (tmp / "keys" / "coordinator.key").string()});
  CliResult r = run_cli(tmp.path(), "status",
                        {"status", "--coordinator", coord.endpoint(), "--json", "--curve-public",
                         (tmp / "keys" / "coordinator.pub").string()});
  EXPECT_EQ(r.status, 0) << r.out << r.err;
}

}  // namespace
}  // namespace dofarm::farm_testing
