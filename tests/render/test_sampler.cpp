// Tests of the per-pixel samplers: the Sobol' construction against an
// independent implementation from direction numbers, the (0,m,2)-net property
// of every slot (the known answer of Burley 2020's shuffled Owen-scrambled
// Sobol'), determinism, decorrelation and a measured integration error.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "worker/render/sampler.h"
#include "worker/render/simd.h"

namespace dofarm::render {
namespace {

constexpr uint64_t kSeed = 0x5eed2024;

// Independent Sobol' dimension 1 from the Joe-Kuo (2008) recurrence for the
// primitive polynomial x + 1 (s = 1, a = 0, m_1 = 1): m_k = 2 m_{k-1} ^ m_{k-1},
// v_k = m_k / 2^k, x = XOR of v_k over the set bits k-1 of the index.
uint32_t sobol_dim1_from_direction_numbers(uint32_t index) {
  std::array<uint32_t, 32> v{};
  uint64_t m = 1;
  for (int k = 1; k <= 32; ++k) {
    if (k > 1) m = (m << 1) ^ m;
    v[k - 1] = uint32_t(m << (32 - k));
  }
  uint32_t x = 0;
  for (int bit = 0; bit < 32; ++bit) {
    if (index & (1u << bit)) x ^= v[bit];
  }
  return x;
}

// True when every elementary interval of shape 2^-i x 2^-(m-i), i = 0..m,
// holds exactly one of the 2^m points.
bool is_0m2_net(const std::vector<Vec2>& pts, size_t first, int m) {
  const size_t n = size_t(1) << m;
  std::vector<int> count(n);
  for (int i = 0; i <= m; ++i) {
    std::fill(count.begin(), count.end(), 0);
    for (size_t k = first; k < first + n; ++k) {
      // Values are multiples of 2^-24, so these products are exact.
      const uint32_t cx = uint32_t(pts[k].x * float(1u << i));
      const uint32_t cy = uint32_t(pts[k].y * float(1u << (m - i)));
      if (++count[(size_t(cx) << (m - i)) | cy] > 1) return false;
    }
  }
  return true;
}

std::vector<Vec2> slot_points(SamplerKind kind, int px, int py, int slot, uint32_t n, int frame = 0,
                              Stream stream = Stream::kTest, uint64_t seed = kSeed) {
  PixelSampler s(kind, seed, frame, px, py, stream);
  std::vector<Vec2> pts(n);
  for (uint32_t i = 0; i < n; ++i) {
    s.start_sample(i);
    for (int k = 0; k < slot; ++k) s.get2d();
    pts[i] = s.get2d();
  }
  return pts;
}

double correlation(const std::vector<double>& a, const std::vector<double>& b) {
  double ma = 0, mb = 0;
  for (size_t i = 0; i < a.size(); ++i) ma += a[i], mb += b[i];
  ma /= a.size();
  mb /= b.size();
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) * (a[i] - ma);
    sbb += (b[i] - mb) * (b[i] - mb);
  }
  return sab / std::sqrt(saa * sbb);
}

std::vector<double> first_dims(SamplerKind kind, int px, int py, uint32_t n, int frame = 0,
                               Stream stream = Stream::kTest) {
  PixelSampler s(kind, kSeed, frame, px, py, stream);
  std::vector<double> v(n);
  for (uint32_t i = 0; i < n; ++i) {
    s.start_sample(i);
    v[i] = s.get1d();
  }
  return v;
}

constexpr SamplerKind kKinds[] = {SamplerKind::kSobol, SamplerKind::kIndependent};

// --- building blocks --------------------------------------------------------

TEST(SobolBits, ReverseBitsKnownValues) {
  static_assert(reverse_bits32(1u) == 0x80000000u);
  static_assert(reverse_bits32(0x80000000u) == 1u);
  static_assert(reverse_bits32(0x0000f00du) == 0xb00f0000u);
  EXPECT_EQ(reverse_bits32(0x12345678u), 0x1e6a2c48u);
  for (uint32_t x = 0; x < 100000; ++x) {
    const uint32_t y = uint32_t(mix64(x));
    ASSERT_EQ(reverse_bits32(reverse_bits32(y)), y);
  }
}

TEST(SobolBits, Dim1FirstPointsAreTheKnownSequence) {
  // Sobol' dimension 2 in the usual 1-based numbering, in natural index order
  // (point i = XOR of v_k over the set bits of i; v_1 = 1/2, v_2 = 3/4, v_3 = 5/8).
  constexpr float kNatural[] = {0, 0.5f, 0.75f, 0.25f, 0.625f, 0.125f, 0.375f, 0.875f};
  for (uint32_t i = 0; i < 8; ++i) {
    EXPECT_EQ(u32_to_unit_float(sobol_dim1(i)), kNatural[i]) << "index " << i;
    EXPECT_EQ(u32_to_unit_float(sobol_dim0(i)),
              (i == 0 ? 0.0f : float(reverse_bits32(i)) * 0x1p-32f))
        << "index " << i;
  }
}

TEST(SobolBits, Dim1ButterflyMatchesJoeKuoDirectionNumbers) {
  for (uint32_t i = 0; i < (1u << 16); ++i) {
    ASSERT_EQ(sobol_dim1(i), sobol_dim1_from_direction_numbers(i)) << "index " << i;
  }
  for (uint32_t k = 0; k < 100000; ++k) {
    const uint32_t i = uint32_t(mix64(k) >> 32);  // indices with high bits set
    ASSERT_EQ(sobol_dim1(i), sobol_dim1_from_direction_numbers(i)) << "index " << i;
  }
}

TEST(SobolBits, LaineKarrasPermutationOnlyLooksAtLowerBits) {
  // What makes it a nested (Owen) scramble after bit reversal: flipping input
  // bit j never changes an output bit below j, and always flips output bit j.
  for (uint32_t k = 0; k < 2000; ++k) {
    const uint32_t x = uint32_t(mix64(k));
    const uint32_t seed = uint32_t(mix64(k + 7777));
    for (int j = 0; j < 32; ++j) {
      const uint32_t d =
          laine_karras_permutation(x, seed) ^ laine_karras_permutation(x ^ (1u << j), seed);
      ASSERT_EQ(d & ((2u << j) - 1), 1u << j) << "x " << x << " bit " << j;
    }
  }
}

TEST(SobolBits, IndexShuffleMapsAlignedBlocksOntoAlignedBlocks) {
  for (int m : {1, 4, 10}) {
    const uint32_t n = 1u << m;
    for (uint32_t seed : {0u, 1u, 0xdeadbeefu, 0x12345u}) {
      for (uint32_t block : {0u, 1u, 77u}) {
        std::vector<bool> seen(n, false);
        const uint32_t base = nested_uniform_scramble(block * n, seed) & ~(n - 1);
        for (uint32_t j = 0; j < n; ++j) {
          const uint32_t s = nested_uniform_scramble(block * n + j, seed);
          ASSERT_EQ(s & ~(n - 1), base) << "m " << m << " seed " << seed;
          ASSERT_FALSE(seen[s & (n - 1)]) << "m " << m << " seed " << seed;
          seen[s & (n - 1)] = true;
        }
      }
    }
  }
}

TEST(SobolBits, UnitFloatNeverReachesOne) {
  static_assert(u32_to_unit_float(0) == 0.0f);
  static_assert(u32_to_unit_float(0xffffffffu) < 1.0f);
  static_assert(u32_to_unit_float(0xffffffffu) == 1.0f - 0x1p-24f);
  static_assert(u32_to_unit_float(0x80000000u) == 0.5f);
}

TEST(Hash, Mix64IsNotTheIdentityAndCombineIsOrdered) {
  static_assert(mix64(1) != 1);
  static_assert(hash_combine(1, 2) != hash_combine(2, 1));
  static_assert(hash_combine(0, 0) != 0);
  // Known value of the splitmix64 output for state 0 + gamma (its first output
  // from seed 0), which pins the constants.
  EXPECT_EQ(mix64(kGoldenGamma), 0xe220a8397b1dcdafull);
}

// --- determinism --------------------------------------------------------------

TEST(Sampler, SameInputsGiveSameValues) {
  for (SamplerKind kind : kKinds) {
    PixelSampler a(kind, kSeed, 3, 10, 20, Stream::kNoisy);
    PixelSampler b(kind, kSeed, 3, 10, 20, Stream::kNoisy);
    for (uint32_t i : {0u, 1u, 2u, 1000u, 65535u, 0xffffffffu}) {
      a.start_sample(i);
      b.start_sample(i);
      for (int d = 0; d < 20; ++d) {
        const Vec2 pa = a.get2d(), pb = b.get2d();
        ASSERT_EQ(pa.x, pb.x);
        ASSERT_EQ(pa.y, pb.y);
        ASSERT_EQ(a.get1d(), b.get1d());
      }
    }
  }
}

TEST(Sampler, SameBytesWhateverOtherPixelsWereSampledFirst) {
  for (SamplerKind kind : kKinds) {
    const auto alone = slot_points(kind, 5, 6, 2, 256);
    // Sample a block of other pixels, interleaved with a live sampler of the
    // same pixel, then the pixel again: a pure function cannot tell.
    PixelSampler live(kind, kSeed, 0, 5, 6, Stream::kTest);
    std::vector<Vec2> interleaved;
    for (uint32_t i = 0; i < 256; ++i) {
      PixelSampler other(kind, kSeed, 0, int(i % 16), int(i / 16), Stream::kTest);
      other.start_sample(i * 3);
      for (int d = 0; d < 5; ++d) other.get2d();
      live.start_sample(i);
      live.get2d();
      live.get2d();
      interleaved.push_back(live.get2d());
    }
    const auto after = slot_points(kind, 5, 6, 2, 256);
    for (size_t i = 0; i < alone.size(); ++i) {
      ASSERT_EQ(alone[i].x, interleaved[i].x);
      ASSERT_EQ(alone[i].y, interleaved[i].y);
      ASSERT_EQ(alone[i].x, after[i].x);
      ASSERT_EQ(alone[i].y, after[i].y);
    }
  }
}

// Slot k of sample i is the formula of the header (Burley 2020, sec. 4),
// computed here from the public building blocks: the index shuffled by the
// slot's first seed, then each Sobol' coordinate Owen-scrambled by its own.
// The sampler keeps the seeds of its first slots from one sample to the
// next; the numbers must not depend on that, for slots inside and beyond
// what it keeps, nor on which samples and slots were drawn before.
TEST(Sampler, SobolSlotsAreTheHeadersFormulaWhateverWasDrawnBefore) {
  PixelSampler live(SamplerKind::kSobol, kSeed, 4, 7, 9, Stream::kReference);
  const uint64_t ps = live.pixel_seed();
  auto expected = [ps](uint32_t index, uint32_t slot) {
    const uint64_t h = mix64(ps + kGoldenGamma * (2 * uint64_t(slot) + 1));
    const uint32_t seed_y = uint32_t(mix64(ps + kGoldenGamma * (2 * uint64_t(slot) + 2)));
    const uint32_t shuffled = nested_uniform_scramble(index, uint32_t(h));
    return Vec2(u32_to_unit_float(nested_uniform_scramble(sobol_dim0(shuffled), uint32_t(h >> 32))),
                u32_to_unit_float(nested_uniform_scramble(sobol_dim1(shuffled), seed_y)));
  };
  for (uint32_t index : {0u, 5u, 1000u, 5u}) {
    live.start_sample(index);
    for (uint32_t slot = 0; slot < 40; ++slot) {
      const Vec2 got = live.get2d(), want = expected(index, slot);
      ASSERT_EQ(got.x, want.x) << "sample " << index << ", slot " << slot;
      ASSERT_EQ(got.y, want.y) << "sample " << index << ", slot " << slot;
    }
  }
  // A fresh sampler that skips straight to a late slot.
  PixelSampler fresh(SamplerKind::kSobol, kSeed, 4, 7, 9, Stream::kReference);
  fresh.start_sample(1000);
  fresh.skip(35);
  EXPECT_EQ(fresh.get1d(), expected(1000, 35).x);
  fresh.start_sample(1000);
  fresh.skip(20);
  const Vec2 late = fresh.get2d();
  EXPECT_EQ(late.x, expected(1000, 20).x);
  EXPECT_EQ(late.y, expected(1000, 20).y);
}

TEST(Sampler, StartSampleRestartsTheDimensionCounter) {
  for (SamplerKind kind : kKinds) {
    PixelSampler s(kind, kSeed, 0, 1, 2, Stream::kTest);
    s.start_sample(42);
    const float a0 = s.get1d();
    const Vec2 a1 = s.get2d();
    s.start_sample(7);  // some other sample in between
    s.get2d();
    s.start_sample(42);
    EXPECT_EQ(s.get1d(), a0);
    const Vec2 b1 = s.get2d();
    EXPECT_EQ(b1.x, a1.x);
    EXPECT_EQ(b1.y, a1.y);
  }
}

TEST(Sampler, Get1dIsTheFirstCoordinateOfItsSlot) {
  for (SamplerKind kind : kKinds) {
    PixelSampler a(kind, kSeed, 0, 3, 4, Stream::kTest);
    PixelSampler b(kind, kSeed, 0, 3, 4, Stream::kTest);
    for (uint32_t i = 0; i < 64; ++i) {
      a.start_sample(i);
      b.start_sample(i);
      for (int d = 0; d < 8; ++d) ASSERT_EQ(a.get1d(), b.get2d().x);
    }
  }
}

TEST(Sampler, DifferentInputsGiveDifferentSequences) {
  struct Variant {
    uint64_t seed;
    int frame, px, py;
    Stream stream;
  };
  const Variant variants[] = {
      {kSeed, 0, 0, 0, Stream::kNoisy},     {kSeed + 1, 0, 0, 0, Stream::kNoisy},
      {kSeed, 1, 0, 0, Stream::kNoisy},     {kSeed, 0, 1, 0, Stream::kNoisy},
      {kSeed, 0, 0, 1, Stream::kNoisy},     {kSeed, 0, 0, 0, Stream::kReference},
      {kSeed, 0, 0, 0, Stream::kAlbedoRef}, {kSeed, 0, 1, 1, Stream::kNoisy},
  };
  for (SamplerKind kind : kKinds) {
    std::vector<std::vector<float>> seqs;
    for (const Variant& v : variants) {
      PixelSampler s(kind, v.seed, v.frame, v.px, v.py, v.stream);
      std::vector<float> seq;
      for (uint32_t i = 0; i < 16; ++i) {
        s.start_sample(i);
        for (int d = 0; d < 4; ++d) {
          const Vec2 p = s.get2d();
          seq.push_back(p.x);
          seq.push_back(p.y);
        }
      }
      seqs.push_back(seq);
    }
    for (size_t a = 0; a < seqs.size(); ++a) {
      for (size_t b = a + 1; b < seqs.size(); ++b) {
        int equal = 0;
        for (size_t k = 0; k < seqs[a].size(); ++k) equal += seqs[a][k] == seqs[b][k];
        // 128 values on a 2^-24 grid: any coincidence means shared randomness.
        EXPECT_EQ(equal, 0) << "variants " << a << " and " << b;
      }
    }
    // Slots of one sample differ from each other too.
    PixelSampler s(kind, kSeed, 0, 0, 0, Stream::kTest);
    s.start_sample(0);
    std::vector<float> slots;
    for (int d = 0; d < 64; ++d) slots.push_back(s.get1d());
    for (size_t a = 0; a < slots.size(); ++a) {
      for (size_t b = a + 1; b < slots.size(); ++b) EXPECT_NE(slots[a], slots[b]);
    }
  }
}

TEST(Sampler, NeighbouringPixelsFramesAndStreamsAreUncorrelated) {
  // For independent sequences the coefficient over 4096 samples has a standard
  // deviation of 1/64; 0.06 is ~4 sigma. Fixed seeds: deterministic.
  constexpr uint32_t kN = 4096;
  for (SamplerKind kind : kKinds) {
    for (int y = 0; y < 3; ++y) {
      for (int x = 0; x < 3; ++x) {
        const auto base = first_dims(kind, x, y, kN);
        EXPECT_LT(std::abs(correlation(base, first_dims(kind, x + 1, y, kN))), 0.06);
        EXPECT_LT(std::abs(correlation(base, first_dims(kind, x, y + 1, kN))), 0.06);
        EXPECT_LT(std::abs(correlation(base, first_dims(kind, x, y, kN, 1))), 0.06);
        EXPECT_LT(std::abs(correlation(base, first_dims(kind, x, y, kN, 0, Stream::kReference))),
                  0.06);
      }
    }
  }
}

TEST(Sampler, SlotsOfOnePixelAreUncorrelated) {
  // Without the per-slot index shuffle every slot would replay the same Sobol'
  // order and slot 0 and slot 1 would be strongly correlated (Burley 2020 sec. 4).
  constexpr uint32_t kN = 4096;
  for (SamplerKind kind : kKinds) {
    std::vector<std::vector<double>> dims(6, std::vector<double>(kN));
    PixelSampler s(kind, kSeed, 0, 9, 9, Stream::kTest);
    for (uint32_t i = 0; i < kN; ++i) {
      s.start_sample(i);
      for (int d = 0; d < 3; ++d) {
        const Vec2 p = s.get2d();
        dims[2 * d][i] = p.x;
        dims[2 * d + 1][i] = p.y;
      }
    }
    for (size_t a = 0; a < dims.size(); ++a) {
      for (size_t b = a + 1; b < dims.size(); ++b) {
        EXPECT_LT(std::abs(correlation(dims[a], dims[b])), 0.06) << a << " vs " << b;
      }
    }
  }
}

// --- Sobol' stratification: the known answer ----------------------------------

TEST(Sampler, EverySobolSlotPrefixIsA0m2Net) {
  for (auto [px, py] : {std::pair{0, 0}, {1, 0}, {17, 5}, {1919, 1079}}) {
    for (int slot : {0, 1, 2, 7}) {
      const auto pts = slot_points(SamplerKind::kSobol, px, py, slot, 1u << 12);
      for (int m = 1; m <= 12; ++m) {
        EXPECT_TRUE(is_0m2_net(pts, 0, m))
            << "pixel " << px << "," << py << " slot " << slot << " m " << m;
      }
    }
  }
}

TEST(Sampler, SobolStaysANetUpTo2To20Samples) {
  const auto pts = slot_points(SamplerKind::kSobol, 3, 4, 1, 1u << 20);
  for (int m = 13; m <= 20; ++m) EXPECT_TRUE(is_0m2_net(pts, 0, m)) << "m " << m;
  // Every aligned block, not only the prefix: progressive rendering in chunks
  // of 2^m samples keeps each chunk stratified.
  for (size_t block = 1; block < 8; ++block) {
    EXPECT_TRUE(is_0m2_net(pts, block << 10, 10)) << "block " << block;
  }
}

TEST(Sampler, IndependentSamplesAreNotANet) {
  // Guards the net check itself: it must be able to say no.
  const auto pts = slot_points(SamplerKind::kIndependent, 0, 0, 0, 1u << 8);
  EXPECT_FALSE(is_0m2_net(pts, 0, 8));
}

TEST(Sampler, SobolGet1dIsStratified) {
  for (auto [px, py] : {std::pair{0, 0}, {2, 9}, {640, 360}}) {
    for (int slot : {0, 3}) {
      PixelSampler s(SamplerKind::kSobol, kSeed, 0, px, py, Stream::kTest);
      std::vector<float> v(1u << 12);
      for (uint32_t i = 0; i < v.size(); ++i) {
        s.start_sample(i);
        for (int k = 0; k < slot; ++k) s.get1d();
        v[i] = s.get1d();
      }
      for (int m = 1; m <= 12; ++m) {
        std::vector<int> count(1u << m, 0);
        bool ok = true;
        for (uint32_t i = 0; i < (1u << m); ++i) ok &= ++count[uint32_t(v[i] * (1u << m))] == 1;
        EXPECT_TRUE(ok) << "pixel " << px << "," << py << " slot " << slot << " m " << m;
      }
    }
  }
}

// --- ranges and uniformity ------------------------------------------------------

TEST(Sampler, ValuesAlwaysInUnitInterval) {
  for (SamplerKind kind : kKinds) {
    for (int p = 0; p < 64; ++p) {
      PixelSampler s(kind, mix64(p), p, p * 31, -p, Stream::kTest);
      for (uint32_t i : {0u, 1u, 0x7fffffffu, 0x80000000u, 0xfffffffeu, 0xffffffffu}) {
        s.start_sample(i);
        for (int d = 0; d < 32; ++d) {
          const Vec2 v = s.get2d();
          const float u = s.get1d();
          ASSERT_TRUE(v.x >= 0.0f && v.x < 1.0f);
          ASSERT_TRUE(v.y >= 0.0f && v.y < 1.0f);
          ASSERT_TRUE(u >= 0.0f && u < 1.0f);
        }
      }
    }
  }
}

TEST(Sampler, IndependentIsUniformChiSquare) {
  // 64 bins, 63 degrees of freedom: the 0.99 quantile is 92.01. Seed kSeed,
  // pixel (12, 34), 4 slots of 16384 samples, both coordinates.
  constexpr int kBins = 64;
  constexpr uint32_t kN = 16384;
  PixelSampler s(SamplerKind::kIndependent, kSeed, 0, 12, 34, Stream::kTest);
  std::vector<std::array<int, kBins>> hist(8, std::array<int, kBins>{});
  std::vector<double> sum(8, 0.0);
  for (uint32_t i = 0; i < kN; ++i) {
    s.start_sample(i);
    for (int d = 0; d < 4; ++d) {
      const Vec2 p = s.get2d();
      ++hist[2 * d][int(p.x * kBins)];
      ++hist[2 * d + 1][int(p.y * kBins)];
      sum[2 * d] += p.x;
      sum[2 * d + 1] += p.y;
    }
  }
  const double expected = double(kN) / kBins;
  for (size_t d = 0; d < hist.size(); ++d) {
    double chi2 = 0;
    for (int c : hist[d]) chi2 += (c - expected) * (c - expected) / expected;
    EXPECT_LT(chi2, 92.01) << "dimension " << d;
    // Mean of kN uniforms: standard deviation sqrt(1/12/kN) = 0.00226; 5 sigma.
    EXPECT_NEAR(sum[d] / kN, 0.5, 5 * std::sqrt(1.0 / 12.0 / kN)) << "dimension " << d;
  }
}

TEST(Sampler, IndependentIsUniformAcrossPixels) {
  // The same sample index over a 128 x 128 tile: no spatial structure.
  constexpr int kBins = 64;
  std::array<int, kBins> hist{};
  for (int y = 0; y < 128; ++y) {
    for (int x = 0; x < 128; ++x) {
      PixelSampler s(SamplerKind::kIndependent, kSeed, 5, x, y, Stream::kNoisy);
      s.start_sample(0);
      ++hist[int(s.get1d() * kBins)];
    }
  }
  const double expected = 128.0 * 128.0 / kBins;
  double chi2 = 0;
  for (int c : hist) chi2 += (c - expected) * (c - expected) / expected;
  EXPECT_LT(chi2, 92.01);
}

// --- integration error --------------------------------------------------------

template <typename F>
double rmse_over_pixels(SamplerKind kind, F f, double exact, int slot) {
  constexpr uint32_t kN = 1024;
  constexpr int kPixels = 64;
  double se = 0;
  for (int p = 0; p < kPixels; ++p) {
    PixelSampler s(kind, kSeed, 0, p % 8, p / 8, Stream::kTest);
    double sum = 0;
    for (uint32_t i = 0; i < kN; ++i) {
      s.start_sample(i);
      for (int k = 0; k < slot; ++k) s.get2d();
      const Vec2 u = s.get2d();
      sum += f(u.x, u.y);
    }
    se += (sum / kN - exact) * (sum / kN - exact);
  }
  return std::sqrt(se / kPixels);
}

TEST(Sampler, SobolBeatsIndependentOnASmoothIntegrand) {
  // Owen-scrambled nets converge as N^-1.5 on smooth integrands, independent
  // samples as N^-0.5: at N = 1024 the ratio is of order 1/N (measured ~1/500);
  // 1/20 leaves a margin of 25.
  auto f = [](double x, double y) { return std::exp(-x) * std::sin(y); };
  const double exact = (1.0 - std::exp(-1.0)) * (1.0 - std::cos(1.0));
  for (int slot : {0, 5}) {
    const double sobol = rmse_over_pixels(SamplerKind::kSobol, f, exact, slot);
    const double indep = rmse_over_pixels(SamplerKind::kIndependent, f, exact, slot);
    EXPECT_LT(sobol, indep / 20) << "slot " << slot << ": " << sobol << " vs " << indep;
    // Independent sampling itself must be right: its RMSE is sigma_f / sqrt(N)
    // (sigma_f ~ 0.14 here), not biased.
    EXPECT_LT(indep, 0.01);
  }
}

TEST(Sampler, SobolBeatsIndependentOnADiskIndicator) {
  // Discontinuous integrand (a lens aperture, a light's silhouette): the rate is
  // ~N^-0.75 against N^-0.5 (constants aside, ~1/6 at N = 1024; measured 0.30).
  auto f = [](double x, double y) {
    return (x - 0.5) * (x - 0.5) + (y - 0.5) * (y - 0.5) < 0.16 ? 1.0 : 0.0;
  };
  const double exact = std::acos(-1.0) * 0.16;
  for (int slot : {0, 5}) {
    const double sobol = rmse_over_pixels(SamplerKind::kSobol, f, exact, slot);
    const double indep = rmse_over_pixels(SamplerKind::kIndependent, f, exact, slot);
    EXPECT_LT(sobol, indep / 2) << "slot " << slot << ": " << sobol << " vs " << indep;
  }
}

// --- 4D points: pixel jitter and lens together ---------------------------------

TEST(SobolBits, RecurrenceGivesDimension1AndTheJoeKuoDimensions2And3) {
  // The recurrence on dimension 1's parameters (degree 1, m = 1) is the
  // Pascal-matrix butterfly.
  constexpr uint32_t kM1[] = {1};
  constexpr SobolColumns dim1 = sobol_reversed_columns(1, 0, kM1);
  for (uint32_t k = 0; k < 100000; ++k) {
    const uint32_t i = k < 65536 ? k : uint32_t(mix64(k) >> 32);
    ASSERT_EQ(sobol_apply(dim1, i), sobol_dim1_reversed(i)) << "index " << i;
  }
  // The first points of Joe and Kuo's dimensions 3 and 4 as their generator
  // lists them (Gray-code order: point i is at index i ^ (i >> 1)).
  constexpr float kDim2[] = {0, 0.5f, 0.25f, 0.75f, 0.625f, 0.125f, 0.875f, 0.375f};
  constexpr float kDim3[] = {0, 0.5f, 0.25f, 0.75f, 0.875f, 0.375f, 0.625f, 0.125f};
  for (uint32_t i = 0; i < 8; ++i) {
    const uint32_t g = i ^ (i >> 1);
    EXPECT_EQ(u32_to_unit_float(sobol_dim2(g)), kDim2[i]) << "point " << i;
    EXPECT_EQ(u32_to_unit_float(sobol_dim3(g)), kDim3[i]) << "point " << i;
  }
  // Direction number k + 1 is m / 2^(k+1) with m odd: digit k + 1 set and
  // no digit after it.
  for (int k = 0; k < 32; ++k) {
    for (uint32_t v : {kSobolDim2Reversed.v[k], kSobolDim3Reversed.v[k]}) {
      const uint32_t fixed = reverse_bits32(v);
      EXPECT_EQ((fixed >> (31 - k)) & 1u, 1u) << k;
      EXPECT_EQ(fixed & uint32_t((uint64_t(1) << (31 - k)) - 1), 0u) << k;
    }
  }
}

// The byte tables get4d() reads give what the columns give, bit for bit:
// every index below 2^16, every single bit and all ones, and hashed ones.
TEST(SobolBits, ByteTablesAreTheColumns) {
  std::vector<uint32_t> indices;
  for (uint32_t k = 0; k < 65536; ++k) indices.push_back(k);
  for (int b = 0; b < 32; ++b) indices.push_back(1u << b);
  indices.push_back(0xffffffffu);
  for (uint32_t k = 0; k < 100000; ++k) indices.push_back(uint32_t(mix64(k + 7) >> 32));
  for (uint32_t i : indices) {
    ASSERT_EQ(sobol_apply(kSobolDim2Bytes, i), sobol_apply(kSobolDim2Reversed, i)) << i;
    ASSERT_EQ(sobol_apply(kSobolDim3Bytes, i), sobol_apply(kSobolDim3Reversed, i)) << i;
  }
  static_assert(sobol_apply(kSobolDim2Bytes, 0x80000001u) ==
                (kSobolDim2Reversed.v[31] ^ kSobolDim2Reversed.v[0]));
}

TEST(Sampler, Get4dFirstPairIsGet2dAndEachPairIsANet) {
  for (auto [px, py] : {std::pair{0, 0}, {17, 5}}) {
    PixelSampler a(SamplerKind::kSobol, kSeed, 0, px, py, Stream::kTest);
    PixelSampler b(SamplerKind::kSobol, kSeed, 0, px, py, Stream::kTest);
    std::vector<Vec2> first(1u << 10), second(1u << 10);
    for (uint32_t i = 0; i < first.size(); ++i) {
      a.start_sample(i);
      b.start_sample(i);
      a.get4d(&first[i], &second[i]);
      const Vec2 p = b.get2d();
      b.skip(1);
      ASSERT_EQ(first[i].x, p.x);
      ASSERT_EQ(first[i].y, p.y);
      // Both samplers are in the same slot afterwards.
      ASSERT_EQ(a.get1d(), b.get1d());
    }
    for (int m = 1; m <= 10; ++m) {
      EXPECT_TRUE(is_0m2_net(first, 0, m)) << "m " << m;
      // Dimensions 2 and 3 are not a (0,2)-sequence together, but Owen
      // scrambling keeps each coordinate stratified in 1D.
      std::vector<Vec2> z(first.size()), w(first.size());
      for (size_t i = 0; i < first.size(); ++i) {
        z[i] = {second[i].x, 0.0f};
        w[i] = {second[i].y, 0.0f};
      }
      EXPECT_TRUE(is_0m2_net(z, 0, 0) && is_0m2_net(w, 0, 0));
    }
  }
}

// RMSE over pixels of N-sample estimates of the integral of f(p, l) over
// [0,1)^4, with (p, l) from get4d() or from two get2d() calls.
template <typename F>
double rmse_4d(bool joint, F f, double exact, uint32_t n) {
  constexpr int kPixels = 256;
  double se = 0;
  for (int px = 0; px < kPixels; ++px) {
    PixelSampler s(SamplerKind::kSobol, kSeed, 0, px % 16, px / 16, Stream::kTest);
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
  return std::sqrt(se / kPixels);
}

TEST(Sampler, Get4dStratifiesAPixelAndLensEdgeJointly) {
  // A defocused edge: a film point p and a lens point l see the emitter when
  // (p.x - 1/2) + (l.x - 1/2) < 0, a half-space of [0,1)^4 (integral 1/2)
  // whose boundary couples the two pairs. Two padded pairs stratify p and l
  // each alone, and their sum converges like independent samples of the
  // 1D distribution of p.x + l.x; one 4D point stratifies the sum.
  // The same for a horizontal edge (dimensions 1 and 3). Measured joint /
  // padded RMSE: vertical 0.60, 0.42, 0.26, 0.23 and horizontal 0.57, 0.61,
  // 0.24, 0.24 at 64, 256, 1024 and 4096 samples.
  auto vertical = [](Vec2 p, Vec2 l) { return p.x + l.x < 1.0f ? 1.0 : 0.0; };
  auto horizontal = [](Vec2 p, Vec2 l) { return p.y + l.y < 1.0f ? 1.0 : 0.0; };
  for (auto [n, bound] : {std::pair{256u, 0.75}, {1024u, 0.4}}) {
    EXPECT_LT(rmse_4d(true, vertical, 0.5, n), bound * rmse_4d(false, vertical, 0.5, n)) << n;
    EXPECT_LT(rmse_4d(true, horizontal, 0.5, n), bound * rmse_4d(false, horizontal, 0.5, n))
        << n;
  }
}

// The batched draws (get_vertex: five slots of a path vertex;
// get4d_samples: the camera's 4D point of up to eight samples) give the
// numbers the single draws give, bit for bit, and leave the sampler where
// the single draws leave it: on this CPU's AVX2 lanes where it has them,
// and with them switched off. Sample indices near 2^32 wrap as the single
// draws do; slots from 0 past the cached 32; samplers fresh and reused
// (the seed cache filled in a different order).
TEST(Sampler, BatchedDrawsAreTheSingleDraws) {
  SimdRestore restore;
  auto same = [](Vec2 a, Vec2 b) { return a.x == b.x && a.y == b.y; };
  std::vector<bool> modes = {false};
  if (simd_available()) modes.push_back(true);
  for (bool simd : modes) {
    allow_simd(simd);
    for (SamplerKind kind : {SamplerKind::kSobol, SamplerKind::kIndependent}) {
      PixelSampler reused(kind, kSeed, 3, 11, 2, Stream::kNoisy);
      for (uint32_t index : {0u, 1u, 7u, 1000u, 12345u, 0xfffffffeu}) {
        for (uint32_t dim : {0u, 2u, 4u, 26u, 27u, 28u, 30u, 31u, 40u}) {
          SCOPED_TRACE(testing::Message() << "simd " << simd << ", kind " << int(kind)
                                          << ", sample " << index << ", first slot " << dim);
          PixelSampler fresh(kind, kSeed, 3, 11, 2, Stream::kNoisy);
          PixelSampler single(kind, kSeed, 3, 11, 2, Stream::kNoisy);
          single.start_sample(index);
          single.skip(dim);
          const float select = single.get1d();
          const Vec2 light = single.get2d();
          const float lobe = single.get1d();
          const Vec2 bsdf = single.get2d();
          const float roulette = single.get1d();
          const Vec2 next = single.get2d();
          for (PixelSampler* batched : {&fresh, &reused}) {
            batched->start_sample(index);
            batched->skip(dim);
            PixelSampler::VertexNumbers v;
            batched->get_vertex(&v);
            EXPECT_EQ(v.select, select);
            EXPECT_TRUE(same(v.light, light));
            EXPECT_EQ(v.lobe, lobe);
            EXPECT_TRUE(same(v.bsdf, bsdf));
            EXPECT_EQ(v.roulette, roulette);
            EXPECT_EQ(batched->slots_used(), dim + 5);
            EXPECT_TRUE(same(batched->get2d(), next));
          }
        }
      }
      PixelSampler reused_camera(kind, kSeed, 8, 1, 30, Stream::kReference);
      reused_camera.start_sample(3);
      reused_camera.skip(12);
      (void)reused_camera.get2d();  // its cache filled past the camera's slots
      for (uint32_t first : {0u, 5u, 64u, 0xfffffffau}) {
        for (int n = 1; n <= 8; ++n) {
          SCOPED_TRACE(testing::Message() << "simd " << simd << ", kind " << int(kind)
                                          << ", samples " << first << " + " << n);
          PixelSampler fresh(kind, kSeed, 8, 1, 30, Stream::kReference);
          PixelSampler single(kind, kSeed, 8, 1, 30, Stream::kReference);
          Vec2 want_a[8], want_b[8];
          for (int k = 0; k < n; ++k) {
            single.start_sample(first + uint32_t(k));
            single.get4d(&want_a[k], &want_b[k]);
          }
          const Vec2 next = single.get2d();
          for (PixelSampler* batched : {&fresh, &reused_camera}) {
            Vec2 a[8], b[8];
            batched->get4d_samples(first, n, a, b);
            for (int k = 0; k < n; ++k) {
              EXPECT_TRUE(same(a[k], want_a[k])) << "sample " << k;
              EXPECT_TRUE(same(b[k], want_b[k])) << "sample " << k;
            }
            EXPECT_EQ(batched->slots_used(), 2u);
            EXPECT_TRUE(same(batched->get2d(), next));
          }
        }
      }
    }
  }
}

}  // namespace
}  // namespace dofarm::render
