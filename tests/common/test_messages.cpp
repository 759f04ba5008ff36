// The message definitions (common/messages.h): every malformed field is a
// ProtocolError naming it, in both directions, and docs/protocol.md is
// rendered from the same table.
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include "common/messages.h"
#include "common/protocol.h"

namespace dofarm::protocol {
namespace {

const std::string kToken(32, 'a');

Json done_message() {
  return {{"v", 1},
          {"type", "done"},
          {"worker", "w-1"},
          {"task", 7},
          {"attempt", 1},
          {"token", kToken},
          {"staged_path", "/out/.staging/b-1/f00000_x0_y0_w16_h16.exr"},
          {"size", 1234},
          {"checksum", "xxh64:0123456789abcdef"},
          {"seconds", 0.5}};
}

// The error parse() gives `j`, or "" when it is accepted.
std::string parse_error(const Json& j) {
  const std::string s = j.dump();
  try {
    parse(s.data(), s.size());
    return "";
  } catch (const ProtocolError& e) {
    return e.what();
  }
}

TEST(Messages, AWellFormedDoneIsAccepted) { EXPECT_EQ(parse_error(done_message()), ""); }

TEST(Messages, EveryWrongFieldIsRefusedByName) {
  struct Case {
    const char* field;
    Json value;
    const char* says;
  };
  const std::vector<Case> cases = {
      {"worker", std::string(129, 'w'), "\"done\".worker: is 129 bytes, at most 128"},
      {"worker", "w 1", "\"done\".worker: allows"},
      {"worker", 5, "\"done\".worker: must be a string"},
      {"task", 0, "\"done\".task: must be in [1,"},
      {"task", -3, "\"done\".task: must be in [1,"},
      {"task", 1.5, "\"done\".task: must be an integer"},
      {"attempt", int64_t(1) << 40, "\"done\".attempt: must be in [1, 2147483647]"},
      {"token", "ABCDEF", "\"done\".token: must be at least 32 bytes"},
      {"token", std::string(32, 'G'), "\"done\".token: allows 32 lowercase hex digits"},
      {"staged_path", std::string(5000, 'p'), "\"done\".staged_path: is 5000 bytes, at most 4096"},
      {"staged_path", "a\nb", "\"done\".staged_path: allows no control characters"},
      {"size", -1, "\"done\".size: must be in [0,"},
      {"checksum", "md5:00", "\"done\".checksum"},
      {"seconds", "fast", "\"done\".seconds: must be a number"},
      {"seconds", -1.0, "\"done\".seconds: must be a finite number in [0,"},
      {"extra", 1, "\"done\": unknown field \"extra\""},
  };
  for (const Case& c : cases) {
    Json j = done_message();
    j[c.field] = c.value;
    const std::string e = parse_error(j);
    EXPECT_NE(e.find(c.says), std::string::npos) << c.field << ": got \"" << e << "\"";
  }
  for (const char* field :
       {"worker", "task", "attempt", "token", "staged_path", "size", "checksum", "seconds"}) {
    Json j = done_message();
    j.erase(field);
    EXPECT_EQ(parse_error(j), std::string("\"done\": missing field \"") + field + "\"");
  }
}

TEST(Messages, NestedItemsAndArraysAreChecked) {
  Json submit = {{"v", 1}, {"type", "submit"}, {"snapshot", "{}"}, {"out_dir", "/out"}};
  EXPECT_EQ(parse_error(submit), "");
  Json status = {{"v", 1}, {"type", "status"}, {"batch", "b-12345678"}};
  EXPECT_EQ(parse_error(status), "");
  status["batch"] = Json::array();
  EXPECT_NE(parse_error(status).find("\"status\".batch: must be a string"), std::string::npos);
  // A task whose pack inputs are malformed: the path of the bad item is named.
  Json task = {{"v", 1},
               {"type", "task"},
               {"task", 3},
               {"attempt", 1},
               {"token", kToken},
               {"kind", "pack_shard"},
               {"batch", "b-1"},
               {"job", kToken},
               {"out_dir", "/out"},
               {"frame", -1},
               {"rect", {0, 0, 0, 0}},
               {"shard", 0},
               {"shard_file", "shard-00000.h5"},
               {"frame_start", 0},
               {"frame_end", 1},
               {"lease_seconds", 30},
               {"inputs", Json::array({{{"task", 1},
                                        {"frame", 0},
                                        {"rect", {0, 0, 16, 16}},
                                        {"path", "/out/x.exr"},
                                        {"checksum", "xxh64:0123456789abcdef"}}})}};
  EXPECT_EQ(parse_error(task), "");
  task["inputs"][0]["rect"] = {0, 0, 16};
  EXPECT_NE(parse_error(task).find("\"task\".inputs[0].rect: has 3 items, allowed 4 to 4"),
            std::string::npos)
      << parse_error(task);
}

TEST(Messages, TheEncoderHoldsTheSenderToTheDefinition) {
  EXPECT_THROW(encode("heartbeat", {{"worker", "w"}, {"task", 1}, {"attempt", 1}}), ProtocolError);
  EXPECT_THROW(encode("no_such_message"), ProtocolError);
  EXPECT_THROW(encode("error", {{"message", std::string(100000, 'x')}}), ProtocolError);
  // error_reply() clips its text to the limit instead.
  const std::string e = error_reply(std::string(100000, 'x'));
  EXPECT_EQ(parse(e.data(), e.size()).str("message").size(), kMaxTextBytes);
}

TEST(Messages, ClipTextFitsATextFieldWithoutCuttingACharacter) {
  const std::string s = "ab\n\xc3\xa9\xc3\xa9";  // a b LF é é
  EXPECT_EQ(clip_text(s, 5), "ab \xc3\xa9");
  EXPECT_EQ(clip_text(s, 4), "ab ");
  EXPECT_EQ(clip_text(s, 100), "ab \xc3\xa9\xc3\xa9");
}

// docs/protocol.md is the rendering of the definitions; regenerate it with
// DOFARM_UPDATE_PROTOCOL_DOC=1 build/tests/test_common --gtest_filter=ProtocolDoc.*
TEST(ProtocolDoc, MatchesTheDefinitions) {
  const std::string path = std::string(DOFARM_SOURCE_DIR) + "/docs/protocol.md";
  const std::string expected = protocol_markdown();
  if (std::getenv("DOFARM_UPDATE_PROTOCOL_DOC")) std::ofstream(path, std::ios::binary) << expected;
  std::ifstream in(path, std::ios::binary);
  std::stringstream got;
  got << in.rdbuf();
  EXPECT_TRUE(got.str() == expected)
      << path << " differs from protocol_markdown() (common/messages.cpp); regenerate it with "
      << "DOFARM_UPDATE_PROTOCOL_DOC=1 test_common --gtest_filter=ProtocolDoc.*";
}

}  // namespace
}  // namespace dofarm::protocol
