#include "common/protocol.h"

#include "common/messages.h"

namespace dofarm::protocol {

const std::string& Message::str(const char* key) const {
  return body.at(key).get_ref<const std::string&>();
}
int64_t Message::integer(const char* key) const { return body.at(key).get<int64_t>(); }
double Message::number(const char* key) const { return body.at(key).get<double>(); }

Message parse(const void* data, size_t size) {
  if (size > kMaxMessageBytes)
    throw ProtocolError("message of " + std::to_string(size) + " bytes exceeds the limit of " +
                        std::to_string(kMaxMessageBytes));
  const char* p = static_cast<const char*>(data);
  Json j = Json::parse(p, p + size, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) throw ProtocolError("message is not a JSON object");
  if (!j.contains("v") || !j["v"].is_number_integer())
    throw ProtocolError("message has no integer protocol version \"v\"");
  if (j["v"].get<int64_t>() != kVersion)
    throw ProtocolError("protocol version " + j["v"].dump() +
                        " is not supported (this build speaks " + std::to_string(kVersion) + ")");
  if (!j.contains("type") || !j["type"].is_string())
    throw ProtocolError("message has no string \"type\"");
  Message m;
  m.type = j["type"].get<std::string>();
  const MessageDef* def = find_message(m.type);
  if (!def) throw ProtocolError("unknown message type \"" + clip_text(m.type, 64) + "\"");
  validate(*def, j);
  m.body = std::move(j);
  return m;
}

std::string encode(const std::string& type, Json fields) {
  if (!fields.is_object()) fields = Json::object();
  fields["v"] = kVersion;
  fields["type"] = type;
  // The sender is held to the same definition as the receiver: a message that
  // breaks it is a programmer error, reported as a ProtocolError here rather
  // than as an error reply from the peer.
  const MessageDef* def = find_message(type);
  if (!def) throw ProtocolError("encode: unknown message type \"" + type + "\"");
  validate(*def, fields);
  std::string out = fields.dump(-1, ' ', false, Json::error_handler_t::replace);
  if (out.size() > kMaxMessageBytes)
    throw ProtocolError("encode: \"" + type + "\" message of " + std::to_string(out.size()) +
                        " bytes exceeds the limit of " + std::to_string(kMaxMessageBytes));
  return out;
}

std::string error_reply(const std::string& message) {
  return encode("error", Json{{"message", clip_text(message)}});
}

}  // namespace dofarm::protocol
