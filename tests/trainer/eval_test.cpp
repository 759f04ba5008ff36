// The evaluation report and whole-frame inference: scores by region and CoC
// band, the CoC probe, full-frame validation, crops, timing, the report page.
#include "trainer/eval.h"

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <tuple>
#include <vector>

#include "common/error.h"
#include "common/exr_io.h"
#include "common/shard.h"
#include "tests/trainer/synthetic.h"
#include "tests/trainer/train_fixtures.h"
#include "trainer/dataset.h"
#include "trainer/metrics.h"
#include "trainer/report.h"
#include "trainer/train.h"

namespace dofarm::trainer {
namespace {

using namespace fixtures;

TEST(Eval, ReportHasEveryFrameAndBeatsTheNoisyInput) {
  fs::path out = fresh_dir("eval_report");
  EvalOptions e{trained_run(), shared_data(), out, 0, 1, 0};
  EvalSummary s = evaluate(e);
  EXPECT_EQ(s.frames, 3);
  for (const char* f : {"report.md", "report.json", "report.html", "loss.svg", "steps.svg",
                        "lr.svg", "frame-000.png"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  EXPECT_FALSE(fs::exists(out / "frame-001.png"));  // max_images = 1
  std::ifstream in(out / "report.json");
  nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["frames"].size(), 3u);
  double noisy = j["summary"]["noisy"]["all"]["ssim"],
         den = j["summary"]["denoised"]["all"]["ssim"];
  EXPECT_GT(den, noisy);
  EXPECT_TRUE(std::isfinite(s.psnr));
  EXPECT_GT(s.ms, 0.0);
  // Synthetic references are converged (reference_half == reference): the
  // ceiling is exactly 1 on every frame (trainer/ceiling.h).
  EXPECT_EQ(j["reference_ceiling"]["frames"], 3);
  EXPECT_DOUBLE_EQ(j["reference_ceiling"]["mean_ssim"].get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(j["frames"][0]["reference_ceiling_ssim"].get<double>(), 1.0);
  // Flicker: none for a sequence's first frame, then per pair of frames; the
  // noisy input (fresh noise every frame) flickers more than the output.
  EXPECT_TRUE(j["frames"][0]["denoised"]["all"]["flicker"].is_null());
  EXPECT_TRUE(j["frames"][1]["denoised"]["all"]["flicker"].is_number());
  const double fl_noisy = j["summary"]["noisy"]["all"]["flicker"],
               fl_den = j["summary"]["denoised"]["all"]["flicker"];
  EXPECT_GT(fl_noisy, fl_den);
  EXPECT_NEAR(s.flicker, fl_den, 1e-12);
  EXPECT_TRUE(j["denoise_ms_at_size"].is_null());  // not asked for
  // Each frame's denoised SSIM per tile of 32 px, for paired comparisons of
  // two models (bench/trainer/study_tables.py): per region, the tiles'
  // sums over their counts give the frame's score.
  for (const auto& row : j["frames"]) {
    const auto& t = row["denoised_tiles"];
    ASSERT_EQ(t["tile"], 32);
    int regions = 0;
    for (const auto& [name, r] : t["regions"].items()) {
      const auto& sum = r["ssim_sum"];
      const auto& count = r["count"];
      ASSERT_EQ(sum.size(), size_t(t["tiles_x"].get<int>() * t["tiles_y"].get<int>()));
      ASSERT_EQ(count.size(), sum.size());
      double a = 0, n = 0;
      for (size_t i = 0; i < sum.size(); ++i)
        a += sum[i].get<double>(), n += count[i].get<double>();
      EXPECT_NEAR(a / n, row["denoised"][name]["ssim"].get<double>(), 1e-12) << name;
      ++regions;
    }
    EXPECT_GE(regions, 2);  // "all" and at least one CoC band
    EXPECT_TRUE(t["regions"].contains("all"));
  }
}

// --held-out: every frame of a folder the run did not train on is scored as
// a validation frame (the run's own split would make a fresh shard's last
// sequence validation, or none); a folder holding a shard the run trained on
// is refused before anything is written.
TEST(Eval, HeldOutScoresEveryFrameOfAnUnseenShardAndRefusesATrainedOne) {
  const fs::path held = fresh_dir("eval_held_out_data");
  testing::write_synthetic_shard(held / "shard-00000.h5", 5, 64, 64, 3, 9, 40);
  const fs::path out = fresh_dir("eval_held_out");
  EvalOptions e{trained_run(), held, out / "report", 0, 0, 0};
  e.held_out = true;
  e.all_frames = false;
  const EvalSummary s = evaluate(e);
  EXPECT_EQ(s.frames, 5);
  std::ifstream in(out / "report" / "report.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["held_out"], true);
  ASSERT_EQ(j["frames"].size(), 5u);
  EXPECT_EQ(j["frames"][0]["frame"], 40);
  EXPECT_EQ(j["frames"][4]["frame"], 44);

  // Without the flag the same folder is split as training data would be:
  // fewer frames (here none, so eval says so).
  EvalOptions plain = e;
  plain.held_out = false;
  plain.out_dir = out / "plain";
  int plain_frames = -1;
  try {
    plain_frames = evaluate(plain).frames;
  } catch (const SpecError&) {
    plain_frames = 0;
  }
  EXPECT_LT(plain_frames, 5);

  // `opts` is refused with a SpecError that says each of `says`, and
  // writes no report.
  const auto expect_refused = [](const EvalOptions& opts, const char* why,
                                 std::initializer_list<const char*> says) {
    try {
      evaluate(opts);
      ADD_FAILURE() << why;
    } catch (const SpecError& err) {
      for (const char* text : says)
        EXPECT_NE(std::string(err.what()).find(text), std::string::npos) << err.what();
    }
    EXPECT_FALSE(fs::exists(opts.out_dir / "report.json"));
  };

  // The run's own training shard is refused, naming the flag.
  EvalOptions trained = e;
  trained.data_dir = shared_data();
  trained.out_dir = out / "trained";
  expect_refused(trained, "a shard the run trained on was accepted as held out",
                 {"--held-out", "trained on this shard"});

  // A run whose split.json is from before content keys (version 1: shards
  // by file name) cannot show that a shard is apart from its training data,
  // whatever the shard's name: refused, naming the split file.
  const fs::path legacy_run = out / "legacy_run";
  fs::copy(trained_run(), legacy_run, fs::copy_options::recursive);
  nlohmann::json v2;
  {
    std::ifstream sin(legacy_run / "split.json");
    v2 = nlohmann::json::parse(sin);
  }
  nlohmann::json v1 = {{"mode", v2["mode"]}, {"shards", nlohmann::json::object()}};
  for (const auto& [key, sh] : v2["shards"].items())
    v1["shards"][sh["file"].get<std::string>()] = {
        {"frames", sh["frames"]}, {"train", sh["train"]}, {"val", sh["val"]}};
  std::ofstream(legacy_run / "split.json") << v1.dump();
  EvalOptions old_split = e;
  old_split.run_dir = legacy_run;
  old_split.out_dir = out / "legacy";
  expect_refused(old_split, "a version-1 split was trusted by file name",
                 {"split.json", "version 1"});
}

// Full-frame validation (train.val_frames): each epoch's val_frame_ssim and
// val_tile_ssim are in (0, 1], full_frame_ssim over all validation frames
// equals what eval scores on them with the same weights, and the tiles'
// figure is that of the frames cut into data.crop-sized tiles.
TEST(Eval, FullFrameValidationScoresAsEvalDoes) {
  const LossCurve c = read_loss_csv(trained_run() / "loss.csv");
  ASSERT_EQ(c.val_frame_ssim.size(), 6u);
  for (double v : c.val_frame_ssim) EXPECT_TRUE(v > 0 && v <= 1) << v;
  ASSERT_EQ(c.val_tile_ssim.size(), 6u);
  for (double v : c.val_tile_ssim) EXPECT_TRUE(v > 0 && v <= 1) << v;

  LoadedRun run = load_run(trained_run(), torch::kCPU, "last");
  run.model->eval();
  const std::vector<ShardSplit> splits = load_split_file(trained_run());
  int frames = 0;
  for (const ShardSplit& s : splits) frames += s.val_end - s.val_begin;
  ASSERT_EQ(frames, 3);
  // The last epoch's figure: the default 2 frames, to the CSV's 6 digits.
  EXPECT_NEAR(full_frame_ssim(run.model, run.config, torch::kCPU, shared_data(), splits, 2),
              c.val_frame_ssim.back(), 1e-5);
  const FrameScores two = full_frame_scores(run.model, run.config, torch::kCPU, shared_data(),
                                            splits, 2, run.config.data.crop);
  EXPECT_NEAR(two.whole, c.val_frame_ssim.back(), 1e-5);
  EXPECT_NEAR(two.tiles, c.val_tile_ssim.back(), 1e-5);
  // The frames are larger than a crop, so the tiles are a different image.
  EXPECT_NE(two.tiles, two.whole);
  EXPECT_TRUE(std::isnan(
      full_frame_scores(run.model, run.config, torch::kCPU, shared_data(), splits, 2, 0).tiles));
  const double whole =
      full_frame_ssim(run.model, run.config, torch::kCPU, shared_data(), splits, frames);
  fs::path out = fresh_dir("eval_whole");
  EvalOptions e{trained_run(), shared_data(), out, 0, 0, 0, "last"};
  e.all_frames = false;
  EXPECT_NEAR(evaluate(e).ssim, whole, 1e-9);
  EXPECT_TRUE(
      std::isnan(full_frame_ssim(run.model, run.config, torch::kCPU, shared_data(), {}, 2)));
}

// Scores by circle of confusion (kFocusRegions): each region's score is the
// metric over exactly its pixels, the shares add up, and a band without
// pixels has no score. The synthetic CoC runs from 0 to 8 px.
TEST(Eval, ScoresEveryBandOfTheCircleOfConfusion) {
  fs::path out = fresh_dir("eval_bands");
  EvalOptions e{trained_run(), shared_data(), out, 0, 0, 0};
  evaluate(e);
  std::ifstream in(out / "report.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  const nlohmann::json& share = j["summary"]["pixel_share"];
  EXPECT_DOUBLE_EQ(share["all"].get<double>(), 1.0);
  EXPECT_NEAR(share["in_focus"].get<double>() + share["out_of_focus"].get<double>(), 1.0, 1e-12);
  EXPECT_NEAR(share["coc_1_4"].get<double>() + share["coc_4_16"].get<double>() +
                  share["coc_16_up"].get<double>(),
              share["out_of_focus"].get<double>(), 1e-12);
  EXPECT_GT(share["coc_1_4"].get<double>(), 0.2);
  EXPECT_GT(share["coc_4_16"].get<double>(), 0.2);
  EXPECT_EQ(share["coc_16_up"].get<double>(), 0.0);
  EXPECT_TRUE(j["summary"]["denoised"]["coc_16_up"]["ssim"].is_null());
  EXPECT_TRUE(j["frames"][0]["noisy"]["coc_16_up"]["ssim"].is_null());
  // Frame 0's noisy input over the 4-16 px band, scored here independently.
  const nlohmann::json& row = j["frames"][0];
  ShardReader reader(shared_data() / row["shard"].get<std::string>());
  const FrameBuffers fb = reader.read_frame(row["frame"].get<int>() - reader.info().frame_start);
  const size_t n = fb.plane();
  std::vector<uint8_t> band(n);
  for (size_t p = 0; p < n; ++p) band[p] = fb.coc[p] >= 4.0f && fb.coc[p] < 16.0f;
  const std::vector<float> noisy(fb.noisy.begin(), fb.noisy.begin() + 3 * n);
  const std::vector<float> a = display_encode({noisy.data(), 3, fb.height, fb.width}),
                           b = display_encode({fb.reference.data(), 3, fb.height, fb.width});
  const double want =
      ssim({a.data(), 3, fb.height, fb.width}, {b.data(), 3, fb.height, fb.width}, band.data());
  EXPECT_NEAR(row["noisy"]["coc_4_16"]["ssim"].get<double>(), want, 1e-12);
  EXPECT_NE(row["noisy"]["coc_4_16"]["ssim"].get<double>(),
            row["noisy"]["coc_1_4"]["ssim"].get<double>());
  std::ifstream md_in(out / "report.md");
  const std::string md((std::istreambuf_iterator<char>(md_in)), std::istreambuf_iterator<char>());
  EXPECT_NE(md.find("By circle of confusion"), std::string::npos);
  EXPECT_NE(md.find("| coc_4_16 | 4–16 |"), std::string::npos);
}

// The CoC probe (--coc-override): a model with a CoC input denoises
// differently when fed a false CoC, while the noisy row and the regions
// (from the frame's own CoC) stay; a model without the input is unmoved,
// to the last bit.
TEST(Eval, CocOverrideMovesOnlyAModelThatReadsTheCoc) {
  auto scores = [](const fs::path& run, const char* name, float coc) {
    fs::path out = fresh_dir(name);
    EvalOptions e{run, shared_data(), out, 0, 0, 0};
    e.all_frames = false;
    e.coc_override = coc;
    evaluate(e);
    std::ifstream in(out / "report.json");
    return nlohmann::json::parse(in);
  };
  const nlohmann::json own = scores(trained_run(), "probe_own", NAN),
                       zero = scores(trained_run(), "probe_zero", 0.0f);
  EXPECT_TRUE(own["coc_override"].is_null());
  EXPECT_EQ(zero["coc_override"].get<double>(), 0.0);
  EXPECT_EQ(zero["summary"]["noisy"], own["summary"]["noisy"]);
  EXPECT_EQ(zero["summary"]["pixel_share"], own["summary"]["pixel_share"]);
  EXPECT_NE(zero["summary"]["denoised"]["out_of_focus"]["ssim"].get<double>(),
            own["summary"]["denoised"]["out_of_focus"]["ssim"].get<double>());

  fs::path nococ = fresh_dir("run_nococ");
  TrainOptions o{shared_data(), nococ, tiny_config()};
  std::erase(o.config.model.inputs, std::string("coc:log"));
  o.config.train.epochs = 1;
  o.config.train.steps_per_epoch = 2;
  train(o);
  const nlohmann::json a = scores(nococ, "probe_nococ_own", NAN),
                       b = scores(nococ, "probe_nococ_big", 50.0f);
  EXPECT_EQ(a["summary"]["denoised"], b["summary"]["denoised"]);
  // The same with the CoC-sized albedo prefilter: the probe feeds the false
  // CoC to the network's inputs only, and the prefilter keeps blurring by
  // the frame's own, so a network without the CoC input is still unmoved.
  fs::path prefiltered = fresh_dir("run_nococ_prefilter");
  TrainOptions p{shared_data(), prefiltered, o.config};
  p.config.data.albedo_prefilter = AlbedoPrefilter::kCoc;
  train(p);
  const nlohmann::json c = scores(prefiltered, "probe_prefilter_own", NAN),
                       d = scores(prefiltered, "probe_prefilter_big", 50.0f);
  EXPECT_EQ(c["summary"]["denoised"], d["summary"]["denoised"]);
  EXPECT_NE(c["summary"]["denoised"], a["summary"]["denoised"]);  // the prefilter did act

  // The command refuses a CoC that is not a finite number of pixels >= 0
  // (NaN would silently mean "no probe"), before writing anything.
  const fs::path refused = fresh_dir("probe_refused") / "report";
  for (const char* bad : {"nan", "inf", "-1"}) {
    const std::string cmd = std::string(DOFARM_TRAIN_EXE) + " eval --run " +
                            trained_run().string() + " --data " + shared_data().string() +
                            " --out " + refused.string() + " --coc-override " + bad +
                            " >/dev/null 2>&1";
    const int rc = std::system(cmd.c_str());
    EXPECT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 2) << bad;
    EXPECT_FALSE(fs::exists(refused)) << bad;
  }
}

// The input probe (--flatten-input): the named buffer reaches the
// network's inputs as its frame mean, channel by channel. Denoising with
// the override equals denoising a frame whose buffer holds that mean (the
// depth feeds the inputs only); the report records the probe and its
// denoised scores move while the noisy row and the regions stay; a buffer
// no input reads is refused before anything is written.
TEST(Eval, FlattenInputFeedsTheFrameMeanToTheInputsOnly) {
  ShardReader reader(shared_data() / list_shards(shared_data())[0]);
  const FrameBuffers fb = reader.read_frame(10);
  const size_t n = fb.plane();
  double sum = 0;
  for (size_t p = 0; p < n; ++p) sum += fb.depth[p];
  const std::vector<float> flat(n, float(sum / double(n)));
  FrameDenoiser den(trained_run(), torch::kCPU);
  const InputOverrides overrides = {{"depth", flat.data()}};
  const std::vector<float> via_override = den.denoise(fb, 1, nullptr, &overrides);
  den.reset_sequence();
  FrameBuffers g = fb;
  g.depth = flat;
  const std::vector<float> via_frame = den.denoise(g, 1);
  den.reset_sequence();
  EXPECT_EQ(via_override, via_frame);  // bit for bit
  EXPECT_NE(via_override, den.denoise(fb, 1));

  auto report = [](const char* name, std::vector<std::string> flatten) {
    fs::path out = fresh_dir(name);
    EvalOptions e{trained_run(), shared_data(), out, 0, 0, 0};
    e.all_frames = false;
    e.flatten_inputs = std::move(flatten);
    evaluate(e);
    std::ifstream in(out / "report.json");
    return nlohmann::json::parse(in);
  };
  const nlohmann::json own = report("flatten_own", {}), depth = report("flatten_depth", {"depth"}),
                       both = report("flatten_both", {"depth", "coc"});
  EXPECT_TRUE(own["flattened_inputs"].empty());
  EXPECT_EQ(depth["flattened_inputs"], nlohmann::json({"depth"}));
  EXPECT_EQ(depth["summary"]["noisy"], own["summary"]["noisy"]);
  EXPECT_EQ(depth["summary"]["pixel_share"], own["summary"]["pixel_share"]);
  EXPECT_NE(depth["summary"]["denoised"]["all"]["ssim"].get<double>(),
            own["summary"]["denoised"]["all"]["ssim"].get<double>());
  EXPECT_NE(both["summary"]["denoised"]["all"]["ssim"].get<double>(),
            depth["summary"]["denoised"]["all"]["ssim"].get<double>());

  for (const char* bad : {"reference", "nonsense"}) {
    const fs::path refused = fresh_dir("flatten_refused") / "report";
    const std::string cmd = std::string(DOFARM_TRAIN_EXE) + " eval --run " +
                            trained_run().string() + " --data " + shared_data().string() +
                            " --out " + refused.string() + " --flatten-input " + bad + " > " +
                            (refused.parent_path() / "log").string() + " 2>&1";
    const int rc = std::system(cmd.c_str());
    EXPECT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 2) << bad;
    EXPECT_FALSE(fs::exists(refused)) << bad;
    std::ifstream log(refused.parent_path() / "log");
    const std::string text((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
    EXPECT_NE(text.find("--flatten-input"), std::string::npos) << text;
    EXPECT_NE(text.find(std::string("no input from buffer \"") + bad), std::string::npos) << text;
  }
}

// Crops where the lens matters (report.h): on a CoC map with one sharp
// square and one blurred square, the windows found are those squares.
TEST(Crops, WindowsOfTheSmallestAndLargestCircleOfConfusion) {
  const int w = 40, h = 24;
  std::vector<float> coc(size_t(w) * h, 1.5f);  // neither sharp nor "out of focus"
  for (int y = 4; y < 12; ++y)
    for (int x = 6; x < 14; ++x) coc[size_t(y) * w + x] = 0.0f;
  for (int y = 14; y < 22; ++y)
    for (int x = 30; x < 38; ++x) coc[size_t(y) * w + x] = 20.0f;
  FocusCrops c = choose_focus_crops(coc, w, h, 8);  // stride 2: both squares on the grid
  ASSERT_TRUE(c.in_focus.found && c.out_of_focus.found);
  EXPECT_EQ(c.in_focus.x, 6);
  EXPECT_EQ(c.in_focus.y, 4);
  EXPECT_DOUBLE_EQ(c.in_focus.mean_coc, 0.0);
  EXPECT_EQ(c.out_of_focus.x, 30);
  EXPECT_EQ(c.out_of_focus.y, 14);
  EXPECT_DOUBLE_EQ(c.out_of_focus.mean_coc, 20.0);
  // A frame that is all pinhole has no out-of-focus window, an all-blurred
  // one no in-focus window.
  EXPECT_FALSE(
      choose_focus_crops(std::vector<float>(size_t(w) * h, 0.0f), w, h, 8).out_of_focus.found);
  EXPECT_FALSE(choose_focus_crops(std::vector<float>(size_t(w) * h, 9.0f), w, h, 8).in_focus.found);
  // Where the reference is display white over the blurred square (a sky
  // behind the focus), the out-of-focus window moves to the most blurred one
  // that is at most half white: (30, 10) overlaps the square by 4 of its 8
  // rows, mean (32 * 20 + 32 * 1.5) / 64; (28, 12) would be 36/64 white.
  // The sharp window is not white and stays. All white: the windows as before.
  std::vector<float> ref(size_t(3) * w * h, 0.5f);
  for (int ch = 0; ch < 3; ++ch)
    for (int y = 14; y < 22; ++y)
      for (int x = 30; x < 38; ++x) ref[size_t(ch) * w * h + size_t(y) * w + x] = 1.0f;
  auto where = [](const CropWindow& win) {
    return std::tuple{win.found, win.x, win.y, win.side, win.mean_coc};
  };
  const FocusCrops shown = choose_focus_crops(coc, w, h, 8, &ref);
  EXPECT_EQ(where(shown.in_focus), where(c.in_focus));
  EXPECT_EQ(where(shown.out_of_focus), std::tuple(true, 30, 10, 8, 10.75));
  const std::vector<float> all_white(size_t(3) * w * h, 2.0f);
  const FocusCrops fallback = choose_focus_crops(coc, w, h, 8, &all_white);
  EXPECT_EQ(where(fallback.in_focus), where(c.in_focus));
  EXPECT_EQ(where(fallback.out_of_focus), where(c.out_of_focus));

  // The crop PNG holds the window's pixels, sRGB-encoded, each drawn 2 x 2.
  std::vector<float> img(size_t(3) * w * h);
  for (size_t i = 0; i < img.size(); ++i) img[i] = float(i % 97) / 96.0f;
  const std::string png = crop_png_bytes(img, w, h, c.out_of_focus, 2);
  RgbImage back = decode_rgb_image(png.data(), png.size(), "crop", /*srgb=*/false);
  ASSERT_EQ(back.width, 16);
  ASSERT_EQ(back.height, 16);
  const size_t n = size_t(w) * h;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x)
      for (int ch = 0; ch < 3; ++ch) {
        const size_t p = size_t(14 + y / 2) * w + size_t(30 + x / 2);
        ASSERT_NEAR(back.rgb[(size_t(y) * 16 + x) * 3 + ch],
                    std::round(srgb_encode_clamped(img[ch * n + p]) * 255.0f) / 255.0f, 1e-6)
            << x << "," << y;
      }
}

// eval --crops: the same windows for any run on the same data (chosen from
// the data's CoC), written as PNGs and listed in report.json and report.md.
TEST(Eval, WritesCropsChosenByTheCircleOfConfusion) {
  fs::path out = fresh_dir("eval_crops");
  EvalOptions e{trained_run(), shared_data(), out, 0, 0, 0};
  e.all_frames = false;
  e.crops = 2;
  e.crop_side = 8;
  evaluate(e);
  nlohmann::json j = nlohmann::json::parse(std::ifstream(out / "report.json"));
  ASSERT_FALSE(j["crops"].empty());
  std::set<int> frames;
  for (const auto& c : j["crops"]) {
    frames.insert(c["index"].get<int>());
    for (const char* kind : {"noisy", "denoised", "reference"})
      EXPECT_TRUE(fs::exists(out / c[kind].get<std::string>())) << c.dump();
    const bool sharp = c["region"] == "in_focus";
    EXPECT_TRUE(sharp ? c["mean_coc_px"] < 1.0 : c["mean_coc_px"] >= 2.0) << c.dump();
    EXPECT_EQ(c["side"], 8);
  }
  EXPECT_EQ(frames.size(), 2u);  // e.crops frames
  std::ifstream md(out / "report.md");
  std::string text((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find(j["crops"][0]["denoised"].get<std::string>()), std::string::npos);
}

// Which frames the crops show: the most blurred, every shard's best before
// any shard's second, the most blurred shard first; ties keep their order.
TEST(Eval, CropsShowTheMostBlurredFramesSpreadOverShards) {
  using Picks = std::vector<std::pair<size_t, size_t>>;
  const std::vector<std::vector<double>> blur = {{3.0, 2.9, 1.0}, {40.0, 39.0}, {}, {12.0}};
  EXPECT_EQ(spread_by_blur(blur, 2), (Picks{{1, 0}, {3, 0}}));
  EXPECT_EQ(spread_by_blur(blur, 4), (Picks{{1, 0}, {3, 0}, {0, 0}, {1, 1}}));
  EXPECT_EQ(spread_by_blur(blur, 9), (Picks{{1, 0}, {3, 0}, {0, 0}, {1, 1}, {0, 1}, {0, 2}}));
  EXPECT_EQ(spread_by_blur({{5.0}, {5.0}}, 2), (Picks{{0, 0}, {1, 0}}));
  EXPECT_TRUE(spread_by_blur(blur, 0).empty());
  EXPECT_TRUE(spread_by_blur({}, 3).empty());
}

// `eval --time-size` times a frame of a size the data does not have: the
// first validation frame repeated periodically.
// crop_frame: the window's pixels in every buffer (per-version planes too),
// the camera kept; a window outside the frame is refused.
TEST(Eval, CropFrameTakesTheWindowOfEveryBuffer) {
  const FrameBuffers f = testing::synthetic_frame(3, 16, 12, 2, 9);
  const FrameBuffers c = crop_frame(f, 5, 4, 6, 3);
  ASSERT_EQ(c.width, 6);
  ASSERT_EQ(c.height, 3);
  EXPECT_EQ(c.camera.focal_distance, f.camera.focal_distance);
  const size_t n = f.plane(), m = c.plane();
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 6; ++x) {
      const size_t s = size_t(4 + y) * 16 + size_t(5 + x), d = size_t(y) * 6 + size_t(x);
      EXPECT_EQ(c.coc[d], f.coc[s]);
      EXPECT_EQ(c.reference[2 * m + d], f.reference[2 * n + s]);
      EXPECT_EQ(c.noisy[5 * m + d], f.noisy[5 * n + s]);  // version 1, blue
    }
  EXPECT_THROW(crop_frame(f, 12, 0, 6, 3), SpecError);
  EXPECT_THROW(crop_frame(f, -1, 0, 6, 3), SpecError);
}

// denoise_in_tiles: every tile is the window crop_frame cuts (narrower at
// the right and bottom), and the joined image puts each tile's output back
// where the window was: a "denoiser" that returns its window's reference
// rebuilds the frame's reference exactly.
TEST(Eval, DenoiseInTilesJoinsTheWindowsBack) {
  const FrameBuffers f = testing::synthetic_frame(3, 16, 12, 2, 9);
  std::vector<std::pair<int, int>> sizes;
  const std::vector<float> joined = denoise_in_tiles(f, 5, [&](const FrameBuffers& part) {
    sizes.emplace_back(part.width, part.height);
    return part.reference;
  });
  EXPECT_EQ(joined, f.reference);
  ASSERT_EQ(sizes.size(), 12u);  // 4 columns (5, 5, 5, 1) x 3 rows (5, 5, 2)
  EXPECT_EQ(sizes[0], std::make_pair(5, 5));
  EXPECT_EQ(sizes[3], std::make_pair(1, 5));
  EXPECT_EQ(sizes[11], std::make_pair(1, 2));
  // A wrong-sized output is an error, not a silently shifted image.
  EXPECT_THROW(denoise_in_tiles(f, 5, [](const FrameBuffers&) { return std::vector<float>(3); }),
               RuntimeError);
  EXPECT_THROW(denoise_in_tiles(f, 0, [](const FrameBuffers& p) { return p.reference; }),
               SpecError);
}

TEST(Eval, TimesTheDenoiseAtARequestedSize) {
  const FrameBuffers f = testing::synthetic_frame(1, 5, 3, 2, 4);
  const FrameBuffers t = tile_frame(f, 12, 7);
  ASSERT_EQ(t.width, 12);
  ASSERT_EQ(t.versions, 2);
  for (int y = 0; y < 7; ++y)
    for (int x = 0; x < 12; ++x) {
      ASSERT_EQ(t.coc[size_t(y) * 12 + x], f.coc[size_t(y % 3) * 5 + x % 5]);
      // Version 1's blue plane.
      ASSERT_EQ(t.noisy[(3 + 2) * 84 + size_t(y) * 12 + x],
                f.noisy[(3 + 2) * 15 + size_t(y % 3) * 5 + x % 5]);
    }
  fs::path out = fresh_dir("eval_time");
  EvalOptions e{trained_run(), shared_data(), out, 1, 0, 0};
  e.all_frames = false;
  e.time_side = 96;
  e.time_reps = 2;
  EvalSummary s = evaluate(e);
  EXPECT_GT(s.ms_at_size, 0.0);
  nlohmann::json j = nlohmann::json::parse(std::ifstream(out / "report.json"));
  EXPECT_EQ(j["denoise_ms_at_size"]["side"], 96);
  EXPECT_EQ(j["denoise_ms_at_size"]["reps"], 2);
  EXPECT_DOUBLE_EQ(j["denoise_ms_at_size"]["ms"].get<double>(), s.ms_at_size);
}

// The page as a reader sees it: opened by a real browser (Debian's
// chromium, headless), its script run, its plots and images decoded, its
// numbers those of report.json.
TEST(Eval, ReportPageLoadsInABrowserWithItsPlotsAndNumbers) {
  const char* browsers[] = {"/usr/bin/chromium", "/usr/bin/chromium-browser"};
  std::string browser;
  for (const char* b : browsers)
    if (fs::exists(b)) browser = b;
  if (browser.empty()) GTEST_SKIP() << "no chromium (scripts/install-deps.sh installs it)";
  fs::path out = fresh_dir("eval_html");
  EvalOptions e{trained_run(), shared_data(), out, 0, 2, 0};
  evaluate(e);
  const fs::path dom = out / "dom.html";
  const std::string cmd = browser +
                          " --headless --no-sandbox --disable-gpu --disable-dev-shm-usage "
                          "--no-first-run --user-data-dir=" +
                          (out / "profile").string() +
                          " --virtual-time-budget=5000 --dump-dom file://" +
                          (out / "report.html").string() + " > " + dom.string() + " 2>/dev/null";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  std::ifstream in(dom);
  const std::string page((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // The script ran: 5 plots + the error scale; both strips decoded.
  EXPECT_NE(page.find("data-svgs=\"6\""), std::string::npos) << page.substr(0, 2000);
  EXPECT_NE(page.find("data-images=\"2\""), std::string::npos);
  // Plots with axis titles, tick values and legends.
  for (const char* text :
       {"Loss per epoch", ">epoch<", ">optimizer step<", "learning rate", "class=\"ytick\"",
        "class=\"xtick\"", ">validation<", ">training (mean over the epoch)<", ">noisy (1 spp)<",
        ">error ×4<", "Validation SSIM per epoch", "PSNR (dB)",
        "mean |denoised - reference| per pixel"})
    EXPECT_NE(page.find(text), std::string::npos) << text;
  // The numbers are report.json's.
  std::ifstream js(out / "report.json");
  nlohmann::json j = nlohmann::json::parse(js);
  char ssim[32];
  std::snprintf(ssim, sizeof ssim, "<td>%.4f</td>",
                j["summary"]["denoised"]["all"]["ssim"].get<double>());
  EXPECT_NE(page.find(ssim), std::string::npos) << ssim;
  EXPECT_NE(page.find(j["checkpoint"]["file"].get<std::string>()), std::string::npos);
}

}  // namespace
}  // namespace dofarm::trainer
