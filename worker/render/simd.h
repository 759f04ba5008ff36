// Where the renderer computes several lanes at once: the sampler's batched
// draws (sampler.h), a packet's camera rays (camera.h), and the
// environment's texel and direction maps of a batch of paths
// (environment.h, with trig8.h's atan2, sine and cosine). dofarm builds for
// the x86-64 baseline so that one binary runs on every worker; these few
// functions are also compiled for AVX2 and run where the CPU has it. Each
// lane does the scalar code's operations in the scalar code's order, with
// no fused multiply-add (IEEE single precision gives the same bits in an
// SSE or AVX lane), so they give the same numbers with and without AVX2;
// the tests compare both ways (allow_simd).
#pragma once

namespace dofarm::render {

bool simd_available();          // this CPU has AVX2 (and this build its kernels)
void allow_simd(bool allowed);  // process-wide; for tests (default: allowed)
bool use_simd();                // available and allowed
// Allows the kernels again when it goes out of scope (a test that switches
// them off with allow_simd(false) leaves them on for the next).
struct SimdRestore {
  ~SimdRestore() { allow_simd(true); }
};

}  // namespace dofarm::render

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define DOFARM_HAVE_AVX2_KERNELS 1
#define DOFARM_AVX2 __attribute__((target("avx2")))
#endif
