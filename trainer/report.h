// Pictures for evaluation reports: side-by-side comparison strips with an
// error heat map (PNG), and plots as SVG (text: axis titles, tick values,
// legends), for report.html and report.md.
#pragma once

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace dofarm::trainer {

// A comparison strip as PNG file bytes (written as frame-NNN.png and embedded
// in report.html): noisy | denoised | reference | error, each sRGB-encoded
// and clamped; the error panel is the mean absolute display-space difference
// between denoised and reference, times 4, on a black-red-yellow-white ramp.
// All images (3, H, W) linear radiance.
std::string comparison_png_bytes(const std::vector<float>& noisy, const std::vector<float>& denoised,
                                 const std::vector<float>& reference, int width, int height);
// Side-by-side crops where depth of field matters: square windows of a
// frame chosen by its circle of confusion (pixels), from a summed-area table
// over windows at a stride of side / 4. in_focus: the window of the smallest
// mean CoC, kept when that mean is below 1 px ("acceptably sharp",
// DESIGN.md); out_of_focus: the window of the largest mean CoC, kept when it
// is at least 2 px. Ties go to the first window in row order, so every
// model evaluated on the same data gets the same windows. With `reference`
// (linear, (3, H, W)), a window whose reference is more than half display
// white (every channel >= 1, which the sRGB crops clamp to a flat white: a
// sky behind the focus, a lamp) is passed over when another window
// qualifies, so that a crop shows something the models could get wrong.
struct CropWindow {
  int x = 0, y = 0, side = 0;
  double mean_coc = 0;
  bool found = false;
};
struct FocusCrops {
  CropWindow in_focus, out_of_focus;
};
FocusCrops choose_focus_crops(const std::vector<float>& coc, int width, int height, int side,
                              const std::vector<float>* reference = nullptr);
// Which frames `eval --crops` shows: given each shard's candidate frames
// ranked by blur (the out-of-focus window's mean CoC, descending), up to `k`
// (shard, rank) picks: every shard's most blurred frame first, the most
// blurred shard first, then every shard's second, and so on. A lens
// animation's first validation frames are often its least blurred, and
// neighbouring frames of one shard look alike.
std::vector<std::pair<size_t, size_t>> spread_by_blur(
    const std::vector<std::vector<double>>& blur, int k);
// The window of a linear (3, H, W) image as PNG bytes, sRGB-encoded and
// clamped as the comparison strips, each pixel drawn zoom x zoom.
std::string crop_png_bytes(const std::vector<float>& image, int width, int height,
                           const CropWindow& window, int zoom);

// The error panel's scale: display-space mean absolute error 0 .. 0.25 on the
// heat ramp, as an SVG colour bar with tick values.
std::string error_scale_svg();

struct LossCurve {
  std::vector<double> epoch, train, val, lr;  // val may hold NaN (no validation set)
  std::vector<double> val_ssim, val_psnr;     // NaN where not recorded
  std::vector<double> val_frame_ssim;         // whole validation frames; NaN where not recorded
  std::vector<double> val_tile_ssim;  // the same frames as crop-sized tiles; NaN where not recorded
};
// Reads RUN/loss.csv (empty curve when absent).
LossCurve read_loss_csv(const std::filesystem::path& csv);
struct StepCurve {
  // loss and grad_norm NaN for a skipped step; grad_norm NaN in rows written
  // before the column existed.
  std::vector<double> step, loss, lr, grad_norm;
};
// Reads RUN/steps.csv (step,loss,lr,grad_norm; empty curve when absent).
StepCurve read_steps_csv(const std::filesystem::path& csv);

struct PlotSeries {
  std::string label, colour;
  std::vector<double> x, y;  // non-finite y (and y <= 0 on a log axis) are gaps
};
struct PlotSpec {
  std::string title, x_title, y_title;
  bool log_y = false;
  std::vector<PlotSeries> series;
  int width = 640, height = 360;
};
// A self-contained <svg> element: axes with titles, tick values (decades on
// a log axis, "nice" steps otherwise), grid, one polyline per series and a
// legend. An empty plot says so instead of drawing nothing.
std::string svg_plot(const PlotSpec& spec);

std::string base64(const std::string& bytes);
std::string html_escape(const std::string& s);

}  // namespace dofarm::trainer
