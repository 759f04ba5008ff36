#include "common/messages.h"

#include <cmath>
#include <sstream>
#include <unordered_map>

#include "common/protocol.h"

namespace dofarm::protocol {

using Json = nlohmann::json;

// --- Builders ---------------------------------------------------------------

Field string_field(std::string name, size_t max_len, Charset charset, std::string doc) {
  Field f;
  f.name = std::move(name);
  f.type = FieldType::kString;
  f.max_len = max_len;
  f.charset = charset;
  f.doc = std::move(doc);
  if (charset == Charset::kHex32) f.min_len = f.max_len = 32;
  if (charset == Charset::kChecksum) f.min_len = f.max_len = 22;
  return f;
}

Field int_field(std::string name, int64_t min, int64_t max, std::string doc) {
  Field f;
  f.name = std::move(name);
  f.type = FieldType::kInt;
  f.min = double(min);
  f.max = double(max);
  f.doc = std::move(doc);
  return f;
}

Field number_field(std::string name, double min, double max, std::string doc) {
  Field f;
  f.name = std::move(name);
  f.type = FieldType::kNumber;
  f.min = min;
  f.max = max;
  f.doc = std::move(doc);
  return f;
}

Field bool_field(std::string name, std::string doc) {
  Field f;
  f.name = std::move(name);
  f.type = FieldType::kBool;
  f.doc = std::move(doc);
  return f;
}

Field array_field(std::string name, size_t max_items, Field item, std::string doc,
                  size_t min_items) {
  Field f;
  f.name = std::move(name);
  f.type = FieldType::kArray;
  f.min_len = min_items;
  f.max_len = max_items;
  f.doc = std::move(doc);
  f.children.push_back(std::move(item));
  return f;
}

Field object_field(std::string name, std::vector<Field> fields, std::string doc) {
  Field f;
  f.name = std::move(name);
  f.type = FieldType::kObject;
  f.doc = std::move(doc);
  f.children = std::move(fields);
  return f;
}

namespace {

Field nullable_number(std::string name, double min, double max, std::string doc) {
  Field f = number_field(std::move(name), min, max, std::move(doc));
  f.type = FieldType::kNullableNumber;
  return f;
}

// --- The definitions ----------------------------------------------------------

constexpr int64_t kMaxId64 = int64_t(1) << 53;  // exact in a double, and in JSON readers
constexpr int64_t kMaxInt32 = std::numeric_limits<int32_t>::max();

Field worker_id() {
  return string_field("worker", kMaxIdBytes, Charset::kId, "the worker's id (`--id`)");
}
Field task_id() { return int_field("task", 1, kMaxId64, "task id"); }
Field attempt() { return int_field("attempt", 1, kMaxInt32, "attempt number of the lease"); }
Field token() {
  return string_field("token", 32, Charset::kHex32,
                      "the lease token of this attempt, from its `task` message");
}
Field batch_id(std::string doc = "batch id") {
  return string_field("batch", kMaxIdBytes, Charset::kId, std::move(doc));
}
Field path_field(std::string name, std::string doc) {
  return string_field(std::move(name), kMaxPathBytes, Charset::kText, std::move(doc));
}
Field text_field(std::string name, std::string doc) {
  return string_field(std::move(name), kMaxTextBytes, Charset::kText, std::move(doc));
}
Field rect_field(std::string doc) {
  return array_field("rect", 4, int_field("", 0, kMaxInt32, ""), std::move(doc), 4);
}
Field checksum_field(std::string name, std::string doc) {
  return string_field(std::move(name), 22, Charset::kChecksum, std::move(doc));
}
Field seconds_field(std::string name, std::string doc) {
  return number_field(std::move(name), 0, 1e9, std::move(doc));
}
Field word_field(std::string name, std::string doc) {
  return string_field(std::move(name), 64, Charset::kWord, std::move(doc));
}

std::vector<MessageDef> make_defs() {
  std::vector<MessageDef> d;
  // Worker -> coordinator.
  d.push_back(
      {"request",
       "worker",
       "asks for work; also says the worker is alive",
       "`task`, `wait`, `shutdown` (embedded run finished) or `error`; with nothing to "
       "do it is parked up to `wait_seconds` (long poll)",
       {worker_id(), string_field("host", kMaxHostBytes, Charset::kId, "host name").optional(),
        int_field("threads", 0, 4096, "render threads").optional()}});
  d.push_back({"heartbeat",
               "worker",
               "extends the lease of a task the worker holds",
               "`ack` {ok: false when the lease is lost or the token is wrong}",
               {worker_id(), task_id(), attempt(), token()}});
  d.push_back({"done",
               "worker",
               "the task's output is written: a render tile's staged EXR or a pack's shard. The "
               "coordinator accepts it only when `staged_path` is exactly where this task's output "
               "belongs and is a regular file of `size` bytes whose checksum is `checksum`",
               "`ack` {status, message}: `accepted`, `duplicate`, `stale`, `unknown task`, or "
               "`refused` with the reason; a large file is checksummed in slices and answered when "
               "done",
               {worker_id(), task_id(), attempt(), token(),
                path_field("staged_path", "absolute path of the output"),
                int_field("size", 0, kMaxId64, "size of the output in bytes"),
                checksum_field("checksum", "XXH64 of the output's bytes"),
                seconds_field("seconds", "render time (0 for packs)")}});
  d.push_back({"failed",
               "worker",
               "the task failed on this worker",
               "`ack` {status}: `retry`, `failed for good`, `tile_requeued`, `stale`, "
               "`unknown task`, or `refused` (wrong token)",
               {worker_id(), task_id(), attempt(), token(),
                text_field("error", "what went wrong (clipped to the limit by the sender)"),
                path_field("bad_tile",
                           "pack: the staged tile that was missing or corrupt (not the "
                           "worker's fault: that tile is rendered again)")
                    .optional()}});
  d.push_back({"release",
               "worker",
               "hands a task back (SIGTERM, preemption); not a failure",
               "`ack` {ok}",
               {worker_id(), task_id(), attempt(), token()}});
  // CLI -> coordinator.
  d.push_back(
      {"submit",
       "CLI",
       "a job as a value: its snapshot (the text of job.json, docs/farm.md \"The job is "
       "a value\"), already copied with its files into `out_dir`/.dofarm-jobs/HASH. The "
       "coordinator plans a batch, returns the folder's batch of this same job, or "
       "refuses a folder that holds another job's batch",
       "`submitted` {batch, job, existing} or `error` {message, bad_input}",
       {string_field("snapshot", kMaxSnapshotTextBytes, Charset::kText, "job.json, compact JSON"),
        path_field("out_dir", "absolute output folder"),
        int_field("priority", kMinPriority, kMaxPriority,
                  "a new batch's priority, higher served first (" +
                      std::to_string(kDefaultPriority) + "); an existing batch keeps its own")
            .optional()}});
  d.push_back(
      {"status",
       "CLI",
       "the farm's state",
       "`status_reply`",
       {batch_id("only this batch").optional(),
        bool_field("tasks", "list the batches' tasks too (`tasks`, `tasks_omitted`)").optional(),
        word_field("state",
                   "with `tasks`: only tasks in this state (pending, leased, done, failed)")
            .optional(),
        int_field("limit", 1, 10000, "with `tasks`: at most this many in all, by id (1000)")
            .optional()}});
  d.push_back({"events",
               "CLI",
               "a batch's newest events, oldest first: leases, expiries, retries and failures "
               "with their text, blocklisting with its reason, submit, cancel, resume, the end",
               "`events_reply`",
               {batch_id(), int_field("limit", 1, 100000, "at most this many (100)").optional()}});
  d.push_back({"resume",
               "CLI",
               "runs a cancelled or failed batch again",
               "`ack` {ok, message}",
               {batch_id()}});
  d.push_back({"cancel",
               "CLI",
               "stops a batch; its leases are revoked",
               "`ack` {ok, message}",
               {batch_id()}});
  d.push_back({"priority",
               "CLI",
               "gives a batch another priority: the runnable tasks of higher-priority batches "
               "are handed out first, equal priorities oldest batch first; leases held are kept",
               "`ack` {ok, message}",
               {batch_id(), int_field("priority", kMinPriority, kMaxPriority,
                                      std::to_string(kMinPriority) + " (last) .. " +
                                          std::to_string(kMaxPriority) + " (first)")}});
  // Coordinator -> worker / CLI.
  Field input = object_field(
      "",
      {task_id(), int_field("frame", 0, kMaxInt32, "frame"), rect_field("x, y, w, h"),
       path_field("path", "staged tile path"), checksum_field("checksum", "its checksum")},
      "");
  d.push_back(
      {"task",
       "coordinator",
       "a lease: the task, its attempt and token, and what to do",
       "",
       {task_id(), attempt(), token(), word_field("kind", "`render_tile` or `pack_shard`"),
        batch_id(),
        string_field("job", 32, Charset::kHex32,
                     "the job hash: the worker renders `out_dir`/.dofarm-jobs/`job`, every file "
                     "checked against it"),
        path_field("out_dir", "output folder"),
        int_field("frame", -1, kMaxInt32, "render_tile: frame (-1 for packs)"),
        rect_field("render_tile: x, y, w, h"), int_field("shard", 0, kMaxInt32, "shard index"),
        string_field("shard_file", 255, Charset::kId, "shard file name in `out_dir`"),
        int_field("frame_start", 0, kMaxInt32, "pack_shard: first frame"),
        int_field("frame_end", 0, kMaxInt32, "pack_shard: last frame (inclusive)"),
        seconds_field("lease_seconds", "lease length; heartbeat well within it"),
        array_field("inputs", kMaxPackInputs, input,
                    "pack_shard: every staged tile of the shard's frames")}});
  d.push_back({"wait",
               "coordinator",
               "nothing to do now",
               "",
               {seconds_field("seconds", "ask again after this long")}});
  d.push_back({"ack",
               "coordinator",
               "answer to a worker's report or a CLI command",
               "",
               {bool_field("ok", "the command or heartbeat took effect").optional(),
                string_field("status", 64, Charset::kText, "outcome of done/failed").optional(),
                text_field("message", "why, or what was done").optional(),
                int_field("tiles_requeued", 0, kMaxId64, "resume: staged tiles rendered again")
                    .optional()}});
  d.push_back({"submitted",
               "coordinator",
               "a batch was recorded, or the folder's batch of this job",
               "",
               {batch_id(), string_field("job", 32, Charset::kHex32, "the job hash"),
                bool_field("existing", "the folder already held this job's batch")}});
  Field failed = object_field(
      "",
      {task_id(), word_field("kind", "task kind"), int_field("frame", -1, kMaxInt32, "frame"),
       rect_field("tile"), int_field("shard", 0, kMaxInt32, "shard"),
       text_field("error", "its last error"),
       text_field("reproduce", "a `dofarm render` command that reproduces it")},
      "");
  auto count = [](std::string name, std::string doc) {
    return int_field(std::move(name), 0, kMaxId64, std::move(doc));
  };
  Field task = object_field(
      "",
      {task_id(), word_field("kind", "task kind"), int_field("frame", -1, kMaxInt32, "frame"),
       rect_field("tile"), int_field("shard", 0, kMaxInt32, "shard"),
       word_field("state", "pending, leased, done, failed"),
       string_field("worker", kMaxIdBytes, Charset::kId,
                    "the lease holder, else the worker of its last attempt (empty: none)"),
       count("attempts", "leases handed out so far"), text_field("error", "its last error"),
       text_field("reproduce", "render_tile: a `dofarm render` command that renders it alone")},
      "");
  Field held = object_field("",
                            {task_id(), batch_id(), word_field("kind", "task kind"),
                             int_field("frame", -1, kMaxInt32, "frame (-1 for packs)"),
                             rect_field("tile"), int_field("shard", 0, kMaxInt32, "shard")},
                            "");
  Field batch = object_field(
      "",
      {batch_id(),
       word_field("state", "running, done, failed, cancelled"),
       int_field("priority", kMinPriority, kMaxPriority, "higher is served first").optional(),
       path_field("spec_path", "job TOML"),
       path_field("out_dir", "output folder"),
       number_field("created", 0, 1e12, "submission time (seconds since the epoch)"),
       count("tasks_total", ""),
       count("tasks_done", ""),
       count("tasks_failed", ""),
       count("tasks_leased", ""),
       count("tasks_pending", ""),
       count("frames_total", ""),
       count("frames_rendered", "every tile done"),
       count("frames_packed", "in a listed shard"),
       number_field("frames_per_hour", 0, 1e12, "over the last rate window"),
       nullable_number("eta_seconds", 0, 1e15, "null when unknown"),
       array_field("failed", 1000, failed, "tasks that failed for good (the first ones)"),
       count("failed_omitted", "failed tasks not listed (reply size bound)"),
       array_field("blocklisted", 1000, string_field("", kMaxIdBytes, Charset::kId, ""),
                   "workers blocklisted for the batch (the first ones)"),
       count("blocklisted_omitted", "blocklisted workers not listed"),
       text_field("reason", "why the batch failed, or why it is stalled").optional(),
       nullable_number("stalled_seconds", 0, 1e15, "seconds without an eligible worker").optional(),
       array_field("tasks", 10000, task, "`status` with `tasks`: the tasks asked for, by id")
           .optional(),
       count("tasks_omitted", "tasks that matched but are not listed (limit, size bound)")
           .optional()},
      "");
  Field worker = object_field(
      "",
      {worker_id(), string_field("host", kMaxHostBytes, Charset::kId, "host name"),
       int_field("threads", 0, 4096, "render threads"),
       number_field("last_seen", 0, 1e12, "seconds since the epoch"),
       bool_field("live", "heard from within one lease length and not gone"),
       array_field("tasks", 1000, task_id(), "tasks it holds (the first ones)"),
       word_field("state",
                  "live; lost: silent for more than one lease length; left: said "
                  "goodbye")
           .optional(),
       number_field("heartbeat_age", 0, 1e12, "seconds since the coordinator last heard from it")
           .optional(),
       count("tasks_done", "its attempts that ended done").optional(),
       count("tasks_failed", "its attempts that ended failed").optional(),
       array_field("current", 16, held, "tasks it holds, with their frame and tile").optional()},
      "");
  d.push_back(
      {"status_reply",
       "coordinator",
       "the farm's state, at most ~900 KiB: running batches first, then the newest; live "
       "workers first, then the most recently seen; what does not fit is counted, not listed",
       "",
       {number_field("now", 0, 1e12, "coordinator clock"),
        array_field("batches", 100000, batch, "batches, oldest first"),
        count("batches_omitted", "batches not listed (reply size bound)"),
        array_field("workers", 100000, worker, "known workers"),
        count("workers_omitted", "workers not listed (reply size bound)")}});
  Field event = object_field(
      "",
      {number_field("time", 0, 1e12, "seconds since the epoch"),
       word_field("level", "info, warn, error"),
       word_field("kind",
                  "lease, expired, retry, failed, blocklisted, submitted, finished, cancelled, "
                  "resumed, invalidated, late_result, priority (empty: an event older than "
                  "kinds)"),
       int_field("task", 0, kMaxId64, "the task it is about (0: none)"),
       string_field("worker", kMaxIdBytes, Charset::kId, "the worker it is about (empty: none)"),
       text_field("text", "what happened, with the error or reason")},
      "");
  d.push_back({"events_reply",
               "coordinator",
               "a batch's newest events, oldest first, at most ~900 KiB",
               "",
               {batch_id(), array_field("events", 100000, event, "oldest first"),
                count("events_omitted", "events left out (the oldest of those asked for) to keep the reply below its bound"),
                bool_field("older", "the job store holds older events than these")}});
  d.push_back({"error",
               "coordinator",
               "the message could not be handled",
               "",
               {text_field("message", "why"),
                bool_field("bad_input", "submit: the job itself is wrong").optional()}});
  d.push_back({"shutdown", "coordinator", "embedded run finished: the worker exits", "", {}});
  return d;
}

// --- Validation -------------------------------------------------------------

bool in_charset(std::string_view s, Charset c) {
  switch (c) {
    case Charset::kText:
      for (unsigned char ch : s)
        if ((ch < 0x20 && ch != '\t') || ch == 0x7f) return false;
      return true;
    case Charset::kId:
      for (unsigned char ch : s)
        if (!((ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
              ch == '.' || ch == '_' || ch == ':' || ch == '@' || ch == '+' || ch == '-'))
          return false;
      return true;
    case Charset::kHex32:
      for (unsigned char ch : s)
        if (!((ch >= '0' && ch <= '9') || (ch >= 'a' && ch <= 'f'))) return false;
      return true;
    case Charset::kChecksum:
      if (s.substr(0, 6) != "xxh64:") return false;
      return in_charset(s.substr(6), Charset::kHex32);
    case Charset::kWord:
      for (unsigned char ch : s)
        if (!((ch >= 'a' && ch <= 'z') || ch == '_')) return false;
      return true;
  }
  return false;
}

const char* charset_text(Charset c) {
  switch (c) {
    case Charset::kText:
      return "no control characters";
    case Charset::kId:
      return "`A-Z a-z 0-9 . _ : @ + -`";
    case Charset::kHex32:
      return "32 lowercase hex digits";
    case Charset::kChecksum:
      return "`xxh64:` + 16 lowercase hex digits";
    case Charset::kWord:
      return "`a-z _`";
  }
  return "?";
}

std::string shown(double v) {
  if (v == std::floor(v) && std::fabs(v) < 1e18) return std::to_string(int64_t(v));
  std::ostringstream o;
  o << v;
  return o.str();
}

[[noreturn]] void reject(const std::string& where, const std::string& what) {
  throw ProtocolError(where + ": " + what);
}

void check_value(const Field& f, const Json& v, const std::string& where);

void check_object(const std::vector<Field>& fields, const Json& v, const std::string& where,
                  bool top) {
  if (!v.is_object()) reject(where, "must be an object");
  size_t known = 0;
  for (const Field& f : fields) {
    auto it = v.find(f.name);
    if (it == v.end()) {
      if (f.required) reject(where, "missing field \"" + f.name + "\"");
      continue;
    }
    ++known;
    check_value(f, *it, where + "." + f.name);
  }
  const size_t expected = known + (top ? 2 : 0);  // "v" and "type"
  if (v.size() != expected) {
    for (auto it = v.begin(); it != v.end(); ++it) {
      if (top && (it.key() == "v" || it.key() == "type")) continue;
      bool listed = false;
      for (const Field& f : fields) listed = listed || f.name == it.key();
      if (!listed) reject(where, "unknown field \"" + clip_text(it.key(), 64) + "\"");
    }
  }
}

void check_value(const Field& f, const Json& v, const std::string& where) {
  switch (f.type) {
    case FieldType::kString: {
      if (!v.is_string()) reject(where, "must be a string");
      const std::string& s = v.get_ref<const std::string&>();
      if (s.size() > f.max_len)
        reject(where, "is " + std::to_string(s.size()) + " bytes, at most " +
                          std::to_string(f.max_len) + " allowed");
      if (s.size() < f.min_len)
        reject(where, "must be at least " + std::to_string(f.min_len) + " bytes");
      if (!in_charset(s, f.charset))
        reject(where, std::string("allows ") + charset_text(f.charset));
      return;
    }
    case FieldType::kInt: {
      if (!v.is_number_integer()) reject(where, "must be an integer");
      const double d =
          v.is_number_unsigned() ? double(v.get<uint64_t>()) : double(v.get<int64_t>());
      if (d < f.min || d > f.max)
        reject(where, "must be in [" + shown(f.min) + ", " + shown(f.max) + "]");
      return;
    }
    case FieldType::kNullableNumber:
      if (v.is_null()) return;
      [[fallthrough]];
    case FieldType::kNumber: {
      if (!v.is_number()) reject(where, "must be a number");
      const double d = v.get<double>();
      if (!std::isfinite(d) || d < f.min || d > f.max)
        reject(where, "must be a finite number in [" + shown(f.min) + ", " + shown(f.max) + "]");
      return;
    }
    case FieldType::kBool:
      if (!v.is_boolean()) reject(where, "must be true or false");
      return;
    case FieldType::kArray: {
      if (!v.is_array()) reject(where, "must be an array");
      if (v.size() > f.max_len || v.size() < f.min_len)
        reject(where, "has " + std::to_string(v.size()) + " items, allowed " +
                          std::to_string(f.min_len) + " to " + std::to_string(f.max_len));
      for (size_t i = 0; i < v.size(); ++i)
        check_value(f.children.at(0), v[i], where + "[" + std::to_string(i) + "]");
      return;
    }
    case FieldType::kObject:
      check_object(f.children, v, where, false);
      return;
  }
}

// --- Markdown ---------------------------------------------------------------

std::string type_text(const Field& f) {
  switch (f.type) {
    case FieldType::kString:
      return "string";
    case FieldType::kInt:
      return "integer";
    case FieldType::kNumber:
      return "number";
    case FieldType::kNullableNumber:
      return "number or null";
    case FieldType::kBool:
      return "bool";
    case FieldType::kArray:
      return "array of " + type_text(f.children.at(0));
    case FieldType::kObject:
      return "object";
  }
  return "?";
}

std::string limits_text(const Field& f) {
  switch (f.type) {
    case FieldType::kString:
      if (f.charset == Charset::kHex32 || f.charset == Charset::kChecksum)
        return charset_text(f.charset);
      return "≤ " + std::to_string(f.max_len) + " bytes, " + charset_text(f.charset);
    case FieldType::kInt:
    case FieldType::kNumber:
    case FieldType::kNullableNumber:
      return shown(f.min) + " … " + shown(f.max);
    case FieldType::kArray: {
      std::string s = f.min_len == f.max_len ? "exactly " + std::to_string(f.max_len) + " items"
                                             : "≤ " + std::to_string(f.max_len) + " items";
      const Field& item = f.children.at(0);
      if (item.type != FieldType::kObject) s += "; each " + limits_text(item);
      return s;
    }
    default:
      return "";
  }
}

void field_rows(const std::vector<Field>& fields, const std::string& prefix, std::ostream& o) {
  for (const Field& f : fields) {
    const std::string name = prefix + f.name;
    o << "| `" << name << "` | " << type_text(f) << " | " << (f.required ? "yes" : "no") << " | "
      << limits_text(f) << " | " << f.doc << " |\n";
    if (f.type == FieldType::kArray && f.children.at(0).type == FieldType::kObject)
      field_rows(f.children.at(0).children, name + "[].", o);
    if (f.type == FieldType::kObject) field_rows(f.children, name + ".", o);
  }
}

}  // namespace

const std::vector<MessageDef>& message_defs() {
  static const std::vector<MessageDef> defs = make_defs();
  return defs;
}

const MessageDef* find_message(std::string_view type) {
  static const std::unordered_map<std::string_view, const MessageDef*> index = [] {
    std::unordered_map<std::string_view, const MessageDef*> m;
    for (const MessageDef& d : message_defs()) m[d.type] = &d;
    return m;
  }();
  auto it = index.find(type);
  return it == index.end() ? nullptr : it->second;
}

void validate(const MessageDef& def, const Json& body) {
  check_object(def.fields, body, "\"" + def.type + "\"", true);
}

std::string clip_text(std::string_view text, size_t max_bytes) {
  size_t end = std::min(text.size(), max_bytes);
  // Never cut a UTF-8 sequence: back off while the first byte left out is a
  // continuation byte.
  while (end > 0 && end < text.size() && (static_cast<unsigned char>(text[end]) & 0xC0) == 0x80)
    --end;
  std::string out(text.substr(0, end));
  for (char& c : out) {
    const unsigned char u = static_cast<unsigned char>(c);
    if ((u < 0x20 && u != '\t') || u == 0x7f) c = ' ';
  }
  return out;
}

std::string protocol_markdown() {
  std::ostringstream o;
  o << "# The farm's wire protocol, version " << kVersion << "\n\n"
    << "<!-- Generated from the definitions in common/messages.cpp (protocol_markdown()); "
       "do not edit. test_common's ProtocolDoc.MatchesTheDefinitions fails when this file "
       "differs; DOFARM_UPDATE_PROTOCOL_DOC=1 test_common --gtest_filter=ProtocolDoc.* "
       "rewrites it. -->\n\n"
    << "One ZeroMQ frame per message, holding a JSON object with `\"v\": " << kVersion
    << "` and `\"type\"`, at most " << kMaxMessageBytes
    << " bytes (larger frames are dropped by ZeroMQ's `maxmsgsize`). Every message, in "
       "either direction, is checked against its definition below when it is encoded and "
       "when it is decoded: an unknown field, a missing required field, a wrong type, an "
       "oversized string or array, an out-of-range number or a character outside the "
       "field's set is an `error` reply; the coordinator never stops for a bad message.\n\n"
    << "Integers are JSON integers; numbers may be any finite JSON number. Lengths of strings "
       "are in bytes of UTF-8.\n";
  std::string section;
  for (const MessageDef& d : message_defs()) {
    const std::string s = d.from == "coordinator" ? "Replies (coordinator to worker or CLI)"
                                                  : "Requests from the " + d.from;
    if (s != section) {
      o << "\n## " << s << "\n";
      section = s;
    }
    std::string doc = d.doc;
    if (!doc.empty() && doc[0] >= 'a' && doc[0] <= 'z') doc[0] = char(doc[0] - 'a' + 'A');
    o << "\n### `" << d.type << "`\n\n" << doc << ".\n";
    if (!d.replies.empty()) o << "\nReply: " << d.replies << ".\n";
    if (d.fields.empty()) {
      o << "\nNo fields.\n";
      continue;
    }
    o << "\n| field | type | required | limits | meaning |\n| --- | --- | --- | --- | --- |\n";
    field_rows(d.fields, "", o);
  }
  return o.str();
}

}  // namespace dofarm::protocol
