// Cost of the material model (worker/render/bsdf.h) per path vertex: Bsdf()
// and outgoing() once, evaluate() for the light sample, sample() for the
// continuation, over a mix of materials and directions: the opaque ones,
// then the same under a clearcoat, then glass under a clearcoat, then the
// opaque ones under a white sheen, and under a sheen and a coat. Prints
// nanoseconds per vertex and the white-furnace albedo of the same calls
// (what the cost buys: 1 is exact); never asserts.
//
//   build/bench/bsdf_cost [--calls 4000000]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <vector>

#include "common/math.h"
#include "worker/render/bsdf.h"
#include "worker/render/glass_albedo.h"
#include "worker/render/microfacet_albedo.h"
#include "worker/render/sheen.h"

using dofarm::Vec2;
using dofarm::Vec3;
using dofarm::render::Bsdf;
using dofarm::render::BsdfSample;

namespace {

struct Input {
  float metallic, roughness;
  Vec3 wo, wi;
  float u_lobe;
  Vec2 u;
};

Vec3 cosine_direction(std::mt19937_64& rng) {
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  float r = std::sqrt(uni(rng)), phi = dofarm::kTwoPi * uni(rng);
  return Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1.0f - r * r)));
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  long calls = 4000000;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--calls") && i + 1 < argc) {
      calls = std::atol(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: %s [--calls N]\n", argv[0]);
      return 2;
    }
  }
  // Inputs drawn up front so that the timed loops do only BSDF work.
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> uni(0.0f, 0.999999f);
  const int kInputs = 1 << 16;
  std::vector<Input> inputs(kInputs);
  const float roughnesses[] = {0.05f, 0.3f, 0.6f, 1.0f};
  for (Input& in : inputs) {
    in.metallic = uni(rng) < 0.5f ? 0.0f : (uni(rng) < 0.5f ? 1.0f : 0.5f);
    in.roughness = roughnesses[std::min(3, int(uni(rng) * 4))];
    in.wo = cosine_direction(rng);
    in.wi = cosine_direction(rng);
    in.u_lobe = uni(rng);
    in.u = Vec2(uni(rng), uni(rng));
  }
  const Vec3 up(0, 0, 1);
  const Vec3 white(1.0f);

  // The tables are built on first use (~0.1 s and ~0.6 s): not part of any
  // per-call cost.
  (void)dofarm::render::ggx::albedo_table();
  (void)dofarm::render::ggx::glass_albedo_table();
  (void)dofarm::render::sheen::albedo_table();

  double sink = 0;
  // The material sets: {transmission, clearcoat, sheen} factors.
  struct Set {
    const char* label;
    dofarm::render::TransmissionLayer transmission;
    dofarm::render::ClearcoatLayer clearcoat;
    dofarm::render::SheenLayer sheen;
  } const sets[] = {{"opaque", {}, {}, {}},
                    {"opaque under a clearcoat (factor 1, roughness 0.3)", {}, {1.0f, 0.3f}, {}},
                    {"glass (transmission 1) under a clearcoat", {1.0f, true}, {1.0f, 0.3f}, {}},
                    {"opaque under a sheen (white, roughness 0.5)", {}, {}, {Vec3(1.0f), 0.5f}},
                    {"opaque under a sheen and a clearcoat", {}, {1.0f, 0.3f}, {Vec3(1.0f), 0.5f}}};
  for (const Set& set : sets) {
    auto make = [&](const Input& in) {
      return Bsdf(up, up, white, in.metallic, in.roughness, 1.5f, {}, set.transmission,
                  set.clearcoat, set.sheen);
    };
    // Construction + outgoing(): once per path vertex.
    auto t0 = std::chrono::steady_clock::now();
    for (long i = 0; i < calls; ++i) {
      const Input& in = inputs[i & (kInputs - 1)];
      const Bsdf bsdf = make(in);
      sink += bsdf.outgoing(in.wo).specular_prob;
    }
    const double ns_vertex = 1e9 * seconds_since(t0) / calls;

    // What the integrator does at a vertex: Bsdf(), outgoing(), evaluate()
    // for the light sample, sample() for the continuation. wi is
    // cosine-distributed, so f cos / (cos / pi) estimates the albedo too
    // (of the reflection only: glass sends the rest below).
    t0 = std::chrono::steady_clock::now();
    double furnace_eval = 0, furnace_sample = 0;
    for (long i = 0; i < calls; ++i) {
      const Input& in = inputs[i & (kInputs - 1)];
      const Bsdf bsdf = make(in);
      const Bsdf::Outgoing o = bsdf.outgoing(in.wo);
      float pdf;
      const Vec3 f = bsdf.evaluate(o, in.wi, &pdf);
      sink += pdf;
      furnace_eval += f.x * dofarm::kPi / in.wi.z;
      const BsdfSample s = bsdf.sample(o, in.u_lobe, in.u);
      if (s.valid) furnace_sample += s.weight.x;
    }
    const double ns_full = 1e9 * seconds_since(t0) / calls;

    std::printf("%s: metallic {0, 0.5, 1} x roughness {0.05, 0.3, 0.6, 1}, white, ior 1.5\n",
                set.label);
    std::printf("  Bsdf() + outgoing():                        %6.1f ns per vertex\n", ns_vertex);
    std::printf("  Bsdf() + outgoing() + evaluate() + sample(): %6.1f ns per vertex\n", ns_full);
    // The evaluate() estimate is noisy (narrow lobes, cosine-distributed
    // wi); the sample() estimate is what the path tracer's continuation sees.
    std::printf("  white-furnace albedo over these calls: sample %.4f, evaluate %.4f\n",
                furnace_sample / calls, furnace_eval / calls);
  }
  std::printf("(checksum %g)\n", sink);
  return 0;
}
