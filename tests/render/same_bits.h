// Bit-for-bit equality of floats and vectors, for the tests of what dofarm
// promises to compute the same bits (AVX2 lanes against the scalar code,
// packets against single rays, a batch of paths against each path alone):
// +0 and -0 differ, and a NaN equals only a NaN of the same bits.
#pragma once

#include <cstring>

#include "common/math.h"

namespace dofarm::test {

inline bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }
inline bool same_bits(Vec2 a, Vec2 b) { return same_bits(a.x, b.x) && same_bits(a.y, b.y); }
inline bool same_bits(Vec3 a, Vec3 b) {
  return same_bits(a.x, b.x) && same_bits(a.y, b.y) && same_bits(a.z, b.z);
}

}  // namespace dofarm::test
