// Chi-square goodness-of-fit test for direction samplers, in the spirit of
// Mitsuba's chi2 test: draw samples, histogram them over cells of the sphere,
// integrate the claimed pdf over the same cells, and ask how likely the
// observed counts are. Header-only so any test suite can include it.
//
// Missing mass is part of the test: a sample the sampler rejects (nullopt)
// lands in an extra "invalid" cell whose expected count is N (1 - ∫pdf), so a
// pdf that claims more or less mass than the sampler delivers is caught too.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include "common/math.h"

namespace dofarm::test {

// ---------------------------------------------------------------------------
// Regularized incomplete gamma function and the chi-square p-value.

namespace detail {

// P(a, x) by its power series; converges quickly for x < a + 1.
inline double gamma_p_series(double a, double x) {
  double term = 1.0 / a;
  double sum = term;
  for (int n = 1; n < 100000; ++n) {
    term *= x / (a + n);
    sum += term;
    if (std::abs(term) < std::abs(sum) * 1e-16) break;
  }
  return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

// Q(a, x) by its continued fraction, evaluated with the modified Lentz
// method; converges quickly for x >= a + 1.
inline double gamma_q_continued_fraction(double a, double x) {
  constexpr double kTiny = 1e-300;
  double b = x + 1.0 - a;
  double c = 1.0 / kTiny;
  double d = 1.0 / b;
  double h = d;
  for (int i = 1; i < 100000; ++i) {
    double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1.0) < 1e-16) break;
  }
  return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

}  // namespace detail

// Upper regularized incomplete gamma Q(a, x) = Gamma(a, x) / Gamma(a).
inline double regularized_gamma_q(double a, double x) {
  if (!(a > 0.0) || std::isnan(x)) return std::numeric_limits<double>::quiet_NaN();
  if (x <= 0.0) return 1.0;
  if (x < a + 1.0) return 1.0 - detail::gamma_p_series(a, x);
  return detail::gamma_q_continued_fraction(a, x);
}

// Probability that a chi-square variable with `dof` degrees of freedom is at
// least `statistic`.
inline double chi2_p_value(double statistic, int dof) {
  return regularized_gamma_q(0.5 * dof, 0.5 * statistic);
}

// ---------------------------------------------------------------------------
// Cells of the sphere.

// Rings around `pole` (bounded by cones) times sectors in azimuth. Ring edges
// are placed in x = 1 - cos(theta), the natural variable near the pole: with
// pole_width == 0 they are equal steps of x (equal-area cells); otherwise equal
// steps of x / (x + s) with s = pole_width^2 / 2, which shrinks the rings near
// the pole so that a lobe about pole_width wide still spreads over many rings.
// (For GGX D(h) cos(theta_h) with pole_width = alpha the rings hold nearly
// equal probability, as its CDF is tan^2 / (tan^2 + alpha^2) ~ x / (x + s).)
struct SphereCells {
  Vec3 pole{0, 0, 1};
  double pole_width = 0;
  int rings = 20;
  int sectors = 40;

  int count() const { return rings * sectors; }

  double warp(double x) const {
    if (!(pole_width > 0)) return 0.5 * x;
    double s = 0.5 * pole_width * pole_width;
    return (x / (x + s)) * ((2.0 + s) / 2.0);
  }
  double unwarp(double t) const {
    if (!(pole_width > 0)) return 2.0 * t;
    double s = 0.5 * pole_width * pole_width;
    double v = t * (2.0 / (2.0 + s));
    return s * v / (1.0 - v);
  }
  // x = 1 - cos(theta) at the inner edge of ring i; ring_edge(rings) == 2.
  double ring_edge(int i) const { return i >= rings ? 2.0 : unwarp(double(i) / rings); }

  // Cell of a unit direction, or -1 for a non-finite one.
  int cell_of(Vec3 dir) const {
    Frame frame(normalize(pole));
    Vec3 l = frame.to_local(dir);
    double lx = l.x, ly = l.y, lz = l.z;
    double r2 = lx * lx + ly * ly;
    // 1 - z without cancellation near the pole.
    double x = lz > 0 ? r2 / (std::sqrt(r2 + lz * lz) + lz) : 1.0 - lz;
    double phi = std::atan2(ly, lx);
    if (phi < 0) phi += 2.0 * std::numbers::pi;
    if (!std::isfinite(x) || !std::isfinite(phi)) return -1;
    int ring = std::clamp(int(warp(std::clamp(x, 0.0, 2.0)) * rings), 0, rings - 1);
    int sector = std::clamp(int(phi / (2.0 * std::numbers::pi) * sectors), 0, sectors - 1);
    return ring * sectors + sector;
  }
};

namespace detail {

// Adaptive Simpson on [a, b] (Lyness 1969); the tolerance halves with each
// split. At a jump the recursion runs to max_depth, which costs only ~2
// evaluations per level.
template <class F>
double simpson_step(F& f, double a, double b, double fa, double fm, double fb, double whole,
                    double tol, int depth) {
  double m = 0.5 * (a + b);
  double lm = 0.5 * (a + m), rm = 0.5 * (m + b);
  double flm = f(lm), frm = f(rm);
  double left = (m - a) / 6.0 * (fa + 4.0 * flm + fm);
  double right = (b - m) / 6.0 * (fm + 4.0 * frm + fb);
  double delta = left + right - whole;
  // The relative floor stops the recursion from chasing float rounding noise
  // in f (~1e-7 relative), which no subdivision can remove.
  bool converged = std::abs(delta) <= 15.0 * std::max(tol, 1e-6 * std::abs(left + right));
  if (depth <= 0 || converged) return left + right + delta / 15.0;
  return simpson_step(f, a, m, fa, flm, fm, left, 0.5 * tol, depth - 1) +
         simpson_step(f, m, b, fm, frm, fb, right, 0.5 * tol, depth - 1);
}

// Starts from `pieces` equal sub-intervals so that a feature narrower than
// the whole interval is not stepped over by the first five evaluations.
template <class F>
double adaptive_simpson(F&& f, double a, double b, double tol, int pieces = 4, int max_depth = 16) {
  double sum = 0.0;
  double h = (b - a) / pieces;
  for (int i = 0; i < pieces; ++i) {
    double a0 = a + i * h, b0 = i + 1 == pieces ? b : a + (i + 1) * h;
    double fa = f(a0), fm = f(0.5 * (a0 + b0)), fb = f(b0);
    double whole = (b0 - a0) / 6.0 * (fa + 4.0 * fm + fb);
    sum += simpson_step(f, a0, b0, fa, fm, fb, whole, tol / pieces, max_depth);
  }
  return sum;
}

}  // namespace detail

// Integral of f (a function of a unit direction, per steradian) over every
// cell, in cell order. dω = dx dphi, integrated in double with an absolute
// error target of about `tolerance` per cell.
template <class F>
std::vector<double> integrate_cells(F&& f, const SphereCells& cells, double tolerance) {
  Frame frame(normalize(cells.pole));
  auto eval = [&](double x, double phi) {
    double sin_theta = std::sqrt(std::max(0.0, x * (2.0 - x)));
    double lx = sin_theta * std::cos(phi), ly = sin_theta * std::sin(phi), lz = 1.0 - x;
    Vec3 dir(float(frame.t.x * lx + frame.b.x * ly + frame.n.x * lz),
             float(frame.t.y * lx + frame.b.y * ly + frame.n.y * lz),
             float(frame.t.z * lx + frame.b.z * ly + frame.n.z * lz));
    return double(f(dir));
  };
  std::vector<double> out(cells.count());
  double dphi = 2.0 * std::numbers::pi / cells.sectors;
  for (int ring = 0; ring < cells.rings; ++ring) {
    double x0 = cells.ring_edge(ring), x1 = cells.ring_edge(ring + 1);
    // An error e in the inner integral becomes e (x1 - x0) in the cell.
    double inner_tol = tolerance / std::max(x1 - x0, 1e-300);
    for (int sector = 0; sector < cells.sectors; ++sector) {
      double phi0 = sector * dphi, phi1 = phi0 + dphi;
      auto over_phi = [&](double x) {
        return detail::adaptive_simpson([&](double phi) { return eval(x, phi); }, phi0, phi1,
                                        inner_tol);
      };
      out[ring * cells.sectors + sector] = detail::adaptive_simpson(over_phi, x0, x1, tolerance);
    }
  }
  return out;
}

template <class F>
double integrate_sphere(F&& f, const SphereCells& cells, double tolerance_per_cell) {
  double sum = 0.0;
  for (double v : integrate_cells(f, cells, tolerance_per_cell)) sum += v;
  return sum;
}

// ---------------------------------------------------------------------------
// The test.

struct Chi2Options {
  SphereCells cells;
  int64_t samples = 200000;
  uint64_t seed = 0x5eed'd0fa'12c0'ffeeULL;
  // Cells expected to hold fewer samples are pooled into one (the chi-square
  // approximation to the multinomial needs about five per cell).
  double min_expected = 5.0;
  // Integration error target per cell, in expected samples.
  double count_tolerance = 1e-3;
};

struct Chi2Result {
  double statistic = 0;
  int dof = 0;
  double p_value = 0;
  double pdf_integral = 0;     // ∫ pdf over the sphere; 1 - this is the missing mass
  int64_t invalid = 0;         // samples the sampler rejected
  int64_t malformed = 0;       // non-finite or non-unit directions: always a failure
  int pooled_cells = 0;        // cells merged because their expected count was small
  double outside_support = 0;  // samples in cells where the pdf integrates to 0

  std::string summary() const {
    std::ostringstream s;
    s << "chi2 = " << statistic << ", dof = " << dof << ", p = " << p_value
      << ", integral of pdf = " << pdf_integral << ", invalid = " << invalid
      << ", malformed = " << malformed << ", pooled cells = " << pooled_cells
      << ", samples outside the pdf's support = " << outside_support;
    return s.str();
  }
};

// `sample` maps (Vec2 u) or (Vec2 u, float u_lobe), all uniform in [0, 1), to
// std::optional<Vec3>; `pdf` maps a unit Vec3 to its density per steradian.
// The p-value is 0 whenever the test cannot be trusted (malformed samples,
// fewer than two cells left after pooling), so a broken setup fails loudly.
template <class Sample, class Pdf>
Chi2Result chi2_test(Sample&& sample, Pdf&& pdf, const Chi2Options& options) {
  const SphereCells& cells = options.cells;
  const double n = double(options.samples);
  Chi2Result result;

  // Observed counts; the extra last cell is "sample rejected".
  std::vector<double> observed(cells.count() + 1, 0.0);
  std::mt19937_64 rng(options.seed);
  // 24 random bits: uniform on the float grid of [0, 1), never 1.
  auto uniform = [&rng] { return float(rng() >> 40) * 0x1p-24f; };
  for (int64_t i = 0; i < options.samples; ++i) {
    Vec2 u;
    u.x = uniform();
    u.y = uniform();
    std::optional<Vec3> dir;
    if constexpr (std::is_invocable_v<Sample&, Vec2, float>) {
      float u_lobe = uniform();
      dir = sample(u, u_lobe);
    } else {
      dir = sample(u);
    }
    if (!dir) {
      ++result.invalid;
      observed.back() += 1;
      continue;
    }
    int cell = is_finite(*dir) && std::abs(length(*dir) - 1.0f) < 1e-3f ? cells.cell_of(*dir) : -1;
    if (cell < 0) {
      ++result.malformed;
      continue;
    }
    observed[cell] += 1;
  }

  std::vector<double> mass = integrate_cells(pdf, cells, options.count_tolerance / n);
  std::vector<double> expected(cells.count() + 1);
  for (int i = 0; i < cells.count(); ++i) {
    result.pdf_integral += mass[i];
    expected[i] = n * mass[i];
    if (!(mass[i] > 0)) result.outside_support += observed[i];
  }
  expected.back() = n * std::max(0.0, 1.0 - result.pdf_integral);

  // Pool the sparse cells; if the pool itself is still too sparse, fold it
  // into the smallest cell that was kept.
  struct Cell {
    double expected, observed;
  };
  std::vector<Cell> kept;
  Cell pool{0, 0};
  for (size_t i = 0; i < expected.size(); ++i) {
    if (expected[i] < options.min_expected) {
      pool.expected += expected[i];
      pool.observed += observed[i];
      ++result.pooled_cells;
    } else {
      kept.push_back({expected[i], observed[i]});
    }
  }
  if (pool.expected >= options.min_expected) {
    kept.push_back(pool);
  } else if (!kept.empty()) {
    auto smallest = std::min_element(kept.begin(), kept.end(),
                                     [](Cell a, Cell b) { return a.expected < b.expected; });
    smallest->expected += pool.expected;
    smallest->observed += pool.observed;
  }
  for (const Cell& c : kept) {
    double d = c.observed - c.expected;
    result.statistic += d * d / c.expected;
  }
  result.dof = int(kept.size()) - 1;
  result.p_value =
      result.dof >= 1 && result.malformed == 0 ? chi2_p_value(result.statistic, result.dof) : 0.0;
  return result;
}

}  // namespace dofarm::test
