// Distant environment light: an equirectangular HDR map (or a constant
// colour) with importance sampling proportional to luminance * sin(theta)
// (pbrt-v3 section 14.2.4). Lookups are nearest-texel, the exact function the
// sampling distribution describes, so MIS weights and pdfs agree exactly.
//
// Memory layout (the map and its tables outgrow the caches, and sampling
// waited on them): texels are stored in blocks of 4x4, each block one
// 320-byte, cache-line-aligned record holding the block's own sampling
// tables (one line) and its 16 texels (radiance and pdf side by side).
// Sampling is hierarchical and exact: a block from a compact 2D distribution
// over the blocks' summed weights (two cache lines per level, 139 KB for a
// 1024x512 map; distribution.h), then a row and a column inside the block
// by inverting its tables, so a texel is chosen with probability weight /
// total, as with one table over all texels, and the map stays a monotone
// (stratification-keeping) function of the sample point. All a sample reads
// beyond the block table is one record, which choose() starts loading
// before the caller's ray traversal and sample(choice) reads after it.
//
// Mapping: +y is up; theta = acos(d.y) from the zenith; phi = atan2(d.x, -d.z),
// so the map's centre column (u = 0.5) is seen looking down -z; `rotation`
// turns the map about +y.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "common/exr_io.h"
#include "common/jobspec.h"
#include "common/math.h"
#include "worker/render/distribution.h"

namespace dofarm::render {

struct EnvSample {
  Vec3 wi;  // direction towards the environment
  Vec3 radiance;
  float pdf = 0;  // solid angle
};

class Environment {
 public:
  // Loads the map (RuntimeError naming the file on failure).
  static std::unique_ptr<Environment> from_spec(const EnvironmentSpec& spec);
  Environment(RgbImage image, float intensity, float rotation_deg);
  explicit Environment(Vec3 constant_radiance);

  Vec3 eval(Vec3 dir) const;
  EnvSample sample(Vec2 u) const { return sample(choose(u)); }
  // sample(u) in two steps, so that a caller can choose before it traces a
  // ray and sample after it: choose() runs the table searches and starts
  // loading the block record that sample(choice) reads, which then waits for
  // nothing the traversal did not hide. The same numbers give the same
  // sample either way.
  struct Choice {
    Vec2 u;         // the sample's numbers
    Vec2 r;         // u rescaled to [0, 1)^2 within the block
    uint32_t block = 0;
    // Every direction of the block lies strictly below the plane through
    // the origin with the normal choose(u, n) was given: its sample is
    // certain to point below that surface. Its record is then not loaded.
    bool below = false;
  };
  Choice choose(Vec2 u) const { return choose(u, Vec3(0.0f)); }
  // choose(u) for a light sample seen from a surface of unit normal n: the
  // same choice, and whether it lies below the surface (Choice::below),
  // from the block's centre direction and a bound on its angular radius
  // (a caller whose BSDF rejects every direction below n can skip the
  // sample; bench/README.md, "Light samples the surface turns away"). A
  // normal that is not unit (zero: no surface) marks nothing.
  Choice choose(Vec2 u, Vec3 n) const;
  EnvSample sample(const Choice& choice) const;
  // sample(choice) of n choices at once (the light samples of a batch of
  // paths): the same samples, the texel-to-direction maps computed in AVX2
  // lanes where the CPU has them (simd.h; Environment.BatchedSamplesAreTheSingleSamples).
  void sample(const Choice* choices, int n, EnvSample* out) const;
  // eval() in two steps, for a ray that may escape: locate() maps the
  // direction to its texel and starts loading it (before the ray is
  // traced), eval(located, ...) reads it (after the ray escaped). Same values
  // as eval(dir) and eval(dir, pdf), from one mapping.
 private:
  struct Texel;

 public:
  struct Located {
    const Texel* texel = nullptr;  // null for a constant environment
  };
  Located locate(Vec3 dir) const;
  // locate() of n directions at once (a batch of escaping paths): the same
  // texels, the direction-to-texel maps computed in AVX2 lanes where the
  // CPU has them (simd.h; bit for bit the scalar ones,
  // Environment.BatchedLocateIsTheSingleLocate).
  void locate(const Vec3* dirs, int n, Located* out) const;
  Vec3 eval(const Located& at) const;
  Vec3 eval(const Located& at, Vec3 dir, float* pdf) const;
  float pdf(Vec3 dir) const;
  // eval() and pdf() at once, from one direction-to-texel mapping and one
  // memory access (an escaped ray under MIS needs both).
  Vec3 eval(Vec3 dir, float* pdf) const;
  // Mean radiance luminance over the sphere (for light selection by power).
  float mean_luminance() const { return mean_luminance_; }
  bool is_black() const { return mean_luminance_ <= 0; }
  // An image, as opposed to a constant colour: sampling and lookups read
  // tables larger than the caches.
  bool has_map() const { return !blocks_.empty(); }

 private:
  Vec2 dir_to_uv(Vec3 d) const;
  Vec3 uv_to_dir(Vec2 uv) const;
  // sample()'s two halves around uv_to_dir(): the texel a choice picks and
  // the point in it (texel null: a sample of pdf 0), then the sample in
  // direction wi from it.
  struct Picked;
  Picked pick(const Choice& choice) const;
  EnvSample finish(const Picked& picked, Vec3 wi) const;
  // Radiance and the sampling pdf over the unit square of one texel, side
  // by side: one cache line serves both.
  struct Texel {
    float r, g, b;
    float pdf_uv;
  };
  struct Picked {
    const Texel* texel = nullptr;
    Vec2 uv;
  };
  static constexpr int kBlock = 4;  // texels per block side
  struct alignas(64) Block {
    // Inversion tables, each the cumulative probability after entries 0..2
    // (the last entry ends at 1): rows of the block, then columns of each row.
    float row_cdf[kBlock - 1];
    float column_cdf[kBlock][kBlock - 1];
    float unused;
    Texel texel[kBlock * kBlock];  // row-major within the block
  };
  static_assert(sizeof(Block) == 320, "one line of tables, four of texels");
  const Texel& texel(int x, int y) const {
    return blocks_[size_t(y / kBlock) * blocks_w_ + size_t(x / kBlock)]
        .texel[(y % kBlock) * kBlock + x % kBlock];
  }

  int width_ = 0, height_ = 0;
  int blocks_w_ = 0, blocks_h_ = 0;
  // The blocks' centre directions, uv_to_dir() of each block's centre, as
  // (sin, cos) of theta per block row and of phi (rotation included) per
  // block column; and the cosine below which a centre direction puts its
  // whole block below a plane: -(sin of the blocks' angular radius) less a
  // margin for rounding.
  std::vector<Vec2> block_row_trig_, block_column_trig_;
  float below_cos_ = -2.0f;
  // Row 0 = top; empty for a constant environment. Texels past the map's
  // edge (in blocks at the right and bottom) have weight 0.
  std::vector<Block> blocks_;
  CompactDistribution2D block_distribution_;  // over the blocks' summed weights
  Vec3 constant_{0};
  float rotation_ = 0;  // radians
  float mean_luminance_ = 0;
};

}  // namespace dofarm::render
