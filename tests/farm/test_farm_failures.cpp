// A task that can never succeed fails for good after three distinct workers,
// with its error and a command that reproduces it, and the farm goes on with
// the other batches.
#include <gtest/gtest.h>

#include <set>

#include "common/job_snapshot.h"
#include "coordinator/job_store.h"
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

using coordinator::AttemptOutcome;
using coordinator::JobStore;

// The user's scene may vanish after submit (the batch renders its own copy),
// but the job's copy in the output folder may not: a worker that finds it
// gone cannot render, and says so.
TEST(FarmFailures, TaskWhoseJobCopyVanishedFailsForGoodAfterThreeWorkersAndTheFarmGoesOn) {
  TempDir tmp;
  fs::create_directories(tmp / "scene");
  fs::copy_file(cornell_scene(), tmp / "scene" / "cornell.gltf");
  fs::copy_file(cornell_scene().parent_path() / "cornell.bin", tmp / "scene" / "cornell.bin");
  TinyJob doomed;  // two one-tile frames: no worker fails three tasks of it
  doomed.scene = tmp / "scene" / "cornell.gltf";
  doomed.tile = 32;
  doomed.frame_end = 1;
  const fs::path doomed_job = write_job(tmp.path(), "doomed.toml", doomed);
  const fs::path healthy_job = write_job(tmp.path(), "healthy.toml", TinyJob{});

  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 2);
  const std::string ep = coord.endpoint();
  auto submit = [&](const fs::path& job, const std::string& out) {
    CliResult r =
        run_cli(tmp.path(), "submit_" + out,
                {"submit", job.string(), "--coordinator", ep, "--out", (tmp / out).string()});
    EXPECT_EQ(r.status, 0) << r.out << r.err;
    return r.out.substr(0, r.out.find('\n'));
  };
  const std::string bad = submit(doomed_job, "out_doomed");
  const fs::path job_folder = job_dir(tmp / "out_doomed", read_output_owner(tmp / "out_doomed")->job);
  const fs::path vanished = job_folder / "files" / "cornell.gltf";
  ASSERT_TRUE(fs::remove(vanished));
  const std::string good = submit(healthy_job, "out_healthy");
  ASSERT_FALSE(bad.empty());
  ASSERT_FALSE(good.empty());

  Child w1 = start_worker(tmp.path(), ep, "w1");
  Child w2 = start_worker(tmp.path(), ep, "w2");
  Child w3 = start_worker(tmp.path(), ep, "w3");
  ASSERT_TRUE(poll_until("both batches to finish", [&] {
    Json st = farm_status(ep);
    return batch_of(st, bad).at("state") != "running" &&
           batch_of(st, good).at("state") != "running";
  })) << coord.child().describe();

  CliResult st = run_cli(tmp.path(), "status", {"status", "--coordinator", ep, "--json"});
  ASSERT_EQ(st.status, 0) << st.err;
  const Json status = Json::parse(st.out);
  const Json b = batch_of(status, bad);
  EXPECT_EQ(b.at("state"), "failed") << b.dump(2);
  EXPECT_EQ(b.at("tasks_done"), 0);
  EXPECT_EQ(b.at("tasks_failed"), b.at("tasks_total"));
  EXPECT_TRUE(b.at("blocklisted").empty()) << b.dump(2);
  int render_failures = 0;
  std::vector<int64_t> failed_renders;
  for (const Json& f : b.at("failed")) {
    const std::string error = f.at("error");
    EXPECT_NE(error.find(vanished.string()), std::string::npos)
        << "the error must name the missing file: " << error;
    if (f.at("kind") != "render_tile") continue;
    ++render_failures;
    failed_renders.push_back(f.at("task"));
    const std::string repro = f.at("reproduce");
    EXPECT_EQ(repro.rfind("dofarm render ", 0), 0u) << repro;
    EXPECT_NE(repro.find((job_folder / "job.toml").string()), std::string::npos) << repro;
    EXPECT_NE(repro.find("--frame " + std::to_string(f.at("frame").get<int>())), std::string::npos)
        << repro;
    EXPECT_NE(repro.find("--tile 0,0,32,24"), std::string::npos) << repro;
  }
  EXPECT_EQ(render_failures, 2) << b.dump(2);

  // The human-readable status shows them as well.
  CliResult table = run_cli(tmp.path(), "status_table", {"status", bad, "--coordinator", ep});
  EXPECT_EQ(table.status, 0);
  EXPECT_NE(table.out.find("FAILED task"), std::string::npos) << table.out;
  EXPECT_NE(table.out.find("reproduce: dofarm render"), std::string::npos) << table.out;

  const Json g = batch_of(status, good);
  EXPECT_EQ(g.at("state"), "done") << g.dump(2);
  EXPECT_TRUE(shards_match_render(tmp / "out_healthy", healthy_job));
  EXPECT_FALSE(fs::exists(tmp / "out_doomed" / kManifestFile));

  coord.child().kill9();
  JobStore store(tmp / "state" / "dofarm.sqlite");
  for (int64_t task : failed_renders) {
    std::set<std::string> workers;
    for (const auto& a : store.attempts(task)) {
      EXPECT_EQ(a.outcome, AttemptOutcome::kFailed) << "task " << task << " by " << a.worker;
      workers.insert(a.worker);
    }
    EXPECT_EQ(workers, (std::set<std::string>{"w1", "w2", "w3"})) << "task " << task;
    EXPECT_EQ(store.attempts(task).size(), 3u) << "task " << task;
  }
}

}  // namespace
}  // namespace dofarm::farm_testing
