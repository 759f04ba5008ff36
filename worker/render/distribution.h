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

}  // namespace dofarm::render
