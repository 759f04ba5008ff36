// The chi-square test (chi2.h) applied to a BSDF: what sample() draws
// against what pdf() claims, and the checks every such test makes. Shared
// by the material tests (test_bsdf.cpp) and the glass tests
// (test_bsdf_glass.cpp).
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdio>
#include <optional>

#include "tests/render/chi2.h"
#include "worker/render/bsdf.h"

namespace dofarm::test {

// The directions `sampler` draws for its non-delta part (rejected and delta
// samples are missing mass, which pdf() must account for) against
// `density`'s pdf(), over `cells`.
inline Chi2Result bsdf_chi2(const render::Bsdf& sampler, const render::Bsdf& density, Vec3 wo,
                            const SphereCells& cells, int64_t samples = 100000) {
  Chi2Options options;
  options.cells = cells;
  options.samples = samples;
  // An error of 0.02 expected samples per cell is far below the Poisson noise
  // of cells that hold >= 5, and keeps the integration of cells cut by the
  // horizon (grazing incidence, narrow lobes) from running to full depth.
  options.count_tolerance = 2e-2;
  return chi2_test(
      [&](Vec2 u, float u_lobe) -> std::optional<Vec3> {
        const render::BsdfSample s = sampler.sample(wo, u_lobe, u);
        if (!s.valid || s.is_delta) return std::nullopt;
        return s.wi;
      },
      [&](Vec3 wi) { return density.pdf(wo, wi); }, options);
}

// A passing test: well-formed samples, no more mass than 1, none where the
// pdf is 0, and a p-value above `threshold`; prints the summary.
inline void expect_chi2_pass(const Chi2Result& r, double threshold, const char* name, double angle,
                             const char* cells) {
  EXPECT_EQ(r.malformed, 0) << r.summary();
  EXPECT_LE(r.pdf_integral, 1.0 + 1e-3) << r.summary();
  EXPECT_EQ(r.outside_support, 0) << r.summary();
  EXPECT_GT(r.p_value, threshold) << r.summary();
  std::printf("  %-16s theta %2.0f, %s cells: %s\n", name, angle, cells, r.summary().c_str());
}

}  // namespace dofarm::test
