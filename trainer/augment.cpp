#include "trainer/augment.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"

namespace dofarm::trainer {

// log1p compresses the HDR range (fireflies of 1-spp radiance reach 1e3 and
// more) so that L1 is not dominated by a few pixels; it is exact to invert.
float radiance_forward(float demodulated) { return std::log1p(std::max(demodulated, 0.0f)); }
float radiance_inverse(float transformed) { return std::expm1(std::max(transformed, 0.0f)); }

void make_input(const FrameView& f, const DataConfig& data, bool dof, float* out) {
  const size_t n = f.pixels;
  const float eps = data.demod_eps;
  for (int c = 0; c < 3; ++c) {
    const float* l = f.noisy + c * n;
    const float* a = f.albedo + c * n;
    float* o = out + c * n;
    for (size_t p = 0; p < n; ++p) o[p] = radiance_forward(demodulate(l[p], a[p], eps));
  }
  std::copy(f.albedo, f.albedo + 3 * n, out + 3 * n);
  std::copy(f.normal, f.normal + 3 * n, out + 6 * n);
  // Depth relative to the focal plane of this frame: scale-free (no per-scene
  // constants, identical for a 64x64 crop and the full frame), 0.5 on the focal
  // plane, -> 1 far away. Escaped rays (stored as 0) are infinitely far.
  const float focal = std::max(f.focal_distance, 1e-6f);
  float* od = out + 9 * n;
  for (size_t p = 0; p < n; ++p) {
    float z = f.depth[p];
    od[p] = z > 0.0f && std::isfinite(z) ? z / (z + focal) : 1.0f;
  }
  std::copy(f.roughness, f.roughness + n, out + 10 * n);
  if (dof) {
    // Thesis 4.2 feeds the CoC scaled by hand-tuned per-scene limits; ours is
    // physical (pixels), so a fixed log scale covers every scene: 0 px -> 0,
    // 1 px (the sharpness limit) -> 0.2, 32 px -> 1, no clamp needed.
    DOFARM_CHECK(f.coc != nullptr);
    float* oc = out + 11 * n;
    for (size_t p = 0; p < n; ++p)
      oc[p] = std::log1p(std::max(f.coc[p], 0.0f)) / data.coc_log_scale;
  }
}

void make_target(const float* reference, const float* albedo, size_t pixels, const DataConfig& data,
                 float* out) {
  for (size_t i = 0; i < 3 * pixels; ++i)
    out[i] = radiance_forward(demodulate(reference[i], albedo[i], data.demod_eps));
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

Sample build_sample(const RawCrop& raw, const SequencePlan& plan, const DataConfig& data,
                    bool dof) {
  const int t = int(plan.offset.size());
  const int s = raw.size;
  const size_t n = size_t(s) * s;
  DOFARM_CHECK_GE(raw.frames, plan.span);
  Sample out;
  out.frames = t;
  out.channels = dof ? 12 : 11;
  out.size = s;
  out.input.resize(size_t(t) * out.channels * n);
  out.target.resize(size_t(t) * 3 * n);
  out.albedo.resize(size_t(t) * 3 * n);
  out.coc.resize(size_t(t) * n);
  for (int i = 0; i < t; ++i) {
    const int f = plan.offset[i], v = plan.version[i];
    DOFARM_CHECK_LT(v, raw.versions);
    const size_t fv = (size_t(f) * raw.versions + v) * 3 * n;  // per-version buffers
    const size_t f3 = size_t(f) * 3 * n, f1 = size_t(f) * n;
    const float* albedo =
        data.albedo == AlbedoSource::kVersion ? &raw.albedo[fv] : &raw.albedo_ref[f3];
    FrameView view;
    view.noisy = &raw.noisy[fv];
    view.albedo = albedo;
    view.normal = &raw.normal[f3];
    view.depth = &raw.depth[f1];
    view.roughness = &raw.roughness[f1];
    view.coc = raw.coc.empty() ? nullptr : &raw.coc[f1];
    view.focal_distance = raw.focal_distance[f];
    view.pixels = n;
    float* in = &out.input[size_t(i) * out.channels * n];
    make_input(view, data, dof, in);
    make_target(&raw.reference[f3], albedo, n, data, &out.target[size_t(i) * 3 * n]);
    std::copy(albedo, albedo + 3 * n, &out.albedo[size_t(i) * 3 * n]);
    if (!raw.coc.empty()) std::copy(&raw.coc[f1], &raw.coc[f1] + n, &out.coc[size_t(i) * n]);

    if (plan.quarter_turns) {
      rotate_planes(in, out.channels, s, plan.quarter_turns);
      rotate_planes(&out.target[size_t(i) * 3 * n], 3, s, plan.quarter_turns);
      rotate_planes(&out.albedo[size_t(i) * 3 * n], 3, s, plan.quarter_turns);
      rotate_planes(&out.coc[size_t(i) * n], 1, s, plan.quarter_turns);
      // View-space normals turn with the image: a quarter turn counter-clockwise
      // maps (nx, ny) to (-ny, nx) (x right, y up), so shading cues stay
      // consistent with the rotated picture.
      float* nx = in + kNormalChannel * n;
      float* ny = nx + n;
      for (size_t p = 0; p < n; ++p) {
        float x = nx[p], y = ny[p];
        for (int k = 0; k < plan.quarter_turns; ++k) {
          float tx = -y;
          y = x;
          x = tx;
        }
        nx[p] = x;
        ny[p] = y;
      }
    }
  }
  return out;
}

}  // namespace dofarm::trainer
