// `dofarm inspect` of a shard (common/inspect.h): the text and JSON reports
// with exact statistics, and the exit codes of what is not a readable shard.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "common/inspect.h"
#include "common/shard.h"
#include "shard_fixtures.h"

namespace dofarm {
namespace {

using namespace shard_testing;

TEST(Inspect, TextReportHasShapesStatsAndNoNonFiniteValues) {
  TempDir dir;
  write_shard(dir.path() / "s.h5", make_info(), make_frames());
  std::ostringstream out, err;
  EXPECT_EQ(inspect_shard(dir.path() / "s.h5", false, out, err), kExitOk) << err.str();
  std::string s = out.str();
  EXPECT_NE(s.find("dofarm.shard/3"), std::string::npos) << s;
  EXPECT_NE(s.find("3x2x3x50x70"), std::string::npos) << s;  // noisy shape
  EXPECT_NE(s.find("1x1x3x50x64"), std::string::npos) << s;  // noisy chunk
  EXPECT_NE(s.find("shuffle,deflate(4),fletcher32"), std::string::npos) << s;
  EXPECT_NE(s.find("non-finite values: 0"), std::string::npos) << s;
  EXPECT_NE(s.find(" ok\n"), std::string::npos) << s;
}

TEST(Inspect, JsonReportParsesAndHoldsExactStatistics) {
  TempDir dir;
  auto frames = make_frames();
  write_shard(dir.path() / "s.h5", make_info(), frames);
  std::ostringstream out, err;
  ASSERT_EQ(inspect_shard(dir.path() / "s.h5", true, out, err), kExitOk) << err.str();
  nlohmann::json j = nlohmann::json::parse(out.str());
  EXPECT_EQ(j["attributes"]["schema"], "dofarm.shard/3");
  EXPECT_EQ(j["attributes"]["job_hash"], make_info().job_hash);
  EXPECT_EQ(j["frames"], kFrames);
  EXPECT_EQ(j["non_finite"], 0);
  EXPECT_TRUE(j["data_checksum"]["ok"].get<bool>());
  // depth is buffer 6: value 6e6 + frame * 40000 + i over i < W*H, frames 10..12.
  const nlohmann::json* depth = nullptr;
  for (const auto& d : j["datasets"])
    if (d["name"] == "depth") depth = &d;
  ASSERT_NE(depth, nullptr);
  const auto& c = (*depth)["channels"][0];
  EXPECT_EQ(c["name"], "Y");
  EXPECT_EQ(c["min"].get<double>(), 6e6 + 10 * 40000);
  EXPECT_EQ(c["max"].get<double>(), 6e6 + 12 * 40000 + kW * kH - 1);
  EXPECT_NEAR(c["mean"].get<double>(), 6e6 + 11 * 40000 + (kW * kH - 1) / 2.0, 1e-6);
  // Independent std: over frames f in {10,11,12} and i in [0, N).
  double n = kW * kH, var_i = (n * n - 1) / 12.0, var_f = 40000.0 * 40000.0 * 2.0 / 3.0;
  EXPECT_NEAR(c["std"].get<double>(), std::sqrt(var_i + var_f), 1e-6);
  EXPECT_EQ(c["non_finite"], 0);
  EXPECT_GT((*depth)["compression_ratio"].get<double>(), 1.0);
}

TEST(Inspect, ExitCodesSayNotAShardOrIoError) {
  TempDir dir;
  std::ostringstream out, err;
  std::ofstream(dir.path() / "notes.h5") << "plain text";
  EXPECT_EQ(inspect_shard(dir.path() / "notes.h5", false, out, err), kExitBadInput);
  EXPECT_NE(err.str().find("not an HDF5 file"), std::string::npos) << err.str();
  EXPECT_EQ(inspect_shard(dir.path() / "missing.h5", false, out, err), kExitRuntime);
  write_shard(dir.path() / "s.h5", make_info(), make_frames());
  corrupt_middle(dir.path() / "s.h5", 16);
  std::ostringstream jout;
  EXPECT_EQ(inspect_shard(dir.path() / "s.h5", true, jout, err), kExitRuntime);
  EXPECT_TRUE(nlohmann::json::parse(jout.str()).contains("error")) << jout.str();
}

}  // namespace
}  // namespace dofarm
