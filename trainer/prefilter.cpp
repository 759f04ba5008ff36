#include "trainer/prefilter.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "common/error.h"

namespace dofarm::trainer {

namespace {

// Normalised 1-D Gaussian of radius ceil(3 sigma), sigma > 0.
std::vector<float> gaussian(float sigma) {
  const int r = int(std::ceil(3.0f * sigma));
  std::vector<float> k(size_t(2 * r + 1));
  double sum = 0;
  for (int i = -r; i <= r; ++i) sum += k[size_t(i + r)] = std::exp(-0.5f * i * i / (sigma * sigma));
  for (float& v : k) v = float(v / sum);
  return k;
}

// One plane blurred separably with edge replication.
void blur_plane(const float* in, int w, int h, const std::vector<float>& k, float* tmp,
                float* out) {
  const int r = int(k.size()) / 2;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double s = 0;
      for (int i = -r; i <= r; ++i)
        s += k[size_t(i + r)] * in[size_t(y) * w + std::clamp(x + i, 0, w - 1)];
      tmp[size_t(y) * w + x] = float(s);
    }
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double s = 0;
      for (int i = -r; i <= r; ++i)
        s += k[size_t(i + r)] * tmp[size_t(std::clamp(y + i, 0, h - 1)) * w + x];
      out[size_t(y) * w + x] = float(s);
    }
}

}  // namespace

void prefilter_by_coc(const float* in, int planes, const float* coc, int width, int height,
                      float scale, float* out) {
  DOFARM_CHECK(in != out);
  const size_t n = size_t(width) * height;
  constexpr int kLevels = int(kPrefilterSigmas.size());
  // Each pixel's sigma and the highest level any pixel reaches.
  std::vector<float> sigma(n);
  int top = 0;
  for (size_t p = 0; p < n; ++p) {
    const float c = coc[p];
    const float s = std::isfinite(c) && c > 0 ? std::min(scale * c, kPrefilterSigmas.back()) : 0;
    sigma[p] = s;
    while (top + 1 < kLevels && kPrefilterSigmas[size_t(top)] < s) ++top;
  }
  std::copy(in, in + size_t(planes) * n, out);  // level 0: sigma 0 is the image itself
  if (top == 0) return;
  // levels[l] holds the image blurred at kPrefilterSigmas[l], l = 1..top.
  std::vector<std::vector<float>> levels(size_t(top) + 1);
  std::vector<float> tmp(n);
  for (int l = 1; l <= top; ++l) {
    const std::vector<float> k = gaussian(kPrefilterSigmas[size_t(l)]);
    levels[size_t(l)].resize(size_t(planes) * n);
    for (int c = 0; c < planes; ++c)
      blur_plane(in + size_t(c) * n, width, height, k, tmp.data(),
                 levels[size_t(l)].data() + size_t(c) * n);
  }
  for (size_t p = 0; p < n; ++p) {
    const float s = sigma[p];
    if (s <= 0) continue;
    int hi = 1;
    while (hi < top && kPrefilterSigmas[size_t(hi)] < s) ++hi;
    const float lo_s = kPrefilterSigmas[size_t(hi - 1)], hi_s = kPrefilterSigmas[size_t(hi)];
    const float t = std::min(1.0f, (s - lo_s) / (hi_s - lo_s));
    for (int c = 0; c < planes; ++c) {
      const size_t i = size_t(c) * n + p;
      const float a = hi == 1 ? in[i] : levels[size_t(hi - 1)][i];
      out[i] = a + t * (levels[size_t(hi)][i] - a);
    }
  }
}

}  // namespace dofarm::trainer
