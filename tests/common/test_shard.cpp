// The dofarm.shard/2 format (and reading /1): writer and reader. Checksums,
// the manifest and inspect: test_checksum.cpp, test_manifest.cpp,
// test_inspect.cpp; the shared batch: shard_fixtures.h.
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
#include "common/shard.h"
#include "shard_fixtures.h"

namespace dofarm {
namespace {
namespace fs = std::filesystem;
using namespace shard_testing;

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
    EXPECT_EQ(c.ortho_height, e.ortho_height);
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
  EXPECT_EQ(out.schema, "dofarm.shard/3");
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
  EXPECT_EQ(cams[0].fov_deg, 40.0f + kFirstFrame);
  EXPECT_EQ(cams[0].ortho_height, 0.0f);
  EXPECT_EQ(cams[1].fov_deg, 0.0f);  // an odd frame: orthographic
  EXPECT_EQ(cams[1].ortho_height, 2.5f);
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
  EXPECT_EQ(chunk_dims(f.id, "camera", &filters), (std::vector<hsize_t>{kFrames, 13}));
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
            "rotation_z,fov_deg,focal_distance,aperture,ortho_height");
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
  EXPECT_EQ(columns.back(), "ortho_height");
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

// Replaces the root string attribute `name` with `value`.
void replace_string_attr(const RawFile& f, const char* name, const char* value) {
  ASSERT_GE(H5Adelete(f.id, name), 0);
  hid_t t = H5Tcopy(H5T_C_S1);
  H5Tset_size(t, H5T_VARIABLE);
  hid_t s = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(f.id, name, t, s, H5P_DEFAULT, H5P_DEFAULT);
  ASSERT_GE(H5Awrite(a, t, &value), 0);
  H5Aclose(a);
  H5Sclose(s);
  H5Tclose(t);
}

// Replaces the shard's schema attribute (and drops job_hash when asked), as
// an older or newer writer would have left it.
void set_schema(const fs::path& p, const char* schema, bool drop_job_hash) {
  RawFile f(p, H5F_ACC_RDWR);
  if (drop_job_hash) {
    ASSERT_GE(H5Adelete(f.id, "job_hash"), 0);
  }
  replace_string_attr(f, "schema", schema);
}

TEST(Shard, UnknownSchemaVersionIsRefusedByName) {
  TempDir dir;
  fs::path p = dir.path() / "s.h5";
  write_shard(p, make_info(), make_frames());
  set_schema(p, "dofarm.shard/4", false);
  try {
    ShardReader r(p);
    FAIL() << "a dofarm.shard/4 file was accepted";
  } catch (const ShardFormatError& e) {
    EXPECT_EQ(std::string(e.what()),
              "shard " + p.string() +
                  ": schema 'dofarm.shard/4' is not supported (this build "
                  "reads dofarm.shard/3, dofarm.shard/2 and dofarm.shard/1)");
  }
}

// Makes a version 3 shard what a version 2 writer (or version 1, with
// `schema` so) wrote: the camera's first 12 columns, and the data checksum
// of that walk (docs/shard_format.md), computed here independently of the
// reader.
void downgrade(const fs::path& p, const char* schema, const std::vector<FrameBuffers>& frames) {
  set_schema(p, schema, std::string(schema) == "dofarm.shard/1");
  RawFile f(p, H5F_ACC_RDWR);
  ASSERT_GE(H5Ldelete(f.id, "camera", H5P_DEFAULT), 0);
  const hsize_t dims[2] = {frames.size(), hsize_t(kCameraColumnsV2)};
  std::vector<float> rows;
  Checksum64 sum;
  for (const FrameBuffers& fb : frames) {
    for (const BufferInfo& b : buffer_infos()) {
      const std::vector<float>& d = buffer_data(fb, b.name);
      sum.update(d.data(), d.size() * sizeof(float));
    }
    const auto row = camera_to_row(fb.camera);
    sum.update(row.data(), kCameraColumnsV2 * sizeof(float));
    rows.insert(rows.end(), row.begin(), row.begin() + kCameraColumnsV2);
  }
  hid_t space = H5Screate_simple(2, dims, nullptr);
  hid_t ds =
      H5Dcreate2(f.id, "camera", H5T_IEEE_F32LE, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  ASSERT_GE(H5Dwrite(ds, H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, rows.data()), 0);
  H5Dclose(ds);
  H5Sclose(space);
  replace_string_attr(f, "data_checksum", checksum_to_string(sum.digest()).c_str());
}

// Version 2 shards (12 camera columns, all frames perspective) still read:
// their cameras as written with ortho_height 0, and the data checksum over
// the 12 columns they store.
TEST(Shard, VersionTwoShardsWithTwelveCameraColumnsStillRead) {
  TempDir dir;
  fs::path p = dir.path() / "s.h5";
  auto frames = make_frames();
  for (FrameBuffers& fb : frames) fb.camera.ortho_height = 0, fb.camera.fov_deg = 35.0f;
  write_shard(p, make_info(), frames);
  downgrade(p, "dofarm.shard/2", frames);
  ShardReader r(p);
  EXPECT_EQ(r.info().schema, "dofarm.shard/2");
  EXPECT_EQ(r.compute_data_checksum(), r.info().data_checksum);
  const std::vector<CameraState> cams = r.cameras();
  ASSERT_EQ(cams.size(), frames.size());
  for (size_t f = 0; f < frames.size(); ++f) {
    EXPECT_EQ(cams[f].fov_deg, 35.0f);
    EXPECT_EQ(cams[f].aperture, frames[f].camera.aperture);
    EXPECT_EQ(cams[f].ortho_height, 0.0f);
    EXPECT_EQ(r.read_frame(int(f)).camera.position[0], frames[f].camera.position[0]);
  }
}

TEST(Shard, VersionOneShardsWithoutJobHashStillRead) {
  TempDir dir;
  fs::path p = dir.path() / "s.h5";
  auto frames = make_frames();
  for (FrameBuffers& fb : frames) fb.camera.ortho_height = 0, fb.camera.fov_deg = 35.0f;
  write_shard(p, make_info(), frames);
  downgrade(p, "dofarm.shard/1", frames);
  ShardReader r(p);
  EXPECT_EQ(r.compute_data_checksum(), r.info().data_checksum);
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

}  // namespace
}  // namespace dofarm
