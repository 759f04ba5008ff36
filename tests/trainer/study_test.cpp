// bench/trainer/dof_study.sh end to end at smoke scale: the real script, the
// real dofarm-train, a synthetic shard; tiny models and 2 steps, so it takes
// seconds. It checks what the script promises (a row with finite numbers for
// every configuration, the plot) and that a second run resumes instead of
// training again; never a score or a timing.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "synthetic.h"
#include "trainer/config.h"

namespace dofarm::trainer {
namespace {

namespace fs = std::filesystem;

std::string read_all(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::vector<std::string> split(const std::string& line, char sep) {
  std::vector<std::string> out;
  std::string cell;
  std::istringstream is(line);
  while (std::getline(is, cell, sep)) out.push_back(cell);
  return out;
}

// A scratch folder `name` whose data/ holds one synthetic shard: 12 frames
// of 64 x 64, 2 noisy versions.
fs::path study_dir(const char* name) {
  const fs::path dir = testing::scratch_dir(name);
  fs::create_directories(dir / "data");
  testing::write_synthetic_shard(dir / "data" / "shard-00000.h5", 12, 64, 64, 2, 5);
  return dir;
}

// `widths`: the encoder widths every configuration is shrunk to (tiny and
// fast); empty: each keeps its own.
int run_study(const fs::path& data, const fs::path& out, const fs::path& log,
              const std::string& configs = "", const std::string& extra = "",
              const std::string& last = "", const std::string& widths = "[8, 8, 8, 8, 8]") {
  const std::string cmd =
      std::string("DOFARM_TRAIN=") + DOFARM_TRAIN_EXE +
#ifdef DOFARM_EXE
      " DOFARM=" + DOFARM_EXE +
#endif
      " bash " + DOFARM_SOURCE_DIR +
      "/bench/trainer/dof_study.sh --steps 2 --epochs 1 --time-size 64 --out " + out.string() +
      (configs.empty() ? "" : " --configs '" + configs + "'") + extra +
      (widths.empty() ? "" : " --set 'model.channels=" + widths + "'") +
      " --set data.crop=32 --set data.sequence=3"
      " --set data.val_fraction=0.25 --set data.readers=1 --set data.queue=4"
      " --set train.batch=2 --set train.val_sequences=1 --set train.device=cpu " +
      last + " " + data.string() + " > " + log.string() + " 2>&1";
  const int rc = std::system(cmd.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

TEST(Study, OneCommandScoresEveryConfigurationAndResumes) {
  const fs::path dir = testing::scratch_dir("study");
  // 12 frames of 3-frame sequences, one of them validation (val_fraction 0.25).
  fs::create_directories(dir / "data");
  testing::write_synthetic_shard(dir / "data" / "shard-00000.h5", 12, 64, 64, 2, 5);
  const fs::path out = dir / "out";
  ASSERT_EQ(run_study(dir / "data", out, dir / "first.log"), 0) << read_all(dir / "first.log");

  const std::vector<std::string> configs = {"thesis",       "thesis_nococ",     "default",
                                            "thesis_focus", "thesis_prefilter", "thesis_recurrent"};
  std::ifstream csv(out / "results.csv");
  std::string line;
  ASSERT_TRUE(std::getline(csv, line));
  const std::vector<std::string> header = split(line, ',');
  ASSERT_EQ(header.size(), 22u) << line;
  EXPECT_EQ(header[21], "denoise_threads");
  EXPECT_EQ(header[15], "ssim_coc_1_4");
  EXPECT_EQ(header[17], "ssim_coc_16_up");
  EXPECT_EQ(header[18], "ms_per_64px_frame");
  std::map<std::string, std::vector<std::string>> rows;
  while (std::getline(csv, line))
    if (!line.empty()) rows[split(line, ',')[0]] = split(line, ',');
  ASSERT_EQ(rows.size(), configs.size());
  for (const std::string& c : configs) {
    ASSERT_TRUE(rows.count(c)) << c;
    const std::vector<std::string>& r = rows[c];
    ASSERT_EQ(r.size(), header.size()) << c;
    EXPECT_EQ(r[2], "3") << c;  // validation frames
    // Every score is finite but that of the CoC band no pixel falls in (the
    // synthetic CoC stays below 8 px): none, not 0.
    for (size_t i = 3; i < r.size(); ++i)
      EXPECT_EQ(std::isfinite(std::stod(r[i])), header[i] != "ssim_coc_16_up")
          << c << " " << header[i] << " = " << r[i];
    EXPECT_EQ(r[19], "2") << c;           // steps
    EXPECT_GE(std::stod(r[21]), 1) << c;  // the threads the denoise was timed on
    // The configuration is what its name says.
    // (configuration, text its config.toml holds or, for the no-CoC
    // network, must not hold)
    const std::map<std::string, std::pair<std::string, bool>> says = {
        {"thesis_nococ", {"coc:thesis", false}},
        {"thesis", {"coc:thesis", true}},
        {"thesis_focus", {"focus_weight = 4", true}},
        {"thesis_prefilter", {"albedo_prefilter = 'coc'", true}},
        {"thesis_recurrent", {"recurrent = true", true}},
        {"default", {"coc:log", true}},
    };
    const std::string cfg = read_all(out / "runs" / c / "config.toml");
    const auto& [text, present] = says.at(c);
    EXPECT_EQ(cfg.find(text) != std::string::npos, present) << c << ": " << text;
  }
  const std::string md = read_all(out / "results.md");
  for (const std::string& c : configs) EXPECT_NE(md.find("`" + c + "`"), std::string::npos) << c;
  // SSIM by circle of confusion, and the CoC input's gain per band for the
  // pair that was run with and without it (thesis, thesis_nococ).
  EXPECT_NE(md.find("SSIM by circle of confusion"), std::string::npos) << md;
  EXPECT_NE(md.find("| CoC input: `thesis` − `thesis_nococ` | "), std::string::npos) << md;
  EXPECT_EQ(md.find("CoC input: `default`"), std::string::npos) << md;  // no default_nococ run
  // Its 95% interval from the paired tile bootstrap: one cell per region.
  const size_t boot = md.find("| `thesis` − `thesis_nococ` | ");
  ASSERT_NE(boot, std::string::npos) << md;
  const std::string boot_row = md.substr(boot, md.find('\n', boot) - boot);
  // All, out of focus and the bands but >= 16 px, where no synthetic pixel falls.
  EXPECT_EQ(split(boot_row, '[').size(), 6u) << boot_row;
  EXPECT_NE(boot_row.find("| – |"), std::string::npos) << boot_row;
  // The CoC probe: every configuration with a CoC input, fed CoC 0.
  EXPECT_NE(md.find("The CoC probe"), std::string::npos) << md;
  for (const std::string& c : configs) {
    const bool reads_coc = c != "thesis_nococ";
    EXPECT_EQ(md.find("| `" + c + "` fed CoC 0 | ") != std::string::npos, reads_coc) << c;
    EXPECT_EQ(fs::exists(out / "reports" / (c + "-coc0") / "report.json"), reads_coc) << c;
  }
  // Side-by-side crops: one picture per configuration of the same window,
  // beside the noisy input and the reference, gathered in OUT/crops.
  for (const std::string& c : configs) {
    const std::string pic = "crops/crop-0-out_of_focus-" + c + ".png";
    EXPECT_NE(md.find("](" + pic + ")"), std::string::npos) << pic;
    EXPECT_TRUE(fs::exists(out / pic)) << pic;
  }
  for (const char* kind : {"noisy", "reference"})
    EXPECT_TRUE(fs::exists(out / (std::string("crops/crop-0-out_of_focus-") + kind + ".png")));
  const std::string svg = read_all(out / "results.svg");
  EXPECT_NE(svg.find("<svg"), std::string::npos);
  size_t points = 0;  // one dot on the plot and one in the legend per configuration
  for (size_t at = svg.find("<circle"); at != std::string::npos; at = svg.find("<circle", at + 1))
    ++points;
  EXPECT_EQ(points, 2 * configs.size());

  // A second run resumes: nothing is trained or evaluated again.
  std::map<std::string, fs::file_time_type> before;
  for (const std::string& c : configs)
    before[c] = fs::last_write_time(out / "runs" / c / "checkpoints" / "last.pt");
  ASSERT_EQ(run_study(dir / "data", out, dir / "second.log"), 0) << read_all(dir / "second.log");
  const std::string second = read_all(dir / "second.log");
  for (const std::string& c : configs) {
    EXPECT_NE(second.find(c + ": trained (2 steps), not trained again"), std::string::npos)
        << second;
    EXPECT_NE(second.find(c + ": evaluated, not evaluated again"), std::string::npos) << second;
    if (c != "thesis_nococ") {
      EXPECT_NE(second.find(c + ": CoC probe done, not made again"), std::string::npos) << second;
    }
    EXPECT_EQ(fs::last_write_time(out / "runs" / c / "checkpoints" / "last.pt"), before[c]) << c;
  }
  EXPECT_EQ(read_all(out / "results.md"), md);  // the same table again
}

// `study_tables.py paired`, on two reports written here: where every tile of
// every frame differs by the same SSIM per window value, the difference is
// that value and the interval shrinks to it; where the tiles differ
// unevenly, the point is the reports' own difference (the mean over frames
// of count-weighted tile means) and the interval holds it and has a width.
// Frames are matched by shard and frame; one only A scored is left out.
TEST(Study, PairedBootstrapOverTilesKnownAnswers) {
  const fs::path dir = testing::scratch_dir("study_paired");
  // frames[f] = per tile (sum A, sum B, count) of region "all"
  auto write = [&](const char* name, const std::vector<std::vector<std::array<double, 3>>>& frames,
                   int which, bool extra) {
    std::ofstream f(dir / name);
    f << "{\"frames\": [";
    for (size_t k = 0; k < frames.size() + (extra ? 1 : 0); ++k) {
      if (k) f << ",";
      f << "{\"shard\": \"s.h5\", \"frame\": " << k
        << ", \"denoised_tiles\": {\"tile\": 32, \"regions\": {\"all\": {\"ssim_sum\": [";
      const auto& tiles = frames[std::min(k, frames.size() - 1)];
      for (size_t t = 0; t < tiles.size(); ++t) f << (t ? "," : "") << tiles[t][which];
      f << "], \"count\": [";
      for (size_t t = 0; t < tiles.size(); ++t) f << (t ? "," : "") << tiles[t][2];
      f << "]}}}}";
    }
    f << "]}";
  };
  auto paired_all = [&](const char* a, const char* b) {
    const std::string cmd = std::string("python3 ") + DOFARM_SOURCE_DIR +
                            "/bench/trainer/study_tables.py paired " + (dir / a).string() + " " +
                            (dir / b).string() + " > " + (dir / "paired.log").string() + " 2>&1";
    EXPECT_EQ(std::system(cmd.c_str()), 0) << read_all(dir / "paired.log");
    const std::string log = read_all(dir / "paired.log");
    const size_t at = log.find("| all | ");
    EXPECT_NE(at, std::string::npos) << log;
    // "| all | D | [LO, HI] | N |"
    double d = NAN, lo = NAN, hi = NAN;
    int n = 0;
    std::sscanf(log.c_str() + at, "| all | %lf | [%lf, %lf] | %d |", &d, &lo, &hi, &n);
    return std::array<double, 4>{d, lo, hi, double(n)};
  };
  // Even: every value of B is 0.01 below A's (sum difference 0.01 x count).
  const std::vector<std::vector<std::array<double, 3>>> even = {
      {{90, 89, 100}, {45, 44.5, 50}, {0, 0, 0}}, {{80, 79, 100}, {7, 6.9, 10}}};
  write("even_a.json", even, 0, true);  // A has a third frame B lacks
  write("even_b.json", even, 1, false);
  auto e = paired_all("even_a.json", "even_b.json");
  EXPECT_NEAR(e[0], 0.01, 1e-4);
  EXPECT_NEAR(e[1], 0.01, 1e-4);
  EXPECT_NEAR(e[2], 0.01, 1e-4);
  EXPECT_EQ(e[3], 4);  // tiles with windows in the region, on matched frames
  // Uneven: frame 0 differs by +0.1 in one tile and -0.02 in the other,
  // frame 1 by 0 and +0.04 (count-weighted), so the point is
  // ((0.1 * 100 - 0.02 * 100) / 200 + (0 + 0.04 * 300) / 400) / 2 = 0.035.
  const std::vector<std::vector<std::array<double, 3>>> uneven = {{{90, 80, 100}, {50, 52, 100}},
                                                                  {{60, 60, 100}, {240, 228, 300}}};
  write("uneven_a.json", uneven, 0, false);
  write("uneven_b.json", uneven, 1, false);
  auto u = paired_all("uneven_a.json", "uneven_b.json");
  EXPECT_NEAR(u[0], 0.035, 1e-4);
  EXPECT_LT(u[1], u[0]);
  EXPECT_GT(u[2], u[0]);
  EXPECT_LE(u[1], u[2]);
  EXPECT_GT(u[2] - u[1], 0.01);
}

// --held-out: every configuration is also scored on all frames of a folder
// it did not train on, in a second table with those frames' reference
// ceiling and the CoC input's gain; with data.val_fraction = 0 the held-out
// frames are what the main table scores. A folder sharing a frame with the
// training shards (same scene and seed) is refused before anything trains.
TEST(Study, HeldOutFramesAreScoredApartAndMayNotOverlapTheTrainingFrames) {
#ifndef DOFARM_EXE
  GTEST_SKIP() << "a trainer-only build has no dofarm to read the shards with";
#else
  const fs::path dir = testing::scratch_dir("study_held_out");
  fs::create_directories(dir / "data");
  fs::create_directories(dir / "held");
  fs::create_directories(dir / "overlap");
  testing::write_synthetic_shard(dir / "data" / "shard-00000.h5", 12, 64, 64, 2, 5);
  testing::write_synthetic_shard(dir / "held" / "shard-00000.h5", 4, 64, 64, 2, 5, 20);
  testing::write_synthetic_shard(dir / "overlap" / "shard-00000.h5", 4, 64, 64, 2, 5, 10);

  const std::string pair = "default default_nococ";
  EXPECT_EQ(run_study(dir / "data", dir / "refused", dir / "refused.log", pair,
                      " --held-out " + (dir / "overlap").string()),
            2);
  const std::string refused = read_all(dir / "refused.log");
  EXPECT_NE(refused.find("frames 10..11 are in the training shard"), std::string::npos) << refused;
  EXPECT_FALSE(fs::exists(dir / "refused" / "runs"));

  const fs::path out = dir / "out";
  ASSERT_EQ(run_study(dir / "data", out, dir / "held.log", pair,
                      " --held-out " + (dir / "held").string()),
            0)
      << read_all(dir / "held.log");
  const std::string md = read_all(out / "results.md");
  EXPECT_NE(md.find("Validation frames: 3"), std::string::npos) << md;
  EXPECT_NE(md.find("**Held-out frames at clean references** (`--held-out`: frames 20, 21, 22, 23"),
            std::string::npos)
      << md;
  EXPECT_NE(md.find("| `default_nococ` (c) without CoC input | "), std::string::npos) << md;
  EXPECT_NE(md.find("| CoC input: `default` − `default_nococ` | "), std::string::npos) << md;
  for (const char* c : {"default", "default_nococ"}) {
    const std::string rep = read_all(out / "reports-held-out" / c / "report.json");
    EXPECT_NE(rep.find("\"held_out\": true"), std::string::npos) << c;
  }

  // Every rendered frame trains: the held-out frames are the main table's.
  const fs::path all = dir / "all";
  ASSERT_EQ(run_study(dir / "data", all, dir / "all.log", pair,
                      " --held-out " + (dir / "held").string(), "--set data.val_fraction=0"),
            0)
      << read_all(dir / "all.log");
  const std::string all_md = read_all(all / "results.md");
  EXPECT_NE(all_md.find("Held-out frames (`eval --held-out`"), std::string::npos) << all_md;
  EXPECT_EQ(all_md.find("**Held-out frames at clean references**"), std::string::npos) << all_md;
  EXPECT_TRUE(fs::exists(all / "reports" / "default-coc0" / "report.json"));
  EXPECT_FALSE(fs::exists(all / "reports-held-out"));
  EXPECT_NE(all_md.find("rendered apart): 4;"), std::string::npos) << all_md;

  // A second held-out folder of the same name (one `dofarm run` per frame
  // range): both are scored, and the reports of the first set are made again.
  fs::create_directories(dir / "more" / "held");
  testing::write_synthetic_shard(dir / "more" / "held" / "shard-00000.h5", 3, 64, 64, 2, 5, 30);
  // Both folders, logged to `log`: the study's exit status.
  const auto with_both = [&](const fs::path& log) {
    return run_study(dir / "data", all, log, pair,
                     " --held-out " + (dir / "held").string() + " --held-out " +
                         (dir / "more" / "held").string(),
                     "--set data.val_fraction=0");
  };
  ASSERT_EQ(with_both(dir / "two.log"), 0) << read_all(dir / "two.log");
  const std::string two_log = read_all(dir / "two.log");
  EXPECT_NE(two_log.find("the held-out frames changed"), std::string::npos) << two_log;
  EXPECT_EQ(two_log.find("default: training"), std::string::npos) << two_log;
  const std::string two_md = read_all(all / "results.md");
  EXPECT_NE(two_md.find("rendered apart): 7;"), std::string::npos) << two_md;
  EXPECT_TRUE(fs::exists(all / "held-out-data" / "0-held-shard-00000.h5"));
  EXPECT_TRUE(fs::exists(all / "held-out-data" / "1-held-shard-00000.h5"));
  // The same set again: nothing is evaluated again.
  ASSERT_EQ(with_both(dir / "again.log"), 0) << read_all(dir / "again.log");
  const std::string again = read_all(dir / "again.log");
  EXPECT_EQ(again.find("evaluating"), std::string::npos) << again;
#endif
}

// --seeds: one study per seed in OUT/seed-S, trained with that seed, and the
// tables across seeds: every configuration's mean and range, the CoC input's
// gain per band seed by seed, the probe; bad seed lists are refused.
TEST(Study, SeedsRunOneStudyEachAndTabulateAcrossThem) {
  const fs::path dir = study_dir("study_seeds");
  const fs::path out = dir / "out";
  const std::string configs = "default default_nococ";
  // --train-only trains every seed's configurations and scores nothing; the
  // same command without it then scores those runs without training again.
  ASSERT_EQ(run_study(dir / "data", out, dir / "train.log", configs,
                      " --crops 0 --seeds '3 4' --train-only"),
            0)
      << read_all(dir / "train.log");
  for (const char* s : {"seed-3", "seed-4"})
    for (const char* c : {"default", "default_nococ"}) {
      EXPECT_EQ(read_all(out / s / "runs" / c / "study.done"), "steps 2\n") << s << " " << c;
      EXPECT_FALSE(fs::exists(out / s / "reports" / c)) << s << " " << c;
    }
  EXPECT_FALSE(fs::exists(out / "seed-3" / "results.md"));
  EXPECT_FALSE(fs::exists(out / "results.md"));
  ASSERT_EQ(run_study(dir / "data", out, dir / "seeds.log", configs, " --crops 0 --seeds '3 4'"), 0)
      << read_all(dir / "seeds.log");
  const std::string log = read_all(dir / "seeds.log");
  EXPECT_NE(log.find("default_nococ: trained (2 steps), not trained again"), std::string::npos)
      << log;
  EXPECT_EQ(log.find(": training ("), std::string::npos) << log;
  for (const char* s : {"3", "4"}) {
    const fs::path one = out / (std::string("seed-") + s);
    EXPECT_TRUE(fs::exists(one / "results.md")) << s;
    for (const char* c : {"default", "default_nococ"})
      EXPECT_NE(read_all(one / "runs" / c / "config.toml").find(std::string("seed = ") + s),
                std::string::npos)
          << s << " " << c;
  }
  const std::string md = read_all(out / "results.md");
  EXPECT_NE(md.find("Across seeds 3, 4"), std::string::npos) << md;
  EXPECT_NE(md.find("| `default` (c) project default | "), std::string::npos) << md;
  // The gain row: the mean, then one value per seed.
  const size_t gain = md.find("| `default` − `default_nococ` | ");
  ASSERT_NE(gain, std::string::npos) << md;
  const std::string row = md.substr(gain, md.find('\n', gain) - gain);
  EXPECT_EQ(std::count(row.begin(), row.end(), ','), 4) << row;  // 4 bands x (a, b)
  EXPECT_NE(md.find("| `default` fed CoC 0 | "), std::string::npos) << md;
  EXPECT_EQ(md.find("| `default_nococ` fed CoC 0"), std::string::npos) << md;
  // The CSV: every seed's rows, the seed first.
  std::ifstream csv(out / "results.csv");
  std::string line;
  std::vector<std::string> seeds;
  ASSERT_TRUE(std::getline(csv, line));
  EXPECT_EQ(line.rfind("seed,config,", 0), 0u) << line;
  while (std::getline(csv, line))
    if (!line.empty()) seeds.push_back(split(line, ',')[0] + " " + split(line, ',')[1]);
  EXPECT_EQ(seeds, (std::vector<std::string>{"3 default", "3 default_nococ", "4 default",
                                             "4 default_nococ"}));

  for (const char* bad : {" --seeds '3 3'", " --seeds x", " --seeds 3 --set train.seed=2"})
    EXPECT_EQ(run_study(dir / "data", dir / "bad", dir / "bad.log", configs, bad), 2) << bad;
  EXPECT_FALSE(fs::exists(dir / "bad"));
}

// "section.key" -> value of a run's config.toml (to_toml's flat layout).
std::map<std::string, std::string> config_keys(const fs::path& toml) {
  std::map<std::string, std::string> out;
  std::istringstream in(read_all(toml));
  std::string line, section;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    if (line[0] == '[') {
      section = line.substr(1, line.find(']') - 1);
      continue;
    }
    const size_t eq = line.find(" = ");
    if (eq != std::string::npos) out[section + "." + line.substr(0, eq)] = line.substr(eq + 3);
  }
  return out;
}

// --configs ablation: the thesis preset, each one-at-a-time ablation and the
// project default; each ablation's config differs from the thesis run's in
// exactly the keys its name says.
TEST(Study, AblationChangesOnlyItsKeyOfTheThesisPreset) {
  const fs::path dir = study_dir("study_ablation");
  const fs::path out = dir / "out";
  ASSERT_EQ(run_study(dir / "data", out, dir / "log", "ablation"), 0) << read_all(dir / "log");
  const auto thesis = config_keys(out / "runs" / "thesis" / "config.toml");
  const std::map<std::string, std::vector<std::string>> changed = {
      {"abl_radiance", {"model.inputs"}},   {"abl_normal", {"model.inputs"}},
      {"abl_depth", {"model.inputs"}},      {"abl_coc", {"model.inputs"}},
      {"abl_bottleneck", {"model.bottleneck_convs"}},
      {"abl_decoder", {"model.decoder"}},   {"abl_gradloss", {"loss.log_form"}},
      {"abl_schedule", {"train.schedule", "train.warmup_steps"}}};
  const std::map<std::string, std::string> input = {{"abl_radiance", "'radiance:log1p'"},
                                                    {"abl_normal", "'normal:as_stored'"},
                                                    {"abl_depth", "'depth:focal'"},
                                                    {"abl_coc", "'coc:log'"}};
  for (const auto& [name, keys] : changed) {
    const auto cfg = config_keys(out / "runs" / name / "config.toml");
    std::vector<std::string> differ;
    for (const auto& [k, v] : cfg)
      if (!thesis.count(k) || thesis.at(k) != v) differ.push_back(k);
    EXPECT_EQ(differ, keys) << name;
    if (input.count(name)) {
      EXPECT_NE(cfg.at("model.inputs").find(input.at(name)), std::string::npos) << name;
    }
  }
  const std::string md = read_all(out / "results.md");
  for (const auto& [name, keys] : changed)
    EXPECT_NE(md.find("`" + name + "`"), std::string::npos) << name;
  EXPECT_NE(md.find("`default`"), std::string::npos);
}

// The project default with the thesis's scene depth, with and without the
// CoC (--configs sdepth): each differs from the default only in its inputs,
// which hold depth:scene in place of depth:focal and, for the _nococ twin, no
// CoC; the table has the CoC input's gain for both pairs.
TEST(Study, SceneDepthPairDiffersFromTheDefaultOnlyInItsInputs) {
  const fs::path dir = study_dir("study_sdepth");
  const fs::path out = dir / "out";
  ASSERT_EQ(run_study(dir / "data", out, dir / "log",
                      "default default_nococ default_sdepth default_sdepth_nococ", " --crops 0"),
            0)
      << read_all(dir / "log");
  const auto base = config_keys(out / "runs" / "default" / "config.toml");
  const std::map<std::string, std::pair<std::string, bool>> inputs = {
      {"default", {"'depth:focal'", true}},
      {"default_nococ", {"'depth:focal'", false}},
      {"default_sdepth", {"'depth:scene'", true}},
      {"default_sdepth_nococ", {"'depth:scene'", false}}};
  for (const auto& [name, want] : inputs) {
    const auto cfg = config_keys(out / "runs" / name / "config.toml");
    std::vector<std::string> differ;
    for (const auto& [k, v] : cfg)
      if (!base.count(k) || base.at(k) != v) differ.push_back(k);
    EXPECT_EQ(differ, name == "default" ? std::vector<std::string>{}
                                        : std::vector<std::string>{"model.inputs"})
        << name;
    const std::string& in = cfg.at("model.inputs");
    EXPECT_NE(in.find(want.first), std::string::npos) << name << ": " << in;
    EXPECT_EQ(in.find("coc:log") != std::string::npos, want.second) << name << ": " << in;
  }
  const std::string md = read_all(out / "results.md");
  EXPECT_NE(md.find("| CoC input: `default` − `default_nococ` | "), std::string::npos) << md;
  EXPECT_NE(md.find("| CoC input: `default_sdepth` − `default_sdepth_nococ` | "), std::string::npos)
      << md;
  // The shorthand names the same pair: run with it, nothing is trained again.
  ASSERT_EQ(run_study(dir / "data", out, dir / "again.log", "sdepth", " --crops 0"), 0)
      << read_all(dir / "again.log");
  const std::string again = read_all(dir / "again.log");
  for (const char* c : {"default_sdepth", "default_sdepth_nococ"})
    EXPECT_NE(again.find(std::string(c) + ": trained (2 steps), not trained again"),
              std::string::npos)
        << again;
  EXPECT_EQ(again.find("default_nococ:"), std::string::npos) << again;
}

// The width-matched CoC ablations: each no-CoC twin has the inputs of its
// CoC network less the CoC and, unlike (b), the CoC network's widths, so
// that the pair differs by the first convolution's CoC column alone; the
// prefiltered twins still blur their albedo by the CoC, and the prefiltered
// default differs from the default by the prefilter alone. Run at their own
// widths (not shrunk), on small frames.
TEST(Study, WidthMatchedNoCocTwinsDifferFromTheirCocNetworksByTheCocInputAlone) {
  const fs::path dir = study_dir("study_wide");
  const fs::path out = dir / "out";
  ASSERT_EQ(run_study(dir / "data", out, dir / "log",
                      "default default_nococ_wide default_prefilter default_prefilter_nococ_wide "
                      "thesis_prefilter thesis_prefilter_nococ",
                      " --crops 0", "", ""),
            0)
      << read_all(dir / "log");
  auto config = [&](const char* name) {
    return load_train_config(out / "runs" / name / "config.toml");
  };
  for (const auto& [with, without] :
       {std::pair{"default", "default_nococ_wide"},
        std::pair{"default_prefilter", "default_prefilter_nococ_wide"},
        std::pair{"thesis_prefilter", "thesis_prefilter_nococ"}}) {
    SCOPED_TRACE(without);
    const TrainConfig a = config(with), b = config(without);
    EXPECT_EQ(b.model.effective_channels(), (std::vector<int>{36, 48, 64, 85, 113}));
    EXPECT_EQ(a.model.effective_channels(), b.model.effective_channels());
    EXPECT_EQ(a.model.input_channels(), b.model.input_channels() + 1);
    std::vector<std::string> coc_less;
    for (const std::string& in : a.model.inputs)
      if (in.rfind("coc:", 0) != 0) coc_less.push_back(in);
    EXPECT_EQ(coc_less, b.model.inputs);
    EXPECT_EQ(a.data.albedo_prefilter, b.data.albedo_prefilter);
    // Every other key alike, as the run folders store them.
    std::vector<std::string> differ;
    for (const std::string& change : config_changes(a, b))
      if (change.rfind("model.inputs:", 0) != 0 && change.rfind("model.channels:", 0) != 0)
        differ.push_back(change);
    EXPECT_EQ(differ, std::vector<std::string>{});
  }
  EXPECT_EQ(config("thesis_prefilter_nococ").data.albedo_prefilter, AlbedoPrefilter::kCoc);
  EXPECT_EQ(config("default_prefilter_nococ_wide").data.albedo_prefilter, AlbedoPrefilter::kCoc);
  EXPECT_EQ(config("default").data.albedo_prefilter, AlbedoPrefilter::kNone);
  const auto prefilter_only = config_changes(config("default"), config("default_prefilter"));
  ASSERT_EQ(prefilter_only.size(), 1u);
  EXPECT_EQ(prefilter_only[0].rfind("data.albedo_prefilter:", 0), 0u) << prefilter_only[0];
  // Every pair in the CoC table and in the table of paired intervals.
  const std::string md = read_all(out / "results.md");
  for (const char* pair : {"`thesis_prefilter` − `thesis_prefilter_nococ` | ",
                           "`default_prefilter` − `default_prefilter_nococ_wide` | ",
                           "`default` − `default_nococ_wide` | "}) {
    EXPECT_NE(md.find(std::string("| CoC input: ") + pair), std::string::npos) << pair << md;
    EXPECT_NE(md.find(std::string("\n| ") + pair), std::string::npos) << pair << md;
  }
  // No CoC probe for a network without the CoC input.
  EXPECT_FALSE(fs::exists(out / "reports" / "default_nococ_wide-coc0"));
  EXPECT_FALSE(fs::exists(out / "reports" / "thesis_prefilter_nococ-coc0"));
  EXPECT_FALSE(fs::exists(out / "reports" / "default_prefilter_nococ_wide-coc0"));
  EXPECT_TRUE(fs::exists(out / "reports" / "thesis_prefilter-coc0"));
}

// Two frame ranges of one job rendered as two farm outputs share their
// folder's name (a/courtyard, b/courtyard) and their shards' names: the
// study trains on both (its data folder links every shard, numbered by the
// folder's place in the list). A later call links the folders it is given
// and nothing else (by name again, when the names differ).
TEST(Study, TwoFarmOutputsOfOneNameAreBothTrainedOn) {
  const fs::path dir = testing::scratch_dir("study_same_name");
  const fs::path a = dir / "a" / "courtyard", b = dir / "b" / "courtyard",
                 c = dir / "c" / "cornell";
  for (const fs::path& d : {a, b, c}) fs::create_directories(d);
  testing::write_synthetic_shard(a / "shard-00000.h5", 12, 64, 64, 2, 5);
  testing::write_synthetic_shard(b / "shard-00000.h5", 12, 64, 64, 2, 6, 12);
  testing::write_synthetic_shard(c / "shard-00000.h5", 12, 64, 64, 2, 7);
  const fs::path out = dir / "out";
  auto links = [&] {
    std::map<std::string, fs::path> found;
    for (const auto& e : fs::directory_iterator(out / "data"))
      found[e.path().filename().string()] = fs::read_symlink(e.path());
    return found;
  };
  ASSERT_EQ(run_study(a.string() + " " + b.string(), out, dir / "log", "default", " --train-only"),
            0)
      << read_all(dir / "log");
  EXPECT_EQ(links(), (std::map<std::string, fs::path>{
                         {"0-courtyard-shard-00000.h5", a / "shard-00000.h5"},
                         {"1-courtyard-shard-00000.h5", b / "shard-00000.h5"}}));
  const std::string split_json = read_all(out / "runs" / "default" / "split.json");
  for (const char* file : {"\"0-courtyard-shard-00000.h5\"", "\"1-courtyard-shard-00000.h5\""})
    EXPECT_NE(split_json.find(file), std::string::npos) << split_json;

  ASSERT_EQ(
      run_study(a.string() + " " + c.string(), out, dir / "again.log", "default", " --train-only"),
      0)
      << read_all(dir / "again.log");
  EXPECT_EQ(links(),
            (std::map<std::string, fs::path>{{"courtyard-shard-00000.h5", a / "shard-00000.h5"},
                                             {"cornell-shard-00000.h5", c / "shard-00000.h5"}}));
}

// cuda_node.sh study checks its settings before it writes or starts
// anything (a GPU machine's minutes are scarce): a bad frame range, a run
// word without its seed, an unknown study job and a missing render kit each
// end with exit 2 and a message naming the setting; neither the output
// folder nor the study folder is made.
TEST(Study, GpuStudyRefusesBadSettingsBeforeWritingAnything) {
  const fs::path dir = testing::scratch_dir("study_cuda_node_settings");
  const fs::path kit = dir / "kit";
  fs::create_directories(kit);
  struct Case {
    std::string env, says;
  };
  const std::vector<Case> cases = {
      {"FRAMES=0-19,x", "FRAMES: expected ranges"},
      {"FRAMES=20-5", "FRAMES: range '20-5' ends before it starts"},
      {"FRAMES=,", "FRAMES: expected ranges"},
      {"RUNS=default", "RUNS: expected CONFIG:SEED words"},
      {"'RUNS=default:1 x:'", "RUNS: expected CONFIG:SEED words like default:1, got 'x:'"},
      {"JOB=nosuch", "JOB: no study job jobs/study/nosuch.toml"},
      {"JOB=courtyard", "render-kit.tar.xz not found"},
  };
  for (const Case& c : cases) {
    const fs::path out = dir / "out", study = dir / "study", log = dir / "log";
    const std::string cmd = "env STUDY_DIR=" + study.string() + " " + c.env + " bash " +
                            DOFARM_SOURCE_DIR + "/bench/trainer/cuda_node.sh study " +
                            kit.string() + " " + out.string() + " > " + log.string() + " 2>&1";
    const int rc = std::system(cmd.c_str());
    ASSERT_TRUE(WIFEXITED(rc)) << c.env;
    EXPECT_EQ(WEXITSTATUS(rc), 2) << c.env << ": " << read_all(log);
    EXPECT_NE(read_all(log).find(c.says), std::string::npos) << c.env << ": " << read_all(log);
    EXPECT_FALSE(fs::exists(out)) << c.env;
    EXPECT_FALSE(fs::exists(study)) << c.env;
  }
}

}  // namespace
}  // namespace dofarm::trainer
