// The farm's messages, each defined once (STYLE.md 15): its fields, their
// types, ranges, length limits and character sets, required or optional.
// protocol::parse() checks every incoming message against its definition and
// protocol::encode() every outgoing one, so the coordinator, the worker and
// the CLI share one encoder, one decoder and one set of limits, and
// docs/protocol.md is rendered from the same table (protocol_markdown(); a
// test keeps the file equal to it).
//
// Strict by design: an unknown field, a missing required field, a wrong type,
// an oversized string or array, an out-of-range number or a character outside
// the field's set is a ProtocolError, which the receiver answers with an
// `error` reply. Adding a field means adding it here (and to the document).
#pragma once

#include <cstdint>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

namespace dofarm::protocol {

// Length limits shared by the definitions and by the code that clips texts
// before sending them (e.g. a worker's error message).
inline constexpr size_t kMaxIdBytes = 128;      // worker ids, batch ids
inline constexpr size_t kMaxHostBytes = 255;    // a host name (RFC 1035)
inline constexpr size_t kMaxPathBytes = 4096;   // PATH_MAX
inline constexpr size_t kMaxTextBytes = 4096;   // error texts, status messages
inline constexpr size_t kMaxOverrides = 256;    // --set KEY=VALUE per batch
inline constexpr size_t kMaxPackInputs = 5000;  // staged tiles of one shard (1 MiB frame)
inline constexpr size_t kMaxSnapshotTextBytes = 900 * 1024;  // a submitted job.json

// A batch's priority (Deadline's and Flamenco's 0-100): runnable tasks of a
// batch of higher priority are handed out before any of a lower one; equal
// priorities go oldest batch first.
inline constexpr int kMinPriority = 0;
inline constexpr int kMaxPriority = 100;
inline constexpr int kDefaultPriority = 50;

enum class FieldType { kString, kInt, kNumber, kBool, kArray, kObject, kNullableNumber };

// Which characters a string may hold.
enum class Charset {
  kText,      // any UTF-8 but NUL and other ASCII control characters except tab
  kId,        // A-Z a-z 0-9 . _ : @ + - (worker ids, host names, batch ids)
  kHex32,     // exactly 32 lowercase hex digits (lease tokens, job hashes)
  kChecksum,  // "xxh64:" + 16 lowercase hex digits
  kWord,      // a-z and _ (kinds, states)
};

struct Field {
  std::string name;
  FieldType type = FieldType::kString;
  bool required = true;
  std::string doc;
  size_t min_len = 0;  // strings: bytes; arrays: items
  size_t max_len = 0;
  double min = 0, max = 0;  // numbers, inclusive
  Charset charset = Charset::kText;
  std::vector<Field> children;  // array: one item definition; object: its fields

  Field optional() const {
    Field f = *this;
    f.required = false;
    return f;
  }
};

// Builders for the definition table.
Field string_field(std::string name, size_t max_len, Charset charset, std::string doc);
Field int_field(std::string name, int64_t min, int64_t max, std::string doc);
Field number_field(std::string name, double min, double max, std::string doc);
Field bool_field(std::string name, std::string doc);
Field array_field(std::string name, size_t max_items, Field item, std::string doc,
                  size_t min_items = 0);
Field object_field(std::string name, std::vector<Field> fields, std::string doc);

struct MessageDef {
  std::string type;
  std::string from;     // "worker", "CLI", "coordinator"
  std::string doc;      // what it means
  std::string replies;  // what answers it (requests only)
  std::vector<Field> fields;
};

// Every message, requests first.
const std::vector<MessageDef>& message_defs();
// The definition of `type`, or null.
const MessageDef* find_message(std::string_view type);
// Throws ProtocolError naming the message, the field path and the rule when
// `body` (the whole object, "v" and "type" included) breaks `def`.
void validate(const MessageDef& def, const nlohmann::json& body);

// `text` cut to at most `max_bytes` bytes at a UTF-8 character boundary, with
// control characters replaced by spaces: fits a kText field.
std::string clip_text(std::string_view text, size_t max_bytes = kMaxTextBytes);

// docs/protocol.md, rendered from message_defs().
std::string protocol_markdown();

}  // namespace dofarm::protocol
