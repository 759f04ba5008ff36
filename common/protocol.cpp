#include "common/protocol.h"

#include <map>
#include <vector>

namespace dofarm::protocol {

namespace {

enum class Kind { kString, kInt, kNumber, kArray, kObject };

// The fields each message type must carry (others are allowed and ignored,
// so a newer peer can add optional fields without a version bump).
const std::map<std::string, std::vector<std::pair<const char*, Kind>>>& schema() {
  static const std::map<std::string, std::vector<std::pair<const char*, Kind>>> s = {
      {"request", {{"worker", Kind::kString}}},
      {"heartbeat", {{"worker", Kind::kString}, {"task", Kind::kInt}, {"attempt", Kind::kInt}}},
      {"done",
       {{"worker", Kind::kString},
        {"task", Kind::kInt},
        {"attempt", Kind::kInt},
        {"staged_path", Kind::kString},
        {"checksum", Kind::kString},
        {"seconds", Kind::kNumber}}},
      {"failed",
       {{"worker", Kind::kString},
        {"task", Kind::kInt},
        {"attempt", Kind::kInt},
        {"error", Kind::kString}}},
      {"release", {{"worker", Kind::kString}, {"task", Kind::kInt}, {"attempt", Kind::kInt}}},
      {"submit",
       {{"spec_path", Kind::kString}, {"overrides", Kind::kArray}, {"out_dir", Kind::kString}}},
      {"status", {}},
      {"resume", {{"batch", Kind::kString}}},
      {"cancel", {{"batch", Kind::kString}}},
      {"task", {{"task", Kind::kInt}, {"attempt", Kind::kInt}, {"kind", Kind::kString}}},
      {"wait", {{"seconds", Kind::kNumber}}},
      {"ack", {}},
      {"submitted", {{"batch", Kind::kString}}},
      {"status_reply", {{"batches", Kind::kArray}}},
      {"error", {{"message", Kind::kString}}},
      {"shutdown", {}},
  };
  return s;
}

bool matches(const Json& v, Kind k) {
  switch (k) {
    case Kind::kString:
      return v.is_string();
    case Kind::kInt:
      return v.is_number_integer();
    case Kind::kNumber:
      return v.is_number() && std::isfinite(v.get<double>());
    case Kind::kArray:
      return v.is_array();
    case Kind::kObject:
      return v.is_object();
  }
  return false;
}

const char* kind_name(Kind k) {
  switch (k) {
    case Kind::kString:
      return "a string";
    case Kind::kInt:
      return "an integer";
    case Kind::kNumber:
      return "a finite number";
    case Kind::kArray:
      return "an array";
    case Kind::kObject:
      return "an object";
  }
  return "?";
}

}  // namespace

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
  auto it = schema().find(m.type);
  if (it == schema().end()) throw ProtocolError("unknown message type \"" + m.type + "\"");
  for (const auto& [key, kind] : it->second) {
    if (!j.contains(key) || !matches(j[key], kind))
      throw ProtocolError("\"" + m.type + "\" message: \"" + key + "\" must be " + kind_name(kind));
  }
  m.body = std::move(j);
  return m;
}

std::string encode(const std::string& type, Json fields) {
  if (!fields.is_object()) fields = Json::object();
  fields["v"] = kVersion;
  fields["type"] = type;
  return fields.dump();
}

std::string error_reply(const std::string& message) {
  return encode("error", Json{{"message", message}});
}

}  // namespace dofarm::protocol
