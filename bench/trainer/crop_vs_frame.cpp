// Whole frames against tiles (docs/results.md, "Longer training"): a
// network trained and validated on 64-px crops can score well on crops and
// fail on whole frames. For each validation frame of a run's split, the
// SSIM of the whole frame denoised at once, and of the same frame denoised
// as independent T x T tiles put back together, for each tile side T. When
// the tiles score far above the whole frame, what fails is the frame's
// extent (pixels further from every border than any crop had them), not
// the content. Tiles have seams, so a sound model scores its tiles a little
// below its whole frames.
//
// --rings W also scores each image by distance to the frame's nearest
// border, in rings W pixels wide (the last ring takes the rest of the
// interior). The frame's content differs from ring to ring, so read the
// whole frame against the tiles ring by ring: a network that leans on the
// borders of the crops it was trained on falls behind its own tiles in the
// interior, further from every border than any crop reached.
//
// --coc PX feeds the network a circle of confusion of PX pixels at every
// pixel instead of the frame's own (as `dofarm-train eval --coc-override`),
// so a failure can be put down to the CoC input or not.
//
// --taps prints, for the deepest levels of the network (the last two
// encoder levels and the bottleneck), the RMS of the activations by each
// cell's distance to the border of its own feature map, in cells: the whole
// frame's against the tiles'. A network trained on 64-px crops sees a
// bottleneck of 2 x 2 cells, every one of them on the zero padding; in a
// 256-px frame most cells of its 8 x 8 bottleneck are not, and if their
// activations leave the range the crops gave them, that is where the whole
// frame goes wrong.
//
// Usage: crop_vs_frame --run RUN --data DIR [--checkpoint best|last|PATH]
//                      [--weights auto|averaged|raw] [--tiles 64,128] [--frames N] [--rings W]
//                      [--coc PX]
//                      [--taps]
// Prints one line per frame and the means; asserts nothing.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "common/shard.h"
#include "trainer/dataset.h"
#include "trainer/eval.h"
#include "trainer/metrics.h"

namespace fs = std::filesystem;
using namespace dofarm;
using namespace dofarm::trainer;

namespace {

// Distance of (x, y) to the nearest border of a w x h image, in pixels
// (or cells of a feature map).
int border_distance(int x, int y, int w, int h) {
  return std::min(std::min(x, w - 1 - x), std::min(y, h - 1 - y));
}

// Masks of the rings: pixels whose distance to the nearest border, in
// pixels, lies in [k W, (k + 1) W), the last ring open-ended.
std::vector<std::vector<uint8_t>> ring_masks(int width, int height, int ring, int rings) {
  std::vector<std::vector<uint8_t>> masks(rings, std::vector<uint8_t>(size_t(width) * height, 0));
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const int d = border_distance(x, y, width, height);
      masks[std::min(d / ring, rings - 1)][size_t(y) * width + x] = 1;
    }
  return masks;
}

// Sums of squared activations (over channels) and cell counts per tapped
// level and per distance of a cell to its feature map's border, in cells.
struct TapStats {
  static constexpr int kRings = 4;  // 0, 1, 2, >= 3 cells from the border
  std::vector<std::array<double, kRings>> sq, cells;

  // Adds the taps of one forward pass; only the last `levels` taps count.
  void add(const std::vector<torch::Tensor>& taps, int levels) {
    if (sq.empty()) {
      sq.assign(levels, {});
      cells.assign(levels, {});
    }
    for (int l = 0; l < levels; ++l) {
      const torch::Tensor t = taps[taps.size() - levels + l].to(torch::kFloat).contiguous();
      const torch::Tensor ms = t.pow(2).mean(1).squeeze(0).contiguous();  // h x w, mean over C
      const int h = int(ms.size(0)), w = int(ms.size(1));
      const float* v = ms.data_ptr<float>();
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const int d = std::min(border_distance(x, y, w, h), kRings - 1);
          sq[l][d] += v[y * w + x];
          cells[l][d] += 1;
        }
    }
  }
};

int usage() {
  std::fprintf(stderr,
               "usage: crop_vs_frame --run RUN --data DIR [--checkpoint best|last|PATH] "
               "[--weights auto|averaged|raw] [--tiles 64,128] [--frames N] [--rings W] [--coc PX] "
               "[--taps]\n");
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  fs::path run, data;
  std::string checkpoint = "best", tiles_arg = "64,128";
  Weights weights = Weights::kAuto;
  int max_frames = 0, ring = 0;
  float coc_px = -1.0f;  // < 0: the frame's own CoC
  bool taps = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--taps") {
      taps = true;
      continue;
    }
    if (i + 1 >= argc) return usage();
    if (a == "--run")
      run = argv[++i];
    else if (a == "--data")
      data = argv[++i];
    else if (a == "--checkpoint")
      checkpoint = argv[++i];
    else if (a == "--weights") {
      try {
        weights = value_of(weights_names(), argv[++i], "--weights");
      } catch (const SpecError&) {
        return usage();
      }
    } else if (a == "--tiles")
      tiles_arg = argv[++i];
    else if (a == "--frames")
      max_frames = std::atoi(argv[++i]);
    else if (a == "--rings")
      ring = std::atoi(argv[++i]);
    else if (a == "--coc")
      coc_px = std::strtof(argv[++i], nullptr);
    else
      return usage();
  }
  if (run.empty() || data.empty() || ring < 0 || !std::isfinite(coc_px)) return usage();
  std::vector<int> tiles;
  std::stringstream ss(tiles_arg);
  for (std::string t; std::getline(ss, t, ',');) {
    const int v = std::atoi(t.c_str());
    if (v < 8) return usage();
    tiles.push_back(v);
  }

  FrameDenoiser den(run, torch::kCPU, checkpoint, Precision::kFp32, weights);
  std::printf(
      "run %s, checkpoint %s (step %lld, %s weights)%s\n", run.c_str(),
      den.run().checkpoint.c_str(), static_cast<long long>(den.run().state.step),
      den.run().averaged ? "averaged" : "trained",
      coc_px >= 0.0f ? (", CoC fed as " + std::to_string(coc_px) + " px everywhere").c_str() : "");
  std::printf("%-28s %6s %9s", "frame", "size", "whole");
  for (int t : tiles) std::printf("  tiles %-4d", t);
  std::printf("\n");
  std::vector<double> sum(tiles.size() + 1, 0.0);
  // Per image kind (whole, then each tile side) and ring: the sum of the
  // frames' finite scores and their count.
  std::vector<std::vector<double>> ring_sum;
  std::vector<std::vector<int>> ring_count;
  int rings = 0;
  int frames = 0;
  // The last two encoder levels and the bottleneck, per image kind.
  constexpr int kTapLevels = 3;
  std::vector<torch::Tensor> tap_buffer;
  std::vector<TapStats> tap_stats(tiles.size() + 1);
  if (taps) den.model()->set_taps(&tap_buffer);
  for (const ShardSplit& sp : load_split_file(run)) {
    if (!fs::exists(data / sp.file)) continue;
    ShardReader reader(data / sp.file);
    for (int f = sp.val_begin; f < sp.val_end; ++f) {
      if (max_frames > 0 && frames >= max_frames) break;
      FrameBuffers fb = reader.read_frame(f);
      if (coc_px >= 0.0f) std::fill(fb.coc.begin(), fb.coc.end(), coc_px);
      const int w = fb.width, h = fb.height;
      if (ring > 0 && rings == 0) {
        rings = std::max(1, (std::min(w, h) / 2 + ring - 1) / ring);
        ring_sum.assign(tiles.size() + 1, std::vector<double>(rings, 0.0));
        ring_count.assign(tiles.size() + 1, std::vector<int>(rings, 0));
      }
      // One SSIM pass per image: the whole image (no mask), then each ring.
      const auto masks =
          ring > 0 ? ring_masks(w, h, ring, rings) : std::vector<std::vector<uint8_t>>{};
      std::vector<const uint8_t*> regions{nullptr};
      for (const auto& m : masks) regions.push_back(m.data());
      const std::vector<float> reference = display_encode({fb.reference.data(), 3, h, w});
      // The image's SSIM; its rings' scores added to those of image kind `kind`.
      const auto score = [&](size_t kind, const std::vector<float>& img) {
        const std::vector<float> shown = display_encode({img.data(), 3, h, w});
        const std::vector<double> s =
            ssim_per_mask({shown.data(), 3, h, w}, {reference.data(), 3, h, w}, regions);
        for (int k = 0; k < int(masks.size()); ++k)
          if (std::isfinite(s[k + 1])) {
            ring_sum[kind][k] += s[k + 1];
            ++ring_count[kind][k];
          }
        return s[0];
      };
      den.reset_sequence();
      tap_buffer.clear();
      const double whole = score(0, den.denoise(fb, 0));
      if (taps) tap_stats[0].add(tap_buffer, kTapLevels);
      std::printf("%-22s %5d %4dx%-4d %7.4f", sp.file.c_str(), reader.info().frame_start + f,
                  fb.width, fb.height, whole);
      sum[0] += whole;
      for (size_t k = 0; k < tiles.size(); ++k) {
        const std::vector<float> joined =
            denoise_in_tiles(fb, tiles[k], [&](const FrameBuffers& part) {
              den.reset_sequence();
              tap_buffer.clear();
              std::vector<float> out = den.denoise(part, 0);
              if (taps) tap_stats[k + 1].add(tap_buffer, kTapLevels);
              return out;
            });
        const double s = score(k + 1, joined);
        sum[k + 1] += s;
        std::printf("  %10.4f", s);
      }
      std::printf("\n");
      ++frames;
    }
  }
  if (frames == 0) {
    std::fprintf(stderr, "crop_vs_frame: no validation frame found in %s\n", data.c_str());
    return 1;
  }
  std::printf("%-28s %6s %9.4f", "mean", "", sum[0] / frames);
  for (size_t k = 0; k < tiles.size(); ++k) std::printf("  %10.4f", sum[k + 1] / frames);
  std::printf("\n");
  if (rings > 0) {
    std::printf("\nSSIM by distance to the nearest border (mean over frames):\n%-14s %9s", "pixels",
                "whole");
    for (int t : tiles) std::printf("  tiles %-4d", t);
    std::printf("\n");
    for (int k = 0; k < rings; ++k) {
      const std::string hi = k + 1 < rings ? std::to_string((k + 1) * ring) : "";
      std::printf("%4d-%-9s", k * ring, hi.c_str());
      for (size_t kind = 0; kind < ring_sum.size(); ++kind) {
        if (ring_count[kind][k] > 0)
          std::printf(kind == 0 ? " %9.4f" : "  %10.4f", ring_sum[kind][k] / ring_count[kind][k]);
        else
          std::printf(kind == 0 ? " %9s" : "  %10s", "n/a");
      }
      std::printf("\n");
    }
  }
  if (taps) {
    den.model()->set_taps(nullptr);
    std::printf(
        "\nActivation RMS by distance to the feature map's border, in cells (0, 1, 2, >= 3):\n");
    const char* names[kTapLevels] = {"encoder 1/8", "encoder 1/16", "bottleneck 1/32"};
    for (int l = 0; l < kTapLevels; ++l) {
      std::printf("%-16s", names[l]);
      for (size_t kind = 0; kind < tap_stats.size(); ++kind) {
        std::printf(kind == 0 ? "  whole" : "  tiles %d", kind == 0 ? 0 : tiles[kind - 1]);
        for (int d = 0; d < TapStats::kRings; ++d) {
          const double n = tap_stats[kind].cells.empty() ? 0 : tap_stats[kind].cells[l][d];
          if (n > 0)
            std::printf(" %7.3f", std::sqrt(tap_stats[kind].sq[l][d] / n));
          else
            std::printf(" %7s", "-");
        }
      }
      std::printf("\n");
    }
  }
  return 0;
}
