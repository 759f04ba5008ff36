// ZAP (ZeroMQ RFC 27) handler for CURVE: lets in the client public keys of
// the allow-list and names their role as the connection's User-Id, which the
// receive loop checks every message against (coordinator/roles.h). Without
// an allow-list every client that completed the CURVE handshake (i.e. knew
// the coordinator's public key) is let in as an operator. Answers on its own
// thread, bound to inproc://zeromq.zap.01 of the server's context, from
// construction until destruction.
#pragma once

#include <atomic>
#include <map>
#include <string>
#include <thread>
#include <vector>
#include <zmq.hpp>

#include "coordinator/roles.h"

namespace dofarm::coordinator {

class ZapHandler {
 public:
  ZapHandler(zmq::context_t& ctx, std::vector<ClientKey> allowed);
  ~ZapHandler();

 private:
  void loop();

  zmq::socket_t socket_;
  bool any_key_;  // no allow-list: every key, as an operator
  std::map<std::string, ClientKey> allowed_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace dofarm::coordinator
