// The reference ceiling of rendered frames (issue 13, item 2): for each frame
// of the EXR files (`dofarm render`) or shards (`dofarm run`) given, the SSIM
// between the two independent half-sample references (trainer/ceiling.h),
// the exact-denoiser score (the noise-free image's SSIM against the
// reference, estimated from the halves: the cap on a denoiser's score),
// the median and 99th percentile of the reference's per-pixel relative
// standard error (sqrt(reference_var) / luminance), the render time an EXR
// records and the largest circle of confusion (px). bench/README.md
// ("reference_ceiling") holds the figures and the commands that made them.
//
// Usage: reference_ceiling FILE.exr|FILE.h5 ...
//        reference_ceiling --staged DIR
//        reference_ceiling --pair A.exr|DIR@FRAME B.exr|DIR@FRAME
// Prints one line per frame and a summary line; asserts nothing. --pair
// scores two renders of the same frame with different seeds against each
// other (the issue's own definition of the ceiling: an independent second
// reference at the full sample count), to compare with the half-vs-half
// figure of each, and gives the ratio of their mean radiances (A over B:
// what a clamped reference loses against an unbiased B,
// buffers.reference_clamp). --staged scores the frames of a farm batch
// while it renders: DIR is its staging folder (OUT/.staging/BATCH), whose
// tile EXRs are pasted into frames, and every frame whose tiles cover it
// is measured as a whole (SSIM's windows then cross the tiles' borders, as
// in the shard the batch will write); the render time is the sum of its
// tiles'. Frames still missing tiles are counted, not measured. In --pair,
// DIR@FRAME is frame FRAME assembled from such a folder.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "common/exr_io.h"
#include "common/shard.h"
#include "trainer/ceiling.h"
#include "trainer/metrics.h"

namespace {

struct Row {
  double ssim, exact, median_rel, p99_rel, seconds, coc_max;
};

// Per-pixel relative standard error of the reference's luminance, as the
// adaptive sampler measures it (worker/render/render_job.cpp).
std::pair<double, double> relative_error_quantiles(const dofarm::FrameBuffers& fb) {
  const size_t n = fb.plane();
  std::vector<double> rel(n);
  for (size_t i = 0; i < n; ++i) {
    const double lum =
        0.2126 * fb.reference[i] + 0.7152 * fb.reference[n + i] + 0.0722 * fb.reference[2 * n + i];
    rel[i] = std::sqrt(std::max(0.0, double(fb.reference_var[i]))) / std::max(std::fabs(lum), 1e-3);
  }
  std::sort(rel.begin(), rel.end());
  return {rel[n / 2], rel[std::min(n - 1, size_t(0.99 * double(n)))]};
}

Row measure(const dofarm::FrameBuffers& fb, double seconds) {
  auto [med, p99] = relative_error_quantiles(fb);
  double coc_max = 0;
  for (float c : fb.coc) coc_max = std::max(coc_max, double(c));
  return {dofarm::trainer::reference_ceiling_ssim(fb),
          dofarm::trainer::exact_denoiser_ssim(fb),
          med,
          p99,
          seconds,
          coc_max};
}

double render_seconds(const dofarm::ExrFrame& exr) {
  auto it = exr.attributes.find("dofarm.render_seconds");
  return it == exr.attributes.end() ? NAN : std::stod(it->second);
}

// A batch's staged tiles (its OUT/.staging/BATCH folder), by frame.
struct StagedFrame {
  std::vector<std::filesystem::path> tiles;
  long long covered = 0;  // pixels
  dofarm::FrameExtent extent;
  bool complete() const { return covered == (long long)extent.width * extent.height; }
};
std::map<int, StagedFrame> staged_index(const std::filesystem::path& dir) {
  std::map<int, StagedFrame> frames;
  std::vector<std::filesystem::path> paths;
  for (const auto& e : std::filesystem::directory_iterator(dir))
    if (e.is_regular_file() && e.path().extension() == ".exr") paths.push_back(e.path());
  std::sort(paths.begin(), paths.end());
  for (const auto& p : paths) {
    const dofarm::ExrFrame exr = dofarm::read_frame_exr(p);
    StagedFrame& f = frames[exr.buffers.camera.frame];
    f.tiles.push_back(p);
    f.covered += (long long)exr.buffers.width * exr.buffers.height;
    f.extent = exr.frame;
  }
  return frames;
}

// The whole frame its tiles make, and the sum of their render times.
dofarm::FrameBuffers assemble(const StagedFrame& f, double* seconds) {
  dofarm::FrameBuffers whole;
  *seconds = 0;
  for (const auto& p : f.tiles) {
    const dofarm::ExrFrame exr = dofarm::read_frame_exr(p);
    if (whole.width == 0) {
      whole.allocate(f.extent.width, f.extent.height, exr.buffers.versions);
      whole.rect = {0, 0, f.extent.width, f.extent.height};
      whole.camera = exr.buffers.camera;
    }
    whole.paste(exr.buffers);
    *seconds += render_seconds(exr);
  }
  return whole;
}

// A frame EXR, or DIR@FRAME: frame FRAME assembled from the staging folder
// DIR (it must be complete).
dofarm::FrameBuffers load_frame(const std::string& arg) {
  const size_t at = arg.rfind('@');
  if (at == std::string::npos || std::filesystem::is_regular_file(arg))
    return dofarm::read_frame_exr(arg).buffers;
  const int frame = std::stoi(arg.substr(at + 1));
  const std::map<int, StagedFrame> index = staged_index(arg.substr(0, at));
  auto it = index.find(frame);
  if (it == index.end() || !it->second.complete())
    throw std::runtime_error("frame " + std::to_string(frame) + " is not complete in " +
                             arg.substr(0, at));
  double seconds;
  return assemble(it->second, &seconds);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: reference_ceiling FILE.exr|FILE.h5 ...\n");
    return 2;
  }
  if (std::string(argv[1]) == "--pair") {
    if (argc != 4) {
      std::fprintf(stderr, "usage: reference_ceiling --pair A.exr|DIR@FRAME B.exr|DIR@FRAME\n");
      return 2;
    }
    dofarm::FrameBuffers a, b;
    try {
      a = load_frame(argv[2]);
      b = load_frame(argv[3]);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "reference_ceiling: %s\n", e.what());
      return 1;
    }
    if (a.width != b.width || a.height != b.height) {
      std::fprintf(stderr, "reference_ceiling: %s and %s differ in size\n", argv[2], argv[3]);
      return 2;
    }
    using dofarm::trainer::display_encode;
    const std::vector<float> da = display_encode({a.reference.data(), 3, a.height, a.width});
    const std::vector<float> db = display_encode({b.reference.data(), 3, b.height, b.width});
    double sum_a = 0, sum_b = 0;
    for (float v : a.reference) sum_a += v;
    for (float v : b.reference) sum_b += v;
    std::printf(
        "pair: SSIM(reference A, reference B) %.5f; half-vs-half A %.5f, B %.5f; mean A / B "
        "%.4f\n",
        dofarm::trainer::ssim({da.data(), 3, a.height, a.width}, {db.data(), 3, b.height, b.width}),
        dofarm::trainer::reference_ceiling_ssim(a), dofarm::trainer::reference_ceiling_ssim(b),
        sum_b > 0 ? sum_a / sum_b : 0.0);
    return 0;
  }
  std::vector<Row> rows;
  std::printf("%-40s %6s %9s %9s %9s %9s %9s %8s\n", "file", "frame", "ceiling", "exact", "rel_med",
              "rel_p99", "render_s", "coc_max");
  if (std::string(argv[1]) == "--staged") {
    if (argc != 3) {
      std::fprintf(stderr, "usage: reference_ceiling --staged DIR\n");
      return 2;
    }
    try {
      int incomplete = 0;
      for (const auto& [frame, f] : staged_index(argv[2])) {
        if (!f.complete()) {
          ++incomplete;
          continue;
        }
        double seconds;
        const dofarm::FrameBuffers whole = assemble(f, &seconds);
        rows.push_back(measure(whole, seconds));
        const Row& row = rows.back();
        std::printf("%-40s %6d %9.5f %9.5f %9.4f %9.4f %9.1f %8.1f\n", "(staged tiles)", frame,
                    row.ssim, row.exact, row.median_rel, row.p99_rel, row.seconds, row.coc_max);
      }
      std::printf("staged: %zu whole frames, %d with tiles still missing\n", rows.size(),
                  incomplete);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "%s: %s\n", argv[2], e.what());
      return 1;
    }
    if (rows.empty()) return 1;
  }
  for (int a = 1; a < argc && std::string(argv[1]) != "--staged"; ++a) {
    const std::string path = argv[a];
    try {
      if (path.size() > 3 && path.substr(path.size() - 3) == ".h5") {
        dofarm::ShardReader reader(path);
        for (int f = 0; f < reader.frame_count(); ++f) {
          rows.push_back(measure(reader.read_frame(f), NAN));
          std::printf("%-40s %6d %9.5f %9.5f %9.4f %9.4f %9s %8.1f\n", path.c_str(),
                      reader.info().frame_start + f, rows.back().ssim, rows.back().exact,
                      rows.back().median_rel, rows.back().p99_rel, "-", rows.back().coc_max);
        }
      } else {
        dofarm::ExrFrame exr = dofarm::read_frame_exr(path);
        const double sec = render_seconds(exr);
        rows.push_back(measure(exr.buffers, sec));
        std::printf("%-40s %6d %9.5f %9.5f %9.4f %9.4f %9.1f %8.1f\n", path.c_str(),
                    exr.buffers.camera.frame, rows.back().ssim, rows.back().exact,
                    rows.back().median_rel, rows.back().p99_rel, sec, rows.back().coc_max);
      }
    } catch (const std::exception& e) {
      std::fprintf(stderr, "%s: %s\n", path.c_str(), e.what());
      return 1;
    }
  }
  double sum = 0, worst = 1, secs = 0, exact = 0;
  for (const Row& r : rows) {
    sum += r.ssim;
    exact += r.exact;
    worst = std::min(worst, r.ssim);
    if (std::isfinite(r.seconds)) secs += r.seconds;
  }
  std::printf(
      "summary: %zu frames, ceiling SSIM mean %.5f min %.5f, exact-denoiser SSIM mean %.5f, "
      "render %.1f s\n",
      rows.size(), sum / double(rows.size()), worst, exact / double(rows.size()), secs);
  return 0;
}
