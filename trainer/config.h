// Training configuration (docs/trainer.md lists every key with its default).
//
// TrainConfig is a plain struct; its in-class initialisers are the defaults and
// the only place they live (STYLE.md 2, 8). load_train_config() reads a TOML
// file plus `--set section.key=value` overrides and throws SpecError
// ("train.toml:12:3: "epochs": expected a positive integer, got -1") on the
// first bad value or unknown key. The run folder keeps the effective config as
// config.toml; resuming compares it with the new one (incompatible_reason()).
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "common/error.h"

namespace dofarm::trainer {

enum class AlbedoSource {
  kReference,  // `albedo_ref` (N spp through the lens): low-noise demodulation
  kVersion,    // the 1-spp `albedo` of the same noisy version (what a game has)
};

enum class AlbedoPrefilter {
  kNone,
  kCoc,  // blur by the CoC (thesis 6.1; trainer/prefilter.h)
};

enum class SplitMode {
  kFrames,  // last val_fraction of every shard's frames is validation
  kShard,   // whole shards are validation, chosen by a hash of the file name
};

enum class DecoderForm {
  // Each block: concat skip -> 2 x (conv to the level's width + LeakyReLU);
  // then a linear 3x3 output convolution to 3 channels.
  kProject,
  // Thesis 4.3.1: each block: concat skip -> conv to the level's width ->
  // conv to the next level's width; the last block ends in 3 channels and
  // has no activation; no output convolution.
  kThesis,
};

// What a 3x3 convolution sees beyond a crop's or frame's border.
enum class PaddingMode {
  // Zeros (the thesis and Chaitanya 2017). The deepest levels of a network
  // trained on 64-px crops always see this border; on whole frames their
  // interior never does, and a network can come to depend on it
  // (docs/results.md, "Where whole frames fail").
  kZeros,
  // The nearest value repeated: a border looks like a smooth continuation,
  // not a drop to zero.
  kReplicate,
};

struct ModelConfig {
  // Input channels in order, "name:encoding" (trainer/inputs.h has the
  // table); the old `model.dof = false` removes the coc entry.
  std::vector<std::string> inputs = {"radiance:log1p", "albedo:as_stored",    "normal:as_stored",
                                     "depth:focal",    "roughness:as_stored", "coc:log"};
  std::vector<int> channels;  // encoder widths; empty = thesis defaults
  int bottleneck = 0;         // 0 = same as the last encoder width
  int bottleneck_convs = 2;   // thesis 4.3.1: 3, like the encoder blocks
  DecoderForm decoder = DecoderForm::kProject;
  PaddingMode padding = PaddingMode::kZeros;
  // With replicate padding: the first level that replicates; shallower ones
  // pad with zeros. Level i works at 1/2^i of the frame (encoder and decoder
  // blocks), 5 is the bottleneck; 0 = every convolution replicates.
  int replicate_from = 0;
  bool recurrent = false;    // Chaitanya 2017 recurrent encoder blocks
  float leaky_slope = 0.1f;  // LeakyReLU negative slope (thesis 4.2)

  bool has_coc() const;  // an input made from the coc buffer
  // Thesis defaults: 32,43,57,76,101 (RAE widths); 36,48,64,85,113 with CoC.
  std::vector<int> effective_channels() const;
  int effective_bottleneck() const;
  int input_channels() const;  // sum of the inputs' buffer channel counts
};

struct DataConfig {
  int sequence = 7;                  // frames per training sequence (thesis 4.3.3)
  int crop = 64;                     // square crop side, pixels
  float stop_probability = 0.25f;    // per frame: the camera "stops" (thesis 4.3.3)
  float reverse_probability = 0.5f;  // per sequence (thesis 4.3.3)
  bool rotate = true;                // one of 0/90/180/270 degrees per sequence
  AlbedoSource albedo = AlbedoSource::kReference;
  // The demodulation albedo blurred per pixel by sigma = scale * CoC
  // (thesis 6.1, 6.3 future work; trainer/prefilter.h). Off by default.
  AlbedoPrefilter albedo_prefilter = AlbedoPrefilter::kNone;
  float albedo_prefilter_scale = 0.25f;  // sigma per CoC pixel: a disc's spread
  float demod_eps = 1e-3f;               // radiance / (albedo + eps)
  float coc_log_scale = 3.4965f;         // ln(1 + 32): a 32-pixel CoC maps to 1 (coc:log)
  float coc_sharp_px = 1.0f;             // coc:thesis "acceptable" CoC (thesis 4.2.4)
  float coc_max_px = 32.0f;              // coc:thesis scene maximum CoC (thesis 4.2.4)
  float depth_scale = 5.0f;              // depth:scene, scene units (thesis 4.2.4)
  SplitMode split = SplitMode::kFrames;
  float val_fraction = 0.1f;     // of frames (kFrames) or of shards (kShard)
  int queue = 32;                // sequences held ready (bounds memory)
  int readers = 2;               // background reader threads
  float rescan_seconds = 10.0f;  // look for new shards this often
};

enum class GradientLoss {
  kL1,      // mean |LoG(P) - LoG(T)| (unit-L1 kernel)
  kThesis,  // thesis eq. 4.4: sum (LoG(P) - LoG(T))^2 / sum LoG(T)^2, per frame
};

struct LossConfig {
  float l1 = 0.8f;   // thesis eq. 4.2, 4.3
  float log = 0.2f;  // Laplacian-of-Gaussian gradient term (form: log_form)
  GradientLoss log_form = GradientLoss::kL1;
  // LoG scale in pixels: the usual sigma of HFEN (Ravishankar and Bresler 2011),
  // the LoG error the RAE's gradient loss is built on.
  float log_sigma = 1.5f;
  float temporal = 0.0f;  // L1 of frame differences (Chaitanya 2017; for the recurrent model)
  // Focus weighting (thesis 6.1 / 6.3 future work: penalise lost detail
  // where the CoC says the pixel is sharp): the L1 and gradient terms weigh
  // each pixel by 1 + focus_weight * exp(-(coc / focus_coc_px)^2), normalised
  // to mean 1 per frame. 0 = off.
  float focus_weight = 0.0f;
  float focus_coc_px = 1.0f;  // CoC (pixels) at which the extra weight falls to 1/e
};

enum class Schedule {
  kWarmupDecay,  // linear warm-up over warmup_steps, then lr_decay^epoch
  kThesis,       // eq. 4.5 with E = passes over the training sequences
};

enum class BestBy { kValidation, kTraining, kFrames };

// A table of an enum's names, as the command line spells them, e.g.
// precision_names(); names_of() lists them, value_of() looks one up and
// throws SpecError naming `key` and the allowed names for any other.
template <typename E>
using NameTable = std::vector<std::pair<std::string, E>>;
template <typename E>
std::vector<std::string> names_of(const NameTable<E>& table) {
  std::vector<std::string> names;
  for (const auto& entry : table) names.push_back(entry.first);
  return names;
}
template <typename E>
E value_of(const NameTable<E>& table, const std::string& name, const std::string& key) {
  std::string allowed;
  for (const auto& [n, value] : table) {
    if (n == name) return value;
    allowed += (allowed.empty() ? "" : " or ") + n;
  }
  throw SpecError(FileLoc{}, key, "expected " + allowed + ", got \"" + name + "\"");
}

// Arithmetic of the network's convolutions (trainer/precision.h).
enum class Precision { kFp32, kBf16 };
// Its names, as train.precision, --precision and the benchmarks spell them.
inline const NameTable<Precision>& precision_names() {
  static const NameTable<Precision> names = {{"fp32", Precision::kFp32},
                                             {"bf16", Precision::kBf16}};
  return names;
}

struct OptimConfig {
  int epochs = 100;
  // 0 = one pass over the training sequences (their count when the run
  // started, recorded in RUN/passes.json).
  int steps_per_epoch = 250;
  Schedule schedule = Schedule::kWarmupDecay;
  // Which loss picks best.pt; training loss is the thesis's (5.1). Without
  // validation sequences it is always the training loss.
  BestBy best_by = BestBy::kValidation;
  int batch = 4;       // sequences per batch (thesis 4.3)
  float lr = 1e-3f;    // peak learning rate
  float beta1 = 0.9f;  // Adam (thesis 4.3)
  float beta2 = 0.99f;
  int warmup_steps = 500;  // linear ramp up to lr (eq. 4.5, first branch)
  float lr_decay = 0.97f;  // per epoch after warm-up (eq. 4.5, second branch)
  float lr_min = 1e-6f;
  uint64_t seed = 1;
  int val_sequences = 32;       // drawn deterministically each epoch
  // Whole validation frames denoised and scored (SSIM) after each epoch,
  // spread over the validation frames (full_frame_ssim in inference.h); 0 = off.
  int val_frames = 2;
  std::string device = "auto";  // auto | cpu | cuda
  int max_bad_steps = 3;        // consecutive non-finite steps before a rollback
  // Gradients whose global L2 norm exceeds this are scaled down to it before
  // the Adam step (clip_gradients in step_runner.h); 0 = off. Every step's
  // norm before clipping is in RUN/steps.csv. 1: about four times the
  // default's median norm once trained; it stopped the loss spikes of longer
  // runs and scored higher on three seeds of 1000 steps (docs/results.md).
  float grad_clip = 1.0f;
  float rollback_lr_factor = 0.5f;
  // Exponential moving average of the weights (Polyak and Juditsky 1992):
  // after every Adam step avg = d * avg + (1 - d) * w with
  // d = min(ema, (1 + t) / (10 + t)) at step t (ema_decay() in train.h), so
  // that early averages do not hold the random initial weights. Validation,
  // best.pt, eval, denoise and export use the average (--weights raw reads
  // the trained weights); checkpoints keep both, and a resumed run continues
  // the average bit for bit. One bad step moves the average by 1 - d only
  // (docs/results.md, "Weight averaging"). 0 = off (the thesis preset).
  float ema = 0.999f;
  // Model copies a CPU step is split across, one thread each (StepRunner in
  // train.h); 0 = auto: 2 when on the CPU with >= 2 intra-op threads and a
  // batch of >= 2, else 1. Changes the float summation order, not the step.
  int cpu_replicas = 0;
  // bf16: the network's forward and backward under bfloat16 autocast on the
  // CPU (training and validation); weights, Adam and the loss stay float32.
  Precision precision = Precision::kFp32;
};

struct TrainConfig {
  ModelConfig model;
  DataConfig data;
  LossConfig loss;
  OptimConfig train;
};

// Parses `path` (empty path: no file) over `base` (null: the defaults) and
// applies overrides in order. A resumed run passes its stored config as
// `base`, so that only what the user names changes.
TrainConfig load_train_config(const std::filesystem::path& path,
                              const std::vector<std::string>& overrides = {},
                              const TrainConfig* base = nullptr);
// The built-in presets: "default" (TrainConfig{}) and "thesis" (every value
// the thesis states; docs/trainer.md lists the differences). Applied over
// `base` like a config file; an unknown name is a SpecError naming it.
std::vector<std::string> preset_names();
const std::string& preset_toml(const std::string& name);
TrainConfig apply_preset(const std::string& name, const TrainConfig& base = {});

// Parses TOML text as if it were the file `virtual_path`.
TrainConfig parse_train_config(const std::string& toml_text,
                               const std::filesystem::path& virtual_path,
                               const std::vector<std::string>& overrides = {},
                               const TrainConfig* base = nullptr);

// The keys whose values differ, as "train.epochs: 3 -> 5", in key order.
std::vector<std::string> config_changes(const TrainConfig& from, const TrainConfig& to);

// Every key, with its current value, as TOML (round-trips through parse).
std::string to_toml(const TrainConfig& cfg);

// Why a run saved with `saved` cannot be resumed with `wanted` (keys that change
// the model or its inputs differ); empty when compatible. Schedule keys such as
// train.epochs may change.
std::string incompatible_reason(const TrainConfig& saved, const TrainConfig& wanted);

}  // namespace dofarm::trainer
