#include "coordinator/roles.h"

#include <fstream>
#include <set>
#include <sstream>

#include "common/error.h"
#include "common/messages.h"
#include "common/transport.h"

namespace dofarm::coordinator {

const char* to_string(Role role) {
  switch (role) {
    case Role::kWorker:
      return "worker";
    case Role::kOperator:
      return "operator";
  }
  return "?";
}

std::optional<Role> role_from_string(std::string_view text) {
  if (text == "worker") return Role::kWorker;
  if (text == "operator") return Role::kOperator;
  return std::nullopt;
}

bool role_may_send(Role role, std::string_view type) {
  // The message table says who sends what (common/messages.h, MessageDef::
  // from): a worker key what workers send, which is all a render node needs
  // to take, keep, finish and give back tasks; an operator key also what the
  // CLI sends. `status` is the CLI's: it shows every batch's paths and
  // workers, and worker keys sit on the most (and least guarded) hosts.
  const protocol::MessageDef* def = protocol::find_message(type);
  // A type nobody sends gets the coordinator's own error reply.
  if (def == nullptr) return role == Role::kOperator;
  if (def->from == "worker") return true;
  return role == Role::kOperator && def->from == "CLI";
}

std::optional<std::string> refusal_for(const char* user_id, std::string_view type) {
  if (user_id == nullptr) return std::nullopt;
  const std::optional<Role> role = role_from_string(user_id);
  if (!role) return "this client's key has no known role";
  if (role_may_send(*role, type)) return std::nullopt;
  return "a " + std::string(to_string(*role)) + " key may not send \"" + std::string(type) +
         "\" (use an operator key)";
}

std::vector<ClientKey> load_client_keys(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw SpecError(FileLoc{path.string()}, "", "cannot read the client allow-list");
  std::vector<ClientKey> keys;
  std::set<std::string> seen;
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    // Words with their 1-based columns.
    std::vector<std::pair<std::string, int>> words;
    for (size_t i = 0; i < line.size();) {
      if (line[i] == ' ' || line[i] == '\t') {
        ++i;
        continue;
      }
      size_t j = line.find_first_of(" \t", i);
      if (j == std::string::npos) j = line.size();
      words.emplace_back(line.substr(i, j - i), int(i) + 1);
      i = j;
    }
    if (words.empty() || words[0].first[0] == '#') continue;
    auto fail = [&](size_t word, const std::string& key, const std::string& message) {
      const int column = word < words.size() ? words[word].second : int(line.size()) + 1;
      throw SpecError(FileLoc{path.string(), number, column}, key, message);
    };
    ClientKey k;
    k.line = number;
    k.public_key = words[0].first;
    if (!is_z85_key(k.public_key))
      fail(0, "",
           "expected a Z85 CURVE public key (40 characters, as in NAME.pub), got \"" +
               k.public_key + "\"");
    if (words.size() < 2) fail(1, "", "expected a role after the key: worker or operator");
    const std::optional<Role> role = role_from_string(words[1].first);
    if (!role) fail(1, "", "expected the role worker or operator, got \"" + words[1].first + "\"");
    k.role = *role;
    if (words.size() > 2) k.name = words[2].first;
    if (words.size() > 3)
      fail(3, "", "expected PUBLIC_KEY ROLE [NAME], got more words (a name has no blanks)");
    if (!seen.insert(k.public_key).second) fail(0, "", "this key is listed twice");
    keys.push_back(std::move(k));
  }
  return keys;
}

}  // namespace dofarm::coordinator
