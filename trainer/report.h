// Pictures for evaluation reports, drawn without a plotting library:
// side-by-side comparison strips with an error heat map, and loss curves.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace dofarm::trainer {

// Writes PNG: noisy | denoised | reference | error, each sRGB-encoded and
// clamped; the error panel is the mean absolute display-space difference
// between denoised and reference, times 4, on a black-red-yellow-white ramp.
// All images (3, H, W) linear radiance.
void write_comparison_png(const std::filesystem::path& path, const std::vector<float>& noisy,
                          const std::vector<float>& denoised, const std::vector<float>& reference,
                          int width, int height);

struct LossCurve {
  std::vector<double> epoch, train, val;  // val may hold NaN (no validation set)
};
// Reads RUN/loss.csv (empty curve when absent).
LossCurve read_loss_csv(const std::filesystem::path& csv);
// Writes a 640x360 PNG: training loss blue, validation orange, log10 y axis
// between the curves' min and max, one tick per decade and per 10 epochs.
// Returns a one-line caption with the axis ranges (the image has no text).
std::string write_loss_plot_png(const std::filesystem::path& path, const LossCurve& curve);

}  // namespace dofarm::trainer
