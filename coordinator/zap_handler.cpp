#include "coordinator/zap_handler.h"

#include <spdlog/spdlog.h>

#include <chrono>

namespace dofarm::coordinator {

ZapHandler::ZapHandler(zmq::context_t& ctx, std::vector<ClientKey> allowed)
    : socket_(ctx, zmq::socket_type::rep), any_key_(allowed.empty()) {
  for (ClientKey& k : allowed) allowed_.emplace(k.public_key, std::move(k));
  socket_.bind("inproc://zeromq.zap.01");
  thread_ = std::thread([this] { loop(); });
}

ZapHandler::~ZapHandler() {
  stop_ = true;
  thread_.join();
}

void ZapHandler::loop() {
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

}  // namespace dofarm::coordinator
