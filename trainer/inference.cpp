#include "trainer/inference.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "common/error.h"
#include "common/shard.h"
#include "trainer/augment.h"
#include "trainer/inputs.h"
#include "trainer/losses.h"
#include "trainer/metrics.h"
#include "trainer/precision.h"

namespace dofarm::trainer {

namespace fs = std::filesystem;

FrameDenoiser::FrameDenoiser(const fs::path& run_dir, torch::Device device,
                             const std::string& checkpoint, Precision precision, Weights weights)
    : run_(load_run(run_dir, device, checkpoint, weights)), device_(device), precision_(precision) {
  warn_if_not_applied(precision, device, "--precision");
}

std::vector<std::pair<std::string, size_t>> non_finite_inputs(FrameBuffers& f, int version,
                                                              const TrainConfig& cfg, bool repair) {
  const size_t n = f.plane();
  std::vector<std::pair<std::string, size_t>> out;
  // The buffers the inputs and the demodulation read, in input order.
  std::vector<std::string> names;
  for (const ResolvedInput& in : resolve_inputs(cfg.model, cfg.data))
    if (std::find(names.begin(), names.end(), in.buffer) == names.end()) names.push_back(in.buffer);
  const std::string albedo = demodulation_buffer(cfg.data);
  if (std::find(names.begin(), names.end(), albedo) == names.end())
    names.insert(names.begin() + std::min<size_t>(1, names.size()), albedo);
  if (cfg.data.albedo_prefilter == AlbedoPrefilter::kCoc &&
      std::find(names.begin(), names.end(), "coc") == names.end())
    names.push_back("coc");  // sizes the albedo prefilter
  for (const std::string& name : names) {
    const BufferInfo& b = buffer_info(name);
    std::vector<float>& data = buffer_data(f, name);
    const size_t count = size_t(b.channels) * n;
    const size_t begin = b.per_version ? size_t(version) * count : 0;
    if (data.size() < begin + count) continue;
    size_t bad = 0;
    for (size_t i = begin; i < begin + count; ++i)
      if (!std::isfinite(data[i])) {
        ++bad;
        if (repair) data[i] = 0.0f;
      }
    if (bad) out.emplace_back(name, bad);
  }
  return out;
}

std::vector<float> FrameDenoiser::denoise(const FrameBuffers& f, int version, double* seconds,
                                          const InputOverrides* overrides) {
  try {
    return denoise_frame(run_.model, run_.config, device_, precision_, state_, f, version, seconds,
                         overrides);
  } catch (const RuntimeError& e) {
    throw RuntimeError(std::string(e.what()) + " (checkpoint " + run_.checkpoint.string() + ")");
  }
}

std::vector<float> denoise_frame(Denoiser& model, const TrainConfig& cfg, torch::Device device,
                                 Precision precision, std::vector<torch::Tensor>& state,
                                 const FrameBuffers& f, int version, double* seconds,
                                 const InputOverrides* overrides) {
  if (version < 0 || version >= f.versions)
    throw SpecError(FileLoc{}, "version",
                    "the frame has " + std::to_string(f.versions) + " noisy versions");
  const size_t n = f.plane();
  // Each buffer the inputs read, at the version being denoised.
  FrameView view;
  view.pixels = n;
  view.focal_distance = f.camera.focal_distance;
  for (const BufferInfo& b : buffer_infos()) {
    const std::vector<float>& data = buffer_data(f, b.name);
    const size_t count = size_t(b.channels) * n,
                 begin = b.per_version ? size_t(version) * count : 0;
    if (data.size() >= begin + count) view.buffers[b.name] = data.data() + begin;
  }
  // As in training (augment.cpp); the prefilter, if any, is part of the
  // denoiser: counted in `seconds`.
  std::vector<float> filtered;
  const auto p0 = std::chrono::steady_clock::now();
  bind_demodulation_albedo(view, cfg.data, f.width, f.height, filtered);
  const double prefilter_seconds =
      cfg.data.albedo_prefilter == AlbedoPrefilter::kCoc
          ? std::chrono::duration<double>(std::chrono::steady_clock::now() - p0).count()
          : 0.0;
  const float* albedo = view.albedo;
  // After the prefilter and the demodulation albedo read the frame's own.
  if (overrides)
    for (const auto& [name, planes] : *overrides) view.buffers[name] = planes;
  const int c = cfg.model.input_channels();
  std::vector<float> input(size_t(c) * n);
  make_input(view, cfg.data, resolve_inputs(cfg.model, cfg.data), input.data());

  // Inference only: no autograd bookkeeping, no version counters.
  c10::InferenceMode inference;
  auto t0 = std::chrono::steady_clock::now();
  torch::Tensor x = torch::from_blob(input.data(), {1, c, f.height, f.width}).to(device);
  torch::Tensor y = float_output(precision, device,
                                 [&] { return model->forward_frame(pad_to_multiple(x), state); })
                        .narrow(2, 0, f.height)
                        .narrow(3, 0, f.width);
  // Remodulation (inverse of make_target) on the device, as a renderer would.
  torch::Tensor a =
      torch::from_blob(const_cast<float*>(albedo), {1, 3, f.height, f.width}).to(device);
  torch::Tensor out = radiance_inverse(y, radiance_space(cfg.model)) * (a + cfg.data.demod_eps);
  out = out.to(torch::kCPU).contiguous();
  if (device.is_cuda()) torch::cuda::synchronize();
  if (seconds)
    *seconds = prefilter_seconds +
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // Finite inputs and finite weights (checked at load) can still overflow:
  // never hand out a non-finite pixel.
  const int64_t bad = (~torch::isfinite(out)).sum().item<int64_t>();
  if (bad > 0)
    throw RuntimeError("the network produced " + std::to_string(bad) + " non-finite output values");
  return std::vector<float>(out.data_ptr<float>(), out.data_ptr<float>() + 3 * n);
}

double full_frame_ssim(Denoiser& model, const TrainConfig& cfg, torch::Device device,
                       const fs::path& data_dir, const std::vector<ShardSplit>& splits, int count) {
  return full_frame_scores(model, cfg, device, data_dir, splits, count, 0).whole;
}

FrameScores full_frame_scores(Denoiser& model, const TrainConfig& cfg, torch::Device device,
                              const fs::path& data_dir, const std::vector<ShardSplit>& splits,
                              int count, int tile) {
  std::vector<std::pair<std::string, int>> frames;  // (shard file, frame index)
  for (const ShardSplit& s : splits)
    for (int f = s.val_begin; f < s.val_end; ++f) frames.emplace_back(s.file, f);
  if (frames.empty() || count <= 0) return {};
  const size_t n = frames.size(), k = std::min(n, size_t(count));
  std::vector<double> whole, tiles;
  const auto denoise = [&](const FrameBuffers& fb) {
    std::vector<torch::Tensor> state;  // each frame and each tile alone
    return denoise_frame(model, cfg, device, cfg.train.precision, state, fb, 0);
  };
  for (size_t i = 0; i < k; ++i) {
    const auto& [file, f] = frames[(2 * i + 1) * n / (2 * k)];  // evenly spread
    const FrameBuffers fb = ShardReader(data_dir / file).read_frame(f);
    const int w = fb.width, h = fb.height;
    const auto score = [&](const std::vector<float>& out) {
      return display_ssim({out.data(), 3, h, w}, {fb.reference.data(), 3, h, w});
    };
    try {
      whole.push_back(score(denoise(fb)));
      if (tile > 0) tiles.push_back(score(denoise_in_tiles(fb, tile, denoise)));
    } catch (const RuntimeError&) {
      return {};  // a non-finite output: the caller reports it
    }
  }
  return {finite_mean(whole), tile > 0 ? finite_mean(tiles) : NAN};
}

std::vector<float> denoise_in_tiles(
    const FrameBuffers& frame, int tile,
    const std::function<std::vector<float>(const FrameBuffers&)>& denoise) {
  if (tile <= 0)
    throw SpecError(FileLoc{}, "tile", "a tile side must be positive, got " + std::to_string(tile));
  const size_t n = frame.plane();
  std::vector<float> joined(3 * n, 0.0f);
  for (int y0 = 0; y0 < frame.height; y0 += tile)
    for (int x0 = 0; x0 < frame.width; x0 += tile) {
      const int w = std::min(tile, frame.width - x0), h = std::min(tile, frame.height - y0);
      const std::vector<float> part = denoise(crop_frame(frame, x0, y0, w, h));
      if (part.size() != 3 * size_t(w) * h)
        throw RuntimeError("denoise_in_tiles: a tile's output has " + std::to_string(part.size()) +
                           " values, not " + std::to_string(3 * size_t(w) * h));
      for (int c = 0; c < 3; ++c)
        for (int y = 0; y < h; ++y)
          std::copy_n(part.data() + (size_t(c) * h + y) * w, w,
                      joined.data() + size_t(c) * n + size_t(y0 + y) * frame.width + x0);
    }
  return joined;
}

namespace {

// A w x h frame whose pixel (x, y) is f's pixel source(x, y) (an index into
// f's planes), in every buffer; the camera kept.
template <typename Source>
FrameBuffers remap_frame(const FrameBuffers& f, int w, int h, Source source) {
  FrameBuffers out;
  out.allocate(w, h, f.versions);
  out.rect = Rect{0, 0, w, h};
  out.camera = f.camera;
  const size_t n = f.plane(), m = out.plane();
  for (const BufferInfo& b : buffer_infos()) {
    const std::vector<float>& src = buffer_data(f, b.name);
    std::vector<float>& dst = buffer_data(out, b.name);
    const size_t planes = n ? src.size() / n : 0;
    dst.assign(planes * m, 0.0f);
    for (size_t k = 0; k < planes; ++k)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) dst[k * m + size_t(y) * w + x] = src[k * n + source(x, y)];
  }
  return out;
}

}  // namespace

FrameBuffers tile_frame(const FrameBuffers& f, int w, int h) {
  return remap_frame(f, w, h,
                     [&](int x, int y) { return size_t(y % f.height) * f.width + x % f.width; });
}

FrameBuffers crop_frame(const FrameBuffers& f, int x0, int y0, int w, int h) {
  if (x0 < 0 || y0 < 0 || w <= 0 || h <= 0 || x0 + w > f.width || y0 + h > f.height)
    throw SpecError(FileLoc{}, "crop",
                    "window outside the " + std::to_string(f.width) + "x" +
                        std::to_string(f.height) + " frame");
  return remap_frame(f, w, h,
                     [&](int x, int y) { return size_t(y0 + y) * f.width + size_t(x0 + x); });
}

}  // namespace dofarm::trainer
