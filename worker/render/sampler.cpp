#include "worker/render/sampler.h"

namespace dofarm::render {

PixelSampler::PixelSampler(SamplerKind kind, uint64_t seed, int frame, int px, int py,
                           Stream stream)
    : kind_(kind) {
  // Pixel coordinates are packed into one word so (px, py) and (py, px) differ;
  // negative values (never expected) still hash deterministically.
  const uint64_t pixel = (uint64_t(uint32_t(px)) << 32) | uint32_t(py);
  uint64_t h = mix64(seed + kGoldenGamma);
  h = hash_combine(h, uint64_t(uint32_t(frame)));
  h = hash_combine(h, pixel);
  h = hash_combine(h, uint64_t(stream));
  pixel_seed_ = h;
  start_sample(0);
}

}  // namespace dofarm::render
