// Evaluation in lanes (Bsdf::evaluate_lanes: the integrator's batches,
// worker/render/bsdf_lanes.cpp): the two-step evaluate() and sample() in
// lanes give the one-step results bit for bit, with AVX2 on and off, for batches of every
// size up to 16 (two rounds of eight lanes), of mixed materials in any
// order, and for records too far apart in memory for the lanes' offsets
// (one on the stack, the rest on the heap: evaluated one by one).
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

#include "common/math.h"
#include "tests/render/same_bits.h"
#include "worker/render/bsdf.h"
#include "worker/render/simd.h"

using dofarm::Vec2;
using dofarm::Vec3;
using dofarm::render::Bsdf;
using dofarm::render::BsdfSample;
using dofarm::test::same_bits;

namespace {

// A direction from rng, unit, with z at least min_z.
Vec3 random_direction(std::mt19937& rng, float min_z) {
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  for (;;) {
    const Vec3 d(2 * u01(rng) - 1, 2 * u01(rng) - 1, 2 * u01(rng) - 1);
    const float l = dofarm::length(d);
    if (l > 0.1f && l <= 1.0f && d.z / l >= min_z) return d / l;
  }
}

// BSDFs of everything in_lanes() allows: dielectric, metal and both at
// once, rough and mirror, black, IOR 1, a grey specular layer, shading and
// geometric normals apart; and an outgoing direction for each (every
// ninth grazing, some below a surface).
std::vector<Bsdf> lane_bsdfs(std::mt19937& rng, std::vector<Vec3>* wo) {
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  std::vector<Bsdf> bsdfs;
  const float roughness[] = {0.0f, 0.03f, 0.05f, 0.3f, 0.9f, 1.0f};
  for (int i = 0; bsdfs.size() < 120; ++i) {
    const Vec3 ng = random_direction(rng, -1.0f);
    const Vec3 ns = normalize(ng + random_direction(rng, -1.0f) * 0.3f);
    const Vec3 base = i % 7 == 0 ? Vec3(0.0f) : Vec3(u01(rng), u01(rng), u01(rng));
    const float metallic = i % 3 == 0 ? 0.0f : (i % 3 == 1 ? 1.0f : u01(rng));
    const float ior = i % 11 == 0 ? 1.0f : 1.0f + u01(rng);
    const dofarm::render::SpecularLayer specular{i % 5 == 0 ? 0.5f : 1.0f, Vec3(1.0f)};
    const bool flip = dot(ns, ng) < 0;
    bsdfs.emplace_back(ns, flip ? -ng : ng, base, metallic, roughness[i % 6], ior, specular);
    const Vec3 w = i % 9 == 0 ? normalize(Vec3(1.0f, 0.0f, 1e-3f)) : random_direction(rng, -0.2f);
    wo->push_back(flip ? -w : w);
  }
  return bsdfs;
}

}  // namespace

TEST(Bsdf, EvaluationsInLanesAreEachBsdfsOwn) {
  dofarm::render::SimdRestore restore;
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  auto direction = [&](float min_z) { return random_direction(rng, min_z); };
  std::vector<Vec3> wos;
  const std::vector<Bsdf> bsdfs = lane_bsdfs(rng, &wos);
  std::vector<Bsdf::Outgoing> outs;
  for (size_t i = 0; i < bsdfs.size(); ++i) {
    ASSERT_TRUE(bsdfs[i].in_lanes());
    outs.push_back(bsdfs[i].outgoing(wos[i]));
  }
  const Bsdf on_stack = bsdfs[0];
  const Bsdf::Outgoing out_on_stack = outs[0];
  size_t evaluated = 0;
  for (bool simd : {true, false}) {
    dofarm::render::allow_simd(simd);
    for (int round = 0; round < 400; ++round) {
      const int n = 1 + round % 16;
      const bool far = round % 13 == 0;  // lane 0 on the stack
      const Bsdf* b[16];
      const Bsdf::Outgoing* o[16];
      Vec3 wi[16], wi_world[16], f[16];
      float pdf[16], ul[16];
      Vec2 uv[16];
      bool sampled[16];
      BsdfSample two_step[16];
      int m = 0;
      for (int k = 0; m < n && k < 64; ++k) {
        const size_t i = std::uniform_int_distribution<size_t>(0, bsdfs.size() - 1)(rng);
        const Bsdf* bk = far && m == 0 ? &on_stack : &bsdfs[i];
        const Bsdf::Outgoing* ok = far && m == 0 ? &out_on_stack : &outs[i];
        // Half the lanes towards a light, half a sample.
        if (k % 2 == 0) {
          wi_world[m] = direction(-1.0f);
          sampled[m] = false;
          if (!bk->evaluate_direction(*ok, wi_world[m], &wi[m])) {
            float p = -1;
            ASSERT_TRUE(same_bits(bk->evaluate(*ok, wi_world[m], &p), Vec3(0)) && p == 0);
            continue;
          }
        } else {
          ul[m] = u01(rng);
          uv[m] = Vec2(u01(rng), u01(rng));
          sampled[m] = true;
          if (!bk->sample_direction(*ok, ul[m], uv[m], &two_step[m], &wi[m])) {
            const BsdfSample one = bk->sample(*ok, ul[m], uv[m]);
            ASSERT_EQ(one.valid, two_step[m].valid);
            if (one.valid) {
              ASSERT_TRUE(same_bits(one.weight, two_step[m].weight) && one.is_delta);
            }
            continue;
          }
        }
        b[m] = bk;
        o[m] = ok;
        ++m;
      }
      if (m == 0) continue;
      Bsdf::evaluate_lanes(m, b, o, wi, f, pdf);
      for (int k = 0; k < m; ++k) {
        ++evaluated;
        if (!sampled[k]) {
          float p = -1;
          const Vec3 one = b[k]->evaluate(*o[k], wi_world[k], &p);
          ASSERT_TRUE(same_bits(one, f[k]) && same_bits(p, pdf[k]))
              << "simd " << simd << " lane " << k << " of " << m << ": (" << one.x << ", " << one.y
              << ", " << one.z << ") pdf " << p << " against (" << f[k].x << ", " << f[k].y << ", "
              << f[k].z << ") pdf " << pdf[k];
        } else {
          Bsdf::finish_sample(&two_step[k], f[k], pdf[k]);
          const BsdfSample one = b[k]->sample(*o[k], ul[k], uv[k]);
          ASSERT_EQ(one.valid, two_step[k].valid) << "simd " << simd << " lane " << k;
          ASSERT_TRUE(same_bits(one.wi, two_step[k].wi) && same_bits(one.pdf, two_step[k].pdf) &&
                      (!one.valid || same_bits(one.weight, two_step[k].weight)))
              << "simd " << simd << " lane " << k << " of " << m;
        }
      }
    }
  }
  EXPECT_GT(evaluated, 3000u);
}
