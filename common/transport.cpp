#include "common/transport.h"

#include <fstream>
#include <thread>

namespace dofarm {

namespace {

// The first line of a key file, without trailing blanks or CR.
std::string first_line(const std::filesystem::path& path, const std::string& option,
                       const std::string& what) {
  std::ifstream in(path);
  std::string line;
  if (!in) throw SpecError(FileLoc{path.string()}, option, "cannot read " + what);
  std::getline(in, line);
  while (!line.empty() && (line.back() == '\r' || line.back() == ' ' || line.back() == '\t'))
    line.pop_back();
  if (!is_z85_key(line))
    throw SpecError(FileLoc{path.string(), 1, 1}, option,
                    "expected " + what + " (40 Z85 characters) on the first line");
  return line;
}

}  // namespace

bool is_z85_key(std::string_view text) {
  if (text.size() != 40) return false;
  uint8_t bytes[32];
  const std::string copy(text);
  return zmq_z85_decode(bytes, copy.c_str()) != nullptr;
}

std::string read_curve_public_key(const std::filesystem::path& path, const std::string& option) {
  return first_line(path, option, "a Z85 CURVE public key");
}

std::string read_curve_secret_key(const std::filesystem::path& path, const std::string& option) {
  return first_line(path, option, "a Z85 CURVE secret key");
}

std::string curve_public_of(const std::string& secret) {
  char pub[41];
  if (zmq_curve_public(pub, secret.c_str()) != 0)
    throw RuntimeError("cannot derive a CURVE public key (ZeroMQ without CURVE?)");
  return pub;
}

std::pair<std::string, std::string> curve_keypair() {
  char pub[41], sec[41];
  if (zmq_curve_keypair(pub, sec) != 0)
    throw RuntimeError("ZeroMQ was built without CURVE support");
  return {pub, sec};
}

CoordinatorClient::CoordinatorClient(zmq::context_t& ctx, ClientOptions options)
    : ctx_(ctx), options_(std::move(options)) {
  // Key files are read once: a bad one is bad input (exit 2) at the start,
  // never a failure at some later reconnect.
  if (options_.curve_client && !options_.curve_public)
    throw SpecError(FileLoc{options_.curve_client->string()}, "curve-client",
                    "a client key pair needs the coordinator's public key too (--curve-public)");
  if (options_.curve_public)
    server_key_ = read_curve_public_key(*options_.curve_public, "curve-public");
  if (options_.curve_client) {
    secret_key_ = read_curve_secret_key(*options_.curve_client, "curve-client");
    public_key_ = curve_public_of(secret_key_);
  }
  reconnect();
}

void CoordinatorClient::reconnect() {
  socket_ = std::make_unique<zmq::socket_t>(ctx_, zmq::socket_type::dealer);
  socket_->set(zmq::sockopt::linger, 0);
  socket_->set(zmq::sockopt::immediate, 1);  // queue nothing for a peer that is not there
  socket_->set(zmq::sockopt::sndtimeo, options_.timeout_ms);
  socket_->set(zmq::sockopt::rcvtimeo, options_.timeout_ms);
  socket_->set(zmq::sockopt::maxmsgsize, int64_t(protocol::kMaxMessageBytes));
  if (!server_key_.empty()) {
    // Without a key pair of its own (--curve-client) a fresh one per socket:
    // enough for a coordinator without an allow-list, refused by one with.
    auto [pub, sec] = secret_key_.empty() ? curve_keypair() : std::pair{public_key_, secret_key_};
    socket_->set(zmq::sockopt::curve_serverkey, server_key_);
    socket_->set(zmq::sockopt::curve_publickey, pub);
    socket_->set(zmq::sockopt::curve_secretkey, sec);
  }
  socket_->connect(options_.endpoint);
}

protocol::Message CoordinatorClient::call(const std::string& payload) {
  if (!socket_->send(zmq::buffer(payload), zmq::send_flags::none)) {
    reconnect();
    throw RuntimeError("cannot reach the coordinator at " + options_.endpoint);
  }
  zmq::message_t reply;
  if (!socket_->recv(reply, zmq::recv_flags::none)) {
    reconnect();  // a late reply must not be taken for the next request's
    throw RuntimeError("no reply from the coordinator at " + options_.endpoint + " within " +
                       std::to_string(options_.timeout_ms) + " ms");
  }
  return protocol::parse(reply.data(), reply.size());
}

protocol::Message CoordinatorClient::call(const std::string& payload,
                                         const std::function<bool()>& give_up) {
  using Steady = std::chrono::steady_clock;
  const auto deadline = Steady::now() + std::chrono::milliseconds(options_.timeout_ms);
  const auto slice = std::chrono::milliseconds(50);
  auto fail = [&](const std::string& why) {
    reconnect();  // a late reply must not be taken for the next request's
    return RuntimeError(why + " (" + options_.endpoint + ")");
  };
  // `immediate`: without a connected coordinator the send fails at once.
  while (!socket_->send(zmq::buffer(payload), zmq::send_flags::dontwait)) {
    if (give_up()) throw fail("gave up sending to the coordinator");
    if (Steady::now() >= deadline) throw fail("cannot reach the coordinator");
    std::this_thread::sleep_for(slice);
  }
  for (;;) {
    zmq::pollitem_t item{socket_->handle(), 0, ZMQ_POLLIN, 0};
    try {
      zmq::poll(&item, 1, slice);
    } catch (const zmq::error_t& e) {
      if (e.num() != EINTR) throw;  // a signal: look at give_up() below
    }
    if (item.revents & ZMQ_POLLIN) {
      zmq::message_t reply;
      if (socket_->recv(reply, zmq::recv_flags::dontwait))
        return protocol::parse(reply.data(), reply.size());
    }
    if (give_up()) throw fail("gave up waiting for the coordinator's reply");
    if (Steady::now() >= deadline)
      throw fail("no reply from the coordinator within " + std::to_string(options_.timeout_ms) +
                 " ms");
  }
}

protocol::Message call_coordinator(const ClientOptions& options, const std::string& payload) {
  zmq::context_t ctx(1);
  CoordinatorClient client(ctx, options);
  return client.call(payload);
}

}  // namespace dofarm
