// Staged tiles that went bad are found and rendered again: a real
// coordinator::Server driven in-process through handle(), as a worker would
// drive it over the wire, with the worker's own render_tile and pack_shard.
#include <gtest/gtest.h>

#include "common/checksum.h"
#include "coordinator/server.h"
#include "tests/farm/farm_fixtures.h"
#include "worker/render/scene.h"
#include "worker/tasks.h"

namespace dofarm::farm_testing {
namespace {

using coordinator::FakeClock;
using coordinator::Server;
using coordinator::ServerOptions;

Rect rect_of(const Json& j) {
  return Rect{j.at(0).get<int>(), j.at(1).get<int>(), j.at(2).get<int>(), j.at(3).get<int>()};
}

// One message through the server exactly as the receive loop does it: the
// request parsed from its wire form, the reply parsed back.
protocol::Message call(Server& server, const std::string& type, const Json& fields) {
  std::string payload = protocol::encode(type, fields);
  std::string reply = server.handle(protocol::parse(payload.data(), payload.size()));
  return protocol::parse(reply.data(), reply.size());
}

ServerOptions server_options(const fs::path& state) {
  ServerOptions so;
  so.listen = "tcp://127.0.0.1:*";
  so.state_dir = state;
  return so;
}

// The worker's side of the loop, in this process.
class LoopWorker {
 public:
  // Called with a pack task's job before it is packed (to damage a tile).
  std::function<void(const worker::ShardJob&)> before_pack;
  // Stop (without running it) at the first pack task.
  bool stop_at_pack = false;

  std::vector<std::pair<int, Rect>> rendered;  // (frame, rect) of each render
  std::vector<std::string> bad_tiles;          // paths of StagedTileErrors
  std::vector<std::string> bad_tile_acks;      // the coordinator's answers

  // Runs tasks until none is left to do; true when it stopped at a pack.
  bool run(Server& server, FakeClock& clock) {
    for (int step = 0; step < 500; ++step) {
      protocol::Message m =
          call(server, "request", {{"worker", "w-test"}, {"host", "test"}, {"threads", 1}});
      if (m.type == "wait") {
        if (server.idle()) return false;
        clock.advance(1);  // a back-off, if any, passes
        continue;
      }
      EXPECT_EQ(m.type, "task") << m.body.dump();
      if (m.type != "task") return false;
      const Json base = {{"worker", "w-test"},
                         {"task", m.integer("task")},
                         {"attempt", m.integer("attempt")},
                         {"token", m.str("token")}};
      const fs::path out_dir = m.str("out_dir");
      std::shared_ptr<const LoadedJob> job_value = jobs_.get(out_dir, m.str("job"));
      const JobSpec& spec = job_value->spec;
      if (m.str("kind") == "render_tile") {
        const int frame = m.body.at("frame").get<int>();
        const Rect rect = rect_of(m.body.at("rect"));
        render::RenderOptions opt;
        opt.threads = 1;
        auto scene = scenes_.get(spec, m.str("job"));
        worker::StagedTile t =
            worker::render_tile(spec, *scene, m.str("batch"), out_dir, frame, rect, opt);
        rendered.push_back({frame, rect});
        Json done = base;
        done["staged_path"] = t.path.string();
        done["checksum"] = checksum_to_string(t.checksum);
        done["size"] = fs::file_size(t.path);
        done["seconds"] = t.seconds;
        EXPECT_EQ(call(server, "done", done).body.value("status", ""), "accepted");
        continue;
      }
      if (stop_at_pack) return true;
      worker::ShardJob job;
      job.batch = m.str("batch");
      job.shard_index = m.body.at("shard").get<int>();
      job.frame_start = m.body.at("frame_start").get<int>();
      job.frame_end = m.body.at("frame_end").get<int>();
      job.file = m.str("shard_file");
      for (const Json& in : m.body.at("inputs")) {
        worker::StagedTile t;
        t.frame = in.at("frame").get<int>();
        t.rect = rect_of(in.at("rect"));
        t.path = in.at("path").get<std::string>();
        t.checksum = parse_checksum(in.at("checksum").get<std::string>()).value_or(0);
        job.tiles.push_back(t);
      }
      if (before_pack) before_pack(job);
      try {
        ManifestEntry e = worker::pack_shard(spec, out_dir, job);
        Json done = base;
        done["staged_path"] = (out_dir / e.file).string();
        done["checksum"] = checksum_to_string(e.checksum);
        done["size"] = e.size;
        done["seconds"] = 0.0;
        EXPECT_EQ(call(server, "done", done).body.value("status", ""), "accepted");
      } catch (const worker::StagedTileError& e) {
        bad_tiles.push_back(e.path().string());
        Json failed = base;
        failed["error"] = e.what();
        failed["bad_tile"] = e.path().string();
        bad_tile_acks.push_back(call(server, "failed", failed).body.value("status", ""));
      }
    }
    ADD_FAILURE() << "the batch did not finish in 500 steps";
    return false;
  }

 private:
  worker::JobCache jobs_;
  worker::SceneCache scenes_;
};

std::string submit(Server& server, const fs::path& job, const fs::path& out) {
  protocol::Message m =
      call(server, "submit", submit_fields(job, out));
  EXPECT_EQ(m.type, "submitted") << m.body.dump();
  return m.type == "submitted" ? m.str("batch") : "";
}

void truncate_half(const fs::path& p) { fs::resize_file(p, fs::file_size(p) / 2); }

void flip_middle_byte(const fs::path& p) {
  std::string bytes = read_text(p);
  ASSERT_FALSE(bytes.empty());
  bytes[bytes.size() / 2] ^= 0x5a;
  write_text(p, bytes);
}

void expect_bad_tile_rendered_again(const std::function<void(const fs::path&)>& damage) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});
  FakeClock clock;
  Server server(server_options(tmp / "state"), clock);
  const std::string batch = submit(server, job, tmp / "out");
  ASSERT_FALSE(batch.empty());

  LoopWorker w;
  std::string damaged;
  Rect damaged_rect;
  int damaged_frame = -1;
  w.before_pack = [&](const worker::ShardJob& j) {
    if (!damaged.empty()) return;  // once
    const worker::StagedTile& t = j.tiles.at(j.tiles.size() / 2);
    damaged = t.path.string();
    damaged_rect = t.rect;
    damaged_frame = t.frame;
    damage(t.path);
  };
  w.run(server, clock);
  ASSERT_FALSE(damaged.empty()) << "no pack task came";
  ASSERT_EQ(w.bad_tiles.size(), 1u) << "pack_shard must refuse the damaged tile";
  EXPECT_EQ(w.bad_tiles[0], damaged);
  EXPECT_EQ(w.bad_tile_acks[0], "tile_requeued");
  int renders = 0;
  for (const auto& [f, r] : w.rendered) renders += f == damaged_frame && r == damaged_rect;
  EXPECT_EQ(renders, 2) << "the damaged tile is rendered again, once";
  Json b = coordinator::status_to_json(server.scheduler().status(batch)).at("batches").at(0);
  EXPECT_EQ(b.at("state"), "done") << b.dump();
  EXPECT_EQ(b.at("tasks_failed"), 0) << "a bad staged tile is not the worker's failure";
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

TEST(FarmStaging, TruncatedStagedTileIsDetectedAtPackAndRenderedAgain) {
  expect_bad_tile_rendered_again(truncate_half);
}

TEST(FarmStaging, CorruptedStagedTileIsDetectedAtPackAndRenderedAgain) {
  expect_bad_tile_rendered_again(flip_middle_byte);
}

TEST(FarmStaging, TileCorruptedWhileTheCoordinatorIsDownIsRenderedAgainOnRestart) {
  TempDir tmp;
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});
  FakeClock clock;
  std::string batch;
  worker::StagedTile victim;
  {
    Server server(server_options(tmp / "state"), clock);
    batch = submit(server, job, tmp / "out");
    ASSERT_FALSE(batch.empty());
    LoopWorker w;
    w.stop_at_pack = true;  // the first shard's tiles are all staged now
    ASSERT_TRUE(w.run(server, clock)) << "no pack task came";
    const auto staged = server.scheduler().staged_tiles_to_verify(batch);
    ASSERT_FALSE(staged.empty());
    victim.path = staged.front().staged_path;
    victim.frame = staged.front().frame;
    victim.rect = staged.front().rect;
  }  // the coordinator goes away, holding the pack's lease
  flip_middle_byte(victim.path);

  Server server(server_options(tmp / "state"), clock);  // checks staged tiles on start
  LoopWorker w;
  w.run(server, clock);
  EXPECT_TRUE(w.bad_tiles.empty())
      << "the restarted coordinator handed out a pack of a bad tile: " << w.bad_tiles.front();
  int renders = 0;
  for (const auto& [f, r] : w.rendered) renders += f == victim.frame && r == victim.rect;
  EXPECT_EQ(renders, 1) << "the damaged tile is rendered again after the restart";
  Json b = coordinator::status_to_json(server.scheduler().status(batch)).at("batches").at(0);
  EXPECT_EQ(b.at("state"), "done") << b.dump();
  EXPECT_TRUE(shards_match_render(tmp / "out", job));
}

}  // namespace
}  // namespace dofarm::farm_testing
