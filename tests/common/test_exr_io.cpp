#include <ImfBoxAttribute.h>
#include <ImfChannelList.h>
#include <ImfFloatAttribute.h>
#include <ImfFloatVectorAttribute.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfIntAttribute.h>
#include <ImfOutputFile.h>
#include <ImfStringAttribute.h>
#include <ImfVecAttribute.h>
#include <gtest/gtest.h>
#include <stb_image.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <set>

#include "common/checksum.h"
#include "common/error.h"
#include "common/exr_io.h"

// Static, so this test's stb_image_write cannot clash with another file's.
#define STB_IMAGE_WRITE_STATIC
#define STB_IMAGE_WRITE_IMPLEMENTATION
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-function"
#include <stb_image_write.h>
#pragma GCC diagnostic pop

namespace dofarm {
namespace {

namespace fs = std::filesystem;

// A fresh folder per test, removed afterwards.
class ExrIo : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           ("dofarm-exrio-" + std::to_string(::getpid()) + "-" + info->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ignored;
    fs::remove_all(dir_, ignored);
  }
  std::vector<std::string> files_in_dir() const {
    std::vector<std::string> names;
    for (const auto& e : fs::recursive_directory_iterator(dir_))
      names.push_back(e.path().lexically_relative(dir_).string());
    return names;
  }
  fs::path dir_;
};

uint32_t bits(float v) {
  uint32_t b;
  std::memcpy(&b, &v, sizeof b);
  return b;
}

// Any finite float, denormals and negative zero included: random bit patterns
// with the all-ones exponent (Inf/NaN) steered away.
float finite_from_bits(uint32_t b) {
  if (((b >> 23) & 0xff) == 0xff) b ^= 0x40000000u;
  float v;
  std::memcpy(&v, &b, sizeof v);
  return v;
}

FrameBuffers make_frame(int w, int h, int versions, uint32_t seed) {
  FrameBuffers fb;
  fb.allocate(w, h, versions);
  fb.rect = {0, 0, w, h};
  std::mt19937 rng(seed);
  for (const BufferInfo& b : buffer_infos())
    for (float& v : buffer_data(fb, b.name)) v = finite_from_bits(rng());
  // The values most likely to be lost by a careless conversion.
  const float specials[] = {-0.0f,
                            std::numeric_limits<float>::denorm_min(),
                            -std::numeric_limits<float>::denorm_min(),
                            1e-40f,
                            std::numeric_limits<float>::max(),
                            -std::numeric_limits<float>::max(),
                            std::numeric_limits<float>::min(),
                            65504.0f,
                            1e30f};
  for (size_t i = 0; i < std::min(std::size(specials), fb.plane()); ++i) {
    fb.noisy[i] = specials[i];
    fb.coc[i] = specials[i];
  }
  fb.camera.frame = 42;
  fb.camera.time = 1.75f;
  fb.camera.position[0] = -1.5f;
  fb.camera.position[1] = 0.1f;
  fb.camera.position[2] = 1e-7f;
  fb.camera.rotation[0] = 0.9238795f;
  fb.camera.rotation[1] = 0.0f;
  fb.camera.rotation[2] = -0.3826834f;
  fb.camera.rotation[3] = -0.0f;
  fb.camera.fov_deg = 39.6f;
  fb.camera.focal_distance = 3.25f;
  fb.camera.aperture = 0.0125f;
  return fb;
}

void expect_bits_equal(const std::vector<float>& a, const std::vector<float>& b,
                       const std::string& what) {
  ASSERT_EQ(a.size(), b.size()) << what;
  size_t differing = 0;
  for (size_t i = 0; i < a.size(); ++i) differing += bits(a[i]) != bits(b[i]);
  EXPECT_EQ(differing, 0u) << what;
}

void expect_frames_identical(const FrameBuffers& a, const FrameBuffers& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  EXPECT_EQ(a.versions, b.versions);
  EXPECT_EQ(a.rect, b.rect);
  EXPECT_EQ(a.camera.frame, b.camera.frame);
  EXPECT_EQ(bits(a.camera.time), bits(b.camera.time));
  for (int i = 0; i < 3; ++i) EXPECT_EQ(bits(a.camera.position[i]), bits(b.camera.position[i]));
  for (int i = 0; i < 4; ++i) EXPECT_EQ(bits(a.camera.rotation[i]), bits(b.camera.rotation[i]));
  EXPECT_EQ(bits(a.camera.fov_deg), bits(b.camera.fov_deg));
  EXPECT_EQ(bits(a.camera.focal_distance), bits(b.camera.focal_distance));
  EXPECT_EQ(bits(a.camera.aperture), bits(b.camera.aperture));
  EXPECT_EQ(bits(a.camera.ortho_height), bits(b.camera.ortho_height));
  for (const BufferInfo& info : buffer_infos())
    expect_bits_equal(buffer_data(a, info.name), buffer_data(b, info.name), info.name);
}

template <typename F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const RuntimeError& e) {
    return e.what();
  }
  return "<no RuntimeError>";
}

TEST_F(ExrIo, FrameRoundTripIsBitExact) {
  FrameBuffers fb = make_frame(13, 7, 3, 1234);
  fb.rect = {0, 0, 13, 7};
  const std::map<std::string, std::string> attrs = {
      {"dofarm.scene", "scenes/cornell.gltf"},
      {"dofarm.batch", "b-0017"},
      {"comments", "spaces, = signs and \"quotes\" survive"},
      {"dofarm.empty", ""},
  };
  const fs::path path = dir_ / "frame.exr";
  write_frame_exr(path, fb, attrs);
  const ExrFrame back = read_frame_exr(path);
  expect_frames_identical(fb, back.buffers);
  EXPECT_EQ(back.attributes, attrs);
  EXPECT_EQ(files_in_dir(), std::vector<std::string>{"frame.exr"}) << "temporary file left over";
}

// An orthographic camera's view height travels in its own attribute; a
// perspective frame's header has none (its file is what it was before
// orthographic cameras), and reads back as perspective.
TEST_F(ExrIo, OrthographicCameraHeightRoundTripsAndOnlyThen) {
  FrameBuffers fb = make_frame(6, 5, 1, 99);
  fb.rect = {0, 0, 6, 5};
  const fs::path persp = dir_ / "persp.exr", ortho = dir_ / "ortho.exr";
  write_frame_exr(persp, fb);
  fb.camera.fov_deg = 0;
  fb.camera.ortho_height = 2.75f;
  write_frame_exr(ortho, fb);
  EXPECT_EQ(read_frame_exr(ortho).buffers.camera.ortho_height, 2.75f);
  EXPECT_EQ(read_frame_exr(persp).buffers.camera.ortho_height, 0.0f);
  auto has_attr = [](const fs::path& p) {
    Imf::InputFile in(p.c_str());
    return in.header().find("dofarm.camera.ortho_height") != in.header().end();
  };
  EXPECT_TRUE(has_attr(ortho));
  EXPECT_FALSE(has_attr(persp));
}

// The checksum returned by the writer and the one the reader computes are both
// the XXH64 of the file's bytes, so a staged tile is checked without a second
// read.
TEST_F(ExrIo, ChecksumsAreThoseOfTheFileBytes) {
  const fs::path path = dir_ / "frame.exr";
  const uint64_t written = write_frame_exr(path, make_frame(24, 8, 2, 77));
  EXPECT_EQ(written, checksum_file(path));
  uint64_t read = 0;
  read_frame_exr(path, &read);
  EXPECT_EQ(read, written);

  // Another frame, another checksum.
  EXPECT_NE(write_frame_exr(path, make_frame(24, 8, 2, 78)), written);
  read_frame_exr(path, &read);
  EXPECT_EQ(read, checksum_file(path));
}

// A tile's data window is its place in the frame's display window, as
// OpenEXR defines the two; no private attribute is needed to find it.
TEST_F(ExrIo, TileDataWindowIsItsPlaceInTheFrame) {
  FrameBuffers tile = make_frame(5, 3, 2, 99);
  tile.rect = {64, 32, 5, 3};
  const fs::path path = dir_ / "tiles" / "f0042" / "tile-64-32.exr";  // parents made on demand
  write_frame_exr(path, tile, {}, FrameExtent{80, 40});

  Imf::InputFile file(path.c_str());
  const Imath::Box2i dw = file.header().dataWindow();
  EXPECT_EQ(dw.min, Imath::V2i(64, 32));
  EXPECT_EQ(dw.max, Imath::V2i(68, 34));
  EXPECT_EQ(file.header().displayWindow(), Imath::Box2i(Imath::V2i(0, 0), Imath::V2i(79, 39)));
  EXPECT_EQ(file.header().findTypedAttribute<Imf::Box2iAttribute>("dofarm.rect"), nullptr);

  const ExrFrame back = read_frame_exr(path);
  expect_frames_identical(tile, back.buffers);
  EXPECT_EQ(back.frame.width, 80);
  EXPECT_EQ(back.frame.height, 40);
  EXPECT_TRUE(back.attributes.empty());

  // The rect read back puts the tile where it belongs in the frame.
  FrameBuffers frame;
  frame.allocate(80, 40, 2);
  frame.paste(back.buffers);
  EXPECT_EQ(bits(frame.coc[(size_t(32 + 2) * 80) + 64 + 4]), bits(tile.coc[size_t(2) * 5 + 4]));

  // Without the frame's size the display window is the least that holds it.
  write_frame_exr(path, tile);
  EXPECT_EQ(Imf::InputFile(path.c_str()).header().displayWindow(),
            Imath::Box2i(Imath::V2i(0, 0), Imath::V2i(68, 34)));
}

// The default layer is the reference and Z is the depth: what any EXR tool
// shows and takes for depth. Read with OpenEXR alone, channel by channel.
TEST_F(ExrIo, RootRgbIsTheReferenceAndZTheDepth) {
  FrameBuffers fb = make_frame(6, 4, 2, 21);
  fb.rect = {2, 1, 6, 4};
  const fs::path path = dir_ / "frame.exr";
  write_frame_exr(path, fb, {}, FrameExtent{10, 7});
  Imf::InputFile file(path.c_str());
  const Imath::Box2i dw = file.header().dataWindow();
  const size_t n = fb.plane();
  std::vector<float> r(n), g(n), b(n), a(n), z(n), nz(n);
  Imf::FrameBuffer slices;
  auto add = [&](const char* name, std::vector<float>& v) {
    slices.insert(name,
                  Imf::Slice::Make(Imf::FLOAT, v.data(), dw, sizeof(float), 6 * sizeof(float)));
  };
  add("R", r), add("G", g), add("B", b), add("A", a), add("Z", z), add("normal.B", nz);
  file.setFrameBuffer(slices);
  file.readPixels(dw.min.y, dw.max.y);
  for (size_t i = 0; i < n; ++i) {
    EXPECT_EQ(bits(r[i]), bits(fb.reference[i])) << i;
    EXPECT_EQ(bits(g[i]), bits(fb.reference[n + i])) << i;
    EXPECT_EQ(bits(b[i]), bits(fb.reference[2 * n + i])) << i;
    EXPECT_EQ(a[i], 1.0f) << i;
    EXPECT_EQ(bits(z[i]), bits(fb.depth[i])) << i;
    EXPECT_EQ(bits(nz[i]), bits(fb.normal[2 * n + i])) << i;
  }
  const auto* rgb = file.header().findTypedAttribute<Imf::StringAttribute>("dofarm.rgb");
  ASSERT_NE(rgb, nullptr);
  EXPECT_EQ(rgb->value(), "reference");
  EXPECT_EQ(file.header().findTypedAttribute<Imf::StringAttribute>("dofarm.schema")->value(),
            "dofarm.frame/2");
}

// Only the root Z may end in ".Z" or be called Depth (OpenImageIO takes the
// first such channel for depth), and only the root A in ".A"/"Alpha".
TEST_F(ExrIo, NoLayerLooksLikeDepthOrAlpha) {
  const fs::path path = dir_ / "frame.exr";
  write_frame_exr(path, make_frame(4, 4, 3, 7));
  Imf::InputFile file(path.c_str());
  for (auto it = file.header().channels().begin(); it != file.header().channels().end(); ++it) {
    std::string name = it.name();
    if (name == "Z" || name == "A") continue;
    const std::string last = name.substr(name.rfind('.') + 1);
    std::string lower = last;
    std::transform(lower.begin(), lower.end(), lower.begin(), ::tolower);
    EXPECT_NE(lower, "z") << name;
    EXPECT_NE(lower, "depth") << name;
    EXPECT_NE(lower, "a") << name;
    EXPECT_NE(lower, "alpha") << name;
  }
}

// A frame without a reference shows the mean of its noisy versions, says so,
// and reads back without a reference.
TEST_F(ExrIo, FrameWithoutReferenceShowsTheNoisyMean) {
  FrameBuffers fb = make_frame(3, 2, 2, 5);
  for (float& v : fb.noisy) v = std::fmod(std::fabs(v), 10.0f);  // a mean that cannot overflow
  fb.reference.clear();
  fb.reference_var.clear();
  fb.reference_half.clear();
  const fs::path path = dir_ / "frame.exr";
  write_frame_exr(path, fb);
  Imf::InputFile file(path.c_str());
  EXPECT_EQ(file.header().findTypedAttribute<Imf::StringAttribute>("dofarm.rgb")->value(),
            "noisy_mean");
  EXPECT_EQ(file.header().channels().findChannel("reference_var.Y"), nullptr);
  std::vector<float> g(6);
  Imf::FrameBuffer slices;
  slices.insert("G", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(g.data()), sizeof(float),
                                3 * sizeof(float)));
  file.setFrameBuffer(slices);
  file.readPixels(0, 1);
  for (size_t i = 0; i < 6; ++i)
    EXPECT_FLOAT_EQ(g[i], (fb.noisy[6 + i] + fb.noisy[18 + 6 + i]) / 2) << i;
  const ExrFrame back = read_frame_exr(path);
  expect_frames_identical(fb, back.buffers);
}

// Version 1 files (staged before an upgrade) still read: tile at 0,0 with
// dofarm.rect, every buffer a named layer, normal X/Y/Z.
TEST_F(ExrIo, ReadsVersion1Files) {
  FrameBuffers fb = make_frame(4, 3, 2, 31);
  fb.rect = {16, 8, 4, 3};
  Imf::Header header(4, 3);
  header.compression() = Imf::ZIP_COMPRESSION;
  header.insert("dofarm.schema", Imf::StringAttribute("dofarm.frame/1"));
  header.insert("dofarm.rect",
                Imf::Box2iAttribute(Imath::Box2i(Imath::V2i(16, 8), Imath::V2i(19, 10))));
  header.insert("dofarm.versions", Imf::IntAttribute(2));
  header.insert("dofarm.camera.frame", Imf::IntAttribute(fb.camera.frame));
  header.insert("dofarm.camera.time", Imf::FloatAttribute(fb.camera.time));
  header.insert("dofarm.camera.position",
                Imf::V3fAttribute(Imath::V3f(fb.camera.position[0], fb.camera.position[1],
                                             fb.camera.position[2])));
  header.insert("dofarm.camera.rotation", Imf::FloatVectorAttribute(std::vector<float>(
                                              fb.camera.rotation, fb.camera.rotation + 4)));
  header.insert("dofarm.camera.fov", Imf::FloatAttribute(fb.camera.fov_deg));
  header.insert("dofarm.camera.focal_distance", Imf::FloatAttribute(fb.camera.focal_distance));
  header.insert("dofarm.camera.aperture", Imf::FloatAttribute(fb.camera.aperture));
  Imf::FrameBuffer slices;
  const size_t n = fb.plane();
  for (const BufferInfo& b : buffer_infos()) {
    const int layers = b.per_version ? 2 : 1;
    for (int v = 0; v < layers; ++v)
      for (int c = 0; c < b.channels; ++c) {
        const std::string layer =
            b.per_version ? std::string(b.name) + "." + std::to_string(v) : std::string(b.name);
        const char* suffix = b.channels == 1                   ? "Y"
                             : std::string(b.name) == "normal" ? "XYZ" + c
                                                               : "RGB" + c;
        const std::string name = layer + "." + std::string(1, suffix[0]);
        header.channels().insert(name, Imf::Channel(Imf::FLOAT));
        float* base = buffer_data(fb, b.name).data() + (size_t(v) * b.channels + c) * n;
        slices.insert(name, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(base), sizeof(float),
                                       4 * sizeof(float)));
      }
  }
  const fs::path path = dir_ / "v1.exr";
  {
    Imf::OutputFile out(path.c_str(), header);
    out.setFrameBuffer(slices);
    out.writePixels(3);
  }
  const ExrFrame back = read_frame_exr(path);
  expect_frames_identical(fb, back.buffers);
  EXPECT_EQ(back.frame.width, 20);
  EXPECT_EQ(back.frame.height, 11);
}

// The command's standard output ("" when it cannot be run) and exit status.
std::pair<std::string, int> run_tool(const std::string& command) {
  std::string out;
  FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return {"", -1};
  char buf[4096];
  size_t k;
  while ((k = std::fread(buf, 1, sizeof buf, pipe)) > 0) out.append(buf, k);
  const int status = ::pclose(pipe);
  return {out, WIFEXITED(status) ? WEXITSTATUS(status) : -1};
}

bool have_tool(const char* name) {
  return run_tool(std::string("command -v ") + name + " >/dev/null").second == 0;
}

// What users do with a frame (issue 14): OpenImageIO lists R, G, B, A, Z
// first and `oiiotool f.exr -o f.png` saves the reference, opaque. Runs only
// where Debian's openimageio-tools is installed.
TEST_F(ExrIo, OpenImageIoShowsTheReference) {
  if (!have_tool("oiiotool") || !have_tool("iinfo")) GTEST_SKIP() << "oiiotool/iinfo not installed";
  FrameBuffers fb = make_frame(8, 5, 2, 3);
  for (size_t i = 0; i < fb.reference.size(); ++i) fb.reference[i] = float(i % 17) / 16.0f;
  const fs::path exr = dir_ / "frame.exr", png = dir_ / "frame.png";
  write_frame_exr(exr, fb);
  const auto [info, info_rc] = run_tool("iinfo -v '" + exr.string() + "'");
  ASSERT_EQ(info_rc, 0) << info;
  EXPECT_NE(info.find("channel list: R, G, B, A, Z, "), std::string::npos) << info;
  const auto [conv, conv_rc] =
      run_tool("oiiotool '" + exr.string() + "' -o '" + png.string() + "'");
  ASSERT_EQ(conv_rc, 0) << conv;
  int w = 0, h = 0, c = 0;
  unsigned char* px = stbi_load(png.c_str(), &w, &h, &c, 4);
  ASSERT_NE(px, nullptr);
  EXPECT_EQ(w, 8);
  EXPECT_EQ(h, 5);
  EXPECT_EQ(c, 4);
  const size_t n = fb.plane();
  int worst = 0;
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) {
      // oiiotool writes the linear values as 8-bit codes, rounded.
      const int want = int(std::lround(std::clamp(fb.reference[k * n + i], 0.0f, 1.0f) * 255));
      worst = std::max(worst, std::abs(int(px[4 * i + k]) - want));
    }
    EXPECT_EQ(px[4 * i + 3], 255) << i;
  }
  stbi_image_free(px);
  EXPECT_LE(worst, 1);
}

// exrheader (Debian's openexr) shows the schema and a tile's data window.
TEST_F(ExrIo, ExrheaderShowsTheTilePlace) {
  if (!have_tool("exrheader")) GTEST_SKIP() << "exrheader not installed";
  FrameBuffers tile = make_frame(5, 3, 1, 4);
  tile.rect = {64, 32, 5, 3};
  const fs::path path = dir_ / "tile.exr";
  write_frame_exr(path, tile, {}, FrameExtent{80, 40});
  const auto [out, rc] = run_tool("exrheader '" + path.string() + "'");
  ASSERT_EQ(rc, 0) << out;
  EXPECT_NE(out.find("dataWindow (type box2i): (64 32) - (68 34)"), std::string::npos) << out;
  EXPECT_NE(out.find("displayWindow (type box2i): (0 0) - (79 39)"), std::string::npos) << out;
  EXPECT_NE(out.find("dofarm.schema (type string): \"dofarm.frame/2\""), std::string::npos) << out;
}

TEST_F(ExrIo, ChannelNamesFollowTheSchema) {
  const fs::path path = dir_ / "frame.exr";
  write_frame_exr(path, make_frame(4, 4, 2, 7));
  Imf::InputFile file(path.c_str());
  std::set<std::string> names;
  for (auto it = file.header().channels().begin(); it != file.header().channels().end(); ++it) {
    names.insert(it.name());
    EXPECT_EQ(it.channel().type, Imf::FLOAT) << it.name();
  }
  const std::set<std::string> expected = {"R",
                                          "G",
                                          "B",
                                          "A",
                                          "Z",
                                          "noisy.0.R",
                                          "noisy.0.G",
                                          "noisy.0.B",
                                          "noisy.1.R",
                                          "noisy.1.G",
                                          "noisy.1.B",
                                          "albedo.0.R",
                                          "albedo.0.G",
                                          "albedo.0.B",
                                          "albedo.1.R",
                                          "albedo.1.G",
                                          "albedo.1.B",
                                          "albedo_ref.R",
                                          "albedo_ref.G",
                                          "albedo_ref.B",
                                          "reference_var.Y",
                                          "normal.R",
                                          "normal.G",
                                          "normal.B",
                                          "roughness.Y",
                                          "coc.Y",
                                          "reference_half.R",
                                          "reference_half.G",
                                          "reference_half.B"};
  EXPECT_EQ(names, expected);
  EXPECT_EQ(file.header().compression(), Imf::ZIP_COMPRESSION);
}

TEST_F(ExrIo, ChannelsHoldTheirPlanes) {
  // Bit-exact round trips would also pass if two planes were swapped in both
  // directions; read single channels independently to pin the mapping.
  FrameBuffers fb;
  fb.allocate(3, 2, 2);
  for (const BufferInfo& b : buffer_infos()) {
    std::vector<float>& data = buffer_data(fb, b.name);
    for (size_t i = 0; i < data.size(); ++i) data[i] = float(i);
  }
  const fs::path path = dir_ / "frame.exr";
  write_frame_exr(path, fb);
  Imf::InputFile file(path.c_str());
  float noisy_1_g[6], normal_z[6];
  Imf::FrameBuffer slices;
  slices.insert("noisy.1.G", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(noisy_1_g),
                                        sizeof(float), 3 * sizeof(float)));
  slices.insert("normal.B", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(normal_z), sizeof(float),
                                       3 * sizeof(float)));
  file.setFrameBuffer(slices);
  file.readPixels(0, 1);
  // noisy.1.G is plane v*3 + c = 4 of noisy; normal.B (z) is plane 2 of normal.
  for (int i = 0; i < 6; ++i) {
    EXPECT_EQ(noisy_1_g[i], float(4 * 6 + i));
    EXPECT_EQ(normal_z[i], float(2 * 6 + i));
  }
}

TEST_F(ExrIo, RefusesNonFiniteBuffersAndKeepsTheOldFile) {
  const fs::path path = dir_ / "frame.exr";
  const FrameBuffers good = make_frame(6, 4, 2, 5);
  write_frame_exr(path, good);

  FrameBuffers bad = make_frame(6, 4, 2, 6);
  bad.noisy[17] = std::numeric_limits<float>::quiet_NaN();
  bad.depth[0] = std::numeric_limits<float>::infinity();
  bad.depth[3] = -std::numeric_limits<float>::infinity();
  const std::string msg = error_of([&] { write_frame_exr(path, bad); });
  EXPECT_NE(msg.find(path.string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("noisy has 1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("depth has 2"), std::string::npos) << msg;
  EXPECT_EQ(msg.find("albedo"), std::string::npos) << msg;

  EXPECT_EQ(files_in_dir(), std::vector<std::string>{"frame.exr"});
  expect_frames_identical(good, read_frame_exr(path).buffers);

  const fs::path fresh = dir_ / "never.exr";
  EXPECT_THROW(write_frame_exr(fresh, bad), RuntimeError);
  EXPECT_FALSE(fs::exists(fresh));
}

TEST_F(ExrIo, RefusesAttributeNamesTheHeaderUses) {
  const fs::path path = dir_ / "frame.exr";
  for (const char* key : {"dofarm.rect", "dofarm.schema", "compression", "type", ""}) {
    const std::map<std::string, std::string> attrs = {{std::string(key), "x"}};
    const std::string msg = error_of([&] { write_frame_exr(path, make_frame(2, 2, 1, 3), attrs); });
    EXPECT_NE(msg.find("reserved"), std::string::npos) << key << ": " << msg;
  }
  EXPECT_TRUE(files_in_dir().empty());
}

TEST_F(ExrIo, OverwriteReplacesTheFile) {
  const fs::path path = dir_ / "frame.exr";
  write_frame_exr(path, make_frame(4, 3, 1, 1), {{"dofarm.try", "1"}});
  const FrameBuffers second = make_frame(2, 5, 2, 2);
  write_frame_exr(path, second, {{"dofarm.try", "2"}});
  const ExrFrame back = read_frame_exr(path);
  expect_frames_identical(second, back.buffers);
  EXPECT_EQ(back.attributes.at("dofarm.try"), "2");
  EXPECT_EQ(files_in_dir(), std::vector<std::string>{"frame.exr"});
}

TEST_F(ExrIo, MissingFileNamesIt) {
  const fs::path path = dir_ / "absent.exr";
  const std::string msg = error_of([&] { read_frame_exr(path); });
  EXPECT_NE(msg.find(path.string()), std::string::npos) << msg;
}

TEST_F(ExrIo, TruncatedFileNamesIt) {
  const fs::path path = dir_ / "frame.exr";
  write_frame_exr(path, make_frame(32, 16, 2, 11));
  const std::uintmax_t full = fs::file_size(path);
  for (std::uintmax_t size : {full / 2, full - 1, std::uintmax_t{40}}) {
    write_frame_exr(path, make_frame(32, 16, 2, 11));
    fs::resize_file(path, size);
    const std::string msg = error_of([&] { read_frame_exr(path); });
    EXPECT_NE(msg.find(path.string()), std::string::npos) << size << " bytes: " << msg;
  }
}

TEST_F(ExrIo, PlainExrIsNotAFrame) {
  const fs::path path = dir_ / "plain.exr";
  write_rgb_exr(path, RgbImage{1, 1, {0.5f, 0.25f, 1.0f}});
  const std::string msg = error_of([&] { read_frame_exr(path); });
  EXPECT_NE(msg.find(path.string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("dofarm.schema"), std::string::npos) << msg;
}

TEST_F(ExrIo, MissingChannelIsNamed) {
  // A frame EXR rewritten without coc.Y, header attributes kept.
  const fs::path full = dir_ / "full.exr";
  write_frame_exr(full, make_frame(3, 2, 1, 8));
  Imf::Header header = Imf::InputFile(full.c_str()).header();
  Imf::ChannelList kept;
  Imf::FrameBuffer zeros;
  std::vector<float> zero(3 * 2, 0.0f);
  for (auto it = header.channels().begin(); it != header.channels().end(); ++it) {
    if (std::string(it.name()) == "coc.Y") continue;
    kept.insert(it.name(), it.channel());
    zeros.insert(it.name(), Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(zero.data()),
                                       sizeof(float), 3 * sizeof(float)));
  }
  header.channels() = kept;
  const fs::path path = dir_ / "no-coc.exr";
  {
    Imf::OutputFile out(path.c_str(), header);
    out.setFrameBuffer(zeros);
    out.writePixels(2);
  }
  const std::string msg = error_of([&] { read_frame_exr(path); });
  EXPECT_NE(msg.find(path.string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("coc.Y"), std::string::npos) << msg;
}

TEST_F(ExrIo, RgbExrLoadsExactly) {
  RgbImage img{4, 3, {}};
  for (int i = 0; i < 4 * 3 * 3; ++i) img.rgb.push_back(0.1f * i + 1e-3f / (i + 1));
  img.rgb[5] = 1e6f;  // no half rounding: 1e6 is beyond half's range
  const fs::path path = dir_ / "sub" / "rgb.exr";
  write_rgb_exr(path, img);
  const RgbImage back = load_rgb_image(path);
  EXPECT_EQ(back.width, 4);
  EXPECT_EQ(back.height, 3);
  expect_bits_equal(back.rgb, img.rgb, "rgb");
  EXPECT_EQ(back.sanitized_values, 0u);
}

TEST_F(ExrIo, LoadedImagesHaveNoNanInfOrNegative) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  const fs::path path = dir_ / "bad.exr";
  write_rgb_exr(path, RgbImage{2, 1, {nan, 0.5f, -2.0f, inf, -inf, 3.0f}});
  const RgbImage back = load_rgb_image(path);
  EXPECT_EQ(back.rgb, (std::vector<float>{0.0f, 0.5f, 0.0f, 0.0f, 0.0f, 3.0f}));
  EXPECT_EQ(back.sanitized_values, 4u);
}

TEST_F(ExrIo, HdrLoadsWithinRgbePrecision) {
  const int w = 5, h = 2;
  std::vector<float> rgb;
  for (int i = 0; i < w * h; ++i) {
    rgb.push_back(0.01f * (i + 1));
    rgb.push_back(3.7f * i);
    rgb.push_back(250.0f / (i + 1));
  }
  const fs::path path = dir_ / "env.HDR";  // extensions are case-insensitive
  ASSERT_NE(stbi_write_hdr(path.c_str(), w, h, 3, rgb.data()), 0);
  const RgbImage img = load_rgb_image(path, /*srgb=*/true);  // .hdr is linear regardless
  ASSERT_EQ(img.width, w);
  ASSERT_EQ(img.height, h);
  ASSERT_EQ(img.rgb.size(), rgb.size());
  for (int p = 0; p < w * h; ++p) {
    // RGBE shares one exponent per pixel with 8-bit mantissas: each channel
    // is within 1/128 of the pixel's largest channel.
    const float m = std::max({rgb[3 * p], rgb[3 * p + 1], rgb[3 * p + 2]});
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(img.rgb[3 * p + c], rgb[3 * p + c], m / 128) << "pixel " << p << " c " << c;
  }
}

TEST_F(ExrIo, PngIsSrgbDecoded) {
  // Grey + alpha: loads as RGB with alpha dropped. Top row first.
  const unsigned char ga[] = {128, 255, 0, 7, 255, 255, 64, 0};
  const fs::path path = dir_ / "tex.png";
  ASSERT_NE(stbi_write_png(path.c_str(), 2, 2, 2, ga, 2 * 2), 0);

  const RgbImage srgb = load_rgb_image(path, true);
  ASSERT_EQ(srgb.width, 2);
  ASSERT_EQ(srgb.height, 2);
  ASSERT_EQ(srgb.rgb.size(), 12u);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(srgb.rgb[c], 0.2158605f, 1e-6f);  // IEC 61966-2-1 at 128/255
    EXPECT_EQ(srgb.rgb[3 + c], 0.0f);
    EXPECT_NEAR(srgb.rgb[6 + c], 1.0f, 1e-6f);
    EXPECT_NEAR(srgb.rgb[9 + c], 0.0512695f, 1e-6f);  // 64/255
  }
  const RgbImage raw = load_rgb_image(path, false);
  EXPECT_EQ(raw.rgb[0], 128 / 255.0f);
  EXPECT_EQ(raw.rgb[9], 64 / 255.0f);
}

TEST_F(ExrIo, UnreadableImagesNameTheFile) {
  const fs::path unknown = dir_ / "tex.webp";
  { std::ofstream(unknown) << "RIFF"; }
  std::string msg = error_of([&] { load_rgb_image(unknown); });
  EXPECT_NE(msg.find(unknown.string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("extension"), std::string::npos) << msg;

  for (const char* name : {"garbage.png", "garbage.hdr", "garbage.exr", "absent.jpg"}) {
    const fs::path path = dir_ / name;
    if (std::string(name) != "absent.jpg") std::ofstream(path) << "not an image at all";
    msg = error_of([&] { load_rgb_image(path); });
    EXPECT_NE(msg.find(path.string()), std::string::npos) << msg;
  }
}

TEST(Srgb, KnownValuesOfTheCurve) {
  EXPECT_EQ(srgb_to_linear(0.0f), 0.0f);
  EXPECT_NEAR(srgb_to_linear(1.0f), 1.0f, 1e-7f);
  EXPECT_NEAR(srgb_to_linear(0.5f), 0.2140411f, 1e-6f);
  EXPECT_NEAR(srgb_to_linear(0.02f), 0.02f / 12.92f, 1e-9f);  // linear segment
  EXPECT_NEAR(linear_to_srgb(0.5f), 0.7353570f, 1e-6f);
  EXPECT_NEAR(linear_to_srgb(0.001f), 0.01292f, 1e-8f);
  // The two pieces meet at the knee (0.04045 <-> 0.0031308).
  EXPECT_NEAR(srgb_to_linear(0.04045f), srgb_to_linear(0.04046f), 1e-6f);
  EXPECT_NEAR(linear_to_srgb(0.0031308f), 0.04045f, 1e-6f);
}

TEST(Srgb, RoundTrip) {
  for (int i = 0; i <= 1000; ++i) {
    const float v = i / 1000.0f;
    EXPECT_NEAR(linear_to_srgb(srgb_to_linear(v)), v, 2e-6f) << v;
    EXPECT_NEAR(srgb_to_linear(linear_to_srgb(v)), v, 2e-6f) << v;
  }
}

TEST(ExrIoAssets, StudioHdriLoads) {
  const fs::path path = fs::path(DOFARM_SOURCE_DIR) / ".." / "shared/assets/hdri/studio.exr";
  if (!fs::exists(path)) GTEST_SKIP() << path << " not found";
  const RgbImage img = load_rgb_image(path);
  EXPECT_EQ(img.width, 1024);
  EXPECT_EQ(img.height, 512);
  ASSERT_EQ(img.rgb.size(), size_t(1024) * 512 * 3);
  double sum = 0;
  size_t bad = 0;
  for (float v : img.rgb) {
    bad += !std::isfinite(v) || v < 0;
    sum += v;
  }
  EXPECT_EQ(bad, 0u);
  EXPECT_GT(sum, 0.0);  // not silently all black
}

}  // namespace
}  // namespace dofarm
