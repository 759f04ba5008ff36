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
#include <cstdio>
#include <fstream>
#include <sstream>

#include "common/error.h"
#include "trainer/metrics.h"

namespace dofarm::trainer {

namespace {

uint8_t to_byte(float v) { return uint8_t(std::lround(std::clamp(v, 0.0f, 1.0f) * 255.0f)); }

// Black -> red -> yellow -> white, t in [0, 1].
void heat(float t, uint8_t* px) {
  t = std::clamp(t, 0.0f, 1.0f) * 3.0f;
  px[0] = to_byte(t);
  px[1] = to_byte(t - 1.0f);
  px[2] = to_byte(t - 2.0f);
}

// 8-bit RGB rows as PNG file bytes.
std::string png_bytes(const std::vector<uint8_t>& rgb, int w, int h) {
  std::string out;
  auto sink = [](void* ctx, void* data, int size) {
    static_cast<std::string*>(ctx)->append(static_cast<const char*>(data), size_t(size));
  };
  if (!stbi_write_png_to_func(sink, &out, w, h, 3, rgb.data(), w * 3))
    throw RuntimeError("cannot encode a PNG of " + std::to_string(w) + "x" + std::to_string(h));
  return out;
}

// A tick value without trailing zeros: 0.05, 2, 1e-05.
std::string fmt_number(double v) {
  if (v == 0) return "0";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

}  // namespace

namespace {

std::vector<uint8_t> comparison_rgb(const std::vector<float>& noisy,
                                    const std::vector<float>& denoised,
                                    const std::vector<float>& reference, int w, int h) {
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
  return rgb;
}

}  // namespace

std::string comparison_png_bytes(const std::vector<float>& noisy, const std::vector<float>& denoised,
                                 const std::vector<float>& reference, int w, int h) {
  return png_bytes(comparison_rgb(noisy, denoised, reference, w, h), 4 * w, h);
}

FocusCrops choose_focus_crops(const std::vector<float>& coc, int w, int h, int side,
                              const std::vector<float>* reference) {
  FocusCrops out;
  side = std::min({side, w, h});
  if (side <= 0 || coc.size() < size_t(w) * h) return out;
  const size_t n = size_t(w) * h;
  const bool judge = reference && reference->size() >= 3 * n;
  // Summed-area tables, (w + 1) x (h + 1), in double (no drift over a
  // frame): of the CoC, and of the reference's display-white pixels.
  std::vector<double> sat(size_t(w + 1) * (h + 1), 0.0), white(judge ? sat.size() : 0, 0.0);
  for (int y = 0; y < h; ++y) {
    double row = 0, row_white = 0;
    for (int x = 0; x < w; ++x) {
      const size_t p = size_t(y) * w + x;
      const float c = coc[p];
      row += std::isfinite(c) ? double(c) : 0.0;
      const size_t at = size_t(y + 1) * (w + 1) + x + 1, above = size_t(y) * (w + 1) + x + 1;
      sat[at] = sat[above] + row;
      if (judge) {
        const auto& r = *reference;
        row_white += (r[p] >= 1.0f && r[n + p] >= 1.0f && r[2 * n + p] >= 1.0f) ? 1.0 : 0.0;
        white[at] = white[above] + row_white;
      }
    }
  }
  const int stride = std::max(1, side / 4);
  const double area = double(side) * side;
  // [0]: any window; [1]: windows whose reference is at most half white.
  double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
  CropWindow lo_w[2], hi_w[2];
  for (int y = 0; y + side <= h; y += stride)
    for (int x = 0; x + side <= w; x += stride) {
      auto box = [&](const std::vector<double>& t) {
        auto at = [&](int xx, int yy) { return t[size_t(yy) * (w + 1) + xx]; };
        return at(x + side, y + side) - at(x, y + side) - at(x + side, y) + at(x, y);
      };
      const double mean = box(sat) / area;
      const bool shows = !judge || box(white) <= 0.5 * area;
      for (int k = 0; k < (shows ? 2 : 1); ++k) {
        if (mean < lo[k]) {
          lo[k] = mean;
          lo_w[k] = {x, y, side, mean, true};
        }
        if (mean > hi[k]) {
          hi[k] = mean;
          hi_w[k] = {x, y, side, mean, true};
        }
      }
    }
  // A window that shows something if one qualifies, else any.
  for (int k : {1, 0}) {
    if (!out.in_focus.found && lo_w[k].found && lo[k] < 1.0) out.in_focus = lo_w[k];
    if (!out.out_of_focus.found && hi_w[k].found && hi[k] >= 2.0) out.out_of_focus = hi_w[k];
  }
  return out;
}

std::string crop_png_bytes(const std::vector<float>& img, int w, int h, const CropWindow& c,
                           int zoom) {
  DOFARM_CHECK(c.side > 0 && c.x >= 0 && c.y >= 0 && c.x + c.side <= w && c.y + c.side <= h &&
               zoom >= 1 && img.size() >= size_t(3) * w * h);
  const size_t n = size_t(w) * h;
  const int out_side = c.side * zoom;
  std::vector<uint8_t> rgb(size_t(out_side) * out_side * 3);
  for (int y = 0; y < out_side; ++y)
    for (int x = 0; x < out_side; ++x) {
      const size_t p = size_t(c.y + y / zoom) * w + size_t(c.x + x / zoom);
      for (int ch = 0; ch < 3; ++ch)
        rgb[(size_t(y) * out_side + x) * 3 + ch] = to_byte(srgb_encode_clamped(img[ch * n + p]));
    }
  return png_bytes(rgb, out_side, out_side);
}

std::string error_scale_svg() {
  // The ramp of heat(): 0 -> black, 1/3 -> red, 2/3 -> yellow, 1 -> white,
  // reached at a mean absolute error of 0.25 (the panel shows 4x the error).
  std::ostringstream os;
  os << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"340\" height=\"46\" "
        "class=\"scale\" role=\"img\" aria-label=\"error colour scale\">"
     << "<defs><linearGradient id=\"heat\"><stop offset=\"0\" stop-color=\"#000\"/>"
     << "<stop offset=\"0.3333\" stop-color=\"#f00\"/><stop offset=\"0.6667\" "
        "stop-color=\"#ff0\"/><stop offset=\"1\" stop-color=\"#fff\"/></linearGradient></defs>"
     << "<rect x=\"10\" y=\"4\" width=\"320\" height=\"14\" fill=\"url(#heat)\" "
        "stroke=\"#444\"/>";
  for (int i = 0; i <= 5; ++i) {
    const double x = 10 + 320.0 * i / 5;
    os << "<line x1=\"" << x << "\" x2=\"" << x << "\" y1=\"18\" y2=\"23\" stroke=\"#444\"/>"
       << "<text x=\"" << x << "\" y=\"34\" font-size=\"10\" text-anchor=\"middle\">"
       << fmt_number(0.05 * i) << "</text>";
  }
  os << "<text x=\"170\" y=\"45\" font-size=\"10\" text-anchor=\"middle\">mean |denoised - "
        "reference| per pixel (sRGB, 0..1)</text></svg>";
  return os.str();
}

namespace {

std::vector<std::vector<std::string>> read_csv_rows(const std::filesystem::path& csv) {
  std::vector<std::vector<std::string>> rows;
  std::ifstream in(csv);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) f.push_back(cell);
    if (!line.empty() && line.back() == ',') f.emplace_back();
    rows.push_back(f);
  }
  return rows;
}

double num(const std::string& s) {
  if (s.empty()) return NAN;
  try {
    return std::stod(s);
  } catch (const std::exception&) {
    return NAN;
  }
}

}  // namespace

LossCurve read_loss_csv(const std::filesystem::path& csv) {
  LossCurve c;
  for (const auto& f : read_csv_rows(csv)) {
    if (f.size() < 5) continue;
    c.epoch.push_back(num(f[0]));
    c.train.push_back(num(f[2]));
    c.val.push_back(num(f[3]));
    c.lr.push_back(num(f[4]));
    c.val_ssim.push_back(f.size() > 7 ? num(f[7]) : NAN);
    c.val_psnr.push_back(f.size() > 8 ? num(f[8]) : NAN);
    c.val_frame_ssim.push_back(f.size() > 9 ? num(f[9]) : NAN);
    c.val_tile_ssim.push_back(f.size() > 10 ? num(f[10]) : NAN);
  }
  return c;
}

StepCurve read_steps_csv(const std::filesystem::path& csv) {
  StepCurve c;
  for (const auto& f : read_csv_rows(csv)) {
    if (f.size() < 3) continue;
    c.step.push_back(num(f[0]));
    c.loss.push_back(num(f[1]));
    c.lr.push_back(num(f[2]));
    c.grad_norm.push_back(f.size() > 3 ? num(f[3]) : NAN);
  }
  return c;
}

namespace {

// Ticks at 1, 2 or 5 times a power of ten, about `target` of them over [lo, hi].
std::vector<double> nice_ticks(double lo, double hi, int target) {
  std::vector<double> t;
  if (!(hi > lo)) return {lo};
  const double raw = (hi - lo) / target;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  double step = mag;
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * mag >= raw) {
      step = m * mag;
      break;
    }
  for (double v = std::ceil(lo / step) * step; v <= hi + step * 1e-9; v += step)
    t.push_back(std::abs(v) < step * 1e-9 ? 0.0 : v);
  return t;
}

}  // namespace

std::string html_escape(const std::string& s) {
  std::string o;
  for (char c : s) {
    switch (c) {
      case '&': o += "&amp;"; break;
      case '<': o += "&lt;"; break;
      case '>': o += "&gt;"; break;
      case '"': o += "&quot;"; break;
      default: o += c;
    }
  }
  return o;
}

std::string base64(const std::string& in) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const uint32_t v = uint32_t(uint8_t(in[i])) << 16 | uint32_t(uint8_t(in[i + 1])) << 8 |
                       uint8_t(in[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out += k[(v >> s) & 63];
  }
  if (i < in.size()) {
    uint32_t v = uint32_t(uint8_t(in[i])) << 16;
    if (i + 1 < in.size()) v |= uint32_t(uint8_t(in[i + 1])) << 8;
    out += k[(v >> 18) & 63];
    out += k[(v >> 12) & 63];
    out += i + 1 < in.size() ? k[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::string svg_plot(const PlotSpec& p) {
  const int w = p.width, h = p.height, left = 70, right = 16, top = 30, bottom = 48;
  const int pw = w - left - right, ph = h - top - bottom;
  auto usable = [&](double x, double y) {
    return std::isfinite(x) && std::isfinite(y) && (!p.log_y || y > 0);
  };
  double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
  for (const PlotSeries& s : p.series)
    for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!usable(s.x[i], s.y[i])) continue;
      const double y = p.log_y ? std::log10(s.y[i]) : s.y[i];
      x0 = std::min(x0, s.x[i]), x1 = std::max(x1, s.x[i]);
      y0 = std::min(y0, y), y1 = std::max(y1, y);
    }
  std::ostringstream os;
  os << "<svg xmlns=\"http://www.w3.org/2000/svg\" class=\"plot\" width=\"" << w
     << "\" height=\"" << h << "\" viewBox=\"0 0 " << w << " " << h << "\" role=\"img\" aria-label=\""
     << html_escape(p.title) << "\" font-family=\"sans-serif\">"
     << "<text class=\"title\" x=\"" << w / 2 << "\" y=\"18\" font-size=\"14\" "
        "text-anchor=\"middle\">" << html_escape(p.title) << "</text>";
  if (!std::isfinite(x0)) {
    os << "<text x=\"" << w / 2 << "\" y=\"" << h / 2
       << "\" font-size=\"12\" text-anchor=\"middle\">no data yet</text></svg>";
    return os.str();
  }
  if (p.log_y) y0 = std::floor(y0), y1 = std::ceil(y1);
  if (!(x1 > x0)) x0 -= 0.5, x1 += 0.5;
  if (!(y1 > y0)) {
    const double pad = p.log_y ? 1.0 : std::max(1e-12, std::abs(y0) * 0.1);
    y0 -= pad, y1 += pad;
  }
  auto X = [&](double x) { return left + (x - x0) / (x1 - x0) * pw; };
  auto Y = [&](double y) { return top + (1 - (y - y0) / (y1 - y0)) * ph; };
  char buf[64];
  auto f = [&](double v) {
    std::snprintf(buf, sizeof buf, "%.1f", v);
    return std::string(buf);
  };
  // Grid and y ticks.
  std::vector<double> yt;
  if (p.log_y) {
    for (double d = y0; d <= y1 + 1e-9; d += 1) yt.push_back(d);
  } else {
    yt = nice_ticks(y0, y1, 5);
  }
  for (double t : yt) {
    os << "<line x1=\"" << left << "\" x2=\"" << left + pw << "\" y1=\"" << f(Y(t)) << "\" y2=\""
       << f(Y(t)) << "\" stroke=\"#ddd\"/>"
       << "<text class=\"ytick\" x=\"" << left - 6 << "\" y=\"" << f(Y(t) + 4)
       << "\" font-size=\"11\" text-anchor=\"end\">"
       << (p.log_y ? fmt_number(std::pow(10.0, t)) : fmt_number(t)) << "</text>";
  }
  for (double t : nice_ticks(x0, x1, 6)) {
    os << "<line x1=\"" << f(X(t)) << "\" x2=\"" << f(X(t)) << "\" y1=\"" << top + ph << "\" y2=\""
       << top + ph + 5 << "\" stroke=\"#444\"/>"
       << "<text class=\"xtick\" x=\"" << f(X(t)) << "\" y=\"" << top + ph + 18
       << "\" font-size=\"11\" text-anchor=\"middle\">" << fmt_number(t) << "</text>";
  }
  os << "<rect x=\"" << left << "\" y=\"" << top << "\" width=\"" << pw << "\" height=\"" << ph
     << "\" fill=\"none\" stroke=\"#444\"/>"
     << "<text class=\"xtitle\" x=\"" << left + pw / 2 << "\" y=\"" << h - 8
     << "\" font-size=\"12\" text-anchor=\"middle\">" << html_escape(p.x_title) << "</text>"
     << "<text class=\"ytitle\" x=\"16\" y=\"" << top + ph / 2 << "\" font-size=\"12\" "
        "text-anchor=\"middle\" transform=\"rotate(-90 16 " << top + ph / 2 << ")\">"
     << html_escape(p.y_title + (p.log_y ? " (log scale)" : "")) << "</text>";
  // Series: polylines broken at gaps, a dot for an isolated point.
  int legend_y = top + 14;
  for (const PlotSeries& s : p.series) {
    std::vector<std::string> runs(1);
    for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!usable(s.x[i], s.y[i])) {
        if (!runs.back().empty()) runs.emplace_back();
        continue;
      }
      const double y = p.log_y ? std::log10(s.y[i]) : s.y[i];
      runs.back() += f(X(s.x[i])) + "," + f(Y(y)) + " ";
    }
    for (const std::string& r : runs) {
      if (r.empty()) continue;
      if (std::count(r.begin(), r.end(), ' ') == 1) {
        const size_t comma = r.find(',');
        os << "<circle cx=\"" << r.substr(0, comma) << "\" cy=\"" << r.substr(comma + 1, r.size() - comma - 2)
           << "\" r=\"2.5\" fill=\"" << s.colour << "\"/>";
      } else {
        os << "<polyline class=\"series\" fill=\"none\" stroke-width=\"1.8\" stroke=\"" << s.colour
           << "\" points=\"" << r << "\"/>";
      }
    }
    os << "<line x1=\"" << left + pw - 215 << "\" x2=\"" << left + pw - 193 << "\" y1=\"" << legend_y - 4
       << "\" y2=\"" << legend_y - 4 << "\" stroke=\"" << s.colour << "\" stroke-width=\"2\"/>"
       << "<text class=\"legend\" x=\"" << left + pw - 187 << "\" y=\"" << legend_y
       << "\" font-size=\"11\">" << html_escape(s.label) << "</text>";
    legend_y += 15;
  }
  os << "</svg>";
  return os.str();
}

std::vector<std::pair<size_t, size_t>> spread_by_blur(
    const std::vector<std::vector<double>>& blur, int k) {
  std::vector<size_t> order(blur.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  auto best = [&](size_t s) { return blur[s].empty() ? -1.0 : blur[s].front(); };
  std::stable_sort(order.begin(), order.end(),
                   [&](size_t a, size_t b) { return best(a) > best(b); });
  std::vector<std::pair<size_t, size_t>> picks;
  for (size_t rank = 0; int(picks.size()) < k; ++rank) {
    bool any = false;
    for (size_t s : order) {
      if (rank >= blur[s].size() || int(picks.size()) >= k) continue;
      any = true;
      picks.emplace_back(s, rank);
    }
    if (!any) break;
  }
  return picks;
}

}  // namespace dofarm::trainer
