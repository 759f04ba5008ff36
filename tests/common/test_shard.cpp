// The dofarm.shard/2 format (and reading /1): writer, reader, checksums, manifest and inspect.
#include <gtest/gtest.h>
#include <hdf5.h>
#include <hdf5_hl.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "common/checksum.h"
#include "common/inspect.h"
#include "common/manifest.h"
#include "common/shard.h"

namespace dofarm {
namespace {
namespace fs = std::filesystem;

// 70x50 is deliberately not a multiple of the 64-pixel chunk edge, so edge
// chunks are partial in both directions.
constexpr int kW = 70, kH = 50, kV = 2, kFirstFrame = 10, kFrames = 3;

// A fresh, empty folder per test.
class TempDir {
 public:
  TempDir() {
    const auto* t = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = fs::temp_directory_path() / ("dofarm_shard_" + std::to_string(::getpid()) + "_" +
                                         t->test_suite_name() + "_" + t->name());
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  const fs::path& path() const { return path_; }
  std::vector<std::string> files() const {
    std::vector<std::string> out;
    for (const auto& e : fs::directory_iterator(path_)) out.push_back(e.path().filename());
    return out;
  }

 private:
  fs::path path_;
};

// Every value of every buffer is distinct (buffer, frame and element are all
// encoded), so any misplaced crop, swapped version or swapped frame shows.
// Integers below 2^24 are exact in float32.
FrameBuffers make_frame(int frame) {
  FrameBuffers fb;
  fb.allocate(kW, kH, kV);
  fb.rect = {0, 0, kW, kH};
  int bi = 0;
  for (const BufferInfo& b : buffer_infos()) {
    std::vector<float>& d = buffer_data(fb, b.name);
    for (size_t i = 0; i < d.size(); ++i) d[i] = float(bi * 1000000 + frame * 40000 + int(i));
    ++bi;
  }
  fb.camera.frame = frame;
  fb.camera.time = frame / 24.0f;
  fb.camera.position[0] = 0.5f * frame;
  fb.camera.position[1] = 1.0f;
  fb.camera.position[2] = 3.6f;
  fb.camera.rotation[0] = 0.9238795f;
  fb.camera.rotation[2] = 0.3826834f;
  fb.camera.fov_deg = 40.0f + frame;
  fb.camera.focal_distance = 3.6f;
  fb.camera.aperture = 0.05f;
  return fb;
}

std::vector<FrameBuffers> make_frames() {
  std::vector<FrameBuffers> frames;
  for (int f = 0; f < kFrames; ++f) frames.push_back(make_frame(kFirstFrame + f));
  return frames;
}

ShardInfo make_info() {
  ShardInfo info;
  info.batch_id = "batch-7f3a";
  info.scene_id = "cornell";
  info.scene_hash = "xxh64:00000000deadbeef";
  info.job_hash = "0123456789abcdef0123456789abcdef";
  info.width = kW;
  info.height = kH;
  info.versions = kV;
  info.spp_reference = 1024;
  info.spp_albedo_ref = 24;
  info.seed = 0xFEDCBA9876543210ull;  // above 2^63: checks the unsigned attribute
  info.frame_start = kFirstFrame;
  info.frame_end = kFirstFrame + kFrames - 1;
  info.renderer_version = "0.1.0";
  info.render_seconds = 12.5;
  return info;
}

// Expected crop of a full-frame buffer, computed independently of HDF5.
std::vector<float> crop_of(const FrameBuffers& fb, const std::string& name, int version, Rect r) {
  const BufferInfo* b = nullptr;
  for (const BufferInfo& x : buffer_infos())
    if (name == x.name) b = &x;
  const std::vector<float>& d = buffer_data(fb, name);
  std::vector<float> out;
  int v0 = b->per_version && version >= 0 ? version : 0;
  int v1 = b->per_version ? (version >= 0 ? version + 1 : fb.versions) : 1;
  for (int v = v0; v < v1; ++v)
    for (int c = 0; c < b->channels; ++c)
      for (int y = r.y; y < r.y + r.h; ++y)
        for (int x = r.x; x < r.x + r.w; ++x)
          out.push_back(d[((size_t(v) * b->channels + c) * fb.height + y) * fb.width + x]);
  return out;
}

// Raw HDF5 access for checks and for forging bad files; the test takes the
// process-wide HDF5 mutex like any other HDF5 user.
struct RawFile {
  explicit RawFile(const fs::path& p, unsigned flags = H5F_ACC_RDONLY) : lock(hdf5_mutex()) {
    id = H5Fopen(p.c_str(), flags, H5P_DEFAULT);
  }
  ~RawFile() {
    if (id >= 0) H5Fclose(id);
  }
  std::lock_guard<std::recursive_mutex> lock;
  hid_t id = -1;
};

// --- checksum -----------------------------------------------------------------

TEST(Checksum, MatchesPublishedXxh64Vectors) {
  // Values from the xxHash reference implementation (seed 0); the 39-byte
  // input exercises the 32-byte stripe loop, the others only the tail.
  EXPECT_EQ(checksum64("", 0), 0xEF46DB3751D8E999ull);
  EXPECT_EQ(checksum64("a", 1), 0xD24EC4F1A98C6E5Bull);
  EXPECT_EQ(checksum64("abc", 3), 0x44BC2CF5AD770999ull);
  const std::string s = "Nobody inspects the spammish repetition";
  EXPECT_EQ(checksum64(s.data(), s.size()), 0xFBCEA83C8A378BF1ull);
}

TEST(Checksum, StreamingEqualsOneShotForEverySplit) {
  std::string data;
  for (int i = 0; i < 150; ++i) data += char(i * 37 + 11);
  for (size_t n = 0; n <= data.size(); n += 7) {
    uint64_t one = checksum64(data.data(), n);
    for (size_t cut = 0; cut <= n; ++cut) {
      Checksum64 c;
      c.update(data.data(), cut);
      c.update(data.data() + cut, 0);
      c.update(data.data() + cut, n - cut);
      ASSERT_EQ(c.digest(), one) << "length " << n << " split at " << cut;
    }
  }
}

TEST(Checksum, OneFlippedBitChangesIt) {
  std::vector<unsigned char> data(4096, 0x5a);
  uint64_t before = checksum64(data.data(), data.size());
  data[2000] ^= 0x10;
  EXPECT_NE(checksum64(data.data(), data.size()), before);
}

TEST(Checksum, TextFormRoundTripsAndRejectsJunk) {
  EXPECT_EQ(checksum_to_string(0x00ab00cd00ef0012ull), "xxh64:00ab00cd00ef0012");
  EXPECT_EQ(parse_checksum("xxh64:00ab00cd00ef0012"), 0x00ab00cd00ef0012ull);
  EXPECT_FALSE(parse_checksum("xxh64:00ab00cd00ef001"));   // too short
  EXPECT_FALSE(parse_checksum("xxh64:00AB00CD00EF0012"));  // upper case is not the form
  EXPECT_FALSE(parse_checksum("crc32:00ab00cd00ef0012"));
}

TEST(Checksum, FileChecksumEqualsChecksumOfContents) {
  TempDir dir;
  std::string data(3 << 20, 'x');  // spans several read blocks
  for (size_t i = 0; i < data.size(); i += 4099) data[i] = char(i);
  std::ofstream(dir.path() / "blob", std::ios::binary) << data;
  EXPECT_EQ(checksum_file(dir.path() / "blob"), checksum64(data.data(), data.size()));
  EXPECT_THROW(checksum_file(dir.path() / "missing"), RuntimeError);
}

// --- shard ----------------------------------------------------------------------

TEST(Shard, FullFramesReadBackBitForBit) {
  TempDir dir;
  auto frames = make_frames();
  ShardWriteResult res = write_shard(dir.path() / "shard-00000.h5", make_info(), frames);
  EXPECT_EQ(res.file_size, fs::file_size(dir.path() / "shard-00000.h5"));
  EXPECT_EQ(res.file_checksum, checksum_file(dir.path() / "shard-00000.h5"));
  EXPECT_EQ(dir.files(), std::vector<std::string>{"shard-00000.h5"});  // no temp left

  ShardReader r(dir.path() / "shard-00000.h5");
  ASSERT_EQ(r.frame_count(), kFrames);
  for (int f = 0; f < kFrames; ++f) {
    FrameBuffers got = r.read_frame(f);
    EXPECT_EQ(got.width, kW);
    EXPECT_EQ(got.height, kH);
    EXPECT_EQ(got.versions, kV);
    for (const BufferInfo& b : buffer_infos())
      // Bit for bit: memcmp, not float comparison.
      ASSERT_EQ(0,
                std::memcmp(buffer_data(got, b.name).data(), buffer_data(frames[f], b.name).data(),
                            buffer_data(frames[f], b.name).size() * sizeof(float)))
          << "frame " << f << " buffer " << b.name;
    const CameraState& c = got.camera;
    const CameraState& e = frames[f].camera;
    EXPECT_EQ(c.frame, e.frame);
    EXPECT_EQ(c.time, e.time);
    EXPECT_EQ(c.position[0], e.position[0]);
    EXPECT_EQ(c.rotation[2], e.rotation[2]);
    EXPECT_EQ(c.fov_deg, e.fov_deg);
    EXPECT_EQ(c.aperture, e.aperture);
  }
  EXPECT_EQ(r.compute_data_checksum(), res.data_checksum);
  EXPECT_EQ(r.info().data_checksum, res.data_checksum);
}

TEST(Shard, ReadFrameOfNamedBuffersLeavesOthersEmpty) {
  TempDir dir;
  auto frames = make_frames();
  write_shard(dir.path() / "s.h5", make_info(), frames);
  ShardReader r(dir.path() / "s.h5");
  FrameBuffers got = r.read_frame(2, {"depth", "noisy"});
  EXPECT_EQ(got.depth, frames[2].depth);
  EXPECT_EQ(got.noisy, frames[2].noisy);
  EXPECT_TRUE(got.reference.empty());
  EXPECT_EQ(got.camera.frame, kFirstFrame + 2);
  EXPECT_THROW(r.read_frame(0, {"nosuchbuffer"}), RuntimeError);
}

TEST(Shard, CropsAtEdgesAndAcrossChunksMatchTheFrames) {
  TempDir dir;
  auto frames = make_frames();
  write_shard(dir.path() / "s.h5", make_info(), frames);
  ShardReader r(dir.path() / "s.h5");
  const Rect rects[] = {{6, 0, 64, 50},  // touches the right edge and spans both column chunks
                        {64, 48, 6, 2},  // the bottom-right corner: the partial chunk only
                        {0, 0, 1, 1},
                        {60, 10, 8, 30},
                        {0, 0, kW, kH}};
  for (const Rect& rc : rects) {
    for (const char* name : {"noisy", "albedo", "reference", "depth", "normal"}) {
      for (int version : {0, 1, ShardReader::kAllVersions}) {
        std::vector<float> got = r.read_crop(name, 1, 2, version, rc);
        std::vector<float> want = crop_of(frames[1], name, version, rc);
        std::vector<float> next = crop_of(frames[2], name, version, rc);
        want.insert(want.end(), next.begin(), next.end());
        ASSERT_EQ(got, want) << name << " version " << version << " rect " << rc.x << "," << rc.y
                             << "," << rc.w << "," << rc.h;
        EXPECT_EQ(got.size(), r.crop_size(name, 2, version, rc));
      }
    }
  }
}

// The trainer's background readers share readers across threads; the
// process-wide HDF5 mutex must keep every crop intact.
TEST(Shard, ConcurrentCropsFromSeveralThreadsAreIntact) {
  TempDir dir;
  auto frames = make_frames();
  write_shard(dir.path() / "s.h5", make_info(), frames);
  ShardReader r(dir.path() / "s.h5");
  std::atomic<int> wrong{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([&, t] {
      for (int k = 0; k < 25; ++k) {
        Rect rc{(t * 7 + k * 3) % 40, (k * 5) % 20, 30, 30};
        int version = (t + k) % kV;
        if (r.read_crop("noisy", 2, 1, version, rc) != crop_of(frames[2], "noisy", version, rc))
          ++wrong;
      }
    });
  for (std::thread& th : threads) th.join();
  EXPECT_EQ(wrong.load(), 0);
}

TEST(Shard, AttributesRoundTrip) {
  TempDir dir;
  ShardInfo in = make_info();
  in.reference_error = 0.01f;
  write_shard(dir.path() / "s.h5", in, make_frames());
  ShardReader r(dir.path() / "s.h5");
  const ShardInfo& out = r.info();
  EXPECT_EQ(out.schema, "dofarm.shard/2");
  EXPECT_EQ(out.batch_id, in.batch_id);
  EXPECT_EQ(out.scene_id, in.scene_id);
  EXPECT_EQ(out.scene_hash, in.scene_hash);
  EXPECT_EQ(out.job_hash, in.job_hash);
  EXPECT_EQ(out.width, kW);
  EXPECT_EQ(out.height, kH);
  EXPECT_EQ(out.versions, kV);
  EXPECT_EQ(out.spp_noisy, 1);
  EXPECT_EQ(out.spp_reference, 1024);
  EXPECT_EQ(out.reference_error, 0.01f);
  EXPECT_EQ(out.spp_albedo_ref, 24);
  EXPECT_EQ(out.seed, in.seed);
  EXPECT_EQ(out.frame_start, kFirstFrame);
  EXPECT_EQ(out.frame_end, kFirstFrame + kFrames - 1);
  EXPECT_EQ(out.renderer_version, "0.1.0");
  EXPECT_EQ(out.render_seconds, 12.5);
  EXPECT_GE(out.pack_seconds, 0.0);
  // ISO 8601 UTC, e.g. 2024-05-01T12:00:00Z
  ASSERT_EQ(out.created.size(), 20u);
  EXPECT_EQ(out.created[10], 'T');
  EXPECT_EQ(out.created.back(), 'Z');
  std::vector<CameraState> cams = r.cameras();
  ASSERT_EQ(cams.size(), size_t(kFrames));
  EXPECT_EQ(cams[1].frame, kFirstFrame + 1);
  EXPECT_EQ(cams[1].fov_deg, 40.0f + kFirstFrame + 1);
}

std::vector<hsize_t> chunk_dims(hid_t file, const char* name, std::vector<H5Z_filter_t>* filters) {
  hid_t ds = H5Dopen2(file, name, H5P_DEFAULT);
  hid_t dcpl = H5Dget_create_plist(ds);
  std::vector<hsize_t> dims(8);
  int rank = H5Pget_chunk(dcpl, 8, dims.data());
  dims.resize(rank > 0 ? rank : 0);
  int n = H5Pget_nfilters(dcpl);
  for (int i = 0; i < n; ++i) {
    unsigned flags = 0;
    size_t nelmts = 0;
    char fname[64];
    filters->push_back(
        H5Pget_filter2(dcpl, i, &flags, &nelmts, nullptr, sizeof fname, fname, nullptr));
  }
  H5Pclose(dcpl);
  H5Dclose(ds);
  return dims;
}

TEST(Shard, ChunksAreOneFrameVersionAndTileWithLosslessFilters) {
  TempDir dir;
  write_shard(dir.path() / "s.h5", make_info(), make_frames());
  RawFile f(dir.path() / "s.h5");
  ASSERT_GE(f.id, 0);
  const std::vector<H5Z_filter_t> pipeline = {H5Z_FILTER_SHUFFLE, H5Z_FILTER_DEFLATE,
                                              H5Z_FILTER_FLETCHER32};
  std::vector<H5Z_filter_t> filters;
  // 64 wide, clipped to the 50-pixel height.
  EXPECT_EQ(chunk_dims(f.id, "noisy", &filters), (std::vector<hsize_t>{1, 1, 3, 50, 64}));
  EXPECT_EQ(filters, pipeline);
  filters.clear();
  EXPECT_EQ(chunk_dims(f.id, "reference", &filters), (std::vector<hsize_t>{1, 3, 50, 64}));
  EXPECT_EQ(filters, pipeline);
  filters.clear();
  EXPECT_EQ(chunk_dims(f.id, "coc", &filters), (std::vector<hsize_t>{1, 1, 50, 64}));
  filters.clear();
  EXPECT_EQ(chunk_dims(f.id, "camera", &filters), (std::vector<hsize_t>{kFrames, 12}));
}

TEST(Shard, DatasetsCarryChannelAndColumnNames) {
  TempDir dir;
  write_shard(dir.path() / "s.h5", make_info(), make_frames());
  RawFile f(dir.path() / "s.h5");
  auto attr = [&](const char* ds, const char* name) {
    hid_t d = H5Dopen2(f.id, ds, H5P_DEFAULT);
    hid_t a = H5Aopen(d, name, H5P_DEFAULT);
    hid_t t = H5Aget_type(a);
    char* s = nullptr;
    H5Aread(a, t, &s);
    std::string out = s ? s : "";
    H5free_memory(s);
    H5Tclose(t);
    H5Aclose(a);
    H5Dclose(d);
    return out;
  };
  EXPECT_EQ(attr("noisy", "channels"), "R,G,B");
  EXPECT_EQ(attr("noisy", "dims"), "frame,version,channel,y,x");
  EXPECT_EQ(attr("normal", "channels"), "X,Y,Z");
  EXPECT_EQ(attr("depth", "channels"), "Y");
  EXPECT_EQ(attr("camera", "columns"),
            "frame,time,position_x,position_y,position_z,rotation_w,rotation_x,rotation_y,"
            "rotation_z,fov_deg,focal_distance,aperture");
}

// Every dimension of every dataset has a label and one attached dimension
// scale (H5DS) holding its coordinates, so h5py shows ds.dims[i].label and
// netCDF-4/h5netcdf (xarray) name the axes. Read back with the HDF5 API.
TEST(Shard, EveryDimensionHasALabelAndAScale) {
  TempDir dir;
  write_shard(dir.path() / "s.h5", make_info(), make_frames());
  RawFile f(dir.path() / "s.h5");
  ASSERT_GE(f.id, 0);
  auto scale_name = [&](hid_t ds, unsigned dim) {
    std::string name;
    H5DSiterate_scales(
        ds, dim, nullptr,
        [](hid_t, unsigned, hid_t scale, void* out) -> herr_t {
          char buf[64] = {0};
          H5DSget_scale_name(scale, buf, sizeof buf);
          *static_cast<std::string*>(out) = buf;
          return 1;  // the first scale is enough
        },
        &name);
    return name;
  };
  auto check = [&](const char* dataset, const std::vector<std::string>& labels,
                   const std::vector<std::string>& scales) {
    hid_t ds = H5Dopen2(f.id, dataset, H5P_DEFAULT);
    ASSERT_GE(ds, 0) << dataset;
    for (unsigned d = 0; d < labels.size(); ++d) {
      char label[64] = {0};
      ASSERT_GT(H5DSget_label(ds, d, label, sizeof label), 0) << dataset << " dim " << d;
      EXPECT_EQ(label, labels[d]) << dataset << " dim " << d;
      EXPECT_EQ(H5DSget_num_scales(ds, d), 1) << dataset << " dim " << d;
      EXPECT_EQ(scale_name(ds, d), scales[d]) << dataset << " dim " << d;
    }
    H5Dclose(ds);
  };
  check("noisy", {"frame", "version", "channel", "y", "x"},
        {"frame", "version", "channel_rgb", "y", "x"});
  check("albedo", {"frame", "version", "channel", "y", "x"},
        {"frame", "version", "channel_rgb", "y", "x"});
  check("reference", {"frame", "channel", "y", "x"}, {"frame", "channel_rgb", "y", "x"});
  check("normal", {"frame", "channel", "y", "x"}, {"frame", "channel_xyz", "y", "x"});
  check("depth", {"frame", "channel", "y", "x"}, {"frame", "channel_y", "y", "x"});
  check("coc", {"frame", "channel", "y", "x"}, {"frame", "channel_y", "y", "x"});
  check("camera", {"frame", "column"}, {"frame", "column"});

  // The scales hold the coordinates: absolute frame numbers, indices, names.
  auto ints = [&](const char* name) {
    hid_t ds = H5Dopen2(f.id, name, H5P_DEFAULT);
    EXPECT_GT(H5DSis_scale(ds), 0) << name;
    hid_t space = H5Dget_space(ds);
    std::vector<int64_t> v(size_t(H5Sget_simple_extent_npoints(space)));
    H5Dread(ds, H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data());
    H5Sclose(space);
    H5Dclose(ds);
    return v;
  };
  auto strings = [&](const char* name) {
    hid_t ds = H5Dopen2(f.id, name, H5P_DEFAULT);
    EXPECT_GT(H5DSis_scale(ds), 0) << name;
    hid_t space = H5Dget_space(ds);
    std::vector<char*> p(size_t(H5Sget_simple_extent_npoints(space)));
    hid_t t = H5Dget_type(ds);
    H5Dread(ds, t, H5S_ALL, H5S_ALL, H5P_DEFAULT, p.data());
    std::vector<std::string> out(p.begin(), p.end());
    H5Dvlen_reclaim(t, space, H5P_DEFAULT, p.data());
    H5Tclose(t);
    H5Sclose(space);
    H5Dclose(ds);
    return out;
  };
  EXPECT_EQ(ints("frame"), (std::vector<int64_t>{kFirstFrame, kFirstFrame + 1, kFirstFrame + 2}));
  EXPECT_EQ(ints("version"), (std::vector<int64_t>{0, 1}));
  const std::vector<int64_t> ys = ints("y"), xs = ints("x");
  ASSERT_EQ(ys.size(), size_t(kH));
  ASSERT_EQ(xs.size(), size_t(kW));
  EXPECT_EQ(ys.back(), kH - 1);
  EXPECT_EQ(xs.back(), kW - 1);
  EXPECT_EQ(strings("channel_rgb"), (std::vector<std::string>{"R", "G", "B"}));
  EXPECT_EQ(strings("channel_xyz"), (std::vector<std::string>{"X", "Y", "Z"}));
  EXPECT_EQ(strings("channel_y"), (std::vector<std::string>{"Y"}));
  const std::vector<std::string> columns = strings("column");
  ASSERT_EQ(columns.size(), size_t(kCameraColumns));
  EXPECT_EQ(columns.front(), "frame");
  EXPECT_EQ(columns.back(), "aperture");
}

// h5dump (Debian's hdf5-tools) shows the labels and the scales; only run
// where it is installed.
TEST(Shard, H5dumpShowsDimensionLabels) {
  if (std::system("command -v h5dump >/dev/null 2>&1") != 0) GTEST_SKIP() << "h5dump not installed";
  TempDir dir;
  const fs::path shard = dir.path() / "s.h5", dump = dir.path() / "dump.txt";
  write_shard(shard, make_info(), make_frames());
  ASSERT_EQ(std::system(
                ("h5dump -A -d noisy '" + shard.string() + "' > '" + dump.string() + "'").c_str()),
            0);
  std::ifstream in(dump);
  std::stringstream text;
  text << in.rdbuf();
  const std::string out = text.str();
  EXPECT_NE(out.find("DIMENSION_LABELS"), std::string::npos) << out;
  EXPECT_NE(out.find("\"frame\", \"version\", \"channel\", \"y\", \"x\""), std::string::npos)
      << out;
  EXPECT_NE(out.find("DIMENSION_LIST"), std::string::npos) << out;
}

// Replaces the shard's schema attribute (and drops job_hash when asked), as
// an older or newer writer would have left it.
void set_schema(const fs::path& p, const char* schema, bool drop_job_hash) {
  RawFile f(p, H5F_ACC_RDWR);
  ASSERT_GE(H5Adelete(f.id, "schema"), 0);
  if (drop_job_hash) ASSERT_GE(H5Adelete(f.id, "job_hash"), 0);
  hid_t t = H5Tcopy(H5T_C_S1);
  H5Tset_size(t, H5T_VARIABLE);
  hid_t s = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(f.id, "schema", t, s, H5P_DEFAULT, H5P_DEFAULT);
  ASSERT_GE(H5Awrite(a, t, &schema), 0);
  H5Aclose(a);
  H5Sclose(s);
  H5Tclose(t);
}

TEST(Shard, UnknownSchemaVersionIsRefusedByName) {
  TempDir dir;
  fs::path p = dir.path() / "s.h5";
  write_shard(p, make_info(), make_frames());
  set_schema(p, "dofarm.shard/3", false);
  try {
    ShardReader r(p);
    FAIL() << "a dofarm.shard/3 file was accepted";
  } catch (const ShardFormatError& e) {
    EXPECT_EQ(std::string(e.what()), "shard " + p.string() +
                                         ": schema 'dofarm.shard/3' is not supported (this build "
                                         "reads dofarm.shard/2 and dofarm.shard/1)");
  }
}

TEST(Shard, VersionOneShardsWithoutJobHashStillRead) {
  TempDir dir;
  fs::path p = dir.path() / "s.h5";
  auto frames = make_frames();
  write_shard(p, make_info(), frames);
  set_schema(p, "dofarm.shard/1", true);
  ShardReader r(p);
  EXPECT_EQ(r.info().schema, "dofarm.shard/1");
  EXPECT_EQ(r.info().job_hash, "");
  EXPECT_EQ(r.info().scene_hash, make_info().scene_hash);
  EXPECT_EQ(r.frame_count(), int(frames.size()));
}

// Shards written before the reference halves existed have no
// `reference_half`: they still read, with that buffer empty, and every
// other buffer as written; a missing required dataset is still an error.
TEST(Shard, ShardWithoutAnOptionalBufferStillReads) {
  TempDir dir;
  fs::path p = dir.path() / "s.h5";
  auto frames = make_frames();
  write_shard(p, make_info(), frames);
  {
    RawFile f(p, H5F_ACC_RDWR);
    ASSERT_GE(H5Ldelete(f.id, "reference_half", H5P_DEFAULT), 0);
  }
  {
    ShardReader r(p);
    FrameBuffers got = r.read_frame(1);
    EXPECT_TRUE(got.reference_half.empty());
    EXPECT_EQ(got.reference, frames[1].reference);
    EXPECT_EQ(got.coc, frames[1].coc);
    for (const auto& l : r.layout()) EXPECT_NE(l.name, "reference_half");
  }
  {
    RawFile f(p, H5F_ACC_RDWR);
    ASSERT_GE(H5Ldelete(f.id, "reference_var", H5P_DEFAULT), 0);
  }
  try {
    ShardReader bad(p);
    ADD_FAILURE() << "a shard without reference_var was read";
  } catch (const ShardFormatError& e) {
    EXPECT_NE(std::string(e.what()).find("'reference_var' is missing"), std::string::npos)
        << e.what();
  }
}

TEST(Shard, NonHdf5FileIsNotAShard) {
  TempDir dir;
  std::ofstream(dir.path() / "notes.h5") << "this is not HDF5\n";
  EXPECT_THROW(ShardReader(dir.path() / "notes.h5"), ShardFormatError);
  try {
    ShardReader r(dir.path() / "missing.h5");
    FAIL();
  } catch (const ShardFormatError&) {
    FAIL() << "a missing file is an IO error, not a format error";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("missing.h5: no such file"), std::string::npos);
  }
}

TEST(Shard, TruncatedFileGivesClearError) {
  TempDir dir;
  fs::path p = dir.path() / "s.h5";
  write_shard(p, make_info(), make_frames());
  fs::resize_file(p, fs::file_size(p) / 2);
  try {
    ShardReader r(p);
    r.compute_data_checksum();
    FAIL() << "a truncated shard was read";
  } catch (const ShardFormatError& e) {
    FAIL() << "truncation is an IO error: " << e.what();
  } catch (const RuntimeError& e) {
    std::string msg = e.what();
    EXPECT_EQ(msg.rfind("shard " + p.string() + ": ", 0), 0u) << msg;  // names the file first
    EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;        // and says what failed
  }
}

// Overwrites `n` bytes in the middle of the file, where the chunk data lies.
void corrupt_middle(const fs::path& p, int n) {
  std::fstream f(p, std::ios::in | std::ios::out | std::ios::binary);
  auto mid = std::streamoff(fs::file_size(p) / 2);
  for (int i = 0; i < n; ++i) {
    f.seekg(mid + i);
    char c = 0;
    f.get(c);
    f.seekp(mid + i);
    f.put(char(c ^ 0xA5));
  }
}

TEST(Shard, CorruptedChunkFailsTheReadNamingTheFile) {
  TempDir dir;
  fs::path p = dir.path() / "s.h5";
  write_shard(p, make_info(), make_frames());
  corrupt_middle(p, 16);
  try {
    ShardReader r(p);
    r.compute_data_checksum();  // reads every chunk
    FAIL() << "a corrupted shard was read without error";
  } catch (const RuntimeError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("shard " + p.string() + ": ", 0), 0u) << e.what();
  }
}

TEST(Shard, NanInputIsRefusedAndLeavesNoFile) {
  TempDir dir;
  auto frames = make_frames();
  frames[1].albedo[2 * kW * kH + 5 * kW + 7] = std::numeric_limits<float>::quiet_NaN();
  try {
    write_shard(dir.path() / "s.h5", make_info(), frames);
    FAIL() << "NaN was written";
  } catch (const RuntimeError& e) {
    std::string msg = e.what();
    EXPECT_NE(msg.find("frame 11, buffer 'albedo'"), std::string::npos) << msg;
    EXPECT_NE(msg.find("channel 2, x 7, y 5"), std::string::npos) << msg;
  }
  EXPECT_TRUE(dir.files().empty());
}

TEST(Shard, StreamingWriterRemovesTempOnInfAndOnAbandon) {
  TempDir dir;
  auto frames = make_frames();
  frames[2].depth[3] = std::numeric_limits<float>::infinity();
  {
    ShardWriter w(dir.path() / "s.h5", make_info());
    EXPECT_TRUE(fs::exists(w.temp_path()));
    w.add_frame(frames[0]);
    w.add_frame(frames[1]);
    EXPECT_THROW(w.add_frame(frames[2]), RuntimeError);
    EXPECT_TRUE(dir.files().empty());
    EXPECT_THROW(w.commit(), RuntimeError);  // an abandoned writer stays abandoned
  }
  {
    ShardWriter w(dir.path() / "s.h5", make_info());
    w.add_frame(make_frame(kFirstFrame));
    EXPECT_THROW(w.commit(), RuntimeError);  // 1 of 3 frames
  }
  {
    ShardWriter w(dir.path() / "s.h5", make_info());
    w.add_frame(make_frame(kFirstFrame));
  }  // destroyed without commit
  EXPECT_TRUE(dir.files().empty());
}

TEST(Shard, WrongFrameSizeIsRefused) {
  TempDir dir;
  FrameBuffers small;
  small.allocate(kW - 1, kH, kV);
  ShardWriter w(dir.path() / "s.h5", make_info());
  EXPECT_THROW(w.add_frame(small), RuntimeError);
  w.abort();
  EXPECT_TRUE(dir.files().empty());
}

// --- manifest ---------------------------------------------------------------------

// Writes shard `index` of the test batch into `dir` and lists it.
ManifestEntry write_and_list(const fs::path& dir, int index) {
  ShardInfo info = make_info();
  info.frame_start = kFirstFrame + index * kFrames;
  info.frame_end = info.frame_start + kFrames - 1;
  std::vector<FrameBuffers> frames;
  for (int f = info.frame_start; f <= info.frame_end; ++f) frames.push_back(make_frame(f));
  char name[32];
  std::snprintf(name, sizeof name, "shard-%05d.h5", index);
  ShardWriteResult res = write_shard(dir / name, info, frames);
  ManifestEntry e = manifest_entry(info, res);
  add_to_manifest(dir, e);
  return e;
}

TEST(Manifest, AbsentManifestIsEmpty) {
  TempDir dir;
  EXPECT_TRUE(load_manifest(dir.path()).shards.empty());
  EXPECT_TRUE(verify_manifest(dir.path()).empty());
}

TEST(Manifest, AddLoadAndVerifyShards) {
  TempDir dir;
  ManifestEntry b = write_and_list(dir.path(), 1);
  ManifestEntry a = write_and_list(dir.path(), 0);
  Manifest m = load_manifest(dir.path());
  ASSERT_EQ(m.shards.size(), 2u);
  EXPECT_EQ(m.shards[0], a);  // sorted by file name
  EXPECT_EQ(m.shards[1], b);
  EXPECT_EQ(a.file, "shard-00000.h5");
  EXPECT_EQ(b.frame_start, kFirstFrame + kFrames);
  EXPECT_EQ(b.frame_end, kFirstFrame + 2 * kFrames - 1);
  EXPECT_EQ(a.scene_id, "cornell");
  EXPECT_EQ(a.size, fs::file_size(dir.path() / a.file));
  EXPECT_EQ(a.checksum, checksum_file(dir.path() / a.file));
  EXPECT_TRUE(verify_manifest(dir.path()).empty());
  // Listing the same shard again (a retried pack job) replaces, not duplicates.
  add_to_manifest(dir.path(), a);
  EXPECT_EQ(load_manifest(dir.path()).shards.size(), 2u);
  for (const std::string& f : dir.files())  // no temporary files left behind
    EXPECT_EQ(f.find(".tmp-"), std::string::npos) << f;
}

TEST(Manifest, VerifyCatchesCorruptionMissingAndResizedShards) {
  TempDir dir;
  ManifestEntry a = write_and_list(dir.path(), 0);
  ManifestEntry b = write_and_list(dir.path(), 1);
  ManifestEntry c = write_and_list(dir.path(), 2);
  corrupt_middle(dir.path() / a.file, 4);  // same size: only the checksum sees it
  fs::remove(dir.path() / b.file);
  fs::resize_file(dir.path() / c.file, c.size + 10);
  std::vector<ManifestProblem> problems = verify_manifest(dir.path());
  ASSERT_EQ(problems.size(), 3u);
  EXPECT_EQ(problems[0].file, a.file);
  EXPECT_EQ(problems[0].problem.rfind("checksum ", 0), 0u) << problems[0].problem;
  EXPECT_EQ(problems[1].file, b.file);
  EXPECT_EQ(problems[1].problem.rfind("missing", 0), 0u) << problems[1].problem;
  EXPECT_EQ(problems[2].file, c.file);
  EXPECT_EQ(problems[2].problem.rfind("size ", 0), 0u) << problems[2].problem;
  // Without checksums only the cheap checks run, so the corruption passes.
  EXPECT_EQ(verify_manifest(dir.path(), false).size(), 2u);
}

TEST(Manifest, MalformedManifestNamesTheKey) {
  TempDir dir;
  write_and_list(dir.path(), 0);
  fs::path p = dir.path() / kManifestFile;
  std::ifstream in(p);
  nlohmann::json j = nlohmann::json::parse(in);
  j["shards"][0]["checksum"] = "12345";
  std::ofstream(p) << j.dump();
  try {
    load_manifest(dir.path());
    FAIL() << "bad checksum accepted";
  } catch (const RuntimeError& e) {
    EXPECT_NE(std::string(e.what()).find("shards[0].checksum"), std::string::npos) << e.what();
  }
  std::ofstream(p) << R"({"schema": "dofarm.manifest/9", "shards": []})";
  EXPECT_THROW(load_manifest(dir.path()), RuntimeError);
  std::ofstream(p) << R"({"schema": "dofarm.manifest/1", "shards": [{"file": "../x.h5"}]})";
  EXPECT_THROW(load_manifest(dir.path()), RuntimeError);
}

// --- inspect ----------------------------------------------------------------------

TEST(Inspect, TextReportHasShapesStatsAndNoNonFiniteValues) {
  TempDir dir;
  write_shard(dir.path() / "s.h5", make_info(), make_frames());
  std::ostringstream out, err;
  EXPECT_EQ(inspect_shard(dir.path() / "s.h5", false, out, err), kExitOk) << err.str();
  std::string s = out.str();
  EXPECT_NE(s.find("dofarm.shard/2"), std::string::npos) << s;
  EXPECT_NE(s.find("3x2x3x50x70"), std::string::npos) << s;  // noisy shape
  EXPECT_NE(s.find("1x1x3x50x64"), std::string::npos) << s;  // noisy chunk
  EXPECT_NE(s.find("shuffle,deflate(4),fletcher32"), std::string::npos) << s;
  EXPECT_NE(s.find("non-finite values: 0"), std::string::npos) << s;
  EXPECT_NE(s.find(" ok\n"), std::string::npos) << s;
}

TEST(Inspect, JsonReportParsesAndHoldsExactStatistics) {
  TempDir dir;
  auto frames = make_frames();
  write_shard(dir.path() / "s.h5", make_info(), frames);
  std::ostringstream out, err;
  ASSERT_EQ(inspect_shard(dir.path() / "s.h5", true, out, err), kExitOk) << err.str();
  nlohmann::json j = nlohmann::json::parse(out.str());
  EXPECT_EQ(j["attributes"]["schema"], "dofarm.shard/2");
  EXPECT_EQ(j["attributes"]["job_hash"], make_info().job_hash);
  EXPECT_EQ(j["frames"], kFrames);
  EXPECT_EQ(j["non_finite"], 0);
  EXPECT_TRUE(j["data_checksum"]["ok"].get<bool>());
  // depth is buffer 6: value 6e6 + frame * 40000 + i over i < W*H, frames 10..12.
  const nlohmann::json* depth = nullptr;
  for (const auto& d : j["datasets"])
    if (d["name"] == "depth") depth = &d;
  ASSERT_NE(depth, nullptr);
  const auto& c = (*depth)["channels"][0];
  EXPECT_EQ(c["name"], "Y");
  EXPECT_EQ(c["min"].get<double>(), 6e6 + 10 * 40000);
  EXPECT_EQ(c["max"].get<double>(), 6e6 + 12 * 40000 + kW * kH - 1);
  EXPECT_NEAR(c["mean"].get<double>(), 6e6 + 11 * 40000 + (kW * kH - 1) / 2.0, 1e-6);
  // Independent std: over frames f in {10,11,12} and i in [0, N).
  double n = kW * kH, var_i = (n * n - 1) / 12.0, var_f = 40000.0 * 40000.0 * 2.0 / 3.0;
  EXPECT_NEAR(c["std"].get<double>(), std::sqrt(var_i + var_f), 1e-6);
  EXPECT_EQ(c["non_finite"], 0);
  EXPECT_GT((*depth)["compression_ratio"].get<double>(), 1.0);
}

TEST(Inspect, ExitCodesSayNotAShardOrIoError) {
  TempDir dir;
  std::ostringstream out, err;
  std::ofstream(dir.path() / "notes.h5") << "plain text";
  EXPECT_EQ(inspect_shard(dir.path() / "notes.h5", false, out, err), kExitBadInput);
  EXPECT_NE(err.str().find("not an HDF5 file"), std::string::npos) << err.str();
  EXPECT_EQ(inspect_shard(dir.path() / "missing.h5", false, out, err), kExitRuntime);
  write_shard(dir.path() / "s.h5", make_info(), make_frames());
  corrupt_middle(dir.path() / "s.h5", 16);
  std::ostringstream jout;
  EXPECT_EQ(inspect_shard(dir.path() / "s.h5", true, jout, err), kExitRuntime);
  EXPECT_TRUE(nlohmann::json::parse(jout.str()).contains("error")) << jout.str();
}

}  // namespace
}  // namespace dofarm
