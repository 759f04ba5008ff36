// DESIGN.md: a frame rendered as 1 tile or as many, with any thread count, is
// bit-for-bit the same.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>

#include "common/cpus.h"
#include "tests/cpu_mask.h"
#include "tests/render/render_fixtures.h"

namespace dofarm::render {
namespace {

using testing::make_scene;
using testing::make_spec;

FrameBuffers render_tiled(const Scene& scene, const JobSpec& spec, int tw, int th, int threads) {
  FrameBuffers full;
  full.allocate(spec.width, spec.height, spec.versions);
  RenderOptions opt;
  opt.threads = threads;
  opt.block_size = 4;
  for (int y = 0; y < spec.height; y += th)
    for (int x = 0; x < spec.width; x += tw) {
      Rect r{x, y, std::min(tw, spec.width - x), std::min(th, spec.height - y)};
      FrameBuffers t = render_frame(scene, spec, 0, r, opt);
      EXPECT_EQ(t.rect, r);
      full.paste(t);
      full.camera = t.camera;
    }
  full.rect = Rect{0, 0, spec.width, spec.height};
  return full;
}

class Determinism : public ::testing::TestWithParam<SamplerKind> {};

TEST_P(Determinism, SameBytesForAnyTilingAndThreadCount) {
  auto scene = make_scene(testing::small_room());
  JobSpec spec = make_spec(32, 24, Vec3(0.2f, 1, 3), Vec3(0, 0.9f, 0), 45, 3.0f, 0.05f);
  spec.sampler = GetParam();
  spec.versions = 3;
  RenderOptions one_thread;
  one_thread.threads = 1;
  FrameBuffers whole = render_frame(*scene, spec, 0, std::nullopt, one_thread);
  ASSERT_EQ(whole.count_non_finite(), 0u);

  EXPECT_TRUE(testing::same_bytes(whole, render_tiled(*scene, spec, 8, 6, 1))) << "16 tiles";
  EXPECT_TRUE(testing::same_bytes(whole, render_tiled(*scene, spec, 13, 7, 2))) << "odd tiles";
  EXPECT_TRUE(testing::same_bytes(whole, render_tiled(*scene, spec, 32, 24, 2))) << "2 threads";
  EXPECT_TRUE(testing::same_bytes(whole, render_tiled(*scene, spec, 5, 24, 3))) << "columns";
}

INSTANTIATE_TEST_SUITE_P(Samplers, Determinism,
                         ::testing::Values(SamplerKind::kSobol, SamplerKind::kIndependent));

TEST(Determinism, AnotherSeedGivesOtherNoise) {
  // The negative control: the comparison above can fail.
  auto scene = make_scene(testing::small_room());
  JobSpec a = make_spec(16, 16, Vec3(0, 1, 3), Vec3(0, 1, 0), 45);
  JobSpec b = a;
  b.seed = a.seed + 1;
  EXPECT_FALSE(testing::same_bytes(render_frame(*scene, a, 0), render_frame(*scene, b, 0)));
}

TEST(Determinism, ReferenceOnlyGivesTheSameReferenceAndNothingElse) {
  // bench/render_spp renders the reference alone: its bytes must be those
  // of a full render, and the buffers it skips stay zero.
  auto scene = make_scene(testing::small_room());
  JobSpec spec = make_spec(20, 14, Vec3(0.2f, 1, 3), Vec3(0, 0.9f, 0), 45, 3.0f, 0.05f);
  spec.versions = 2;
  spec.reference_spp = 8;
  const FrameBuffers full = render_frame(*scene, spec, 0);
  RenderOptions options;
  options.reference_only = true;
  RenderStats stats;
  options.stats = &stats;
  const FrameBuffers ref = render_frame(*scene, spec, 0, std::nullopt, options);
  EXPECT_EQ(ref.reference, full.reference);
  EXPECT_EQ(ref.reference_half, full.reference_half);
  EXPECT_EQ(ref.reference_var, full.reference_var);
  auto zero = [](const std::vector<float>& v) {
    return std::all_of(v.begin(), v.end(), [](float x) { return x == 0.0f; });
  };
  EXPECT_FALSE(zero(full.noisy));
  EXPECT_TRUE(zero(ref.noisy));
  EXPECT_TRUE(zero(ref.albedo_ref));
  EXPECT_TRUE(zero(ref.depth));
  EXPECT_EQ(stats.paths, uint64_t(20 * 14 * 8));  // the reference's paths only
}

// --threads 0 means the CPUs this process may run on (its affinity mask, as
// under Slurm or taskset), not every hardware thread of the machine: with the
// mask narrowed to one CPU a default render runs one thread.
TEST(RenderThreads, DefaultFollowsTheAffinityMask) {
  dofarm::cpu_testing::CpuMask mask;
  if (mask.count() < 2) GTEST_SKIP() << "one CPU: nothing to narrow";
  auto scene = make_scene(testing::small_room());
  const JobSpec spec = make_spec(64, 64, Vec3(0, 1, 3), Vec3(0, 1, 0), 45);  // 16 blocks
  RenderStats wide;
  RenderOptions options;
  options.stats = &wide;
  render_frame(*scene, spec, 0, std::nullopt, options);
  EXPECT_EQ(wide.threads, std::min(mask.count(), 16));

  ASSERT_TRUE(mask.narrow_to_one());
  RenderStats narrow;
  options.stats = &narrow;
  render_frame(*scene, spec, 0, std::nullopt, options);
  ASSERT_TRUE(mask.restore());
  EXPECT_EQ(narrow.threads, 1);
  EXPECT_EQ(cpus_available(), mask.count());
}

// A cancel request is seen within a pixel, not only between blocks: one
// block of reference pixels at study settings takes seconds, and a worker
// told to stop must hand its task back at once. Here the only block of the
// tile would take tens of seconds; cancelled after 0.2 s, the render throws
// (when cancel was seen only between blocks it finished the block and
// returned).
TEST(RenderCancel, ACancelRequestIsSeenInsideABlock) {
  auto scene = make_scene(testing::small_room());
  JobSpec spec = make_spec(16, 16, Vec3(0, 1, 3), Vec3(0, 1, 0), 45);
  spec.reference_spp = 1 << 17;
  RenderOptions opt;
  opt.threads = 1;
  opt.block_size = 16;
  std::atomic<bool> cancel{false};
  opt.cancel = &cancel;
  std::thread stopper([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    cancel = true;
  });
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_THROW(render_frame(*scene, spec, 0, std::nullopt, opt), Cancelled);
  stopper.join();
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_LT(took, 10.0);
}

}  // namespace
}  // namespace dofarm::render
