#include "trainer/eval.h"

#include <ATen/Parallel.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>

#include "common/error.h"
#include "common/shard.h"
#include "trainer/augment.h"
#include "trainer/ceiling.h"
#include "trainer/dataset.h"
#include "trainer/inputs.h"
#include "trainer/losses.h"
#include "trainer/metrics.h"
#include "trainer/model.h"
#include "trainer/precision.h"
#include "trainer/report.h"

namespace dofarm::trainer {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

struct Scores {
  double ssim = NAN, psnr = NAN, rel_mse = NAN;
  double flicker = NAN;  // against the previous frame (none for a sequence's first)
};

// The scores of `img` against the reference `ref` (linear; `display_ref` its
// display encoding) over every region: masks[r] (null: all pixels) holding
// pixels[r] pixels. The image is encoded once and SSIM's windows filtered
// once for all regions; a region without a pixel has no score (not 0).
// With `tiles`, also the regions' SSIM sums per tile of kSsimTile pixels
// (report.json frames[].denoised_tiles; regions without pixels left out).
constexpr int kSsimTile = 32;
std::array<Scores, kRegionCount> score_regions(const std::vector<float>& img,
                                               const std::vector<float>& ref,
                                               const std::vector<float>& display_ref, int w, int h,
                                               const uint8_t* const* masks, const size_t* pixels,
                                               json* tiles = nullptr) {
  ImageView vi{img.data(), 3, h, w}, vr{ref.data(), 3, h, w};
  const std::vector<float> di = display_encode(vi);
  ImageView ddi{di.data(), 3, h, w}, ddr{display_ref.data(), 3, h, w};
  std::vector<const uint8_t*> scored;
  for (int r = 0; r < kRegionCount; ++r)
    if (pixels[r] > 0) scored.push_back(masks[r]);
  TiledSsim tiled;
  const std::vector<double> s =
      ssim_per_mask(ddi, ddr, scored, kSsimTile, tiles ? &tiled : nullptr);
  std::array<Scores, kRegionCount> out;
  if (tiles)
    *tiles = {{"tile", tiled.tile}, {"tiles_x", tiled.tiles_x}, {"tiles_y", tiled.tiles_y}};
  for (int r = 0, i = 0; r < kRegionCount; ++r)
    if (pixels[r] > 0) {
      if (tiles)
        (*tiles)["regions"][kFocusRegions[r].name] = {{"ssim_sum", tiled.sum[i]},
                                                      {"count", tiled.count[i]}};
      out[r] = {s[i++], psnr(ddi, ddr, masks[r]), relative_mse(vi, vr, masks[r])};
    }
  return out;
}

// "a, b, c": the names of a refusal or a report line.
std::string comma_list(const std::vector<std::string>& names) {
  std::string list;
  for (const std::string& n : names) list += (list.empty() ? "" : ", ") + n;
  return list;
}

json to_json(const Scores& s) {
  auto j = [](double v) { return std::isfinite(v) ? json(v) : json(nullptr); };
  return {{"ssim", j(s.ssim)},
          {"psnr", j(s.psnr)},
          {"rel_mse", j(s.rel_mse)},
          {"flicker", j(s.flicker)}};
}

// Per-frame scores, kept as lists so means skip frames without a region.
struct Accumulator {
  // [noisy, denoised][kFocusRegions][ssim, psnr, rel_mse, flicker]
  std::vector<double> v[2][kRegionCount][4];
  std::vector<double> ms;
  int frames = 0;
  // Per region: pixels in it, over all frames (a band's share of the data).
  double pixels[kRegionCount] = {};
  json summary() const {
    const char* who[2] = {"noisy", "denoised"};
    json j;
    for (int k = 0; k < 2; ++k)
      for (int r = 0; r < kRegionCount; ++r)
        j[who[k]][kFocusRegions[r].name] =
            to_json(Scores{finite_mean(v[k][r][0]), finite_mean(v[k][r][1]),
                           finite_mean(v[k][r][2]), finite_mean(v[k][r][3])});
    for (int r = 0; r < kRegionCount; ++r)
      j["pixel_share"][kFocusRegions[r].name] = pixels[0] > 0 ? pixels[r] / pixels[0] : 0.0;
    j["denoise_ms_mean"] = finite_mean(ms);
    j["frames"] = frames;
    return j;
  }
};

std::string cell(double v, int prec) {
  if (!std::isfinite(v)) return "–";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.*f", prec, v);
  return buf;
}

// Three significant digits: flicker spans decades (1e-4 denoised, ~1 noisy).
std::string cell_g(double v) {
  if (!std::isfinite(v)) return "–";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", v);
  return buf;
}

// The regions' table (report.md "By circle of confusion", report.html
// #by_coc): per region the CoC range, its share of the pixels, and the
// noisy and denoised scores, means over the frames that have pixels there.
const char* const kCocBandMdHeader =
    "| region | CoC (px) | pixels | frames | SSIM noisy | SSIM denoised | PSNR noisy | "
    "PSNR denoised | relMSE denoised | flicker denoised |\n"
    "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
const char* const kCocBandHtmlHeader =
    "<tr><th>region</th><th>CoC (px)</th><th>pixels</th><th>frames</th><th>SSIM noisy</th>"
    "<th>SSIM denoised</th><th>PSNR noisy</th><th>PSNR denoised</th><th>relMSE denoised</th>"
    "<th>flicker denoised</th></tr>";

std::vector<std::vector<std::string>> coc_band_rows(const Accumulator& a) {
  std::vector<std::vector<std::string>> rows;
  for (int r = 1; r < kRegionCount; ++r) {
    const FocusRegion& g = kFocusRegions[r];
    auto bound = [](float v) { return std::isfinite(v) ? cell(v, 0) : std::string(); };
    const std::string range = !std::isfinite(g.lo)   ? "< " + bound(g.hi)
                              : !std::isfinite(g.hi) ? "≥ " + bound(g.lo)
                                                     : bound(g.lo) + "–" + bound(g.hi);
    size_t scored = 0;
    for (double v : a.v[1][r][0]) scored += std::isfinite(v);
    rows.push_back({g.name, range,
                    cell(a.pixels[0] > 0 ? 100.0 * a.pixels[r] / a.pixels[0] : 0.0, 1) + "%",
                    std::to_string(scored), cell(finite_mean(a.v[0][r][0]), 4),
                    cell(finite_mean(a.v[1][r][0]), 4), cell(finite_mean(a.v[0][r][1]), 2),
                    cell(finite_mean(a.v[1][r][1]), 2), cell(finite_mean(a.v[1][r][2]), 4),
                    cell_g(finite_mean(a.v[1][r][3]))});
  }
  return rows;
}

constexpr int kCropZoom = 2;  // crop pixels drawn kCropZoom x kCropZoom

// The side-by-side crops of one frame (EvalOptions::crops): its windows
// (report.h, choose_focus_crops), encoded once as PNG, and their report.json
// entries, each `where` (shard, scene, frame) plus the window. Empty when
// the frame has no out-of-focus window.
struct FrameCrops {
  // What ranks frames (spread_by_blur): the out-of-focus window's mean CoC,
  // plus kShowsBoth when the frame also has a sharp window, so that frames
  // showing both sides of the focus come first (no CoC reaches kShowsBoth).
  double blur = 0;
  std::vector<std::pair<std::string, std::string>> files;  // name suffix, PNG bytes
  json entries = json::array();
};

FrameCrops focus_crops_of(int side, const FrameBuffers& fb, const std::vector<float>& noisy,
                          const std::vector<float>& denoised, const json& where) {
  FrameCrops fc_out;
  const FocusCrops fc = choose_focus_crops(fb.coc, fb.width, fb.height, side, &fb.reference);
  if (!fc.out_of_focus.found) return fc_out;
  constexpr double kShowsBoth = 1e6;
  fc_out.blur = fc.out_of_focus.mean_coc + (fc.in_focus.found ? kShowsBoth : 0.0);
  const std::pair<const char*, const std::vector<float>*> images[] = {
      {"noisy", &noisy}, {"denoised", &denoised}, {"reference", &fb.reference}};
  for (const auto& [region, win] : {std::pair<const char*, CropWindow>{"in_focus", fc.in_focus},
                                    {"out_of_focus", fc.out_of_focus}}) {
    if (!win.found) continue;
    json entry = where;
    entry.update({{"region", region},
                  {"x", win.x},
                  {"y", win.y},
                  {"side", win.side},
                  {"zoom", kCropZoom},
                  {"mean_coc_px", win.mean_coc}});
    for (const auto& [kind, img] : images) {
      const std::string suffix = std::string(region) + "-" + kind + ".png";
      fc_out.files.emplace_back(suffix,
                                crop_png_bytes(*img, fb.width, fb.height, win, kCropZoom));
      entry[kind] = suffix;  // completed with the crop's index when it is chosen
    }
    fc_out.entries.push_back(entry);
  }
  return fc_out;
}

// Which frames the crops show (spread_by_blur in report.h): the most blurred
// validation frames, those with a sharp window too first, spread over the
// shards. Keeps at most `k` frames per shard, so memory is bounded by
// k x shards crops, not by the frames scored.
class CropPicker {
 public:
  explicit CropPicker(int k) : k_(k) {}
  bool wanted() const { return k_ > 0; }
  void offer(const std::string& shard, FrameCrops c) {
    if (k_ <= 0 || c.entries.empty()) return;
    auto& kept = by_shard_[shard];
    // Stable: of equally blurred frames the earlier one stays first.
    auto at = std::upper_bound(kept.begin(), kept.end(), c.blur,
                               [](double b, const FrameCrops& x) { return b > x.blur; });
    kept.insert(at, std::move(c));
    if (int(kept.size()) > k_) kept.pop_back();
  }
  // Writes DIR/crops/crop-INDEX-REGION-KIND.png for the chosen frames and
  // returns their report.json entries.
  json write(const fs::path& dir) const {
    std::vector<const std::vector<FrameCrops>*> shards;
    std::vector<std::vector<double>> blurs;
    for (const auto& [name, kept] : by_shard_) {
      shards.push_back(&kept);
      blurs.emplace_back();
      for (const FrameCrops& c : kept) blurs.back().push_back(c.blur);
    }
    json out = json::array();
    const auto picks = spread_by_blur(blurs, k_);
    if (!picks.empty()) fs::create_directories(dir / "crops");
    int index = 0;
    for (const auto& [shard, rank] : picks) {
      const FrameCrops& c = (*shards[shard])[rank];
      const std::string prefix = "crop-" + std::to_string(index) + "-";
      for (const auto& [suffix, png] : c.files)
        write_text_atomic(dir / "crops" / (prefix + suffix), png);
      for (json e : c.entries) {
        e["index"] = index;
        for (const char* kind : {"noisy", "denoised", "reference"})
          e[kind] = "crops/" + prefix + e[kind].get<std::string>();
        out.push_back(e);
      }
      ++index;
    }
    return out;
  }

 private:
  int k_;
  std::map<std::string, std::vector<FrameCrops>> by_shard_;
};

}  // namespace

EvalSummary evaluate(const EvalOptions& o) {
  const torch::Device device = pick_device("auto");
  FrameDenoiser den(o.run_dir, device, o.checkpoint, o.precision, o.weights);
  const LoadedRun& used = den.run();
  const TrainConfig& cfg = den.config();
  // --flatten-input: only buffers some input of the network reads.
  {
    std::vector<std::string> read;
    for (const ResolvedInput& in : resolve_inputs(cfg.model, cfg.data)) read.push_back(in.buffer);
    for (const std::string& name : o.flatten_inputs)
      if (std::find(read.begin(), read.end(), name) == read.end())
        throw SpecError(FileLoc{(o.run_dir / "config.toml").string()}, "--flatten-input",
                        "the network reads no input from buffer \"" + name +
                            "\" (it reads: " + comma_list(read) + ")");
  }
  fs::create_directories(o.out_dir);

  // Validation frames: the run's own split (split.json), so eval never
  // scores frames the model was trained on.
  std::map<std::string, ShardSplit> splits, legacy;  // by content key / by file
  for (const ShardSplit& sp : load_split_file(o.run_dir))
    (sp.key.empty() ? legacy[sp.file] : splits[sp.key]) = sp;
  // Held-out frames are checked by content. A split from before content keys
  // (split.json version 1) names the shards the run trained on by file name
  // only, and a name proves nothing: refuse rather than trust it.
  if (o.held_out)
    for (const auto& [file, sp] : legacy)
      if (sp.train_end > sp.train_begin)
        throw SpecError(FileLoc{(o.run_dir / "split.json").string()}, "--held-out",
                        "the run's split (version 1) names the shards it trained on by file "
                        "name only (\"" +
                            file +
                            "\"), so no shard can be shown to be apart "
                            "from them; --held-out needs a split keyed by content (version 2)");
  struct Strip {
    std::string shard;
    int frame, width, height;
    std::string png;
  };
  std::vector<Strip> strips;
  CropPicker crop_picker(o.crops);  // side-by-side crops (EvalOptions::crops)
  Accumulator all, every;  // validation frames; all frames (thesis 5.1, table 5.1)
  std::map<std::string, Accumulator> by_scene, by_scene_every;  // table 5.1 has a row per scene
  json frames = json::array();
  ReferenceCeiling ceiling;  // how converged the references are (ceiling.h)
  std::optional<FrameBuffers> timing_frame;  // the first validation frame (time_side)
  int done = 0, done_every = 0, images = 0;
  for (const std::string& file : list_shards(o.data_dir)) {
    ShardReader reader(o.data_dir / file);
    Accumulator& scene = by_scene[reader.info().scene_id];
    Accumulator& scene_every = by_scene_every[reader.info().scene_id];
    const std::string key = shard_content_key(reader.info());
    ShardSplit sp = splits.count(key)    ? splits[key]
                    : legacy.count(file) ? legacy[file]
                                         : assign_split(file, key, reader.frame_count(), cfg.data);
    if (o.held_out) {
      if (splits.count(key) && sp.train_end > sp.train_begin)
        throw SpecError(FileLoc{(o.data_dir / file).string()}, "--held-out",
                        "the run trained on this shard (its split.json holds its content as " +
                            sp.file + "); held-out frames must be rendered apart");
      sp.train_begin = sp.train_end = sp.val_begin = 0;
      sp.val_end = reader.frame_count();
    }
    den.reset_sequence();
    // The previous scored frame of this shard, for the flicker of (f-1, f).
    int prev_f = -1;
    bool prev_val = false;
    std::vector<float> prev_out, prev_noisy, prev_ref;
    // With all_frames every frame is scored once, in order; the validation
    // frames also count for the validation table, and the recurrent state
    // restarts at the first of them, so that table does not depend on
    // whether the training frames were scored too.
    const int first = o.all_frames ? 0 : sp.val_begin;
    const int end = o.all_frames ? reader.frame_count() : sp.val_end;
    for (int f = first; f < end; ++f) {
      const bool validation = f >= sp.val_begin && f < sp.val_end;
      const bool want_val = validation && !(o.max_frames > 0 && done >= o.max_frames);
      const bool want_every = o.all_frames && !(o.max_frames > 0 && done_every >= o.max_frames);
      if (!want_val && !want_every) {
        if (f < sp.val_begin) continue;
        break;
      }
      if (f == sp.val_begin) den.reset_sequence();
      FrameBuffers fb = reader.read_frame(f);
      if (o.time_side > 0 && want_val && !timing_frame) timing_frame = fb;
      const int w = fb.width, h = fb.height;
      const size_t n = fb.plane();
      double sec = 0;
      // The probes: what the network's inputs read in place of the frame's own.
      InputOverrides overrides;
      std::vector<std::vector<float>> probes;
      probes.reserve(o.flatten_inputs.size() + 1);
      if (std::isfinite(o.coc_override)) {
        probes.emplace_back(n, o.coc_override);
        overrides["coc"] = probes.back().data();
      }
      for (const std::string& name : o.flatten_inputs) {
        const BufferInfo& b = buffer_info(name);
        const std::vector<float>& data = buffer_data(fb, name);
        const size_t count = size_t(b.channels) * n,
                     begin = b.per_version ? size_t(o.version) * count : 0;
        if (data.size() < begin + count)
          throw SpecError(FileLoc{(o.data_dir / file).string()}, "--flatten-input",
                          "frame " + std::to_string(f) + " has no buffer \"" + name + "\"");
        std::vector<float>& flat = probes.emplace_back(count);
        for (int c = 0; c < b.channels; ++c) {
          const float* plane = data.data() + begin + size_t(c) * n;
          double sum = 0;
          for (size_t p = 0; p < n; ++p) sum += plane[p];
          std::fill_n(flat.begin() + size_t(c) * n, n, float(sum / double(n)));
        }
        overrides[name] = flat.data();
      }
      const std::vector<float> out =
          den.denoise(fb, o.version, &sec, overrides.empty() ? nullptr : &overrides);
      std::vector<float> noisy(fb.noisy.begin() + size_t(o.version) * 3 * n,
                               fb.noisy.begin() + size_t(o.version + 1) * 3 * n);
      // One mask per region (kFocusRegions; "all" needs none).
      std::vector<std::vector<uint8_t>> region_mask(kRegionCount);
      const uint8_t* masks[kRegionCount] = {};
      size_t region_pixels[kRegionCount] = {};
      for (int r = 0; r < kRegionCount; ++r) {
        const FocusRegion& g = kFocusRegions[r];
        std::vector<uint8_t>& m = region_mask[r];
        m.resize(n);
        for (size_t p = 0; p < n; ++p) {
          m[p] = fb.coc[p] >= g.lo && fb.coc[p] < g.hi;
          region_pixels[r] += m[p];
        }
        masks[r] = r == 0 ? nullptr : m.data();
      }
      std::vector<Accumulator*> to;
      if (want_val) to.insert(to.end(), {&all, &scene});
      if (want_every) to.insert(to.end(), {&every, &scene_every});
      json row = {{"shard", file},
                  {"scene", reader.info().scene_id},
                  {"frame", reader.info().frame_start + f},
                  {"denoise_ms", sec * 1e3}};
      // Flicker needs the frame before, scored in the same pass: it counts
      // for the validation table when both frames are validation frames.
      const bool pair = prev_f >= 0 && prev_f == f - 1;
      std::vector<Accumulator*> to_flicker;
      if (pair && want_val && prev_val) to_flicker.insert(to_flicker.end(), {&all, &scene});
      if (pair && want_every) to_flicker.insert(to_flicker.end(), {&every, &scene_every});
      const std::vector<float> display_ref = display_encode({fb.reference.data(), 3, h, w});
      json tiles;  // the denoised frame's SSIM per tile, validation frames only
      for (int k = 0; k < 2; ++k) {
        const std::vector<float>& img = k == 0 ? noisy : out;
        const std::array<Scores, kRegionCount> scores =
            score_regions(img, fb.reference, display_ref, w, h, masks, region_pixels,
                          k == 1 && want_val ? &tiles : nullptr);
        for (int r = 0; r < kRegionCount; ++r) {
          Scores s = scores[r];
          if (pair && region_pixels[r] > 0) {
            const std::vector<float>& before = k == 0 ? prev_noisy : prev_out;
            s.flicker = temporal_relative_mse({before.data(), 3, h, w}, {img.data(), 3, h, w},
                                              {prev_ref.data(), 3, h, w},
                                              {fb.reference.data(), 3, h, w}, masks[r]);
          }
          for (Accumulator* a : to) {
            a->v[k][r][0].push_back(s.ssim);
            a->v[k][r][1].push_back(s.psnr);
            a->v[k][r][2].push_back(s.rel_mse);
          }
          for (Accumulator* a : to_flicker) a->v[k][r][3].push_back(s.flicker);
          // The rows list validation frames: a pair counts there when the
          // frame before is a validation frame too.
          Scores shown = s;
          if (!(pair && want_val && prev_val)) shown.flicker = NAN;
          row[k == 0 ? "noisy" : "denoised"][kFocusRegions[r].name] = to_json(shown);
        }
      }
      prev_f = f;
      prev_val = want_val;
      prev_out = out;
      prev_noisy = noisy;
      prev_ref = fb.reference;
      for (Accumulator* a : to) {
        a->ms.push_back(sec * 1e3);
        ++a->frames;
        for (int r = 0; r < kRegionCount; ++r) a->pixels[r] += double(region_pixels[r]);
      }
      done_every += want_every;
      if (!want_val) continue;
      const double c = ceiling.add(fb, file, reader.info().frame_start + f);
      row["reference_ceiling_ssim"] = std::isfinite(c) ? json(c) : json();
      row["exact_denoiser_ssim"] = std::isfinite(c) ? json(ceiling.last_exact()) : json();
      row["denoised_tiles"] = std::move(tiles);
      frames.push_back(row);
      if (crop_picker.wanted())
        crop_picker.offer(file, focus_crops_of(o.crop_side, fb, noisy, out,
                                               {{"shard", file},
                                                {"scene", reader.info().scene_id},
                                                {"frame", reader.info().frame_start + f}}));
      if (images < o.max_images) {
        char name[64];
        std::snprintf(name, sizeof name, "frame-%03d.png", images);
        // Encoded once: the same bytes go to the file and into report.html.
        std::string png = comparison_png_bytes(noisy, out, fb.reference, w, h);
        {
          std::ofstream f(o.out_dir / name, std::ios::binary);
          f << png;
          if (!f) throw RuntimeError((o.out_dir / name).string() + ": cannot write PNG");
        }
        strips.push_back({file, reader.info().frame_start + f, w, h, std::move(png)});
        ++images;
      }
      ++done;
    }
  }
  if (done == 0)
    throw SpecError(FileLoc{o.data_dir.string()}, "",
                    "no validation frames (check the data folder and the run's split.json)");
  const json crops = crop_picker.write(o.out_dir);

  // Time at a fixed size (e.g. 512^2), so runs on data of any size compare.
  json at_size;
  if (timing_frame) {
    const FrameBuffers big = tile_frame(*timing_frame, o.time_side, o.time_side);
    std::vector<double> ms;
    for (int r = 0; r <= std::max(1, o.time_reps); ++r) {
      den.reset_sequence();  // the state would be of the data's size
      double sec = 0;
      den.denoise(big, o.version, &sec);
      if (r > 0) ms.push_back(sec * 1e3);  // the first run warms up
    }
    std::sort(ms.begin(), ms.end());
    at_size = {{"side", o.time_side},
               {"ms", ms[ms.size() / 2]},
               {"reps", ms.size()},
               {"threads", at::get_num_threads()}};
  }

  EvalSummary sum;
  if (!at_size.is_null()) sum.ms_at_size = at_size["ms"].get<double>();
  sum.frames = done;
  sum.ssim = finite_mean(all.v[1][0][0]);
  sum.psnr = finite_mean(all.v[1][0][1]);
  sum.rel_mse = finite_mean(all.v[1][0][2]);
  sum.ms = finite_mean(all.ms);
  sum.flicker = finite_mean(all.v[1][0][3]);
  sum.frames_all = every.frames;
  sum.ssim_all = finite_mean(every.v[1][0][0]);

  // Plots (SVG, with text): loss per epoch and per step, learning rate.
  const LossCurve epochs = read_loss_csv(o.run_dir / "loss.csv");
  const StepCurve steps = read_steps_csv(o.run_dir / "steps.csv");
  PlotSpec loss_plot{"Loss per epoch", "epoch", "loss (L1 + LoG terms)", true,
                     {{"training (mean over the epoch)", "#1f77b4", epochs.epoch, epochs.train},
                      {"validation", "#ff7f0e", epochs.epoch, epochs.val}}};
  PlotSpec step_plot{"Training loss per step", "optimizer step", "loss (L1 + LoG terms)", true,
                     {{"training batch loss", "#1f77b4", steps.step, steps.loss}}};
  PlotSpec lr_plot{"Learning rate", "optimizer step", "learning rate", true,
                   {{"Adam step size", "#2ca02c", steps.step, steps.lr}}};
  if (steps.step.empty())  // a run from before steps.csv: per epoch
    lr_plot = PlotSpec{"Learning rate", "epoch", "learning rate", true,
                       {{"Adam step size (last step of the epoch)", "#2ca02c", epochs.epoch,
                         epochs.lr}}};
  PlotSpec ssim_plot{
      "Validation SSIM per epoch",
      "epoch",
      "SSIM (sRGB, 0..1)",
      false,
      {{"validation frames (64 px crops)", "#9467bd", epochs.epoch, epochs.val_ssim},
       {"whole validation frames", "#17becf", epochs.epoch, epochs.val_frame_ssim},
       {"the same frames as crop-sized tiles", "#bcbd22", epochs.epoch, epochs.val_tile_ssim}}};
  PlotSpec psnr_plot{"Validation PSNR per epoch", "epoch", "PSNR (dB)", false,
                     {{"validation frames (64 px crops)", "#8c564b", epochs.epoch, epochs.val_psnr}}};
  const std::string loss_svg = svg_plot(loss_plot), step_svg = svg_plot(step_plot),
                    lr_svg = svg_plot(lr_plot), quality_svg = svg_plot(ssim_plot) + svg_plot(psnr_plot);
  std::ofstream(o.out_dir / "quality.svg")
      << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"640\" height=\"720\">"
      << svg_plot(ssim_plot) << "<g transform=\"translate(0 360)\">" << svg_plot(psnr_plot)
      << "</g></svg>\n";
  std::ofstream(o.out_dir / "loss.svg") << loss_svg << "\n";
  std::ofstream(o.out_dir / "steps.svg") << step_svg << "\n";
  std::ofstream(o.out_dir / "lr.svg") << lr_svg << "\n";
  json summary = all.summary();
  json scenes = json::object();
  for (const auto& [name, a] : by_scene) scenes[name] = a.summary();
  json scenes_every = json::object();
  if (o.all_frames)
    for (const auto& [name, a] : by_scene_every) scenes_every[name] = a.summary();
  json report = {
      {"run", o.run_dir.string()},
      {"data", o.data_dir.string()},
      {"device", device.str()},
      {"noisy_version", o.version},
      {"held_out", o.held_out},
      {"checkpoint",
       {{"file", used.checkpoint.string()},
        {"epoch", used.state.epoch},
        {"step", used.state.step},
        {"weights", used.weights_label()},
        {"best_loss", std::isfinite(used.state.best) ? json(used.state.best) : json()}}},
      {"metrics_note",
       "SSIM and PSNR on sRGB-encoded images clamped to [0,1]; relative MSE on "
       "linear HDR, (d-r)^2/(r^2+0.01); flicker: relative MSE of frame-to-frame differences, "
       "((d_t-d_t-1)-(r_t-r_t-1))^2/(m^2+0.01), m = (r_t+r_t-1)/2, over consecutive frames "
       "(null on a sequence's first frame); in focus = CoC < 1 px"},
      {"summary", summary},
      {"coc_override", std::isfinite(o.coc_override) ? json(o.coc_override) : json()},
      {"flattened_inputs", o.flatten_inputs},
      {"denoise_ms_at_size", at_size},
      {"reference_ceiling", ceiling.to_json()},
      {"crops", crops},
      {"scenes", scenes},
      {"all_frames",
       o.all_frames ? json{{"summary", every.summary()}, {"scenes", scenes_every}} : json()},
      {"frames", frames}};
  std::ofstream(o.out_dir / "report.json") << report.dump(1) << "\n";

  // The summary tables' header, the same for the validation and all-frames
  // tables of report.md, and of report.html.
  const std::string md_header =
      "| scene | input | SSIM all | SSIM in focus | SSIM out of focus | PSNR all (dB) | "
      "PSNR in | PSNR out | relMSE all | relMSE in | relMSE out | flicker all | flicker in | "
      "flicker out | ms/frame |\n"
      "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- "
      "|\n";
  const std::string html_header =
      "<tr><th>scene</th><th>input</th><th>SSIM all</th><th>SSIM in focus</th>"
      "<th>SSIM out of focus</th><th>PSNR all (dB)</th><th>PSNR in (dB)</th>"
      "<th>PSNR out (dB)</th><th>relMSE all</th><th>relMSE in</th><th>relMSE out</th>"
      "<th>flicker all</th><th>flicker in</th><th>flicker out</th><th>ms/frame</th></tr>";
  std::ofstream md(o.out_dir / "report.md");
  md << "# Denoiser evaluation\n\n"
     << "Run `" << o.run_dir.string() << "`, data `" << o.data_dir.string() << "`, " << done
     << (o.held_out ? " held-out frames (`--held-out`: all frames of the data, which the run "
                      "did not train on)"
                    : " validation frames")
     << ", device " << device.str() << ".\n\n"
     << "Checkpoint `" << used.checkpoint.string() << "`: epoch " << used.state.epoch << ", step "
     << used.state.step << ", " << (used.averaged ? "moving average of the" : "trained")
     << " weights, best loss " << cell(used.state.best, 5) << ".\n\n"
     << "SSIM and PSNR are taken on sRGB-encoded images clamped to [0, 1]; relative MSE on "
        "linear HDR radiance, mean of (d - r)^2 / (r^2 + 0.01). Flicker: the same relative MSE "
        "of the frame-to-frame differences, ((d_t - d_t-1) - (r_t - r_t-1))^2 / (m^2 + 0.01) "
        "with m the mean of r_t and r_t-1, over consecutive frames (Chaitanya et al. 2017, "
        "eq. 4). In focus: CoC < 1 pixel. Time: network + remodulation per frame, no IO.\n\n"
     << (std::isfinite(o.coc_override)
             ? "**CoC probe** (`--coc-override " + cell(o.coc_override, 2) +
                   "`): the network was fed a circle of confusion of " + cell(o.coc_override, 2) +
                   " px at every pixel instead of the frame's own; the regions are still those "
                   "of the frame's own CoC.\n\n"
             : std::string())
     << (o.flatten_inputs.empty()
             ? std::string()
             : "**Input probe** (`--flatten-input`): the network was fed " +
                   comma_list(o.flatten_inputs) +
                   " as each frame's mean, channel by channel, instead of the frame's own.\n\n")
     << md_header;
  // The tables' cells, one row per (scene, input), for report.md and report.html.
  using Rows = std::vector<std::vector<std::string>>;
  auto add_rows = [](Rows& summary_rows, const std::string& name, const Accumulator& a) {
    for (int k = 0; k < 2; ++k) {
      std::vector<std::string> row = {name + " (" + std::to_string(a.frames) + " frames)",
                                      k == 0 ? "noisy (1 spp)" : "denoised"};
      for (int m = 0; m < 4; ++m)
        for (int r = 0; r < 3; ++r)
          row.push_back(m == 3 ? cell_g(finite_mean(a.v[k][r][m]))
                               : cell(finite_mean(a.v[k][r][m]), m == 1 ? 2 : 4));
      row.push_back(k == 1 ? cell(finite_mean(a.ms), 2) : std::string("–"));
      summary_rows.push_back(std::move(row));
    }
  };
  auto rows_of = [&](const std::map<std::string, Accumulator>& scenes, const Accumulator& total) {
    Rows rows;
    for (const auto& [name, a] : scenes) add_rows(rows, name.empty() ? "(unnamed)" : name, a);
    if (scenes.size() > 1) add_rows(rows, "all scenes", total);
    return rows;
  };
  const Rows summary_rows = rows_of(by_scene, all);
  const Rows every_rows = o.all_frames ? rows_of(by_scene_every, every) : Rows{};
  auto md_rows = [&md](const Rows& rows) {
    for (const auto& row : rows) {
      for (const std::string& c : row) md << "| " << c << " ";
      md << "|\n";
    }
  };
  md_rows(summary_rows);
  const Rows coc_rows = coc_band_rows(all);
  md << "\n**By circle of confusion** (validation frames; a frame counts in a band where it "
        "has pixels there):\n\n"
     << kCocBandMdHeader;
  md_rows(coc_rows);
  if (o.all_frames) {
    md << "\n**All frames** (training and validation frames, as thesis table 5.1 scores "
          "its scenes; the training frames flatter the model):\n\n"
       << md_header;
    md_rows(every_rows);
  }
  md << "\nMean denoise time: " << cell(sum.ms, 2) << " ms per frame"
     << (at_size.is_null()
             ? std::string()
             : "; " + cell(sum.ms_at_size, 2) + " ms per " + std::to_string(o.time_side) +
                   "² frame (median of " + std::to_string(at_size["reps"].get<size_t>()) + ", " +
                   std::to_string(at_size["threads"].get<int>()) + " intra-op thread(s))")
     << ".\n\n"
     << ceiling.markdown() << "\n\n"
     << "![loss per epoch](loss.svg)\n\n![loss per step](steps.svg)\n\n![learning "
        "rate](lr.svg)\n\n![validation SSIM and PSNR](quality.svg)\n\n"
     << "Comparison images (`frame-NNN.png`): noisy | denoised | reference | error "
        "(mean absolute sRGB difference, ×4, black-red-yellow-white; white = 0.25). "
        "`report.html` shows all of this on one page.\n\n";
  if (!crops.empty()) {
    md << "## Crops where the lens matters\n\nThe window of the smallest and of the largest "
          "mean circle of confusion of the most blurred validation frames (those with a sharp "
          "window first; one per shard before a second of any), drawn 2×.\n\n"
          "| frame | region | noisy | denoised | reference |\n| --- | --- | --- | --- | --- |\n";
    for (const json& c : crops)
      md << "| " << c["shard"].get<std::string>() << " " << c["frame"].get<int>() << " | "
         << c["region"].get<std::string>() << ", mean CoC " << cell(c["mean_coc_px"].get<double>(), 1)
         << " px, " << c["side"].get<int>() << "² at (" << c["x"].get<int>() << ", "
         << c["y"].get<int>() << ") | ![](" << c["noisy"].get<std::string>() << ") | ![]("
         << c["denoised"].get<std::string>() << ") | ![](" << c["reference"].get<std::string>()
         << ") |\n";
    md << "\n";
  }
  md
     << "## Per frame\n\n| shard | frame | ms | SSIM | PSNR | relMSE |\n| --- | --- | --- | --- | "
        "--- | --- |\n";
  for (const json& r : frames) {
    auto v = [&](const char* m) {
      const json& x = r["denoised"]["all"][m];
      return x.is_null() ? std::string("–") : cell(x.get<double>(), 4);
    };
    md << "| " << r["shard"].get<std::string>() << " | " << r["frame"].get<int>() << " | "
       << cell(r["denoise_ms"].get<double>(), 2) << " | " << v("ssim") << " | " << v("psnr")
       << " | " << v("rel_mse") << " |\n";
  }

  // One self-contained page: the same numbers, the plots inline, the strips
  // embedded, labelled and shown at least 256 px a panel (pixelated).
  std::ostringstream html;
  html << "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
       << "<title>Denoiser evaluation</title><style>"
       << "body{font-family:sans-serif;margin:24px;max-width:1400px}"
       << "table{border-collapse:collapse;margin:8px 0}td,th{border:1px solid #bbb;"
          "padding:3px 7px;text-align:right}th{background:#eee}td:first-child,"
          "td:nth-child(2){text-align:left}"
       << ".strip img{image-rendering:pixelated;display:block}.labels{display:grid;"
          "grid-template-columns:repeat(4,1fr);font-size:13px;text-align:center}"
       << "figure{margin:16px 0}</style></head><body>"
       << "<h1>Denoiser evaluation</h1><p>Run <code>" << html_escape(o.run_dir.string())
       << "</code>, data <code>" << html_escape(o.data_dir.string())
       << "</code>, <span id=\"frames\">" << done << "</span> validation frames, device "
       << html_escape(device.str()) << ".</p>"
       << "<p>Checkpoint <code id=\"checkpoint\">" << html_escape(used.checkpoint.string())
       << "</code>: epoch " << used.state.epoch << ", step " << used.state.step << ", "
       << (used.averaged ? "moving average of the" : "trained") << " weights, best loss "
       << cell(used.state.best, 5) << ".</p>"
       << "<p>SSIM and PSNR on sRGB-encoded images clamped to [0, 1]; relative MSE on linear HDR "
          "radiance, mean of (d − r)² / (r² + 0.01). Flicker: that relative MSE of the "
          "frame-to-frame differences, ((d<sub>t</sub> − d<sub>t−1</sub>) − (r<sub>t</sub> − "
          "r<sub>t−1</sub>))² / (m² + 0.01), m the mean of r<sub>t</sub> and r<sub>t−1</sub>, over "
          "consecutive frames (Chaitanya et al. 2017, eq. 4). In focus: CoC &lt; 1 pixel. Time: "
          "network + "
          "remodulation per frame, no IO.</p><table id=\"summary\">"
       << html_header;
  auto html_rows = [&html](const Rows& rows) {
    for (const auto& row : rows) {
      html << "<tr>";
      for (const std::string& c : row) html << "<td>" << html_escape(c) << "</td>";
      html << "</tr>";
    }
  };
  html_rows(summary_rows);
  html << "</table><p>By circle of confusion (validation frames):</p><table id=\"by_coc\">"
       << kCocBandHtmlHeader;
  html_rows(coc_rows);
  html << "</table><p id=\"reference-ceiling\">" << html_escape(ceiling.markdown()) << "</p>";
  if (o.all_frames) {
    html << "<p>All frames (training and validation frames, as thesis table 5.1 scores its "
            "scenes; the training frames flatter the model):</p><table id=\"summary_all_frames\">"
         << html_header;
    html_rows(every_rows);
    html << "</table>";
  }
  html << "<h2>Training</h2>" << loss_svg << step_svg << lr_svg << quality_svg
       << "<h2>Comparisons</h2>";
  for (const Strip& st : strips) {
    const int panel = std::max(st.width, 256);
    const int shown_h = int(std::lround(double(st.height) * panel / st.width));
    html << "<figure class=\"strip\" style=\"width:" << 4 * panel << "px\"><div class=\"labels\">"
         << "<span>noisy (1 spp)</span><span>denoised</span><span>reference</span>"
            "<span>error ×4</span></div><img alt=\"noisy, denoised, reference and error of "
         << html_escape(st.shard) << " frame " << st.frame << "\" width=\"" << 4 * panel
         << "\" height=\"" << shown_h << "\" src=\"data:image/png;base64," << base64(st.png)
         << "\"><figcaption>" << html_escape(st.shard) << ", frame " << st.frame << " ("
         << st.width << "×" << st.height << " px"
         << (panel > st.width ? ", shown enlarged " + cell(double(panel) / st.width, 1) + "×" : "")
         << ")</figcaption></figure>";
  }
  if (!strips.empty()) html << "<p>Error colour scale:</p>" << error_scale_svg();
  html << "<script>document.body.dataset.svgs = document.querySelectorAll('svg').length;"
          "document.body.dataset.images = Array.from(document.images).filter("
          "i => i.complete && i.naturalWidth > 0).length;</script></body></html>\n";
  {
    const fs::path tmp = o.out_dir / "report.html.tmp";
    std::ofstream(tmp) << html.str();
    fs::rename(tmp, o.out_dir / "report.html");
  }
  return sum;
}

}  // namespace dofarm::trainer
