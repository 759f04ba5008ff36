// How well the camera's film and lens samples stratify a defocused edge:
// the RMSE over pixels of N-sample estimates of the share of (film, lens)
// points on one side of an edge c (p.x + l.x - 1) + s (p.y + l.y - 1) < 0.1
// at angle theta, with the pair drawn as one 4D Sobol' point
// (PixelSampler::get4d, what the camera uses) and as two independently
// shuffled 2D points (two get2d calls: "padded"). Prints the ratio joint /
// padded per angle and sample count (below 1: the 4D point is better); the
// exact share comes from 4M independent samples. Asserts nothing.
//
// Usage: lens_edge [--pixels 256]
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "worker/render/sampler.h"

namespace {

using dofarm::Vec2;
using dofarm::render::PixelSampler;
using dofarm::SamplerKind;
using dofarm::render::Stream;

struct Edge {
  double c, s;
  double operator()(Vec2 p, Vec2 l) const {
    return c * (p.x + l.x - 1.0) + s * (p.y + l.y - 1.0) < 0.1 ? 1.0 : 0.0;
  }
};

double rmse(bool joint, const Edge& f, uint32_t n, double exact, int pixels) {
  double se = 0;
  for (int px = 0; px < pixels; ++px) {
    PixelSampler s(SamplerKind::kSobol, 42, 0, px % 16, px / 16, Stream::kTest);
    double sum = 0;
    for (uint32_t i = 0; i < n; ++i) {
      s.start_sample(i);
      Vec2 p, l;
      if (joint) {
        s.get4d(&p, &l);
      } else {
        p = s.get2d();
        l = s.get2d();
      }
      sum += f(p, l);
    }
    se += (sum / n - exact) * (sum / n - exact);
  }
  return std::sqrt(se / pixels);
}

}  // namespace

int main(int argc, char** argv) {
  int pixels = 256;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--pixels") && i + 1 < argc) {
      pixels = std::atoi(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: lens_edge [--pixels 256]\n");
      return 2;
    }
  }
  if (pixels < 1) pixels = 1;
  std::printf("| edge angle | 16 spp | 64 spp | 256 spp | 1024 spp |\n");
  std::printf("| --- | --- | --- | --- | --- |\n");
  for (double degrees : {0.0, 15.0, 30.0, 45.0, 60.0, 90.0}) {
    const double a = degrees * M_PI / 180.0;
    const Edge f{std::cos(a), std::sin(a)};
    PixelSampler ind(SamplerKind::kIndependent, 7, 0, 0, 0, Stream::kTest);
    double sum = 0;
    const int m = 4'000'000;
    for (int i = 0; i < m; ++i) {
      ind.start_sample(uint32_t(i));
      const Vec2 p = ind.get2d(), l = ind.get2d();
      sum += f(p, l);
    }
    const double exact = sum / m;
    std::printf("| %.0f° |", degrees);
    for (uint32_t n : {16u, 64u, 256u, 1024u})
      std::printf(" %.2f |", rmse(true, f, n, exact, pixels) / rmse(false, f, n, exact, pixels));
    std::printf("\n");
  }
  return 0;
}
