// The client side of the farm's transport: DEALER sockets to the
// coordinator, for workers and for the CLI (submit, status, resume, cancel).
// Sockets are set to fail fast (immediate, send/receive timeouts, no linger)
// so a refused or absent coordinator gives an error, not a hang.
#pragma once

#include <chrono>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <zmq.hpp>

#include "common/protocol.h"

namespace dofarm {

struct ClientOptions {
  std::string endpoint;                               // tcp://HOST:PORT
  std::optional<std::filesystem::path> curve_public;  // the coordinator's Z85 public key file
  int timeout_ms = 10000;                             // per request
  // This client's own key pair (`dofarm keygen --client NAME`: NAME.key, the
  // secret key on its first line), needed where the coordinator has an
  // allow-list; without it every connection makes a fresh key pair.
  std::optional<std::filesystem::path> curve_client = std::nullopt;
};

class CoordinatorClient {
 public:
  CoordinatorClient(zmq::context_t& ctx, ClientOptions options);
  // Sends one message and waits for its reply. Throws RuntimeError on a
  // timeout (the socket is then rebuilt, dropping any late reply) and
  // protocol::ProtocolError for a malformed reply.
  protocol::Message call(const std::string& payload);
  // The same, but gives up (RuntimeError, the socket rebuilt) as soon as
  // `give_up` returns true; it is asked every 50 ms while the message waits
  // to be sent or for its reply. A worker that must stop promptly on SIGTERM
  // cannot sit out a whole timeout_ms.
  protocol::Message call(const std::string& payload, const std::function<bool()>& give_up);
  // Drops the connection and makes a new one (fresh identity).
  void reconnect();

 private:
  zmq::context_t& ctx_;
  ClientOptions options_;
  std::string server_key_;               // Z85; empty without CURVE
  std::string public_key_, secret_key_;  // Z85; empty without --curve-client
  std::unique_ptr<zmq::socket_t> socket_;
};

// One request and its reply on a fresh connection (the CLI commands).
protocol::Message call_coordinator(const ClientOptions& options, const std::string& payload);

// A fresh CURVE key pair, Z85-encoded (public, secret).
std::pair<std::string, std::string> curve_keypair();
// The public key of a Z85 secret key.
std::string curve_public_of(const std::string& secret);
// 40 Z85 characters that decode to a 32-byte key.
bool is_z85_key(std::string_view text);
// Key files (dofarm keygen): a Z85 key on the first line (trailing blanks
// and CR ignored). Anything else is a SpecError naming the file and `option`.
std::string read_curve_public_key(const std::filesystem::path& path, const std::string& option);
std::string read_curve_secret_key(const std::filesystem::path& path, const std::string& option);

}  // namespace dofarm
