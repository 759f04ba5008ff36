// Inference on full frames and the evaluation report (thesis 5.1, table 5.1).
#pragma once

#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <iterator>
#include <vector>

#include "common/image.h"
#include "trainer/config.h"
#include "trainer/dataset.h"
#include "trainer/model.h"
#include "trainer/run_folder.h"

namespace dofarm::trainer {

// Denoises full frames of any size with a trained run. Frames of one
// sequence must come in order: the recurrent model carries its state.
class FrameDenoiser {
 public:
  // `checkpoint`: "best", "last" or a checkpoint file (load_run).
  // `precision`: the network under bf16 autocast on the CPU
  // (trainer/precision.h); fp32 is the exact one.
  FrameDenoiser(const std::filesystem::path& run_dir, torch::Device device,
                const std::string& checkpoint = "best", Precision precision = Precision::kFp32);
  // Linear RGB (3, H, W) from noisy version `version` of `frame`.
  // `seconds` receives the time of network + remodulation (no IO, no input
  // preparation; with data.albedo_prefilter the prefilter too), synchronised
  // with the device.
  std::vector<float> denoise(const FrameBuffers& frame, int version, double* seconds = nullptr);
  void reset_sequence() { state_.clear(); }
  const TrainConfig& config() const { return run_.config; }
  const LoadedRun& run() const { return run_; }

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
                                 const FrameBuffers& frame, int version, double* seconds = nullptr);

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

struct EvalOptions {
  std::filesystem::path run_dir, data_dir, out_dir;
  int max_frames = 0;  // 0 = every validation frame
  int max_images = 8;  // comparison PNGs written (first frames)
  int version = 0;     // noisy version fed to the network
  std::string checkpoint = "best";  // best | last | PATH
  // Also score every frame of the data, training frames included (thesis
  // 5.1: table 5.1 averages over each scene's complete set of frames): a
  // second table in the report, "all_frames" in report.json.
  bool all_frames = true;
  // Also time the denoise of a side x side frame (the first validation frame
  // repeated periodically to that size), median of `time_reps` runs after
  // one warm-up: "denoise_ms_at_size" in report.json. 0 = off.
  int time_side = 0;
  int time_reps = 3;
  Precision precision = Precision::kFp32;  // the network's arithmetic (precision.h)
  // Side-by-side crops (report.h, choose_focus_crops) of the `crops` most
  // blurred validation frames (the out-of-focus window's mean CoC; frames
  // with a sharp window too first; every shard's best frame before any
  // shard's second): crops/crop-K-REGION-
  // {noisy,denoised,reference}.png, `crop_side` px windows drawn 2x, listed
  // in report.md and report.json ("crops"). 0 = none.
  int crops = 0;
  int crop_side = 64;
  // A probe of whether the model uses its CoC input: when finite, the
  // network is fed this circle of confusion (pixels) at every pixel instead
  // of the frame's own (0: everything in focus). The regions scored
  // (kFocusRegions) still come from the frame's own CoC. Recorded in the
  // report ("coc_override"). NaN = off.
  float coc_override = NAN;
};

struct EvalSummary {
  int frames = 0;
  double ssim = 0, psnr = 0, rel_mse = 0, ms = 0;  // means over frames, denoised
  double flicker = NAN;  // mean over consecutive validation frame pairs (metrics.h)
  double ms_at_size = NAN;  // with time_side: median ms per side x side frame
  int frames_all = 0;                              // with all_frames: every frame
  double ssim_all = NAN;
};

// The buffers denoise() reads for noisy version `version` with `cfg`, and how
// many non-finite values each holds: {layer name, count} for every layer
// with at least one. With `repair`, those values are set to 0.
std::vector<std::pair<std::string, size_t>> non_finite_inputs(FrameBuffers& frame, int version,
                                                              const TrainConfig& cfg,
                                                              bool repair);

// `frame` repeated periodically (x mod width, y mod height) to w x h: every
// buffer, the camera kept. For timing at a size the data does not have.
FrameBuffers tile_frame(const FrameBuffers& frame, int w, int h);
// The w x h window at (x0, y0) of `frame`, every buffer, the camera kept
// (a CoC in pixels stays right: the window keeps the frame's scale).
FrameBuffers crop_frame(const FrameBuffers& frame, int x0, int y0, int w, int h);

// The pixel regions every score is taken over, by circle of confusion in
// pixels, lo <= CoC < hi: all pixels, in focus ("acceptably sharp", CoC < 1
// px, DESIGN.md), out of focus, and the out-of-focus pixels in three bands
// of blur, each 4x the last, so that what an input does for the blurred
// pixels can be seen by how blurred they are (report.json: the region's
// name under "summary", "frames", "scenes"; report.md: "By circle of
// confusion"). The first three are the report's main table.
struct FocusRegion {
  const char* name;
  float lo, hi;
};
inline constexpr FocusRegion kFocusRegions[] = {
    {"all", -INFINITY, INFINITY}, {"in_focus", -INFINITY, 1.0f}, {"out_of_focus", 1.0f, INFINITY},
    {"coc_1_4", 1.0f, 4.0f},      {"coc_4_16", 4.0f, 16.0f},     {"coc_16_up", 16.0f, INFINITY}};
inline constexpr int kRegionCount = int(std::size(kFocusRegions));

// Writes OUT/report.md, OUT/report.json, OUT/frame-*.png, OUT/loss.png.
EvalSummary evaluate(const EvalOptions& options);

}  // namespace dofarm::trainer
