// CoC-sized albedo prefilter (thesis 6.1, 6.3 future work).
//
// The thesis finds that the noise of the albedo it demodulates by grows with
// how far out of focus a pixel is, and that remodulation carries that noise
// into the result; it proposes "a fairly straight forward average across an
// area of pixels that depends on the size of the circle of confusion". With
// data.albedo_prefilter = "coc" the demodulation albedo (whichever
// data.albedo picks) is replaced, before anything reads it, by a Gaussian
// blur of standard deviation sigma = data.albedo_prefilter_scale * CoC
// (pixels) at each pixel: the radiance input's demodulation, the albedo
// input, the target and the remodulation all use the filtered albedo, in
// training, eval and denoise alike (so remodulating the target's inverse
// still gives the reference exactly). The default scale 0.25 gives the
// Gaussian the per-axis spread of a disc of diameter CoC (radius R: R / 2).
//
// Fast by construction: the image is blurred once per fixed level
// (kPrefilterSigmas, only the levels some pixel needs) and each pixel
// interpolates linearly in sigma between the two levels around its own
// sigma; sigmas beyond the last level take the last. Borders replicate the
// edge. A pixel of sigma 0 keeps its value exactly, and a constant image
// stays constant (each level's kernel sums to 1). Training crops are
// filtered as crops (edge replication at the crop border), full frames as
// frames.
#pragma once

#include <array>
#include <cstddef>

namespace dofarm::trainer {

inline constexpr std::array<float, 7> kPrefilterSigmas = {0.0f, 0.5f, 1.0f, 2.0f,
                                                          4.0f, 8.0f, 16.0f};

// `planes` planes of width x height (e.g. the 3 albedo planes), each pixel
// blurred with sigma = scale * coc[pixel] (coc: one plane, pixels; NaN and
// negative count as 0). `out` must not alias `in`.
void prefilter_by_coc(const float* in, int planes, const float* coc, int width, int height,
                      float scale, float* out);

}  // namespace dofarm::trainer
