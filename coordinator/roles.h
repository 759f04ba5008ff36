// Roles under CURVE (docs/farm.md, "Authentication (CURVE)").
//
// The coordinator's allow-list (`--curve-clients FILE`) names each client
// public key with a role; the ZAP handler lets in listed keys only and hands
// the role to ZeroMQ as the connection's User-Id, which every message frame
// of that connection then carries. The receive loop checks each message's
// type against its sender's role before anything else is done with it; the
// message table (common/messages.h, MessageDef::from) says who sends what:
//   worker:   what workers send: request, heartbeat, done, failed, release
//   operator: that, and what the CLI sends: submit, status, resume, cancel
// A connection without a User-Id (no CURVE: the embedded `dofarm run` on
// loopback, or a farm on a trusted network) may send everything.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace dofarm::coordinator {

enum class Role { kWorker, kOperator };
const char* to_string(Role role);  // "worker", "operator"
std::optional<Role> role_from_string(std::string_view text);

// Whether a client of `role` may send a message of `type`.
bool role_may_send(Role role, std::string_view type);

// The receive loop's check: `user_id` is the ZAP User-Id of the message's
// frame (nullptr without CURVE, which allows everything). Returns why the
// message is refused, or nothing when it may be handled. An unknown User-Id
// refuses everything.
std::optional<std::string> refusal_for(const char* user_id, std::string_view type);

// One line of the allow-list: "PUBLIC_KEY ROLE [NAME]".
struct ClientKey {
  std::string public_key;  // Z85, 40 characters
  Role role = Role::kWorker;
  std::string name;  // for the log; may be empty
  int line = 0;
};

// Reads an allow-list: one client per line, "PUBLIC_KEY ROLE [NAME]"
// separated by blanks; blank lines and lines starting with '#' are skipped.
// A key that is not a Z85 CURVE public key, an unknown role, extra words or
// a key listed twice is a SpecError at file:line:column.
std::vector<ClientKey> load_client_keys(const std::filesystem::path& path);

}  // namespace dofarm::coordinator
