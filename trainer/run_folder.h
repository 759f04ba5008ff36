// A training run's folder as files: its checkpoints (written atomically and
// verified on every load), the choice of checkpoint for eval / denoise /
// export, and loading a trained model without the training loop.
//
// Checkpoint file (docs/trainer.md, "Checkpoints"):
//   line 1   "dofarm-checkpoint 1 <BLAKE2b-128 of the payload, hex> <payload bytes>\n"
//   payload  a libtorch archive (torch::serialize::OutputArchive) holding
//            model, optimizer, state (epoch, step, sample index),
//            state_f (LR scale, best loss), the run's config TOML and, when
//            train.ema is on, average (the weights' moving average).
// A file whose payload does not match its header is refused with an error
// naming it; nothing is ever trained or denoised from a damaged checkpoint.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "trainer/config.h"
#include "trainer/model.h"

namespace dofarm::trainer {

// Everything that, with the config and the data, determines the rest of a run.
struct RunState {
  int64_t epoch = 0;         // next epoch to run
  int64_t step = 0;          // optimizer steps taken
  int64_t sample_index = 0;  // next training sample of the stream
  double lr_scale = 1.0;     // lowered by rollbacks
  double best = INFINITY;    // lowest validation loss (training loss without validation)
};

// Writes `path` through a temporary file in the same folder, fsynced, then
// renamed over the old one (a crash leaves the previous checkpoint intact).
// `average` (train.ema; may be null) is stored beside the trained weights.
// Throws RuntimeError for non-finite weights: no NaN/Inf reaches a checkpoint.
void save_checkpoint(const std::filesystem::path& path, Denoiser& model, torch::optim::Adam& opt,
                     const RunState& st, const TrainConfig& cfg, Denoiser* average = nullptr);

// Verifies the file's checksum, then loads the trained weights into `model`
// (and the optimizer when `opt` is given; the moving average into `average`
// when given: the stored one, or a copy of the trained weights when the
// checkpoint has none, and *had_average says which). Throws RuntimeError
// naming the file when it is missing, damaged, not a checkpoint, or holds
// non-finite values.
RunState load_checkpoint(const std::filesystem::path& path, Denoiser& model,
                         torch::optim::Adam* opt, torch::Device device, Denoiser* average = nullptr,
                         bool* had_average = nullptr);

// `dst`'s weights become a copy of `src`'s (same model config).
void copy_weights(Denoiser& dst, Denoiser& src);

// Whole small text files are read with read_file_bytes (common/file_bytes.h);
// write_text_atomic as save_checkpoint.
void write_text_atomic(const std::filesystem::path& path, const std::string& text);

// The device the config asks for: CUDA when `auto` and available.
torch::Device pick_device(const std::string& device);

// `which`: "best" (the lowest validation loss; the default), "last", or a
// path to a checkpoint file. "best" falls back to "last" while a run has
// no best checkpoint yet (it is written after the first epoch).
std::filesystem::path checkpoint_path(const std::filesystem::path& run_dir,
                                      const std::string& which);

// Which weights of a checkpoint a trained model is made of.
enum class Weights {
  kAuto,      // the moving average when the checkpoint holds one, else the trained
  kAveraged,  // the moving average (an error when the run kept none: train.ema = 0)
  kRaw,       // the trained weights, as after the checkpoint's last step
};
// Its names, as --weights spells them.
const NameTable<Weights>& weights_names();

// A trained model from a run folder, its config, on `device`, in eval mode,
// with the checkpoint it came from, that checkpoint's state and whether the
// model is the moving average.
struct LoadedRun {
  TrainConfig config;
  Denoiser model{nullptr};
  std::filesystem::path checkpoint;
  RunState state;
  bool averaged = false;
  // "moving average" or "trained": what reports, EXR headers and the export
  // contract record.
  const char* weights_label() const { return averaged ? "moving average" : "trained"; }
};
// A checkpoint of `run`'s weights alone (the ones load_run chose, under the
// key they came from: "average" or "model"), its state and config, without
// the optimizer state: a quarter to a third of a training checkpoint, for
// evaluation and denoising on another machine (`eval --checkpoint FILE`).
// Training refuses to resume from it.
void save_weights_checkpoint(const std::filesystem::path& path, LoadedRun& run);

LoadedRun load_run(const std::filesystem::path& run_dir, torch::Device device,
                   const std::string& which = "best", Weights weights = Weights::kAuto);

}  // namespace dofarm::trainer
