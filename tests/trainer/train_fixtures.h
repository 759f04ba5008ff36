// Shared fixtures of the trainer's tests (train_test.cpp, eval_test.cpp): a
// tiny configuration, one synthetic shard and one trained run, each made
// once per test binary (static locals of inline functions).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "tests/trainer/synthetic.h"
#include "trainer/config.h"
#include "trainer/run_folder.h"
#include "trainer/train.h"

namespace dofarm::trainer::fixtures {

namespace fs = std::filesystem;

inline fs::path fresh_dir(const std::string& name) { return testing::scratch_dir(name); }

// A tiny but complete configuration: 8-channel model, 32x32 crops, 3 frames.
inline TrainConfig tiny_config() {
  TrainConfig c = load_train_config(
      "", {"model.channels=[8, 8, 8, 8, 8]", "data.crop=32", "data.sequence=3", "data.queue=4",
           "data.readers=1", "train.epochs=2", "train.steps_per_epoch=3", "train.batch=2",
           "train.warmup_steps=2", "train.val_sequences=2", "train.device=cpu"});
  return c;
}

inline fs::path shared_data() {
  static fs::path d = [] {
    fs::path p = fresh_dir("train_data");
    testing::write_synthetic_shard(p / "shard-00000.h5", 12, 64, 64, 3, 5);
    return p;
  }();
  return d;
}

inline torch::Tensor flat_params(const fs::path& run) {
  LoadedRun r = load_run(run, torch::kCPU);
  std::vector<torch::Tensor> ps;
  for (const auto& p : r.model->parameters()) ps.push_back(p.detach().flatten());
  return torch::cat(ps);
}

// A run trained 6 epochs of 5 steps on shared_data() (9 frames to train, 3
// to validate), for the tests that evaluate.
inline fs::path trained_run() {
  static fs::path run = [] {
    fs::path r = fresh_dir("run_eval");
    TrainOptions o{shared_data(), r, tiny_config()};
    o.config.data.sequence = 3;  // 12 frames: 9 to train, 3 to validate
    o.config.data.val_fraction = 0.25f;
    o.config.train.epochs = 6;
    o.config.train.steps_per_epoch = 5;
    train(o);
    return r;
  }();
  return run;
}

}  // namespace dofarm::trainer::fixtures
