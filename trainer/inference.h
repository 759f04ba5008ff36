// Inference on whole frames: a trained run's denoiser over frames of any
// size, a model in memory over validation frames (the trainer's full-frame
// validation), and the frame reshaping they use (tiles, windows).
#pragma once

#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "common/image.h"
#include "trainer/config.h"
#include "trainer/dataset.h"
#include "trainer/model.h"
#include "trainer/run_folder.h"

namespace dofarm::trainer {

// Buffers (by buffer_infos() name) that the network's inputs read in place
// of the frame's own, each with the buffer's channels x pixels values at
// the version being denoised. Only the inputs: the demodulation albedo,
// its CoC-sized prefilter and the remodulation still read the frame's own
// buffers, so a probe changes what the network is told and nothing else.
using InputOverrides = std::map<std::string, const float*>;

// Denoises full frames of any size with a trained run. Frames of one
// sequence must come in order: the recurrent model carries its state.
class FrameDenoiser {
 public:
  // `checkpoint`: "best", "last" or a checkpoint file (load_run).
  // `precision`: the network under bf16 autocast on the CPU
  // (trainer/precision.h); fp32 is the exact one.
  // `weights`: the moving average or the trained weights (load_run).
  FrameDenoiser(const std::filesystem::path& run_dir, torch::Device device,
                const std::string& checkpoint = "best", Precision precision = Precision::kFp32,
                Weights weights = Weights::kAuto);
  // Linear RGB (3, H, W) from noisy version `version` of `frame`.
  // `seconds` receives the time of network + remodulation (no IO, no input
  // preparation; with data.albedo_prefilter the prefilter too), synchronised
  // with the device.
  // `overrides` (optional): buffers the network's inputs read in place of
  // the frame's own (InputOverrides; the CoC probe, eval --coc-override;
  // eval --flatten-input).
  std::vector<float> denoise(const FrameBuffers& frame, int version, double* seconds = nullptr,
                             const InputOverrides* overrides = nullptr);
  void reset_sequence() { state_.clear(); }
  const TrainConfig& config() const { return run_.config; }
  const LoadedRun& run() const { return run_; }
  Denoiser& model() { return run_.model; }

 private:
  LoadedRun run_;
  torch::Device device_;
  Precision precision_;
  std::vector<torch::Tensor> state_;
};

// Denoises noisy version `version` of `frame` with `model` (configured by
// `cfg`): FrameDenoiser::denoise without a run folder, for a model in
// memory (the trainer's full-frame validation). `state`: the recurrent
// state, carried from the previous frame of the sequence (empty = none).
// Throws RuntimeError when the network's output is not finite.
std::vector<float> denoise_frame(Denoiser& model, const TrainConfig& cfg, torch::Device device,
                                 Precision precision, std::vector<torch::Tensor>& state,
                                 const FrameBuffers& frame, int version, double* seconds = nullptr,
                                 const InputOverrides* overrides = nullptr);

// The trainer's full-frame validation (train.val_frames): `count` whole
// validation frames, spread evenly over the validation frames of `splits`
// (in their order), read from `data_dir`, each denoised alone (no recurrent
// state) at noisy version 0 and scored by SSIM against its reference as
// eval scores (sRGB, clamped). Returns the mean; NaN when there is no
// validation frame or an output was not finite. Networks trained on crops
// meet whole frames only here: a model can score well on crops and fail on
// whole frames (docs/trainer.md, "Full-frame validation").
double full_frame_ssim(Denoiser& model, const TrainConfig& cfg, torch::Device device,
                       const std::filesystem::path& data_dir, const std::vector<ShardSplit>& splits,
                       int count);

// The same frames scored whole and also denoised as independent tile x tile
// windows put back together (denoise_in_tiles). A sound model scores its
// whole frames a little above its tiles (the tiles have seams); one that
// depends on the borders of the crops it was trained on scores them below,
// losing its pixels far from the frame's border (docs/results.md, "Where
// whole frames fail"). tile = 0: whole frames only (tiles NaN).
struct FrameScores {
  double whole = NAN;
  double tiles = NAN;
};
FrameScores full_frame_scores(Denoiser& model, const TrainConfig& cfg, torch::Device device,
                              const std::filesystem::path& data_dir,
                              const std::vector<ShardSplit>& splits, int count, int tile);

// `frame` cut into tile x tile windows from its top-left corner (narrower at
// the right and bottom where its sides are not multiples of tile), each
// denoised alone by `denoise` (3 planes of the window's pixels), and joined
// into one 3-plane image of the frame's size.
std::vector<float> denoise_in_tiles(
    const FrameBuffers& frame, int tile,
    const std::function<std::vector<float>(const FrameBuffers&)>& denoise);

// The buffers denoise() reads for noisy version `version` with `cfg`, and how
// many non-finite values each holds: {layer name, count} for every layer
// with at least one. With `repair`, those values are set to 0.
std::vector<std::pair<std::string, size_t>> non_finite_inputs(FrameBuffers& frame, int version,
                                                              const TrainConfig& cfg, bool repair);

// `frame` repeated periodically (x mod width, y mod height) to w x h: every
// buffer, the camera kept. For timing at a size the data does not have.
FrameBuffers tile_frame(const FrameBuffers& frame, int w, int h);
// The w x h window at (x0, y0) of `frame`, every buffer, the camera kept
// (a CoC in pixels stays right: the window keeps the frame's scale).
FrameBuffers crop_frame(const FrameBuffers& frame, int x0, int y0, int w, int h);

}  // namespace dofarm::trainer
