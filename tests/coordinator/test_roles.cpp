// Roles under CURVE: which message types each role may send (from the message
// table), the receive loop's check of a frame's ZAP User-Id, and the
// allow-list file with its located errors. tests/farm/test_farm_roles.cpp
// runs the same against a real coordinator.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "common/error.h"
#include "common/transport.h"
#include "coordinator/roles.h"

namespace dofarm::coordinator {
namespace {

namespace fs = std::filesystem;

TEST(Roles, WorkersReportOperatorsAlsoSubmitStatusResumeCancel) {
  for (const char* t : {"request", "heartbeat", "done", "failed", "release"}) {
    EXPECT_TRUE(role_may_send(Role::kWorker, t)) << t;
    EXPECT_TRUE(role_may_send(Role::kOperator, t)) << t;
  }
  for (const char* t : {"submit", "status", "resume", "cancel"}) {
    EXPECT_FALSE(role_may_send(Role::kWorker, t)) << t;
    EXPECT_TRUE(role_may_send(Role::kOperator, t)) << t;
  }
  // Replies are the coordinator's; nobody sends them to it.
  for (const char* t : {"task", "ack", "status_reply"}) {
    EXPECT_FALSE(role_may_send(Role::kWorker, t)) << t;
    EXPECT_FALSE(role_may_send(Role::kOperator, t)) << t;
  }
  EXPECT_FALSE(role_may_send(Role::kWorker, "no_such_type"));
}

TEST(Roles, WithoutCurveEverythingIsAllowedWithAnUnknownRoleNothing) {
  EXPECT_FALSE(refusal_for(nullptr, "submit"));
  EXPECT_FALSE(refusal_for("operator", "cancel"));
  EXPECT_FALSE(refusal_for("worker", "done"));
  ASSERT_TRUE(refusal_for("worker", "submit"));
  EXPECT_EQ(*refusal_for("worker", "submit"),
            "a worker key may not send \"submit\" (use an operator key)");
  EXPECT_TRUE(refusal_for("", "request"));
  EXPECT_TRUE(refusal_for("admin", "request"));
}

class AllowList : public testing::Test {
 protected:
  fs::path write(const std::string& text) {
    const fs::path p =
        fs::temp_directory_path() / ("dofarm_roles_" + std::to_string(::getpid()) + "_" +
                                     testing::UnitTest::GetInstance()->current_test_info()->name());
    std::ofstream(p) << text;
    files_.push_back(p);
    return p;
  }
  SpecError error_of(const std::string& text) {
    const fs::path p = write(text);
    try {
      load_client_keys(p);
    } catch (const SpecError& e) {
      EXPECT_EQ(e.loc().file, p.string());
      return e;
    }
    ADD_FAILURE() << "accepted:\n" << text;
    return SpecError(FileLoc{}, "", "none");
  }
  void TearDown() override {
    for (const fs::path& p : files_) fs::remove(p);
  }
  std::vector<fs::path> files_;
  const std::string a = curve_keypair().first, b = curve_keypair().first;
};

TEST_F(AllowList, LinesCommentsAndBlanks) {
  const fs::path p =
      write("# farm clients\n\n" + a + " worker render-01\r\n  \t" + b + "\toperator\n");
  const std::vector<ClientKey> keys = load_client_keys(p);
  ASSERT_EQ(keys.size(), 2u);
  EXPECT_EQ(keys[0].public_key, a);
  EXPECT_EQ(keys[0].role, Role::kWorker);
  EXPECT_EQ(keys[0].name, "render-01");
  EXPECT_EQ(keys[0].line, 3);
  EXPECT_EQ(keys[1].public_key, b);
  EXPECT_EQ(keys[1].role, Role::kOperator);
  EXPECT_EQ(keys[1].name, "");
}

TEST_F(AllowList, BadLinesAreLocated) {
  SpecError role = error_of(a + " worker\n" + b + " root\n");
  EXPECT_EQ(role.loc().line, 2);
  EXPECT_EQ(role.loc().column, 42);
  SpecError key = error_of("  notakey worker\n");
  EXPECT_EQ(key.loc().line, 1);
  EXPECT_EQ(key.loc().column, 3);
  SpecError missing = error_of(a + "\n");
  EXPECT_EQ(missing.loc().line, 1);
  EXPECT_NE(std::string(missing.what()).find("expected a role"), std::string::npos);
  SpecError twice = error_of(a + " worker\n" + a + " operator\n");
  EXPECT_EQ(twice.loc().line, 2);
  SpecError extra = error_of(a + " worker two words\n");
  EXPECT_EQ(extra.loc().column, 53);
}

}  // namespace
}  // namespace dofarm::coordinator
