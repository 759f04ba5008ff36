#include "worker/render/distribution.h"

#include <algorithm>
#include <bit>
#include <cmath>
#if defined(__SSE2__)
#include <immintrin.h>
#endif

namespace dofarm::render {

Distribution1D::Distribution1D(std::vector<float> weights) : func_(std::move(weights)) {
  size_t n = func_.size();
  cdf_.assign(n + 1, 0.0);
  for (float& f : func_)
    if (!(f > 0) || !std::isfinite(f)) f = 0;
  for (size_t i = 0; i < n; ++i) cdf_[i + 1] = cdf_[i] + double(func_[i]) / double(n);
  integral_ = cdf_[n];
  if (integral_ <= 0) {  // nothing to importance-sample: fall back to uniform
    for (size_t i = 0; i < n; ++i) {
      func_[i] = 1;
      cdf_[i + 1] = double(i + 1) / double(n);
    }
    integral_ = 0;
  } else {
    for (size_t i = 1; i <= n; ++i) cdf_[i] /= integral_;
  }
  if (n > 0) cdf_[n] = 1.0;

  if (n == 0) return;
  size_t m = std::bit_ceil(n);
  guide_.resize(m);
  size_t i = 0;
  for (size_t k = 0; k < m; ++k) {
    const double start = double(k) / double(m);
    while (i + 1 < n && cdf_[i + 1] <= start) ++i;
    guide_[k] = uint32_t(i);
  }
}

size_t Distribution1D::find_cell(float u) const {
  // Largest i with cdf_[i] <= u, restricted to [0, n-1]: from the guide
  // entry of u's bucket forwards (the entry's cdf is <= k/m <= u; the
  // backward step only matters for u < 0, which the guide maps to bucket 0).
  const size_t n = func_.size();
  const double ud = double(u);
  const double x = ud * double(guide_.size());
  size_t i = guide_[x > 0 ? std::min(guide_.size() - 1, size_t(x)) : 0];
  while (i > 0 && cdf_[i] > ud) --i;
  while (i + 1 < n && cdf_[i + 1] <= ud) ++i;
  // Skip zero-probability cells that the clamps above can land on.
  while (i + 1 < n && cdf_[i + 1] <= cdf_[i]) ++i;
  return i;
}

float Distribution1D::pmf(size_t i) const { return float(cdf_[i + 1] - cdf_[i]); }

size_t Distribution1D::sample_discrete(float u, float* pmf_out, float* remapped) const {
  size_t i = find_cell(u);
  double width = cdf_[i + 1] - cdf_[i];
  if (pmf_out) *pmf_out = float(width);
  if (remapped) {
    double r = width > 0 ? (double(u) - cdf_[i]) / width : 0.0;
    *remapped = float(std::clamp(r, 0.0, double(0x1.fffffep-1)));
  }
  return i;
}

float Distribution1D::sample_continuous(float u, float* pdf_out, size_t* cell) const {
  size_t i = find_cell(u);
  double width = cdf_[i + 1] - cdf_[i];
  double du = width > 0 ? (double(u) - cdf_[i]) / width : 0.5;
  if (cell) *cell = i;
  if (pdf_out) *pdf_out = float(width * double(func_.size()));
  double x = (double(i) + std::clamp(du, 0.0, 1.0)) / double(func_.size());
  return float(std::min(x, double(0x1.fffffep-1)));
}

float Distribution1D::pdf(float x) const {
  size_t n = func_.size();
  size_t i = std::min(n - 1, size_t(std::max(0.0f, x) * float(n)));
  return float((cdf_[i + 1] - cdf_[i]) * double(n));
}

Distribution2D::Distribution2D(const std::vector<float>& w, int nu, int nv) : nu_(nu), nv_(nv) {
  std::vector<float> row_sums(nv);
  conditional_.reserve(nv);
  for (int v = 0; v < nv; ++v) {
    conditional_.emplace_back(
        std::vector<float>(w.begin() + size_t(v) * nu, w.begin() + size_t(v + 1) * nu));
    row_sums[v] = float(conditional_.back().integral());
  }
  marginal_ = Distribution1D(std::move(row_sums));
}

Vec2 Distribution2D::sample(Vec2 u, float* pdf_out, size_t* cell) const {
  float pdf_v, pdf_u;
  size_t row, column;
  float y = marginal_.sample_continuous(u.y, &pdf_v, &row);
  float x = conditional_[row].sample_continuous(u.x, &pdf_u, &column);
  *pdf_out = pdf_v * pdf_u;
  if (cell) *cell = row * size_t(nu_) + column;
  return {x, y};
}

size_t Distribution2D::sample_discrete(Vec2 u, Vec2* remapped) const {
  float ry, rx;
  const size_t row = marginal_.sample_discrete(u.y, nullptr, &ry);
  const size_t column = conditional_[row].sample_discrete(u.x, nullptr, &rx);
  *remapped = Vec2(rx, ry);
  return row * size_t(nu_) + column;
}

double Distribution2D::pmf(size_t cell) const {
  const size_t row = cell / size_t(nu_);
  return double(marginal_.pmf(row)) * double(conditional_[row].pmf(cell % size_t(nu_)));
}

float Distribution2D::pdf(Vec2 p) const {
  int row = std::clamp(int(p.y * float(nv_)), 0, nv_ - 1);
  return marginal_.pdf(p.y) * conditional_[row].pdf(p.x);
}

}  // namespace dofarm::render

namespace dofarm::render {

namespace {

constexpr float kPad = 2.0f;  // above every u in [0, 1): never counted

// How many of the 16 floats at p (a 64-byte-aligned line) are <= u: four
// vector compares and a bit scan, no branches. A line is non-decreasing
// (cell starts, then kPad), so the compares that hold are a prefix and
// their count is the mask's trailing ones: a bit scan, which every x86-64
// has, where std::popcount without -mpopcnt is a call into libgcc
// (__popcountdi2, 2.6% of a courtyard render's samples). (The plain loop
// below is what it computes; inside the search's loop over summary lines
// the compiler left it as 16 scalar compares.)
inline int count_at_most(const float* p, float u) {
#if defined(__SSE2__)
  const __m128 v = _mm_set1_ps(u);
  const int mask = _mm_movemask_ps(_mm_cmple_ps(_mm_load_ps(p), v)) |
                   (_mm_movemask_ps(_mm_cmple_ps(_mm_load_ps(p + 4), v)) << 4) |
                   (_mm_movemask_ps(_mm_cmple_ps(_mm_load_ps(p + 8), v)) << 8) |
                   (_mm_movemask_ps(_mm_cmple_ps(_mm_load_ps(p + 12), v)) << 12);
  return std::countr_one(static_cast<unsigned>(mask));
#else
  int c = 0;
  for (int k = 0; k < 16; ++k) c += p[k] <= u ? 1 : 0;
  return c;
#endif
}

}  // namespace

CompactDistribution2D::Layout CompactDistribution2D::layout(int n) {
  Layout l;
  l.n = n;
  l.lines = (n + 15) / 16;
  l.summary = (l.lines + 15) / 16;
  return l;
}

void CompactDistribution2D::fill(const double* w, int n, const Layout& l, Line* out) {
  double total = 0;
  for (int i = 0; i < n; ++i) total += std::isfinite(w[i]) && w[i] > 0 ? w[i] : 0.0;
  float* summary = out[0].start;
  float* cells = out[l.summary].start;
  std::fill(summary, summary + size_t(l.summary) * 16, kPad);
  std::fill(cells, cells + size_t(l.lines) * 16, kPad);
  double run = 0;
  for (int i = 0; i < n; ++i) {
    // The start of cell i as a float; rounding keeps the starts
    // non-decreasing, and cells after the last positive weight start at
    // exactly 1 (run == total), so u < 1 never reaches them.
    const float s = total > 0 ? float(std::min(1.0, run / total)) : float(double(i) / double(n));
    cells[i] = s;
    if (i % 16 == 0) summary[i / 16] = s;
    run += std::isfinite(w[i]) && w[i] > 0 ? w[i] : 0.0;
  }
}

CompactDistribution2D::CompactDistribution2D(const std::vector<double>& w, int nu, int nv)
    : nu_(nu), nv_(nv) {
  marginal_ = layout(nv);
  row_ = layout(nu);
  row_base_ = marginal_.stride();
  lines_.resize(row_base_ + size_t(nv) * row_.stride());
  std::vector<double> row_sums(size_t(nv), 0.0);
  for (int v = 0; v < nv; ++v) {
    const double* row = &w[size_t(v) * nu];
    for (int x = 0; x < nu; ++x) row_sums[v] += std::isfinite(row[x]) && row[x] > 0 ? row[x] : 0.0;
    fill(row, nu, row_, &lines_[row_base_ + size_t(v) * row_.stride()]);
  }
  fill(row_sums.data(), nv, marginal_, lines_.data());
}

float CompactDistribution2D::start(const Line* base, const Layout& l, int i) {
  return base[l.summary + i / 16].start[i % 16];
}

double CompactDistribution2D::cell_pmf(const Line* base, const Layout& l, int i) {
  const double end = i + 1 < l.n ? double(start(base, l, i + 1)) : 1.0;
  return end - double(start(base, l, i));
}

size_t CompactDistribution2D::find(const Line* base, const Layout& l, float u,
                                   float* remapped) const {
  // The line: how many line starts are <= u, less one (entry 0 is 0 <= u).
  int g = -1;
  for (int s = 0; s < l.summary; ++s) g += count_at_most(base[s].start, u);
  // The cell within the line, whose first start is <= u by the choice of g:
  // the largest i with start(i) <= u, which skips cells of zero width (their
  // start equals the next one's).
  const float* c = base[l.summary + g].start;
  const int j = count_at_most(c, u) - 1;
  const float lo = c[j];
  const float next = j < 15            ? c[j + 1]
                     : g + 1 < l.lines ? base[(g + 1) / 16].start[(g + 1) % 16]
                                       : kPad;
  const float hi = std::min(1.0f, next);  // the padding past the last cell ends at 1
  *remapped = hi > lo ? std::clamp((u - lo) / (hi - lo), 0.0f, 0x1.fffffep-1f) : 0.5f;
  return size_t(g) * 16 + size_t(j);
}

size_t CompactDistribution2D::sample_discrete(Vec2 u, Vec2* remapped) const {
  auto unit = [](float x) { return x >= 0.0f ? std::min(x, 0x1.fffffep-1f) : 0.0f; };  // NaN -> 0
  float ry, rx;
  const size_t row = find(lines_.data(), marginal_, unit(u.y), &ry);
  const size_t column = find(row_table(int(row)), row_, unit(u.x), &rx);
  *remapped = Vec2(rx, ry);
  return row * size_t(nu_) + column;
}

double CompactDistribution2D::pmf(size_t cell) const {
  const int row = int(cell / size_t(nu_)), column = int(cell % size_t(nu_));
  return cell_pmf(lines_.data(), marginal_, row) * cell_pmf(row_table(row), row_, column);
}

}  // namespace dofarm::render
