// Issue 10, defect 10: fail, don't hang. A standalone coordinator with two
// workers and a batch whose every task fails at the workers (its output
// folder turned into a plain file after submit, so no tile can be staged)
// used to stay `running` forever once both workers were blocklisted, with
// the reason only in the job store's events. Now the tasks fail for good,
// the batch fails after --stall-timeout with its reason, and the coordinator
// logs the failures and the blocklisting; `dofarm status` shows them.
#include <gtest/gtest.h>

#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

TEST(FarmStall, BatchFailingOnBothWorkersEndsFailedWithItsReason) {
  TempDir tmp;
  TinyJob job;
  job.tile = 8;  // 12 tiles a frame: more failing tasks than the blocklist needs
  const fs::path spec = write_job(tmp.path(), "job.toml", job);
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 5, {"--stall-timeout", "3"});
  const std::string ep = coord.endpoint();
  const fs::path out = tmp / "out";
  CliResult sub = run_cli(tmp.path(), "submit",
                          {"submit", spec.string(), "--coordinator", ep, "--out", out.string()});
  ASSERT_EQ(sub.status, 0) << sub.out << sub.err;
  const std::string batch = sub.out.substr(0, sub.out.find('\n'));
  // What submit accepted breaks at the workers: nothing can be written under
  // a plain file.
  fs::remove_all(out);
  write_text(out, "not a folder");

  Child w1 = start_worker(tmp.path(), ep, "w1");
  Child w2 = start_worker(tmp.path(), ep, "w2");
  ASSERT_TRUE(poll_until(
      "the batch to end", [&] { return batch_state(ep, batch) != "running"; }, 60))
      << coord.child().describe();

  CliResult st = run_cli(tmp.path(), "status", {"status", batch, "--coordinator", ep, "--json"});
  ASSERT_EQ(st.status, 0) << st.err;
  const Json b = batch_of(Json::parse(st.out), batch);
  EXPECT_EQ(b.at("state"), "failed") << b.dump(2);
  EXPECT_EQ(b.at("tasks_failed"), b.at("tasks_total")) << b.dump(2);
  EXPECT_EQ(b.at("blocklisted"), Json({"w1", "w2"})) << b.dump(2);
  const std::string reason = b.at("reason");
  EXPECT_NE(reason.find("no eligible worker"), std::string::npos) << reason;
  int naming_the_folder = 0;
  for (const Json& f : b.at("failed"))
    naming_the_folder += f.at("error").get<std::string>().find(out.string()) != std::string::npos;
  EXPECT_GT(naming_the_folder, 0) << "some error must name the output folder: " << b.dump(2);

  CliResult table = run_cli(tmp.path(), "status_table", {"status", batch, "--coordinator", ep});
  EXPECT_EQ(table.status, 0);
  EXPECT_NE(table.out.find("reason: "), std::string::npos) << table.out;
  EXPECT_NE(table.out.find("blocklisted workers:"), std::string::npos) << table.out;

  // The coordinator said so in its log, at warning level or above.
  const std::string log = coord.child().err() + coord.child().out();
  EXPECT_NE(log.find("w1 blocklisted for the batch"), std::string::npos) << log;
  EXPECT_NE(log.find("w2 blocklisted for the batch"), std::string::npos) << log;
  EXPECT_NE(log.find("failed for good"), std::string::npos) << log;
  EXPECT_NE(log.find("no eligible worker"), std::string::npos) << log;
}

}  // namespace
}  // namespace dofarm::farm_testing
