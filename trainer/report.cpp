#include "trainer/report.h"

#define STB_IMAGE_WRITE_STATIC  // private copy: no clash with other users of stb
#define STB_IMAGE_WRITE_IMPLEMENTATION
// Its own code's warnings (unused writers, partial struct initialisers).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-function"
#include <stb_image_write.h>
#pragma GCC diagnostic pop

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <sstream>

#include "common/error.h"
#include "trainer/metrics.h"

namespace dofarm::trainer {

namespace {

void write_png(const std::filesystem::path& path, const std::vector<uint8_t>& rgb, int w, int h) {
  if (!stbi_write_png(path.string().c_str(), w, h, 3, rgb.data(), w * 3))
    throw RuntimeError(path.string() + ": cannot write PNG");
}

uint8_t to_byte(float v) { return uint8_t(std::lround(std::clamp(v, 0.0f, 1.0f) * 255.0f)); }

// Black -> red -> yellow -> white, t in [0, 1].
void heat(float t, uint8_t* px) {
  t = std::clamp(t, 0.0f, 1.0f) * 3.0f;
  px[0] = to_byte(t);
  px[1] = to_byte(t - 1.0f);
  px[2] = to_byte(t - 2.0f);
}

}  // namespace

void write_comparison_png(const std::filesystem::path& path, const std::vector<float>& noisy,
                          const std::vector<float>& denoised, const std::vector<float>& reference,
                          int w, int h) {
  const size_t n = size_t(w) * h;
  const int total_w = 4 * w;
  std::vector<uint8_t> rgb(size_t(total_w) * h * 3);
  const std::vector<float>* panels[3] = {&noisy, &denoised, &reference};
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      size_t p = size_t(y) * w + x;
      float err = 0;
      for (int k = 0; k < 3; ++k) {
        uint8_t* px = &rgb[(size_t(y) * total_w + k * w + x) * 3];
        for (int c = 0; c < 3; ++c) px[c] = to_byte(srgb_encode_clamped((*panels[k])[c * n + p]));
      }
      for (int c = 0; c < 3; ++c)
        err += std::abs(srgb_encode_clamped(denoised[c * n + p]) -
                        srgb_encode_clamped(reference[c * n + p]));
      heat(4.0f * err / 3.0f, &rgb[(size_t(y) * total_w + 3 * w + x) * 3]);
    }
  write_png(path, rgb, total_w, h);
}

LossCurve read_loss_csv(const std::filesystem::path& csv) {
  LossCurve c;
  std::ifstream in(csv);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) f.push_back(cell);
    if (f.size() < 4) continue;
    auto num = [](const std::string& s) { return s.empty() ? NAN : std::stod(s); };
    c.epoch.push_back(num(f[0]));
    c.train.push_back(num(f[2]));
    c.val.push_back(num(f[3]));
  }
  return c;
}

std::string write_loss_plot_png(const std::filesystem::path& path, const LossCurve& curve) {
  const int w = 640, h = 360, left = 40, right = 10, top = 10, bottom = 30;
  std::vector<uint8_t> rgb(size_t(w) * h * 3, 255);
  auto put = [&](int x, int y, const uint8_t* col) {
    if (x < 0 || y < 0 || x >= w || y >= h) return;
    std::copy(col, col + 3, &rgb[(size_t(y) * w + x) * 3]);
  };
  auto line = [&](int x0, int y0, int x1, int y1, const uint8_t* col) {  // Bresenham
    int dx = std::abs(x1 - x0), dy = -std::abs(y1 - y0), sx = x0 < x1 ? 1 : -1,
        sy = y0 < y1 ? 1 : -1, e = dx + dy;
    for (;;) {
      put(x0, y0, col);
      put(x0, y0 + 1, col);  // two pixels thick
      if (x0 == x1 && y0 == y1) break;
      int e2 = 2 * e;
      if (e2 >= dy) e += dy, x0 += sx;
      if (e2 <= dx) e += dx, y0 += sy;
    }
  };
  double lo = INFINITY, hi = -INFINITY, emax = 1;
  for (size_t i = 0; i < curve.epoch.size(); ++i) {
    for (double v : {curve.train[i], curve.val[i]})
      if (std::isfinite(v) && v > 0) lo = std::min(lo, v), hi = std::max(hi, v);
    emax = std::max(emax, curve.epoch[i]);
  }
  if (!std::isfinite(lo)) lo = 0.1, hi = 1;
  double llo = std::floor(std::log10(lo)), lhi = std::ceil(std::log10(hi));
  if (lhi <= llo) lhi = llo + 1;
  const uint8_t axis[3] = {0, 0, 0}, grid[3] = {220, 220, 220};
  const uint8_t blue[3] = {31, 119, 180}, orange[3] = {255, 127, 14};
  auto px = [&](double e) { return left + int(std::lround(e / emax * (w - left - right - 1))); };
  auto py = [&](double v) {
    double t = (std::log10(v) - llo) / (lhi - llo);
    return top + int(std::lround((1 - t) * (h - top - bottom - 1)));
  };
  for (double d = llo; d <= lhi; d += 1)
    line(left, py(std::pow(10, d)), w - right, py(std::pow(10, d)), grid);
  for (double e = 10; e <= emax; e += 10) line(px(e), h - bottom, px(e), h - bottom + 6, axis);
  line(left, top, left, h - bottom, axis);
  line(left, h - bottom, w - right, h - bottom, axis);
  for (int k = 0; k < 2; ++k) {
    const std::vector<double>& ys = k == 0 ? curve.train : curve.val;
    int lx = -1, ly = -1;
    for (size_t i = 0; i < ys.size(); ++i) {
      if (!(std::isfinite(ys[i]) && ys[i] > 0)) continue;
      int x = px(curve.epoch[i]), y = py(ys[i]);
      if (lx >= 0)
        line(lx, ly, x, y, k == 0 ? blue : orange);
      else
        put(x, y, k == 0 ? blue : orange);
      lx = x, ly = y;
    }
  }
  write_png(path, rgb, w, h);
  std::ostringstream os;
  os << "x: epoch 0.." << emax << " (ticks every 10); y: log10 loss, 1e" << llo << "..1e" << lhi
     << " (grid per decade); blue = training, orange = validation";
  return os.str();
}

}  // namespace dofarm::trainer
