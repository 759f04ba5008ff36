// A worker's default thread count (--threads 0) is the CPUs it may run on,
// its affinity mask (under Slurm the job's allocation, under taskset the set
// given), resolved at start: the coordinator's status shows the number it
// renders with. Before, it counted every hardware thread of the machine and
// reported 0.
#include <gtest/gtest.h>
#include <sched.h>

#include <map>
#include <string>

#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

Child default_worker(const fs::path& dir, const std::string& endpoint, const std::string& id) {
  return Child(
      {"worker", "--connect", endpoint, "--id", id, "--heartbeat", "0.5", "--give-up", "120"},
      dir / (id + ".out"), dir / (id + ".err"));
}

TEST(FarmThreads, AWorkersDefaultIsTheCpusItMayRunOn) {
  cpu_set_t saved;
  CPU_ZERO(&saved);
  ASSERT_EQ(sched_getaffinity(0, sizeof(saved), &saved), 0);
  if (CPU_COUNT(&saved) < 2) GTEST_SKIP() << "one CPU: nothing to narrow";
  TempDir tmp;
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 10);
  const std::string ep = coord.endpoint();

  Child all = default_worker(tmp.path(), ep, "all");
  // A child inherits the mask of the thread that forks it.
  int first = 0;
  while (!CPU_ISSET(first, &saved)) ++first;
  cpu_set_t one;
  CPU_ZERO(&one);
  CPU_SET(first, &one);
  ASSERT_EQ(sched_setaffinity(0, sizeof(one), &one), 0);
  Child narrow = default_worker(tmp.path(), ep, "one");
  ASSERT_EQ(sched_setaffinity(0, sizeof(saved), &saved), 0);

  std::map<std::string, int> threads;
  Json status;
  ASSERT_TRUE(poll_until("both workers in the status", [&] {
    threads.clear();
    status = farm_status(ep);
    for (const Json& w : status.at("workers"))
      threads[w.at("worker").get<std::string>()] = w.at("threads").get<int>();
    return threads.size() == 2;
  })) << status.dump();
  EXPECT_EQ(threads["all"], CPU_COUNT(&saved));
  EXPECT_EQ(threads["one"], 1);
}

}  // namespace
}  // namespace dofarm::farm_testing
