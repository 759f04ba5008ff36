// Piecewise-constant 1D and 2D distributions for importance sampling (light
// selection by power, environment maps). pbrt-v3 section 13.6. Sampling
// inverts the CDF (so stratified sample points stay stratified); the cell is
// found through a guide table (Chen and Asau 1974, "On generating random
// variates from an empirical distribution"; Devroye 1986, "Non-Uniform Random
// Variate Generation", sec. III.2.4) in O(1) expected steps, and it is
// exactly the cell a binary search of the CDF would find.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "common/math.h"

namespace dofarm::render {

class Distribution1D {
 public:
  Distribution1D() = default;
  // Negative and non-finite weights count as 0. All zero: uniform.
  explicit Distribution1D(std::vector<float> weights);

  size_t size() const { return func_.size(); }
  bool empty() const { return func_.empty(); }
  double integral() const { return integral_; }  // sum of weights / n
  // Discrete: index with probability weight / sum; `remapped` is u rescaled
  // to [0,1) within the chosen cell, so it can be reused.
  size_t sample_discrete(float u, float* pmf, float* remapped = nullptr) const;
  float pmf(size_t i) const;
  // Continuous over [0,1): density pdf (relative to the uniform density).
  float sample_continuous(float u, float* pdf, size_t* cell = nullptr) const;
  float pdf(float x) const;

 private:
  size_t find_cell(float u) const;
  std::vector<float> func_;
  std::vector<double> cdf_;  // size n+1, cdf_[n] = 1
  // m = a power of two >= n entries (so k / m and u * m are exact); guide_[k]
  // is the last cell i < n with cdf_[i] <= k / m: where the search for any u
  // in [k/m, (k+1)/m) starts.
  std::vector<uint32_t> guide_;
  double integral_ = 0;
};

// Over [0,1)^2: rows (v) chosen by the marginal, then u within the row.
class Distribution2D {
 public:
  Distribution2D() = default;
  Distribution2D(const std::vector<float>& weights, int nu, int nv);  // row-major, v rows
  // pdf relative to the unit square; `cell` (optional) = row * nu + column of
  // the cell the point lies in, known before the point's coordinates are
  // (a caller's lookup by cell can start while they are computed).
  Vec2 sample(Vec2 u, float* pdf, size_t* cell = nullptr) const;
  // Discrete: the cell (row * nu + column) with probability pmf(cell), by
  // the same inversion as sample(); `remapped` is u rescaled to [0,1)^2
  // within the cell (x from the column, y from the row), for sampling inside it.
  size_t sample_discrete(Vec2 u, Vec2* remapped) const;
  double pmf(size_t cell) const;
  float pdf(Vec2 p) const;

 private:
  std::vector<Distribution1D> conditional_;
  Distribution1D marginal_;
  int nu_ = 0, nv_ = 0;
};

// A piecewise-constant 2D distribution over a grid of nu x nv cells, laid
// out for sampling from tables larger than the caches (the environment map's
// blocks): a row by the marginal, then a column within the row, each by
// inverting a float CDF. Same inversion as Distribution2D (monotone in u, so
// stratified points stay stratified; pbrt-v3 sec. 13.6.7), but the search
// reads exactly two cache lines per table: the cell starts lie in lines of 16
// floats, and a summary line holds the start of each line's first cell
// (a two-level search in the spirit of the guide tables of Chen and Asau 1974,
// with one fixed, branch-free step per level). A row of 256 cells costs
// 17 lines (1088 bytes) against 4 KB for Distribution1D's double CDF, pdf
// and guide. Probabilities are those of the float CDF, exactly:
// pmf = (end - start) computed in double from the two floats, which is the
// length of the cell's interval of u.
class CompactDistribution2D {
 public:
  CompactDistribution2D() = default;
  // Row-major weights, v rows of nu; negative and non-finite weights count as
  // 0. A row of weight 0 is uniform within itself (never picked unless all are
  // zero; then everything is uniform).
  CompactDistribution2D(const std::vector<double>& weights, int nu, int nv);

  // The cell (row * nu + column) with probability pmf(cell); `remapped` is
  // u rescaled to [0,1)^2 within the cell (x from the column, y from the
  // row). u outside [0,1) is clamped into it.
  size_t sample_discrete(Vec2 u, Vec2* remapped) const;
  double pmf(size_t cell) const;
  int nu() const { return nu_; }
  int nv() const { return nv_; }

 private:
  struct alignas(64) Line {
    float start[16];
  };
  // One table of n cells at line `base`: `summary` lines of line starts
  // (entry g = start of cell 16 g; padded with 2, above every u), then
  // ceil(n / 16) lines of cell starts (padded with 2).
  struct Layout {
    int n = 0, summary = 0, lines = 0;
    size_t stride() const { return size_t(summary + lines); }
  };
  static Layout layout(int n);
  static void fill(const double* weights, int n, const Layout& l, Line* out);
  // The cell of u in the table at `base`: the largest i with start(i) <= u.
  size_t find(const Line* base, const Layout& l, float u, float* remapped) const;
  static float start(const Line* base, const Layout& l, int i);
  static double cell_pmf(const Line* base, const Layout& l, int i);
  const Line* row_table(int v) const { return &lines_[row_base_ + size_t(v) * row_.stride()]; }

  std::vector<Line> lines_;  // the marginal's table at 0, then one per row
  Layout marginal_, row_;
  size_t row_base_ = 0;
  int nu_ = 0, nv_ = 0;
};

}  // namespace dofarm::render
