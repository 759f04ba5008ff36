#include "trainer/dataset.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <thread>

#include "tests/trainer/synthetic.h"

namespace dofarm::trainer {
namespace {

namespace fs = std::filesystem;

fs::path fresh_dir(const std::string& name) { return testing::scratch_dir(name); }

ModelConfig no_coc() {
  ModelConfig m;
  std::erase(m.inputs, std::string("coc:log"));
  return m;
}

DataConfig small_data() {
  DataConfig d;
  d.crop = 32;
  d.sequence = 4;
  d.queue = 6;
  d.readers = 2;
  return d;
}

TEST(Split, TrainAndValidationNeverOverlap) {
  DataConfig d;
  for (int frames : {7, 13, 14, 16, 40, 100}) {
    ShardSplit s = assign_split("shard-00001.h5", "xxh64:000000000000000" + std::to_string(frames % 10), frames, d);
    EXPECT_LE(s.train_end, s.val_begin == s.val_end ? frames : s.val_begin) << frames;
    EXPECT_EQ(s.train_begin, 0);
    if (s.val_end > s.val_begin) {
      EXPECT_GE(s.val_end - s.val_begin, d.sequence);
    }
    EXPECT_LE(s.val_end, frames);
  }
  d.split = SplitMode::kShard;
  d.val_fraction = 0.5f;
  int val = 0;
  for (int i = 0; i < 200; ++i) {
    ShardSplit s = assign_split("shard.h5", "key-" + std::to_string(i), 16, d);
    bool is_val = s.val_end > 0;
    EXPECT_EQ(is_val ? s.train_end : s.val_end, 0);  // whole shard one side
    val += is_val;
    EXPECT_EQ(s, assign_split("shard.h5", "key-" + std::to_string(i), 16, d));
  }
  EXPECT_GT(val, 60);
  EXPECT_LT(val, 140);
}

// val_fraction is the share of whole sequences, also for shards that hold
// only two (16 frames of 7: the old rule gave 7 of 16 frames, 44%).
TEST(Split, ValFractionIsTheShareOfWholeSequences) {
  DataConfig d;  // sequence 7, val_fraction 0.1
  for (int frames : {7, 16, 50, 100}) {
    int val = 0, total = 0;
    for (int i = 0; i < 4000; ++i) {
      ShardSplit s = assign_split("a.h5", "xxh64:" + std::to_string(i * 7919 + frames), frames, d);
      EXPECT_EQ((s.val_end - s.val_begin) % d.sequence, 0);
      EXPECT_EQ(s.val_end == s.val_begin ? frames : s.val_end, frames);
      EXPECT_EQ(s.train_end, s.val_end == s.val_begin ? frames : s.val_begin);
      val += (s.val_end - s.val_begin) / d.sequence;
      total += frames / d.sequence;
    }
    EXPECT_NEAR(double(val) / total, 0.1, 0.015) << frames;
  }
  // A whole number of sequences is exact: 10 sequences, 1 for validation.
  ShardSplit s = assign_split("a.h5", "xxh64:1", 70, d);
  EXPECT_EQ(s.val_end - s.val_begin, 7);
  // The file name plays no part.
  EXPECT_EQ(assign_split("a.h5", "xxh64:5", 16, d).val_begin,
            assign_split("b.h5", "xxh64:5", 16, d).val_begin);
}

// split.json is keyed by content: a new shard under an old name (more
// frames) is a new shard, not a mismatch with the old one's ranges.
TEST(SequenceStream, SplitIsKeyedByShardContent) {
  fs::path data = fresh_dir("ds_key_data"), run = fresh_dir("ds_key_run");
  DataConfig d = small_data();
  d.val_fraction = 0.25f;
  testing::write_synthetic_shard(data / "shard-00000.h5", 8, 48, 48, 2, 1);
  std::string first_key;
  {
    SequenceStream s(data, run, d, ModelConfig{}, 1);
    ASSERT_EQ(s.splits().size(), 1u);
    first_key = s.splits()[0].key;
    EXPECT_EQ(first_key.rfind("xxh64:", 0), 0u);
  }
  fs::remove(data / "shard-00000.h5");
  testing::write_synthetic_shard(data / "shard-00000.h5", 16, 48, 48, 2, 2);
  SequenceStream s(data, run, d, ModelConfig{}, 1);
  ASSERT_EQ(s.splits().size(), 1u);
  EXPECT_NE(s.splits()[0].key, first_key);
  EXPECT_EQ(s.splits()[0].frames, 16);
  EXPECT_EQ(s.splits()[0].val_end - s.splits()[0].val_begin, 4);  // 4 sequences, 1 validation
  EXPECT_FALSE(s.next().input.empty());
  // Both shards' assignments stay on record.
  EXPECT_EQ(load_split_file(run).size(), 2u);
}

// A new run on a few short shards still gets one validation sequence.
TEST(SequenceStream, ANewRunHasAtLeastOneValidationSequence) {
  fs::path data = fresh_dir("ds_one_val_data"), run = fresh_dir("ds_one_val_run");
  for (int i = 0; i < 2; ++i)
    testing::write_synthetic_shard(data / ("shard-0000" + std::to_string(i) + ".h5"), 8, 48, 48, 2,
                                   40 + i);
  DataConfig d = small_data();  // sequence 4: two sequences per shard
  d.val_fraction = 0.001f;
  std::vector<ShardSplit> first;
  {
    SequenceStream s(data, run, d, ModelConfig{}, 1);
    first = s.splits();
  }
  int val = 0;
  for (const ShardSplit& sp : first) val += (sp.val_end - sp.val_begin) / d.sequence;
  EXPECT_EQ(val, 1);
  EXPECT_FALSE(SequenceStream(data, run, d, ModelConfig{}, 1).validation(1).empty());
  // Resumed, the split is the recorded one.
  SequenceStream again(data, run, d, ModelConfig{}, 1);
  EXPECT_EQ(again.splits(), first);
}

TEST(SequenceStream, HoldsAtMostQueueSamplesWhateverTheData) {
  fs::path data = fresh_dir("ds_bound_data"), run = fresh_dir("ds_bound_run");
  for (int i = 0; i < 3; ++i)
    testing::write_synthetic_shard(data / ("shard-0000" + std::to_string(i) + ".h5"), 12, 64, 48, 3,
                                   20 + i);
  DataConfig d = small_data();
  d.queue = 3;
  d.readers = 4;  // more readers than queue slots
  SequenceStream s(data, run, d, ModelConfig{}, 5);
  auto wait_full = [&] {
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (s.held() < 3 && std::chrono::steady_clock::now() < deadline)
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
  };
  for (int round = 0; round < 3; ++round) {
    wait_full();
    EXPECT_EQ(s.held(), 3u) << round;
    // The consumer is slow: the readers must wait, not read ahead.
    for (int i = 0; i < 20; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      ASSERT_LE(s.held(), 3u) << round;
    }
    s.next();
    EXPECT_LE(s.held(), 2u + 1u);
  }
  EXPECT_EQ(s.next_index(), 3u);
}

TEST(SequenceStream, DeterministicFiniteAndSplitPersisted) {
  fs::path data = fresh_dir("ds_data"), run = fresh_dir("ds_run");
  testing::write_synthetic_shard(data / "shard-00000.h5", 12, 64, 48, 3, 7);
  DataConfig d = small_data();
  std::vector<Sample> a, b;
  {
    SequenceStream s(data, run, d, ModelConfig{}, 42);
    for (int i = 0; i < 5; ++i) a.push_back(s.next());
    EXPECT_EQ(s.next_index(), 5u);
  }
  ASSERT_TRUE(fs::exists(run / "split.json"));
  {
    SequenceStream s(data, run, d, ModelConfig{}, 42, /*first_index=*/3);
    for (int i = 0; i < 2; ++i) b.push_back(s.next());
  }
  EXPECT_EQ(a[3].input, b[0].input);  // sample i depends on (seed, i) only
  EXPECT_EQ(a[4].target, b[1].target);
  EXPECT_NE(a[0].input, a[1].input);
  for (const Sample& smp : a) {
    EXPECT_EQ(smp.frames, 4);
    EXPECT_EQ(smp.channels, 12);
    for (float v : smp.input) ASSERT_TRUE(std::isfinite(v));
    for (float v : smp.target) ASSERT_TRUE(std::isfinite(v));
  }
}

TEST(SequenceStream, PicksUpShardsThatAppearWhileRunning) {
  fs::path data = fresh_dir("ds_new"), run = fresh_dir("ds_new_run");
  testing::write_synthetic_shard(data / "shard-00000.h5", 10, 64, 64, 2, 1);
  DataConfig d = small_data();
  d.rescan_seconds = 0.05f;
  SequenceStream s(data, run, d, no_coc(), 1);
  EXPECT_EQ(s.splits().size(), 1u);
  testing::write_synthetic_shard(data / "shard-00001.h5", 10, 64, 64, 2, 2);
  for (int i = 0; i < 400 && s.splits().size() < 2; ++i) {
    s.next();  // keeps training while the farm adds data
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(s.splits().size(), 2u);
}

TEST(SequenceStream, CorruptedShardGivesAClearError) {
  fs::path data = fresh_dir("ds_bad"), run = fresh_dir("ds_bad_run");
  testing::write_synthetic_shard(data / "shard-00000.h5", 10, 64, 64, 2, 1);
  // Damage the data: keep the size, overwrite the middle of the file.
  auto size = fs::file_size(data / "shard-00000.h5");
  {
    std::fstream f(data / "shard-00000.h5", std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(std::streamoff(size / 3));
    std::string junk(size / 3, '\x5a');
    f.write(junk.data(), std::streamsize(junk.size()));
  }
  { std::ofstream(data / "shard-00001.h5") << "this is not an HDF5 file"; }
  try {
    SequenceStream s(data, run, small_data(), ModelConfig{}, 1);
    for (int i = 0; i < 20; ++i) s.next();  // damage may only show when chunks are read
    FAIL() << "no error";
  } catch (const RuntimeError& e) {
    std::string msg = e.what();
    EXPECT_NE(msg.find("shard-0000"), std::string::npos) << msg;
  }
}

}  // namespace
}  // namespace dofarm::trainer

namespace dofarm::trainer {
namespace {

TEST(SequenceStream, DamagedShardIsDroppedAndTrainingGoesOn) {
  fs::path data = fresh_dir("ds_mixed"), run = fresh_dir("ds_mixed_run");
  testing::write_synthetic_shard(data / "shard-00000.h5", 10, 64, 64, 2, 1);
  testing::write_synthetic_shard(data / "shard-00001.h5", 10, 64, 64, 2, 2);
  auto size = fs::file_size(data / "shard-00001.h5");
  {
    std::fstream f(data / "shard-00001.h5", std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(std::streamoff(size / 4));
    std::string junk(size / 2, '\x5a');
    f.write(junk.data(), std::streamsize(junk.size()));
  }
  SequenceStream s(data, run, small_data(), ModelConfig{}, 3);
  for (int i = 0; i < 30; ++i) {
    Sample smp = s.next();
    for (float v : smp.target) ASSERT_TRUE(std::isfinite(v));
  }
  std::vector<std::string> problems = s.problems();
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems[0].find("shard-00001.h5"), std::string::npos) << problems[0];
  ASSERT_EQ(s.splits().size(), 1u);
  EXPECT_EQ(s.splits()[0].file, "shard-00000.h5");
}

}  // namespace
}  // namespace dofarm::trainer

namespace dofarm::trainer {
namespace {

TEST(SequenceStream, ReadsExactlyThePlannedFramesVersionsAndCrop) {
  fs::path data = fresh_dir("ds_exact"), run = fresh_dir("ds_exact_run");
  testing::write_synthetic_shard(data / "shard-00000.h5", 12, 96, 64, 4, 8);
  for (AlbedoSource src : {AlbedoSource::kReference, AlbedoSource::kVersion}) {
    DataConfig d = small_data();
    d.albedo = src;
    SequenceStream s(data, run, d, ModelConfig{}, 1);
    std::mt19937_64 rng(4);
    SequencePlan plan = draw_plan(rng, d, 0, 12, 4, 96, 64);
    RawCrop raw = s.read_raw("shard-00000.h5", plan);
    // Exactly the buffers the inputs, the demodulation and the target need.
    std::vector<std::string> names;
    for (const auto& [name, planes] : raw.buffers) names.push_back(name);
    std::vector<std::string> want = sample_buffers(ModelConfig{}, d);
    std::sort(want.begin(), want.end());
    EXPECT_EQ(names, want);
    ShardReader reader(data / "shard-00000.h5");
    const int c = d.crop;
    const size_t n = size_t(c) * c;
    for (size_t i = 0; i < plan.offset.size(); ++i) {
      FrameBuffers fb = reader.read_frame(plan.first_frame + plan.offset[i]);
      const int v = plan.version[i];
      for (int ch = 0; ch < 3; ++ch)
        for (int y = 0; y < c; ++y)
          for (int x = 0; x < c; ++x) {
            size_t src_i =
                ((size_t(v) * 3 + ch) * fb.height + plan.crop_y + y) * fb.width + plan.crop_x + x;
            size_t dst = ((size_t(plan.offset[i]) * raw.versions + v) * 3 + ch) * n + y * c + x;
            ASSERT_EQ(raw.buffers.at("noisy")[dst], fb.noisy[src_i]);
            if (src == AlbedoSource::kVersion) {
              ASSERT_EQ(raw.buffers.at("albedo")[dst], fb.albedo[src_i]);
            }
          }
      EXPECT_EQ(raw.focal_distance[plan.offset[i]], fb.camera.focal_distance);
    }
  }
}

}  // namespace
}  // namespace dofarm::trainer

namespace dofarm::trainer {
namespace {

// The reader's own chunk decoding (H5Dread_chunk + Fletcher-32 + inflate +
// unshuffle outside the HDF5 lock) against HDF5's H5Dread, on a shard whose
// size is not a multiple of the 64-pixel tile (partial edge chunks).
TEST(ShardReader, OwnChunkDecodingGivesHdf5sValuesForAnyCrop) {
  fs::path dir = fresh_dir("own_decode");
  const int w = 150, h = 97, versions = 3, frames = 5;
  testing::write_synthetic_shard(dir / "s.h5", frames, w, h, versions, 9);
  ShardReader own(dir / "s.h5"), hdf5(dir / "s.h5", ShardReaderOptions{false});
  std::mt19937 rng(4);
  for (const BufferInfo& b : buffer_infos()) {
    ASSERT_TRUE(own.decodes_chunks(b.name)) << b.name;
    ASSERT_FALSE(hdf5.decodes_chunks(b.name)) << b.name;
    for (int k = 0; k < 12; ++k) {
      Rect r;
      r.w = std::uniform_int_distribution<int>(1, w)(rng);
      r.h = std::uniform_int_distribution<int>(1, h)(rng);
      r.x = std::uniform_int_distribution<int>(0, w - r.w)(rng);
      r.y = std::uniform_int_distribution<int>(0, h - r.h)(rng);
      int n = std::uniform_int_distribution<int>(1, frames)(rng);
      int f0 = std::uniform_int_distribution<int>(0, frames - n)(rng);
      int v = k % 4 == 0 ? ShardReader::kAllVersions : k % versions;
      std::vector<float> a = own.read_crop(b.name, f0, n, v, r);
      std::vector<float> e = hdf5.read_crop(b.name, f0, n, v, r);
      ASSERT_EQ(a.size(), e.size());
      ASSERT_TRUE(a == e) << b.name << " frames " << f0 << "+" << n << " version " << v << " rect "
                          << r.x << "," << r.y << "," << r.w << "," << r.h;
    }
  }
  // Whole frames (read_frame) too, the checksum walk the writer verifies.
  EXPECT_EQ(own.compute_data_checksum(), own.info().data_checksum);
}

TEST(ShardReader, OwnChunkDecodingFindsADamagedChunkAsHdf5Does) {
  fs::path dir = fresh_dir("own_decode_bad");
  testing::write_synthetic_shard(dir / "s.h5", 6, 128, 128, 2, 3);
  // Flip bytes in the middle of the file, where chunk data lies.
  {
    std::fstream f(dir / "s.h5", std::ios::in | std::ios::out | std::ios::binary);
    auto mid = std::streamoff(fs::file_size(dir / "s.h5") / 2);
    for (int i = 0; i < 16; ++i) {
      f.seekg(mid + i);
      char c = 0;
      f.get(c);
      f.seekp(mid + i);
      f.put(char(c ^ 0xA5));
    }
  }
  for (bool direct : {true, false}) {
    ShardReader r(dir / "s.h5", ShardReaderOptions{direct});
    try {
      for (int f = 0; f < r.frame_count(); ++f)
        for (const BufferInfo& b : buffer_infos())
          r.read_crop(b.name, f, 1, ShardReader::kAllVersions, Rect{0, 0, 128, 128});
      FAIL() << "a damaged chunk was read without error (direct " << direct << ")";
    } catch (const RuntimeError& e) {
      std::string msg = e.what();
      EXPECT_EQ(msg.rfind("shard " + (dir / "s.h5").string() + ": ", 0), 0u) << msg;
    }
  }
}

}  // namespace
}  // namespace dofarm::trainer
