#include "trainer/foreign_frame.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>

#include "common/error.h"
#include "common/exr_io.h"
#include "common/thin_lens.h"

namespace dofarm::trainer {

namespace fs = std::filesystem;

namespace {

// Defaults for what neither the options nor the file say (Blender's).
constexpr double kDefaultSensorWidthMm = 36.0;
constexpr double kDefaultClipStart = 0.1;
// Cycles writes 1e10 for the depth of a ray that escapes; anything this far
// is "no hit" (dofarm's 0).
constexpr float kEscapedDepth = 1e9f;

// One image from a file: named H x W planes.
struct Planes {
  int width = 0, height = 0;  // the data window
  int frame_height = 0;       // the display window's height (CoC scale)
  std::map<std::string, std::vector<float>> channels;
  std::map<std::string, std::string> strings;
  std::map<std::string, double> numbers;
};

bool ends_with(const std::string& s, const std::string& tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

std::string lower_extension(const fs::path& p) {
  std::string e = p.extension().string();
  std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return std::tolower(c); });
  return e;
}

// --- PFM (Portable Float Map), as Open Image Denoise's tools write it -------
//   "PF\n" (RGB) or "Pf\n" (grey), "W H\n", scale ("-1.0\n": negative = little
//   endian), then H rows of W pixels of float32, the bottom row first.
Planes read_pfm(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw RuntimeError("cannot open '" + path.string() + "'");
  std::string magic;
  long long w = 0, h = 0;
  double scale = 0;
  in >> magic >> w >> h >> scale;
  if (!in || (magic != "PF" && magic != "Pf") || in.get() != '\n')
    throw SpecError(FileLoc{path.string()}, "",
                    "not a PFM file (expected 'PF' or 'Pf', size, scale)");
  if (w <= 0 || h <= 0 || w > (1 << 16) || h > (1 << 16) || !std::isfinite(scale) || scale == 0)
    throw SpecError(FileLoc{path.string()}, "",
                    "PFM size " + std::to_string(w) + "x" + std::to_string(h) + " or scale " +
                        std::to_string(scale) + " out of range");
  const int c = magic == "PF" ? 3 : 1;
  const size_t n = size_t(w) * size_t(h) * c;
  // The size the header claims must be there before anything is allocated.
  std::error_code ec;
  const uintmax_t file_size = fs::file_size(path, ec);
  if (ec || file_size < uintmax_t(in.tellg()) + n * sizeof(float))
    throw SpecError(FileLoc{path.string()}, "", "PFM data is truncated");
  std::vector<float> data(n);
  in.read(reinterpret_cast<char*>(data.data()), std::streamsize(n * sizeof(float)));
  if (size_t(in.gcount()) != n * sizeof(float))
    throw SpecError(FileLoc{path.string()}, "", "PFM data is truncated");
  const bool little = scale < 0;
  const uint16_t probe = 1;
  const bool host_little = *reinterpret_cast<const uint8_t*>(&probe) == 1;
  if (little != host_little)
    for (float& v : data) {
      uint32_t b;
      std::memcpy(&b, &v, 4);
      b = __builtin_bswap32(b);
      std::memcpy(&v, &b, 4);
    }
  Planes p;
  p.width = int(w);
  p.height = int(h);
  p.frame_height = int(h);
  static const char* const kRgb[] = {"R", "G", "B"};
  for (int k = 0; k < c; ++k) {
    std::vector<float>& plane = p.channels[c == 3 ? kRgb[k] : "Y"];
    plane.resize(size_t(w) * h);
    for (long long y = 0; y < h; ++y)  // bottom row first in the file
      for (long long x = 0; x < w; ++x)
        plane[size_t(h - 1 - y) * w + x] = data[(size_t(y) * w + x) * c + k];
  }
  return p;
}

Planes read_planes(const fs::path& path) {
  const std::string ext = lower_extension(path);
  if (ext == ".pfm") return read_pfm(path);
  if (ext != ".exr")
    throw SpecError(FileLoc{path.string()}, "",
                    "unknown image type '" + ext + "' (expected .exr or .pfm)");
  ExrImage img;
  try {
    img = read_exr_image(path);
  } catch (const RuntimeError& e) {
    throw SpecError(FileLoc{path.string()}, "", e.what());
  }
  Planes p;
  p.width = img.width;
  p.height = img.height;
  p.frame_height = std::max(img.display.height, img.height);
  p.channels = std::move(img.channels);
  p.strings = std::move(img.strings);
  p.numbers = std::move(img.numbers);
  return p;
}

// The first of `names` the image has, or nullptr.
const std::vector<float>* find_channel(const Planes& p, std::initializer_list<std::string> names,
                                       std::string* which = nullptr) {
  for (const std::string& n : names) {
    auto it = p.channels.find(n);
    if (it != p.channels.end()) {
      if (which) *which = n;
      return &it->second;
    }
  }
  return nullptr;
}

// Copies three planes into `dst` (3, H, W) or throws naming what is missing.
void take_rgb(const Planes& p, const fs::path& file, const std::string& prefix,
              const char* const (&names)[3], std::vector<float>& dst, const std::string& what) {
  const size_t n = size_t(p.width) * p.height;
  for (int c = 0; c < 3; ++c) {
    auto it = p.channels.find(prefix + names[c]);
    if (it == p.channels.end())
      throw SpecError(FileLoc{file.string()}, prefix + names[c], "missing channel (" + what + ")");
    std::copy(it->second.begin(), it->second.end(), dst.begin() + c * n);
  }
}

void check_size(const Planes& p, const fs::path& file, int w, int h) {
  if (p.width != w || p.height != h)
    throw SpecError(FileLoc{file.string()}, "",
                    "is " + std::to_string(p.width) + "x" + std::to_string(p.height) +
                        ", the colour image " + std::to_string(w) + "x" + std::to_string(h));
}

// The view layers of a Blender multilayer EXR: every L with "L.Combined.R".
std::vector<std::string> cycles_layers(const Planes& p) {
  std::vector<std::string> out;
  for (const auto& [name, plane] : p.channels)
    if (ends_with(name, ".Combined.R")) out.push_back(name.substr(0, name.size() - 11));
  return out;
}

// A number from the header: a float/int attribute or a string that starts
// with one ("50.00", "50.00 mm").
std::optional<double> header_number(const Planes& p, const std::string& name) {
  if (auto it = p.numbers.find(name); it != p.numbers.end()) return it->second;
  if (auto it = p.strings.find(name); it != p.strings.end()) {
    const char* s = it->second.c_str();
    char* end = nullptr;
    const double v = std::strtod(s, &end);
    if (end != s && std::isfinite(v)) return v;
  }
  return std::nullopt;
}

// The lens of a foreign frame: options, then metadata, then defaults.
struct Lens {
  double fstop = 0, focal_mm = 0, sensor_mm = 0, focus = 0, clip_start = 0;
  bool has_fstop = false;
};

Lens resolve_lens(const LensOptions& o, const Planes& meta, bool needs_coc,
                  std::vector<std::string>* notes) {
  Lens l;
  auto pick = [&](const std::optional<double>& opt, std::initializer_list<const char*> keys,
                  const char* what) -> std::optional<double> {
    if (opt) return opt;
    for (const char* k : keys)
      if (auto v = header_number(meta, k)) {
        notes->push_back(std::string(what) + " " + std::to_string(*v) + " from the header's '" + k +
                         "'");
        return v;
      }
    return std::nullopt;
  };
  const auto fstop = pick(o.fstop, {"dofarm.lens.fstop"}, "f-number");
  const auto focal =
      pick(o.focal_length_mm, {"dofarm.lens.focal_length_mm", "Lens"}, "focal length (mm)");
  const auto sensor = pick(o.sensor_width_mm, {"dofarm.lens.sensor_width_mm"}, "sensor width (mm)");
  const auto focus = pick(o.focus_distance, {"dofarm.lens.focus_distance"}, "focus distance");
  const auto clip = pick(o.clip_start, {"dofarm.lens.clip_start"}, "clip start");
  // The network's depth input is z relative to the focus distance, so a
  // frame without one cannot be encoded as in training.
  if (!focus || !(*focus > 0) || !std::isfinite(*focus))
    throw SpecError(FileLoc{"--focus-distance"}, "",
                    "give the camera's focus distance in scene units (> 0): the network's depth "
                    "input is relative to it");
  if (!focal || !(*focal > 0) || !std::isfinite(*focal))
    throw SpecError(FileLoc{"--focal-length"}, "",
                    "give the lens's focal length in mm (> 0): the header has no 'Lens' stamp");
  if (needs_coc && !fstop)
    throw SpecError(FileLoc{"--fstop"}, "",
                    "the model takes the circle of confusion: give the f-number the frame was "
                    "rendered at (0 for a pinhole camera)");
  if (fstop && (!(*fstop >= 0) || !std::isfinite(*fstop)))
    throw SpecError(FileLoc{"--fstop"}, "", "must be >= 0 (0 = pinhole)");
  l.fstop = fstop.value_or(0);
  l.has_fstop = fstop.has_value();
  l.focal_mm = *focal;
  l.sensor_mm = sensor.value_or(kDefaultSensorWidthMm);
  if (!(l.sensor_mm > 0) || !std::isfinite(l.sensor_mm))
    throw SpecError(FileLoc{"--sensor-width"}, "", "must be > 0 (mm)");
  if (!sensor) notes->push_back("sensor width 36 mm (Blender's default; --sensor-width)");
  l.focus = *focus;
  l.clip_start = clip.value_or(kDefaultClipStart);
  return l;
}

// View-space normal from `space`, unit length; a zero vector (nothing hit)
// stays zero.
void convert_normals(std::vector<float>& n3, size_t n, NormalSpace space) {
  for (size_t i = 0; i < n; ++i) {
    float x = n3[i], y = n3[n + i], z = n3[2 * n + i];
    if (space == NormalSpace::kCycles) z = -z;  // Cycles' camera looks down +z
    const float len = std::sqrt(x * x + y * y + z * z);
    if (len > 1e-12f && std::isfinite(len)) x /= len, y /= len, z /= len;
    n3[i] = x, n3[n + i] = y, n3[2 * n + i] = z;
  }
}

// The camera fields the network reads, and the CoC from depth and lens
// with the renderer's formula; `frame_height` is the whole frame's (the
// CoC is in pixels of it).
void apply_lens(FrameBuffers& f, const Lens& lens, int frame_height) {
  const double tan_v = sensor_tan_half_vfov(lens.focal_mm, lens.sensor_mm, f.width, f.height);
  f.camera.fov_deg = float(2.0 * std::atan(tan_v) * 180.0 / M_PI);
  f.camera.focal_distance = float(lens.focus);
  f.camera.aperture = lens.fstop > 0 ? fstop_lens_radius(lens.focal_mm, lens.fstop) : 0.0f;
  for (size_t i = 0; i < f.plane(); ++i)
    f.coc[i] = coc_diameter_pixels(f.camera.aperture, f.camera.focal_distance, float(tan_v),
                                   std::max(frame_height, f.height), f.depth[i]);
}

// The pinhole ray's cos(angle to the viewing axis) through pixel (x, y)'s
// centre, for a vertical half-fov tangent `tan_v`.
double axis_cosine(int x, int y, int w, int h, double tan_v) {
  const double sx = (2.0 * (x + 0.5) / w - 1.0) * tan_v * double(w) / h;
  const double sy = (1.0 - 2.0 * (y + 0.5) / h) * tan_v;
  return 1.0 / std::sqrt(1.0 + sx * sx + sy * sy);
}

DenoiseInput load_cycles(const ForeignInputs& in, const Planes& p, bool needs_coc) {
  const fs::path& file = in.input;
  std::vector<std::string> layers = cycles_layers(p);
  std::string layer = in.view_layer;
  if (layer.empty()) {
    if (layers.size() != 1) {
      std::string list;
      for (const std::string& l : layers) list += (list.empty() ? "" : ", ") + l;
      throw SpecError(FileLoc{file.string()}, "",
                      "holds " + std::to_string(layers.size()) + " view layers (" + list +
                          "): choose one with --view-layer");
    }
    layer = layers[0];
  } else if (std::find(layers.begin(), layers.end(), layer) == layers.end()) {
    throw SpecError(FileLoc{"--view-layer"}, "",
                    "'" + layer + "' is not a view layer of " + file.string());
  }
  const std::string pre = layer + ".";
  DenoiseInput out;
  out.source = "cycles";
  FrameBuffers& f = out.frame;
  f.allocate(p.width, p.height, 1);
  f.rect = {0, 0, p.width, p.height};
  const size_t n = f.plane();
  static const char* const kRgb[] = {"R", "G", "B"};
  static const char* const kXyz[] = {"X", "Y", "Z"};
  take_rgb(p, file, pre + "Combined.", kRgb, f.noisy, "the noisy render");
  if (auto it = p.channels.find(pre + "Combined.A"); it != p.channels.end()) out.alpha = it->second;
  if (!in.albedo.empty() || !in.normal.empty() || !in.depth.empty())
    throw SpecError(FileLoc{file.string()}, "",
                    "is a Cycles multilayer EXR: its passes are used; --albedo, --normal and "
                    "--depth are for a plain colour image");
  take_rgb(p, file, pre + "Denoising Albedo.", kRgb, f.albedo,
           "enable View Layer > Passes > Data > Denoising Data");
  take_rgb(p, file, pre + "Denoising Normal.", kXyz, f.normal,
           "enable View Layer > Passes > Data > Denoising Data");
  // Cycles' Denoising Normal is in its camera space (x right, y up, z away
  // from the viewer: the camera looks down +z), averaged over the pixel's
  // samples; dofarm's is unit length with z towards the viewer.
  convert_normals(f.normal, n, NormalSpace::kCycles);
  std::copy(f.albedo.begin(), f.albedo.end(), f.albedo_ref.begin());

  const Lens lens = resolve_lens(in.lens, p, needs_coc, &out.notes);
  // Cycles' Depth (Z) pass is view-space z, as dofarm's; its Denoising
  // Depth is the distance along the ray from where camera rays start (the
  // near clip, clip_start along the ray). Both measured on the backdrop of
  // tests/data/cycles, 6 m along the viewing axis: Z = 6.00 everywhere,
  // Denoising Depth = 6 / cos(theta) - 0.1 (6.49 in a corner).
  std::string depth_name;
  const std::string ray_depth = pre + "Denoising Depth.Z";
  const std::vector<float>* depth = find_channel(p, {pre + "Depth.Z", ray_depth}, &depth_name);
  if (!depth)
    throw SpecError(FileLoc{file.string()}, pre + "Depth.Z",
                    "missing depth (enable View Layer > Passes > Data > Z, or Denoising Data)");
  const double tan_v = sensor_tan_half_vfov(lens.focal_mm, lens.sensor_mm, p.width, p.height);
  for (size_t i = 0; i < n; ++i) {
    float z = (*depth)[i];
    if (!(z > 0) || !(z < kEscapedDepth)) {
      f.depth[i] = 0;  // escaped (or not finite: never a buffer value)
      continue;
    }
    if (depth_name == ray_depth) {
      const int x = int(i % p.width), y = int(i / p.width);
      z = float((double(z) + lens.clip_start) * axis_cosine(x, y, p.width, p.height, tan_v));
    }
    f.depth[i] = z;
  }
  if (depth_name == ray_depth)
    out.notes.push_back("depth from '" + depth_name +
                        "' (ray distance) converted to view z with clip start " +
                        std::to_string(lens.clip_start));
  std::fill(f.roughness.begin(), f.roughness.end(), in.roughness);
  out.notes.push_back("roughness " + std::to_string(in.roughness) +
                      " everywhere (no such pass; --roughness)");
  apply_lens(f, lens, p.frame_height);
  return out;
}

DenoiseInput load_files(const ForeignInputs& in, const Planes& colour, bool needs_coc) {
  if (in.albedo.empty() || in.normal.empty() || in.depth.empty())
    throw SpecError(FileLoc{in.input.string()}, "",
                    "is neither a dofarm frame nor a Cycles multilayer EXR: give its passes as "
                    "--albedo FILE --normal FILE --depth FILE");
  DenoiseInput out;
  out.source = "files";
  FrameBuffers& f = out.frame;
  const int w = colour.width, h = colour.height;
  f.allocate(w, h, 1);
  f.rect = {0, 0, w, h};
  const size_t n = f.plane();
  static const char* const kRgb[] = {"R", "G", "B"};
  static const char* const kXyz[] = {"X", "Y", "Z"};
  take_rgb(colour, in.input, "", kRgb, f.noisy, "the noisy colour");
  if (auto it = colour.channels.find("A"); it != colour.channels.end()) out.alpha = it->second;

  const Planes albedo = read_planes(in.albedo);
  check_size(albedo, in.albedo, w, h);
  take_rgb(albedo, in.albedo, "", kRgb, f.albedo, "the albedo");
  std::copy(f.albedo.begin(), f.albedo.end(), f.albedo_ref.begin());

  const Planes normal = read_planes(in.normal);
  check_size(normal, in.normal, w, h);
  const bool xyz = normal.channels.count("X") != 0;
  take_rgb(normal, in.normal, "", xyz ? kXyz : kRgb, f.normal, "the normal");
  convert_normals(f.normal, n, in.normal_space);

  const Planes depth = read_planes(in.depth);
  check_size(depth, in.depth, w, h);
  const std::vector<float>* z = find_channel(depth, {"Z", "Y", "R"});
  if (!z)
    throw SpecError(FileLoc{in.depth.string()}, "Z", "missing channel (the depth: Z, Y or R)");
  for (size_t i = 0; i < n; ++i) {
    const float v = (*z)[i];
    f.depth[i] = v > 0 && v < kEscapedDepth ? v : 0.0f;
  }
  const Lens lens = resolve_lens(in.lens, colour, needs_coc, &out.notes);
  std::fill(f.roughness.begin(), f.roughness.end(), in.roughness);
  out.notes.push_back("roughness " + std::to_string(in.roughness) +
                      " everywhere (no such pass; --roughness)");
  apply_lens(f, lens, colour.frame_height);
  return out;
}

}  // namespace

DenoiseInput load_denoise_input(const ForeignInputs& in, bool needs_coc) {
  const Planes p = read_planes(in.input);
  if (p.strings.count("dofarm.schema")) {
    if (!in.albedo.empty() || !in.normal.empty() || !in.depth.empty())
      throw SpecError(FileLoc{in.input.string()}, "",
                      "is a dofarm frame with all its buffers: --albedo, --normal and --depth "
                      "are for a plain colour image");
    const LensOptions& l = in.lens;
    if (l.fstop || l.focal_length_mm || l.sensor_width_mm || l.focus_distance || l.clip_start)
      throw SpecError(FileLoc{in.input.string()}, "",
                      "is a dofarm frame: its camera and circle of confusion are in the file; "
                      "the lens options are for other renderers' frames");
    DenoiseInput out;
    out.source = "dofarm";
    ExrFrame frame;
    try {
      frame = read_frame_exr(in.input);
    } catch (const RuntimeError& e) {
      throw SpecError(FileLoc{in.input.string()}, "", e.what());
    }
    out.frame = std::move(frame.buffers);
    return out;
  }
  if (!cycles_layers(p).empty()) return load_cycles(in, p, needs_coc);
  return load_files(in, p, needs_coc);
}

}  // namespace dofarm::trainer
