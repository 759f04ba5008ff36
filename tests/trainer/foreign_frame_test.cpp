// Denoising other renderers' frames (trainer/foreign_frame.h): a real Blender
// 3.4 Cycles multilayer EXR (tests/data/cycles, made by make_cycles_frame.py)
// and OIDN-style separate files become the FrameBuffers dofarm's own reader
// gives, and `dofarm-train denoise` writes a finite image of the input's size
// that keeps its header.
#include "trainer/foreign_frame.h"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>

#include "common/error.h"
#include "common/exr_io.h"
#include "tests/trainer/synthetic.h"
#include "trainer/config.h"
#include "trainer/eval.h"
#include "trainer/train.h"

namespace dofarm::trainer {
namespace {

namespace fs = std::filesystem;

const fs::path kCycles = fs::path(DOFARM_TEST_DATA) / "cycles" / "cycles_48x40.exr";

// The scene of make_cycles_frame.py: 50 mm lens (the header's "Lens"), 36 mm
// sensor, f/2 focused at 3 m; the backdrop is 6 m along the viewing axis.
constexpr double kFocus = 3.0, kFstop = 2.0, kBackdrop = 6.0;

ForeignInputs cycles_inputs(const fs::path& file = kCycles) {
  ForeignInputs in;
  in.input = file;
  in.lens.fstop = kFstop;
  in.lens.focus_distance = kFocus;
  return in;
}

size_t at(const FrameBuffers& f, int x, int y) { return size_t(y) * f.width + x; }

template <typename F>
std::string spec_error_of(F&& f) {
  try {
    f();
  } catch (const SpecError& e) {
    return e.what();
  }
  return "<no SpecError>";
}

TEST(ForeignFrame, CyclesPassesBecomeDofarmBuffers) {
  const DenoiseInput in = load_denoise_input(cycles_inputs(), /*needs_coc=*/true);
  const FrameBuffers& f = in.frame;
  EXPECT_EQ(in.source, "cycles");
  ASSERT_EQ(f.width, 48);
  ASSERT_EQ(f.height, 40);
  ASSERT_EQ(f.versions, 1);
  const size_t n = f.plane();

  // Colour and albedo are the passes as stored; alpha is carried along.
  const ExrImage raw = read_exr_image(kCycles);
  EXPECT_EQ(f.noisy[n + 7], raw.channels.at("ViewLayer.Combined.G")[7]);
  EXPECT_EQ(f.albedo[2 * n + 100], raw.channels.at("ViewLayer.Denoising Albedo.B")[100]);
  EXPECT_EQ(f.albedo, f.albedo_ref);
  ASSERT_EQ(in.alpha.size(), n);
  EXPECT_EQ(in.alpha[5], raw.channels.at("ViewLayer.Combined.A")[5]);

  // Known answers from the scene: the backdrop (the corners) is 6 m away
  // along the axis (the Z pass, used as it is) and faces the camera, so its
  // view-space normal is +z.
  for (auto [x, y] : {std::pair{0, 0}, {47, 0}, {0, 39}, {47, 39}, {24, 2}}) {
    const size_t i = at(f, x, y);
    EXPECT_NEAR(f.depth[i], kBackdrop, 1e-4) << x << "," << y;
    EXPECT_NEAR(f.normal[2 * n + i], 1.0f, 1e-5) << x << "," << y;
    EXPECT_NEAR(f.normal[i], 0.0f, 1e-5);
  }
  // The sphere in the middle: its left side faces left (-x), its top up (+y),
  // and every normal is unit length.
  EXPECT_LT(f.normal[at(f, 17, 20)], -0.3f);
  EXPECT_GT(f.normal[n + at(f, 24, 8)], 0.5f);
  for (size_t i = 0; i < n; ++i) {
    const float x = f.normal[i], y = f.normal[n + i], z = f.normal[2 * n + i];
    EXPECT_NEAR(x * x + y * y + z * z, 1.0f, 1e-5) << i;
  }

  // The thin lens: radius 50 mm / (2 * 2) = 12.5 mm; tan(vfov/2) = 18/50 *
  // 40/48 = 0.3; c = A |z - S| / z * H / (S tan) pixels.
  const double tan_v = 18.0 / 50.0 * 40.0 / 48.0;
  EXPECT_NEAR(f.camera.aperture, 0.0125, 1e-7);
  EXPECT_NEAR(f.camera.focal_distance, kFocus, 1e-6);
  EXPECT_NEAR(std::tan(f.camera.fov_deg * M_PI / 360.0), tan_v, 1e-6);
  const size_t corner = at(f, 0, 0);
  const double want =
      0.0125 * std::fabs(f.depth[corner] - kFocus) / f.depth[corner] * 40.0 / (kFocus * tan_v);
  EXPECT_NEAR(f.coc[corner], want, 1e-5);
  EXPECT_NEAR(f.coc[corner], 0.0125 * 0.5 * 40 / 0.9, 1e-3);  // 0.278 px
  // The sphere's front (2.4 m) is nearer the focus: |1 - S/z| is 0.25 there
  // against 0.5 on the backdrop.
  EXPECT_LT(f.coc[at(f, 24, 20)], f.coc[corner]);

  // What was assumed is said.
  bool lens_note = false;
  for (const std::string& s : in.notes) lens_note |= s.find("'Lens'") != std::string::npos;
  EXPECT_TRUE(lens_note);
}

// Without the Z pass, Cycles' Denoising Depth (the distance along the ray
// from the near clip) is converted to view-space z: the backdrop is again 6 m.
TEST(ForeignFrame, CyclesDenoisingDepthIsConvertedToViewZ) {
  const fs::path dir = testing::scratch_dir("cycles_depth");
  const fs::path file = dir / "no_z_pass.exr";
  {
    Imf::InputFile src(kCycles.c_str());
    Imf::Header header = src.header();
    Imf::ChannelList kept;
    for (auto it = header.channels().begin(); it != header.channels().end(); ++it)
      if (std::string(it.name()) != "ViewLayer.Depth.Z") kept.insert(it.name(), it.channel());
    header.channels() = kept;
    const Imath::Box2i dw = header.dataWindow();
    std::vector<std::vector<float>> planes;
    Imf::FrameBuffer fb;
    for (auto it = kept.begin(); it != kept.end(); ++it) {
      planes.emplace_back(48 * 40);
      fb.insert(it.name(), Imf::Slice::Make(Imf::FLOAT, planes.back().data(), dw, sizeof(float),
                                            48 * sizeof(float)));
    }
    src.setFrameBuffer(fb);
    src.readPixels(dw.min.y, dw.max.y);
    for (auto it = kept.begin(); it != kept.end(); ++it)
      header.channels()[it.name()].type = Imf::FLOAT;
    Imf::OutputFile out(file.c_str(), header);
    out.setFrameBuffer(fb);
    out.writePixels(40);
  }
  const DenoiseInput in = load_denoise_input(cycles_inputs(file), true);
  const FrameBuffers& f = in.frame;
  const DenoiseInput ref = load_denoise_input(cycles_inputs(), true);
  for (auto [x, y] : {std::pair{0, 0}, {47, 0}, {0, 39}, {47, 39}, {24, 2}, {0, 20}})
    EXPECT_NEAR(f.depth[at(f, x, y)], kBackdrop, 0.02 * kBackdrop) << x << "," << y;
  // On the sphere (Cycles averaged its samples over the pixel; the
  // conversion uses the pixel centre) within 2 % of the Z pass.
  EXPECT_NEAR(f.depth[at(f, 24, 20)], ref.frame.depth[at(f, 24, 20)], 0.02 * 2.4);
}

TEST(ForeignFrame, MissingLensOrPassIsBadInput) {
  ForeignInputs in = cycles_inputs();
  in.lens.fstop.reset();
  EXPECT_NE(spec_error_of([&] { load_denoise_input(in, true); }).find("--fstop"),
            std::string::npos);
  EXPECT_NO_THROW(load_denoise_input(in, /*needs_coc=*/false));
  in = cycles_inputs();
  in.lens.focus_distance.reset();
  EXPECT_NE(spec_error_of([&] { load_denoise_input(in, true); }).find("focus"), std::string::npos);
  in = cycles_inputs();
  in.view_layer = "Other";
  EXPECT_NE(spec_error_of([&] { load_denoise_input(in, true); }).find("view layer"),
            std::string::npos);
  // A plain colour image needs its passes.
  const fs::path plain = testing::scratch_dir("plain") / "plain.exr";
  write_rgb_exr(plain, RgbImage{2, 2, std::vector<float>(12, 0.5f)});
  in = cycles_inputs(plain);
  EXPECT_NE(spec_error_of([&] { load_denoise_input(in, true); }).find("--albedo"),
            std::string::npos);
}

// PFM as Open Image Denoise's tools write it: little-endian, bottom row first.
void write_pfm(const fs::path& path, int w, int h, const float* planes, int channels) {
  std::ofstream out(path, std::ios::binary);
  out << (channels == 3 ? "PF" : "Pf") << "\n" << w << " " << h << "\n-1.0\n";
  const size_t n = size_t(w) * h;
  for (int y = h - 1; y >= 0; --y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < channels; ++c) {
        const float v = planes[c * n + size_t(y) * w + x];
        out.write(reinterpret_cast<const char*>(&v), sizeof v);
      }
}

// Colour, albedo, normal (PFM) and depth (EXR) files of a dofarm frame read
// back as its buffers, value for value; the CoC is the renderer's formula.
TEST(ForeignFrame, SeparateFilesAsOidnTakesThem) {
  const int w = 37, h = 29;
  const FrameBuffers src = testing::synthetic_frame(0, w, h, 1, 4);
  const fs::path dir = testing::scratch_dir("separate");
  write_pfm(dir / "color.pfm", w, h, src.noisy.data(), 3);
  write_pfm(dir / "albedo.pfm", w, h, src.albedo.data(), 3);
  write_pfm(dir / "normal.pfm", w, h, src.normal.data(), 3);
  write_pfm(dir / "depth.pfm", w, h, src.depth.data(), 1);
  ForeignInputs in;
  in.input = dir / "color.pfm";
  in.albedo = dir / "albedo.pfm";
  in.normal = dir / "normal.pfm";
  in.depth = dir / "depth.pfm";
  in.lens.fstop = 4.0;
  in.lens.focal_length_mm = 35.0;
  in.lens.focus_distance = 2.0;
  const DenoiseInput got = load_denoise_input(in, true);
  const FrameBuffers& f = got.frame;
  EXPECT_EQ(got.source, "files");
  ASSERT_EQ(f.width, w);
  ASSERT_EQ(f.height, h);
  EXPECT_EQ(f.noisy, src.noisy);
  EXPECT_EQ(f.albedo, src.albedo);
  EXPECT_EQ(f.normal, src.normal);  // already unit, view space
  EXPECT_EQ(f.depth, src.depth);
  const double tan_v = 36.0 / 70.0 * double(h) / w, a = 0.035 / 8;
  for (size_t i : {size_t(0), size_t(w * h / 2), size_t(w * h - 1)})
    EXPECT_NEAR(f.coc[i], a * std::fabs(f.depth[i] - 2.0) / f.depth[i] * h / (2.0 * tan_v), 1e-4);

  // A PFM shorter than its header says is refused before anything is read.
  { std::ofstream(dir / "short.pfm", std::ios::binary) << "PF\n60000 60000\n-1.0\n1234"; }
  in.albedo = dir / "short.pfm";
  EXPECT_NE(spec_error_of([&] { load_denoise_input(in, true); }).find("truncated"),
            std::string::npos);

  // A file of another size is named.
  write_pfm(dir / "small.pfm", 3, 3, src.albedo.data(), 3);
  in.albedo = dir / "small.pfm";
  EXPECT_NE(spec_error_of([&] { load_denoise_input(in, true); }).find("small.pfm"),
            std::string::npos);
}

// A run trained for a few steps on synthetic shards (as train_test does).
fs::path tiny_run() {
  static fs::path run = [] {
    const fs::path data = testing::scratch_dir("foreign_data");
    testing::write_synthetic_shard(data / "shard-00000.h5", 6, 64, 64, 2, 3);
    const fs::path r = testing::scratch_dir("foreign_run");
    TrainOptions o;
    o.data_dir = data;
    o.run_dir = r;
    o.config = load_train_config(
        "", {"model.channels=[8, 8, 8, 8, 8]", "data.crop=32", "data.sequence=3", "data.queue=4",
             "data.readers=1", "train.epochs=1", "train.steps_per_epoch=2", "train.batch=2",
             "train.warmup_steps=1", "train.val_sequences=1", "train.device=cpu"});
    train(o);
    return r;
  }();
  return run;
}

int run_denoise(const std::string& args) {
  const std::string cmd = std::string(DOFARM_TRAIN_EXE) + " denoise " + args + " >/dev/null 2>&1";
  const int rc = std::system(cmd.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

// The real Cycles frame through `dofarm-train denoise`: 48x40 (not a
// multiple of the network's 32) in, 48x40 finite RGBA out, equal to the
// library's denoising of the adapted frame, with the input's header kept and
// what made the file added.
TEST(Denoise, CyclesFrameThroughTheCommand) {
  const fs::path run = tiny_run();
  const fs::path out = testing::scratch_dir("foreign_out") / "denoised.exr";
  // On the CPU, as the comparison below: CUDA's kernels round differently.
  const std::string args =
      "--run " + run.string() + " --device cpu " + kCycles.string() + " " + out.string();
  EXPECT_EQ(run_denoise(args + " --focus-distance 3"), 2) << "a DOF model needs the f-number";
  EXPECT_EQ(run_denoise(args + " --fstop 2"), 2) << "the depth input needs the focus distance";
  ASSERT_FALSE(fs::exists(out));
  ASSERT_EQ(run_denoise(args + " --fstop 2 --focus-distance 3"), 0);

  const ExrImage img = read_exr_image(out);
  ASSERT_EQ(img.width, 48);
  ASSERT_EQ(img.height, 40);
  for (const char* c : {"R", "G", "B", "A"}) ASSERT_TRUE(img.has(c)) << c;
  for (const auto& [name, plane] : img.channels)
    for (float v : plane) ASSERT_TRUE(std::isfinite(v)) << name;
  // Kept: Blender's stamps; dropped: the multilayer marker; added: the maker.
  EXPECT_EQ(img.strings.at("Lens"), "50.00");
  EXPECT_EQ(img.strings.at("Camera"), "Camera");
  EXPECT_EQ(img.strings.at("cycles.ViewLayer.samples"), "8");
  EXPECT_EQ(img.strings.count("BlenderMultiChannel"), 0u);
  EXPECT_EQ(img.strings.at("Software").rfind("dofarm-train denoise", 0), 0u);
  EXPECT_EQ(img.strings.at("dofarm.denoise.source"), "cycles");
  EXPECT_NE(img.strings.at("dofarm.denoise.checkpoint").find("best"), std::string::npos);
  EXPECT_EQ(img.strings.at("dofarm.denoise.input"), "cycles_48x40.exr");

  // The command denoised exactly the adapted frame.
  const DenoiseInput in = load_denoise_input(cycles_inputs(), true);
  FrameDenoiser den(run, torch::kCPU);
  const std::vector<float> want = den.denoise(in.frame, 0);
  const size_t n = in.frame.plane();
  for (size_t i = 0; i < n; i += 97) {
    EXPECT_FLOAT_EQ(img.channels.at("R")[i], want[i]) << i;
    EXPECT_FLOAT_EQ(img.channels.at("B")[i], want[2 * n + i]) << i;
    EXPECT_EQ(img.channels.at("A")[i], in.alpha[i]) << i;
  }
}

}  // namespace
}  // namespace dofarm::trainer
