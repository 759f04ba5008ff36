// The farm's wire protocol (docs/protocol.md). Every message is one ZeroMQ
// frame holding a JSON object {"v": 1, "type": "...", ...}, at most
// kMaxMessageBytes, defined field by field in common/messages.h. parse() is
// the one place incoming bytes are checked:
// anything malformed, oversized, of another version or an unknown type, or
// missing a field becomes a ProtocolError, which the receiver turns into an
// "error" reply; it never stops the receiver.
#pragma once

#include <cstddef>
#include <nlohmann/json.hpp>
#include <string>

#include "common/error.h"

namespace dofarm::protocol {

using Json = nlohmann::json;

inline constexpr int kVersion = 1;
inline constexpr size_t kMaxMessageBytes = 1 << 20;

class ProtocolError : public RuntimeError {
 public:
  using RuntimeError::RuntimeError;
};

struct Message {
  std::string type;
  Json body;  // the whole object, "v" and "type" included

  const std::string& str(const char* key) const;
  int64_t integer(const char* key) const;
  double number(const char* key) const;
  bool has(const char* key) const { return body.contains(key); }
};

// Worker -> coordinator: request (asks for work), heartbeat, done, failed,
// release. Client -> coordinator: submit, status, resume, cancel.
// Coordinator -> worker/client: task, wait, ack, submitted, status, error,
// shutdown.
Message parse(const void* data, size_t size);
std::string encode(const std::string& type, Json fields = Json::object());
std::string error_reply(const std::string& message);

}  // namespace dofarm::protocol
