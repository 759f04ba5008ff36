// A worker's default thread count (--threads 0) is the CPUs it may run on,
// its affinity mask (under Slurm the job's allocation, under taskset the set
// given), resolved at start: the coordinator's status shows the number it
// renders with. Before, it counted every hardware thread of the machine and
// reported 0.
#include <gtest/gtest.h>

#include <map>
#include <string>

#include "tests/cpu_mask.h"
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

Child default_worker(const fs::path& dir, const std::string& endpoint, const std::string& id) {
  return Child(
      {"worker", "--connect", endpoint, "--id", id, "--heartbeat", "0.5", "--give-up", "120"},
      dir / (id + ".out"), dir / (id + ".err"));
}

TEST(FarmThreads, AWorkersDefaultIsTheCpusItMayRunOn) {
  dofarm::cpu_testing::CpuMask mask;
  if (mask.count() < 2) GTEST_SKIP() << "one CPU: nothing to narrow";
  TempDir tmp;
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 10);
  const std::string ep = coord.endpoint();

  Child all = default_worker(tmp.path(), ep, "all");
  // A child inherits the mask of the thread that forks it.
  ASSERT_TRUE(mask.narrow_to_one());
  Child narrow = default_worker(tmp.path(), ep, "one");
  ASSERT_TRUE(mask.restore());

  std::map<std::string, int> threads;
  Json status;
  ASSERT_TRUE(poll_until("both workers in the status", [&] {
    threads.clear();
    status = farm_status(ep);
    for (const Json& w : status.at("workers"))
      threads[w.at("worker").get<std::string>()] = w.at("threads").get<int>();
    return threads.size() == 2;
  })) << status.dump();
  EXPECT_EQ(threads["all"], mask.count());
  EXPECT_EQ(threads["one"], 1);
}

}  // namespace
}  // namespace dofarm::farm_testing
