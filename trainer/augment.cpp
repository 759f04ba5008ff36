#include "trainer/augment.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "common/image.h"
#include "trainer/prefilter.h"

namespace dofarm::trainer {

const float* FrameView::at(const std::string& buffer) const {
  auto it = buffers.find(buffer);
  if (it == buffers.end() || it->second == nullptr)
    throw RuntimeError("the frame has no '" + buffer + "' buffer, which the model's inputs need");
  return it->second;
}

void bind_demodulation_albedo(FrameView& view, const DataConfig& data, int width, int height,
                              std::vector<float>& storage) {
  const std::string name = demodulation_buffer(data);
  const float* albedo = view.at(name);
  if (data.albedo_prefilter == AlbedoPrefilter::kCoc) {
    // Thesis 6.1: every use of the demodulation albedo sees it filtered.
    storage.resize(3 * size_t(width) * size_t(height));
    prefilter_by_coc(albedo, 3, view.at("coc"), width, height, data.albedo_prefilter_scale,
                     storage.data());
    albedo = storage.data();
    view.buffers[name] = albedo;
  }
  view.albedo = albedo;
}

void make_input(const FrameView& f, const DataConfig& data,
                const std::vector<ResolvedInput>& inputs, float* out) {
  EncodeArgs args;
  args.albedo = f.albedo;
  args.pixels = f.pixels;
  args.focal_distance = f.focal_distance;
  args.data = &data;
  for (const ResolvedInput& in : inputs) {
    args.src = f.at(in.buffer);
    in.row->encode(args, out + size_t(in.offset) * f.pixels);
  }
}

void make_target(const float* reference, const float* albedo, size_t pixels, const DataConfig& data,
                 RadianceSpace space, float* out) {
  for (size_t i = 0; i < 3 * pixels; ++i)
    out[i] = radiance_forward(demodulate(reference[i], albedo[i], data.demod_eps), space);
}

SequencePlan draw_plan(std::mt19937_64& rng, const DataConfig& data, int frame_begin, int frame_end,
                       int versions, int width, int height) {
  const int t = data.sequence;
  DOFARM_CHECK_GE(frame_end - frame_begin, t);
  DOFARM_CHECK_GE(versions, 1);
  DOFARM_CHECK_GE(std::min(width, height), data.crop);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  SequencePlan plan;
  plan.offset.resize(t);
  plan.version.resize(t);
  plan.stopped.assign(t, 0);
  // Versions already shown per source frame, so that a stop shows new noise.
  std::vector<std::vector<int>> used(t);
  int offset = 0;
  for (int i = 0; i < t; ++i) {
    if (i > 0) {
      // Thesis 4.3.3: with p = 0.25 the camera stops at this frame: the same
      // frame again (target and aux unchanged) with another noisy version.
      plan.stopped[i] = u01(rng) < data.stop_probability ? 1 : 0;
      if (!plan.stopped[i]) ++offset;
    }
    plan.offset[i] = offset;
    std::vector<int> fresh;
    for (int v = 0; v < versions; ++v)
      if (std::find(used[offset].begin(), used[offset].end(), v) == used[offset].end())
        fresh.push_back(v);
    int v;
    if (!fresh.empty()) {
      v = fresh[std::uniform_int_distribution<int>(0, int(fresh.size()) - 1)(rng)];
    } else {  // more stops than versions: any version but the one just shown
      v = std::uniform_int_distribution<int>(0, versions - 1)(rng);
      if (versions > 1 && v == plan.version[i - 1]) v = (v + 1) % versions;
    }
    used[offset].push_back(v);
    plan.version[i] = v;
  }
  plan.span = offset + 1;
  plan.first_frame = std::uniform_int_distribution<int>(frame_begin, frame_end - plan.span)(rng);
  plan.reversed = u01(rng) < data.reverse_probability;
  if (plan.reversed) {
    std::reverse(plan.offset.begin(), plan.offset.end());
    std::reverse(plan.version.begin(), plan.version.end());
    // A stop belongs to the step that repeats its predecessor; reversed, the
    // repeated pair is the same, so the flag moves one step earlier.
    std::vector<uint8_t> s(t, 0);
    for (int i = 1; i < t; ++i) s[i] = plan.offset[i] == plan.offset[i - 1];
    plan.stopped = s;
  }
  plan.crop_x = std::uniform_int_distribution<int>(0, width - data.crop)(rng);
  plan.crop_y = std::uniform_int_distribution<int>(0, height - data.crop)(rng);
  plan.quarter_turns = data.rotate ? std::uniform_int_distribution<int>(0, 3)(rng) : 0;
  return plan;
}

void rotate_planes(float* data, int planes, int size, int quarter_turns) {
  quarter_turns = ((quarter_turns % 4) + 4) % 4;
  if (quarter_turns == 0) return;
  const size_t n = size_t(size) * size;
  std::vector<float> tmp(n);
  for (int p = 0; p < planes; ++p) {
    float* d = data + p * n;
    for (int k = 0; k < quarter_turns; ++k) {
      // One turn counter-clockwise: dst[row y][col x] = src[row x][col size-1-y]
      // (the top-right corner moves to the top-left).
      for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x)
          tmp[size_t(y) * size + x] = d[size_t(x) * size + size - 1 - y];
      std::copy(tmp.begin(), tmp.end(), d);
    }
  }
}

namespace {

// Camera-space directions (buffers whose channels are X,Y,Z: the normal)
// turn with the image: a quarter turn counter-clockwise maps (x, y) to
// (-y, x) (x right, y up), so shading cues stay consistent with the rotated
// picture. Per pixel, so it commutes with the spatial rotation; done before
// encoding because an encoding (normal:remap01) is not linear in the sign.
void rotate_directions(float* xyz, size_t n, int quarter_turns) {
  float* nx = xyz;
  float* ny = xyz + n;
  for (size_t p = 0; p < n; ++p) {
    float x = nx[p], y = ny[p];
    for (int k = 0; k < quarter_turns; ++k) {
      const float tx = -y;
      y = x;
      x = tx;
    }
    nx[p] = x;
    ny[p] = y;
  }
}

}  // namespace

Sample build_sample(const RawCrop& raw, const SequencePlan& plan, const DataConfig& data,
                    const ModelConfig& model) {
  const int t = int(plan.offset.size());
  const int s = raw.size;
  const size_t n = size_t(s) * s;
  DOFARM_CHECK_GE(raw.frames, plan.span);
  const std::vector<ResolvedInput> inputs = resolve_inputs(model, data);
  const RadianceSpace space = radiance_space(model);
  Sample out;
  out.frames = t;
  out.channels = model.input_channels();
  out.size = s;
  out.input.resize(size_t(t) * out.channels * n);
  out.target.resize(size_t(t) * 3 * n);
  out.albedo.resize(size_t(t) * 3 * n);
  const bool has_coc = raw.buffers.count("coc") > 0;
  if (has_coc) out.coc.resize(size_t(t) * n);
  std::vector<float> turned;    // a direction buffer's planes, turned per pixel
  std::vector<float> filtered;  // the prefiltered albedo (data.albedo_prefilter)
  for (int i = 0; i < t; ++i) {
    const int f = plan.offset[i], v = plan.version[i];
    DOFARM_CHECK_LT(v, raw.versions);
    FrameView view;
    for (const auto& [name, data_planes] : raw.buffers) {
      const BufferInfo& b = buffer_info(name);
      const size_t planes = size_t(b.channels) * n;
      const size_t at =
          b.per_version ? (size_t(f) * raw.versions + v) * planes : size_t(f) * planes;
      DOFARM_CHECK_LE(at + planes, data_planes.size());
      view.buffers[name] = &data_planes[at];
    }
    bind_demodulation_albedo(view, data, s, s, filtered);
    view.focal_distance = raw.focal_distance[f];
    view.pixels = n;
    if (plan.quarter_turns)
      for (const ResolvedInput& in : inputs)
        if (std::string(buffer_info(in.buffer).channel_names) == "X,Y,Z") {
          turned.assign(view.at(in.buffer), view.at(in.buffer) + 3 * n);
          rotate_directions(turned.data(), n, plan.quarter_turns);
          view.buffers[in.buffer] = turned.data();
        }
    float* in = &out.input[size_t(i) * out.channels * n];
    make_input(view, data, inputs, in);
    make_target(view.at("reference"), view.albedo, n, data, space,
                &out.target[size_t(i) * 3 * n]);
    std::copy(view.albedo, view.albedo + 3 * n, &out.albedo[size_t(i) * 3 * n]);
    if (has_coc) std::copy(view.at("coc"), view.at("coc") + n, &out.coc[size_t(i) * n]);
    if (plan.quarter_turns) {
      if (has_coc) rotate_planes(&out.coc[size_t(i) * n], 1, s, plan.quarter_turns);
      rotate_planes(in, out.channels, s, plan.quarter_turns);
      rotate_planes(&out.target[size_t(i) * 3 * n], 3, s, plan.quarter_turns);
      rotate_planes(&out.albedo[size_t(i) * 3 * n], 3, s, plan.quarter_turns);
    }
  }
  return out;
}

}  // namespace dofarm::trainer
