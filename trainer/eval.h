// The evaluation report (thesis 5.1, table 5.1); inference itself is
// trainer/inference.h.
#pragma once

#include <cmath>
#include <filesystem>
#include <iterator>
#include <string>

#include "trainer/config.h"
#include "trainer/inference.h"

namespace dofarm::trainer {

struct EvalOptions {
  std::filesystem::path run_dir, data_dir, out_dir;
  int max_frames = 0;  // 0 = every validation frame
  int max_images = 8;  // comparison PNGs written (first frames)
  int version = 0;     // noisy version fed to the network
  std::string checkpoint = "best";  // best | last | PATH
  Weights weights = Weights::kAuto;  // the moving average or the trained weights
  // Also score every frame of the data, training frames included (thesis
  // 5.1: table 5.1 averages over each scene's complete set of frames): a
  // second table in the report, "all_frames" in report.json.
  bool all_frames = true;
  // Every frame of the data is a validation frame: frames rendered apart
  // from the run's training data (the same sequence's held-out frames at
  // cleaner references, say). A shard whose content the run's split trained
  // on is refused.
  bool held_out = false;
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
  // (kFocusRegions) and the albedo prefilter (data.albedo_prefilter) still
  // read the frame's own CoC. Recorded in the report ("coc_override").
  // NaN = off.
  float coc_override = NAN;
  // A probe of which inputs the model uses: each named buffer (buffer_infos()
  // name, e.g. "depth", "coc", "normal") reaches the network's inputs as its
  // frame mean, channel by channel, so the input keeps its level and loses
  // every spatial detail. Only the inputs: demodulation, the prefilter and
  // the regions scored read the frame's own buffers. A buffer no input of
  // the model reads is refused. Recorded in the report ("flattened_inputs").
  std::vector<std::string> flatten_inputs;
};

struct EvalSummary {
  int frames = 0;
  double ssim = 0, psnr = 0, rel_mse = 0, ms = 0;  // means over frames, denoised
  double flicker = NAN;  // mean over consecutive validation frame pairs (metrics.h)
  double ms_at_size = NAN;  // with time_side: median ms per side x side frame
  int frames_all = 0;                              // with all_frames: every frame
  double ssim_all = NAN;
};

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
