// A run's life outside the happy path: damaged and missing checkpoints, a
// failed first start, a stop request and real SIGINT/SIGTERM, the choice of
// checkpoint, and denoise inputs that are not finite.
#include "trainer/run_folder.h"

#include <gtest/gtest.h>
#include <torch/script.h>
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "common/error.h"
#include "common/exr_io.h"
#include "tests/trainer/synthetic.h"
#include "trainer/eval.h"
#include "trainer/export_contract.h"
#include "trainer/train.h"

extern char** environ;

namespace dofarm::trainer {
namespace {

namespace fs = std::filesystem;

TrainConfig small_config(int epochs, int steps) {
  return load_train_config(
      "", {"model.channels=[8, 8, 8, 8, 8]", "data.crop=32", "data.sequence=3", "data.queue=4",
           "data.readers=1", "train.epochs=" + std::to_string(epochs),
           "train.steps_per_epoch=" + std::to_string(steps), "train.batch=2",
           "train.warmup_steps=2", "train.val_sequences=2", "train.device=cpu",
           "data.val_fraction=0.25"});
}

fs::path data_dir() {
  static fs::path d = [] {
    fs::path p = testing::scratch_dir("rf_data");
    testing::write_synthetic_shard(p / "shard-00000.h5", 12, 64, 64, 3, 5);
    return p;
  }();
  return d;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

torch::Tensor params_of(const fs::path& checkpoint, const TrainConfig& cfg) {
  Denoiser m(cfg.model);
  load_checkpoint(checkpoint, m, nullptr, torch::kCPU);
  std::vector<torch::Tensor> ps;
  for (const auto& p : m->parameters()) ps.push_back(p.detach().flatten());
  return torch::cat(ps);
}

// A trained two-epoch run, shared by the read-only tests.
fs::path trained() {
  static fs::path run = [] {
    fs::path r = testing::scratch_dir("rf_trained") / "run";
    train(TrainOptions{data_dir(), r, small_config(2, 3)});
    return r;
  }();
  return run;
}

void flip_bytes(const fs::path& p, size_t offset, size_t count) {
  std::string bytes = slurp(p);
  ASSERT_LT(offset + count, bytes.size());
  for (size_t i = 0; i < count; ++i) bytes[offset + i] = char(~bytes[offset + i]);
  std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
}

TEST(Checkpoint, DamageIsRefusedWithTheFileNamed) {
  const fs::path dir = testing::scratch_dir("rf_damage");
  const fs::path good = trained() / "checkpoints" / "last.pt";
  const TrainConfig cfg = small_config(2, 3);
  EXPECT_TRUE(torch::isfinite(params_of(good, cfg)).all().item<bool>());

  struct Case {
    const char* name;
    size_t offset_from_end;  // where 16 bytes are flipped
    bool truncate;
  };
  // Somewhere in the middle (weights or optimizer state), near the end (the
  // archive's directory), and a file cut short.
  for (const Case& c : {Case{"middle", 0, false}, Case{"end", 64, false}, Case{"cut", 0, true}}) {
    const fs::path bad = dir / (std::string(c.name) + ".pt");
    fs::copy_file(good, bad, fs::copy_options::overwrite_existing);
    const size_t size = fs::file_size(bad);
    if (c.truncate) {
      fs::resize_file(bad, size - 1000);
    } else {
      flip_bytes(bad, c.offset_from_end ? size - c.offset_from_end : size / 2, 16);
    }
    try {
      params_of(bad, cfg);
      ADD_FAILURE() << c.name << ": a damaged checkpoint loaded";
    } catch (const RuntimeError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(bad.string()), std::string::npos) << what;
      EXPECT_NE(what.find("damaged checkpoint"), std::string::npos) << what;
    }
  }
  // Not a checkpoint at all.
  std::ofstream(dir / "text.pt") << "hello\n";
  EXPECT_THROW(params_of(dir / "text.pt", cfg), RuntimeError);
}

TEST(Checkpoint, ResumeFromDamagedOptimizerStateIsAnErrorNotASilentRun) {
  const fs::path run = testing::scratch_dir("rf_damage_resume") / "run";
  TrainOptions o{data_dir(), run, small_config(1, 2)};
  train(o);
  // The optimizer state is the archive's second half: flip bytes there.
  const fs::path last = run / "checkpoints" / "last.pt";
  flip_bytes(last, fs::file_size(last) * 3 / 4, 16);
  o.config.train.epochs = 2;
  try {
    train(o);
    FAIL() << "trained on from a damaged checkpoint";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find(last.string()), std::string::npos) << e.what();
  }
}

TEST(Checkpoint, MissingLastBesideALossCsvIsAnError) {
  const fs::path run = testing::scratch_dir("rf_missing") / "run";
  TrainOptions o{data_dir(), run, small_config(1, 2)};
  train(o);
  const std::string csv_before = slurp(run / "loss.csv");
  fs::remove(run / "checkpoints" / "last.pt");
  fs::remove(run / "checkpoints" / "best.pt");
  o.config.train.epochs = 2;
  try {
    train(o);
    FAIL() << "started again from scratch";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("missing"), std::string::npos) << e.what();
  }
  EXPECT_EQ(slurp(run / "loss.csv"), csv_before);  // no duplicate epochs appended
}

TEST(Train, AFailedFirstStartLeavesNoRunFolder) {
  const fs::path base = testing::scratch_dir("rf_failed_start");
  const fs::path empty_data = base / "no_shards";
  fs::create_directories(empty_data);
  const fs::path run = base / "run";
  EXPECT_ANY_THROW(train(TrainOptions{empty_data, run, small_config(1, 2)}));
  EXPECT_FALSE(fs::exists(run));
  // The retry, with another model setting, is a new run.
  TrainConfig other = small_config(1, 2);
  other.model.recurrent = true;
  EXPECT_EQ(train(TrainOptions{data_dir(), run, other}).steps, 2);
}

TEST(Train, AStopRequestFinishesTheStepSavesAndResumesExactly) {
  const fs::path base = testing::scratch_dir("rf_stop");
  const TrainConfig cfg = small_config(2, 4);
  train(TrainOptions{data_dir(), base / "whole", cfg});

  std::atomic<bool> stop{false};
  TrainOptions o{data_dir(), base / "stopped", cfg};
  o.stop = &stop;
  // The request arrives while step 5 (index 5, mid-epoch 2) is computed.
  o.loss_hook = [&stop](int64_t step, const torch::Tensor& loss) {
    if (step == 5) stop.store(true);
    return loss;
  };
  TrainResult r = train(o);
  EXPECT_TRUE(r.stopped);
  EXPECT_EQ(r.steps, 6);  // the step in flight was finished, not dropped
  std::string events = slurp(base / "stopped" / "events.log");
  EXPECT_NE(events.find("stopped on request at epoch 1 step 6"), std::string::npos) << events;

  stop.store(false);
  o.loss_hook = {};
  TrainResult rest = train(o);
  EXPECT_TRUE(rest.resumed);
  EXPECT_FALSE(rest.stopped);
  EXPECT_EQ(rest.steps, 8);
  EXPECT_TRUE(torch::equal(params_of(base / "whole" / "checkpoints" / "last.pt", cfg),
                           params_of(base / "stopped" / "checkpoints" / "last.pt", cfg)));
}

TEST(Train, SaveEveryKeepsPeriodicCheckpoints) {
  const fs::path run = testing::scratch_dir("rf_save_every") / "run";
  TrainOptions o{data_dir(), run, small_config(1, 5)};
  o.save_every = 2;
  train(o);
  EXPECT_TRUE(fs::exists(run / "checkpoints" / "step-00000002.pt"));
  EXPECT_TRUE(fs::exists(run / "checkpoints" / "step-00000004.pt"));
  EXPECT_FALSE(fs::exists(run / "checkpoints" / "step-00000005.pt"));
  const TrainConfig cfg = small_config(1, 5);
  // Each is a complete, verified checkpoint of its step.
  Denoiser m(cfg.model);
  EXPECT_EQ(load_checkpoint(run / "checkpoints" / "step-00000004.pt", m, nullptr, torch::kCPU).step,
            4);
}

TEST(LoadRun, CheckpointChoice) {
  const fs::path run = trained();
  EXPECT_EQ(load_run(run, torch::kCPU, "last").checkpoint, run / "checkpoints" / "last.pt");
  EXPECT_EQ(load_run(run, torch::kCPU, "last").state.step, 6);
  EXPECT_EQ(load_run(run, torch::kCPU).checkpoint, run / "checkpoints" / "best.pt");
  const fs::path path = run / "checkpoints" / "last.pt";
  EXPECT_EQ(load_run(run, torch::kCPU, path.string()).checkpoint, path);
  EXPECT_THROW(load_run(run, torch::kCPU, (run / "nope.pt").string()), SpecError);
}

TEST(Denoise, NonFiniteInputsAreNamedAndCountedOrRepaired) {
  TrainConfig cfg = small_config(1, 1);
  FrameBuffers fb = testing::synthetic_frame(1, 32, 32, 2, 3);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < 10; ++y)
    for (int x = 0; x < 10; ++x) fb.noisy[size_t(3 * 32 * 32) + size_t(y * 32 + x)] = nan;  // v1
  fb.depth[7] = std::numeric_limits<float>::infinity();
  // Version 0 is clean but for the depth.
  auto v0 = non_finite_inputs(fb, 0, cfg, false);
  ASSERT_EQ(v0.size(), 1u);
  EXPECT_EQ(v0[0], (std::pair<std::string, size_t>{"depth", 1}));
  auto v1 = non_finite_inputs(fb, 1, cfg, false);
  ASSERT_EQ(v1.size(), 2u);
  EXPECT_EQ(v1[0], (std::pair<std::string, size_t>{"noisy", 100}));
  auto repaired = non_finite_inputs(fb, 1, cfg, true);
  EXPECT_EQ(repaired, v1);
  EXPECT_TRUE(non_finite_inputs(fb, 1, cfg, false).empty());
}

// The exported file alone says how to use it, and takes any size.
TEST(Export, CarriesItsContractAndTakesAnySize) {
  LoadedRun r = load_run(trained(), torch::kCPU, "last");
  const fs::path file = testing::scratch_dir("rf_export") / "model.pt";
  r.model->export_torchscript(file, {{kContractFile, denoiser_contract(r)}});
  torch::jit::ExtraFilesMap extra{{kContractFile, ""}};
  torch::jit::Module m = torch::jit::load(file.string(), torch::kCPU, extra);
  const nlohmann::json c = nlohmann::json::parse(extra[kContractFile]);
  EXPECT_EQ(c["format"], kContractFormat);
  EXPECT_EQ(c["input_channels"], r.config.model.input_channels());
  ASSERT_EQ(c["inputs"].size(), size_t(r.config.model.input_channels()));
  EXPECT_EQ(c["inputs"][11]["name"], "coc");
  EXPECT_EQ(c["checkpoint"]["step"], 6);
  EXPECT_EQ(parse_train_config(c["model_config"].get<std::string>(), "contract").model.channels,
            r.config.model.channels);
  torch::NoGradGuard ng;
  for (auto [h, w] : {std::pair{48, 40}, std::pair{32, 64}, std::pair{7, 33}}) {
    torch::Tensor x = torch::rand({1, r.config.model.input_channels(), h, w});
    std::vector<torch::Tensor> state;
    torch::Tensor want = r.model->forward_frame(pad_to_multiple(x), state).narrow(2, 0, h).narrow(3, 0, w);
    torch::Tensor got = m.forward({x}).toTensor();
    ASSERT_EQ(got.sizes(), want.sizes()) << h << "x" << w;
    EXPECT_LT((got - want).abs().max().item<float>(), 1e-5f) << h << "x" << w;
  }
}

// export --format checkpoint: the weights eval chose, without the optimizer
// state, read back by eval as the run's own checkpoint; training cannot
// resume from it, and --weights raw says why the trained weights are absent.
TEST(Export, AWeightsOnlyCheckpointLoadsAsTheRunAndCannotResume) {
  const fs::path run = trained();
  const fs::path last = run / "checkpoints" / "last.pt";
  const fs::path dir = testing::scratch_dir("rf_export_ckpt");
  for (Weights w : {Weights::kAuto, Weights::kRaw}) {
    LoadedRun r = load_run(run, torch::kCPU, "last", w);
    const fs::path file = dir / (w == Weights::kRaw ? "raw.pt" : "auto.pt");
    save_weights_checkpoint(file, r);
    // Weights, no Adam moments: under half a training checkpoint.
    EXPECT_LT(fs::file_size(file) * 2, fs::file_size(last));
    LoadedRun back = load_run(run, torch::kCPU, file.string());
    EXPECT_EQ(back.checkpoint, file);
    EXPECT_EQ(back.averaged, r.averaged);
    EXPECT_EQ(back.state.step, 6);
    EXPECT_EQ(back.state.epoch, r.state.epoch);
    const auto a = r.model->parameters(), b = back.model->parameters();
    ASSERT_EQ(a.size(), b.size());
    for (size_t i = 0; i < a.size(); ++i) EXPECT_TRUE(torch::equal(a[i], b[i])) << i;
    // Resuming training from it is refused with the file named.
    Denoiser m(r.config.model);
    torch::optim::Adam opt(m->parameters());
    try {
      load_checkpoint(file, m, &opt, torch::kCPU);
      ADD_FAILURE() << "resumed from a weights-only checkpoint";
    } catch (const RuntimeError& e) {
      EXPECT_NE(std::string(e.what()).find(file.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("cannot resume"), std::string::npos) << e.what();
    }
  }
  // The run averages its weights (train.ema), so the default export holds
  // the average alone: asking it for the trained weights is an error that
  // says so, not "damaged".
  ASSERT_TRUE(load_run(run, torch::kCPU, "last").averaged);
  try {
    load_run(run, torch::kCPU, (dir / "auto.pt").string(), Weights::kRaw);
    ADD_FAILURE() << "raw weights from an average-only checkpoint";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find("moving average"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(load_run(run, torch::kCPU, (dir / "raw.pt").string()).averaged);
}

// The contract is written from the input table: one entry per channel, in
// model.inputs order, with its input, encoding, layer and transform.
TEST(Export, ContractListsTheInputTableChannels) {
  LoadedRun r;
  r.config = apply_preset("thesis");
  r.checkpoint = "best.pt";
  const nlohmann::json c = nlohmann::json::parse(denoiser_contract(r));
  ASSERT_EQ(c["inputs"].size(), 12u);
  EXPECT_EQ(c["input_channels"], 12);
  const char* names[] = {"radiance.R", "radiance.G", "radiance.B", "albedo.R",
                         "albedo.G",   "albedo.B",   "normal.X",   "normal.Y",
                         "normal.Z",   "depth",      "roughness",  "coc"};
  const char* encodings[] = {"linear",  "linear",  "linear",  "as_stored", "as_stored", "as_stored",
                             "remap01", "remap01", "remap01", "scene",     "as_stored", "thesis"};
  for (int i = 0; i < 12; ++i) {
    EXPECT_EQ(c["inputs"][i]["index"], i);
    EXPECT_EQ(c["inputs"][i]["name"], names[i]) << i;
    EXPECT_EQ(c["inputs"][i]["encoding"], encodings[i]) << i;
  }
  EXPECT_EQ(c["inputs"][0]["layer"], "noisy.<v>.R, albedo_ref.R");
  EXPECT_EQ(c["inputs"][7]["layer"], "normal.G");  // docs/exr_format.md: normal x, y, z in R, G, B
  EXPECT_NE(c["inputs"][11]["transform"].get<std::string>().find("coc_max_px"), std::string::npos);
  EXPECT_EQ(c["constants"]["depth_scale"], 5.0);
  EXPECT_EQ(c["output"]["transform"], "radiance.c = max(y.c, 0) * (albedo_ref.c + demod_eps)");
  // The no-CoC ablation: 11 channels, no coc entry; the version's own albedo.
  r.config = parse_train_config("", "t.toml", {"model.dof=false", "data.albedo=\"version\""});
  const nlohmann::json d = nlohmann::json::parse(denoiser_contract(r));
  ASSERT_EQ(d["inputs"].size(), 11u);
  for (const auto& e : d["inputs"]) EXPECT_NE(e["input"], "coc");
  EXPECT_EQ(d["inputs"][0]["layer"], "noisy.<v>.R, albedo.<v>.R");
  EXPECT_EQ(d["inputs"][4]["layer"], "albedo.<v>.G");
  EXPECT_EQ(d["output"]["transform"],
            "radiance.c = expm1(max(y.c, 0)) * (albedo.<v>.c + demod_eps)");
}

// Real processes and real signals.

pid_t spawn(const std::vector<std::string>& args, const fs::path& log) {
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  pid_t pid = -1;
  EXPECT_EQ(posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ), 0);
  posix_spawn_file_actions_destroy(&fa);
  return pid;
}

int wait_status(pid_t pid) {
  int st = 0;
  EXPECT_EQ(waitpid(pid, &st, 0), pid);
  return st;
}

bool wait_for_file(const fs::path& p, double seconds) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    if (fs::exists(p)) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return false;
}

std::vector<std::string> train_args(const fs::path& run) {
  std::vector<std::string> a = {DOFARM_TRAIN_EXE, "train", "--data", data_dir().string(),
                                "--run", run.string(), "--save-every", "1"};
  for (const char* s : {"model.channels=[8, 8, 8, 8, 8]", "data.crop=32", "data.sequence=3",
                        "data.readers=1", "train.epochs=1", "train.steps_per_epoch=60",
                        "train.batch=2", "train.warmup_steps=2", "train.val_sequences=2",
                        "train.device=cpu", "train.cpu_replicas=1"}) {
    a.push_back("--set");
    a.push_back(s);
  }
  return a;
}

TEST(TrainSignals, SigtermAndSigintCheckpointThenResumeToTheSameWeights) {
  const fs::path base = testing::scratch_dir("rf_signals");
  for (int sig : {SIGTERM, SIGINT}) {
    const fs::path run = base / ("run" + std::to_string(sig));
    pid_t pid = spawn(train_args(run), base / "log.txt");
    ASSERT_TRUE(wait_for_file(run / "checkpoints" / "step-00000003.pt", 120))
        << slurp(base / "log.txt");
    ASSERT_EQ(kill(pid, sig), 0);
    int st = wait_status(pid);
    ASSERT_TRUE(WIFEXITED(st)) << "killed by signal " << WTERMSIG(st);
    EXPECT_EQ(WEXITSTATUS(st), 3) << slurp(base / "log.txt");
    const std::string events = slurp(run / "events.log");
    EXPECT_NE(events.find("stopped on request"), std::string::npos) << events;
    const int64_t stopped_at =
        load_run(run, torch::kCPU, "last").state.step;
    EXPECT_GE(stopped_at, 3);
    EXPECT_LT(stopped_at, 60);

    // The same command resumes and finishes; the result equals training the
    // same steps without the interruption.
    pid = spawn(train_args(run), base / "log2.txt");
    st = wait_status(pid);
    ASSERT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << slurp(base / "log2.txt");
    EXPECT_EQ(load_run(run, torch::kCPU, "last").state.step, 60);
    if (sig == SIGTERM) {
      // The uninterrupted reference, once.
      const fs::path whole = base / "whole";
      pid = spawn(train_args(whole), base / "log3.txt");
      st = wait_status(pid);
      ASSERT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << slurp(base / "log3.txt");
      const TrainConfig cfg = load_run(whole, torch::kCPU, "last").config;
      EXPECT_TRUE(torch::equal(params_of(whole / "checkpoints" / "last.pt", cfg),
                               params_of(run / "checkpoints" / "last.pt", cfg)));
    }
  }
}

TEST(TrainSignals, ASecondSignalEndsAtOnce) {
  const fs::path base = testing::scratch_dir("rf_signals2");
  const fs::path run = base / "run";
  pid_t pid = spawn(train_args(run), base / "log.txt");
  ASSERT_TRUE(wait_for_file(run / "checkpoints" / "step-00000002.pt", 120))
      << slurp(base / "log.txt");
  ASSERT_EQ(kill(pid, SIGTERM), 0);
  ASSERT_EQ(kill(pid, SIGTERM), 0);
  int st = wait_status(pid);
  // Either the second signal ended it (its default action), or the first
  // one's clean stop won the race; never a hang or a crash.
  if (WIFSIGNALED(st)) {
    EXPECT_EQ(WTERMSIG(st), SIGTERM);
  } else {
    EXPECT_EQ(WEXITSTATUS(st), 3);
  }
  // Whatever happened, last.pt is a complete checkpoint.
  EXPECT_NO_THROW(load_run(run, torch::kCPU, "last"));
}

TEST(TrainCli, ResumeKeepsTheRunsSettingsAndLogsChanges) {
  const fs::path base = testing::scratch_dir("rf_resume_cfg");
  const fs::path run = base / "run";
  auto args = train_args(run);
  // Shorter: 1 epoch of 3 steps.
  for (auto& a : args)
    if (a == "train.steps_per_epoch=60") a = "train.steps_per_epoch=3";
  pid_t pid = spawn(args, base / "log.txt");
  int st = wait_status(pid);
  ASSERT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << slurp(base / "log.txt");

  // Resume with nothing repeated but one more epoch: the stored settings hold.
  pid = spawn({DOFARM_TRAIN_EXE, "train", "--data", data_dir().string(), "--run", run.string(),
               "--set", "train.epochs=2"},
              base / "log2.txt");
  st = wait_status(pid);
  const std::string log = slurp(base / "log2.txt");
  ASSERT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << log;
  EXPECT_NE(log.find("resume with a changed setting: train.epochs: 1 -> 2"), std::string::npos)
      << log;
  const std::string config = slurp(run / "config.toml");
  EXPECT_NE(config.find("steps_per_epoch = 3"), std::string::npos) << config;
  EXPECT_NE(config.find("warmup_steps = 2"), std::string::npos) << config;
  EXPECT_EQ(load_run(run, torch::kCPU, "last").state.step, 6);

  // Another model is refused, naming the key.
  pid = spawn({DOFARM_TRAIN_EXE, "train", "--data", data_dir().string(), "--run", run.string(),
               "--set", "model.recurrent=true"},
              base / "log3.txt");
  st = wait_status(pid);
  EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 2);
  EXPECT_NE(slurp(base / "log3.txt").find("model.recurrent"), std::string::npos);
}

TEST(DenoiseCli, RefusesToWriteOverItsInput) {
  const fs::path dir = testing::scratch_dir("rf_denoise_self");
  FrameBuffers fb = testing::synthetic_frame(2, 32, 32, 1, 4);
  const fs::path exr = dir / "frame.exr";
  write_frame_exr(exr, fb);
  const std::string before = slurp(exr);
  for (const std::string& out : {exr.string(), (dir / "." / "frame.exr").string()}) {
    pid_t pid = spawn({DOFARM_TRAIN_EXE, "denoise", "--run", trained().string(), exr.string(), out},
                      dir / "log.txt");
    int st = wait_status(pid);
    EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 2) << slurp(dir / "log.txt");
    EXPECT_NE(slurp(dir / "log.txt").find("never replaces its input"), std::string::npos);
  }
  EXPECT_EQ(slurp(exr), before);
}

}  // namespace
}  // namespace dofarm::trainer
