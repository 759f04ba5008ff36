// Image loading (common/exr_io.h: load_rgb_image, decode_rgb_image): .exr
// through OpenEXR, .hdr and 8/16-bit formats through stb_image, every value
// made safe for the renderer; and the sRGB transfer curve.
#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfRgbaFile.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <exception>
#include <limits>

#include "common/content_hash.h"
#include "common/error.h"
#include "common/exr_io.h"
#include "common/exr_stream.h"

#define STB_IMAGE_IMPLEMENTATION
#define STBI_NO_PSD
#define STBI_NO_PIC
#define STBI_NO_PNM
#define STBI_NO_GIF
#include <stb_image.h>

namespace dofarm {
namespace {

using exr_detail::quoted;

std::string lower_extension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext;
}

RgbImage load_exr_rgb(const std::filesystem::path& path) {
  RgbImage img;
  try {
    Imf::InputFile file(path.c_str());
    const Imf::Header& header = file.header();
    const Imath::Box2i dw = header.dataWindow();
    img.width = dw.max.x - dw.min.x + 1;
    img.height = dw.max.y - dw.min.y + 1;
    img.rgb.assign(size_t(img.width) * img.height * 3, 0.0f);
    const Imf::ChannelList& channels = header.channels();
    if (channels.findChannel("R") && channels.findChannel("G") && channels.findChannel("B")) {
      // Read R, G, B as FLOAT whatever their stored type: OpenEXR converts
      // exactly, where RgbaInputFile would round 32-bit data to half.
      Imf::FrameBuffer fb;
      const char* const names[] = {"R", "G", "B"};
      for (int c = 0; c < 3; ++c)
        fb.insert(names[c], Imf::Slice::Make(Imf::FLOAT, img.rgb.data() + c, dw, 3 * sizeof(float),
                                             3 * sizeof(float) * size_t(img.width)));
      file.setFrameBuffer(fb);
      file.readPixels(dw.min.y, dw.max.y);
    } else {
      // Luminance or luminance/chroma files: RgbaInputFile knows how to turn
      // them into RGB (half precision is all such files hold).
      Imf::RgbaInputFile rgba_file(path.c_str());
      if (!(rgba_file.channels() & Imf::WRITE_Y)) throw RuntimeError("no R, G, B or Y channels");
      std::vector<Imf::Rgba> pixels(size_t(img.width) * img.height);
      rgba_file.setFrameBuffer(pixels.data() - dw.min.x - size_t(dw.min.y) * img.width, 1,
                               size_t(img.width));
      rgba_file.readPixels(dw.min.y, dw.max.y);
      for (size_t i = 0; i < pixels.size(); ++i) {
        img.rgb[3 * i + 0] = pixels[i].r;
        img.rgb[3 * i + 1] = pixels[i].g;
        img.rgb[3 * i + 2] = pixels[i].b;
      }
    }
  } catch (const std::exception& e) {
    throw RuntimeError("cannot read image " + quoted(path) + ": " + e.what());
  }
  return img;
}

// Where stb_image reads from: a file, or encoded bytes in memory (a texture
// embedded in a glTF). Both decode through the same code below.
struct StbSource {
  const std::filesystem::path* path = nullptr;
  const stbi_uc* data = nullptr;
  int size = 0;
  bool is_16_bit() const {
    return path ? stbi_is_16_bit(path->c_str()) : stbi_is_16_bit_from_memory(data, size);
  }
  float* loadf(int* w, int* h, int* c) const {
    return path ? stbi_loadf(path->c_str(), w, h, c, 3)
                : stbi_loadf_from_memory(data, size, w, h, c, 3);
  }
  stbi_us* load_16(int* w, int* h, int* c) const {
    return path ? stbi_load_16(path->c_str(), w, h, c, 3)
                : stbi_load_16_from_memory(data, size, w, h, c, 3);
  }
  stbi_uc* load(int* w, int* h, int* c) const {
    return path ? stbi_load(path->c_str(), w, h, c, 3)
                : stbi_load_from_memory(data, size, w, h, c, 3);
  }
};

// The error for a failed stb_image call on `what` (the file, or the
// embedded image), with stb_image's reason.
RuntimeError stb_error(const std::string& what) {
  const char* reason = stbi_failure_reason();
  return RuntimeError("cannot read image " + what + ": " +
                      (reason ? reason : "unknown stb_image error"));
}

// Throws RuntimeError naming `what` (the file, or the embedded image).
RgbImage load_stb_rgb(const StbSource& src, const std::string& what, bool hdr, bool srgb) {
  RgbImage img;
  int channels_in_file = 0;
  const size_t n = [&] {
    if (hdr) {
      // Radiance .hdr holds linear radiance; stbi_loadf returns it unchanged.
      float* data = src.loadf(&img.width, &img.height, &channels_in_file);
      if (!data) return size_t(0);
      img.rgb.assign(data, data + size_t(img.width) * img.height * 3);
      stbi_image_free(data);
    } else if (src.is_16_bit()) {
      // 16-bit PNGs keep their precision instead of being cut to 8 bits.
      stbi_us* data = src.load_16(&img.width, &img.height, &channels_in_file);
      if (!data) return size_t(0);
      const size_t count = size_t(img.width) * img.height * 3;
      img.rgb.resize(count);
      for (size_t i = 0; i < count; ++i) {
        float v = data[i] / 65535.0f;
        img.rgb[i] = srgb ? srgb_to_linear(v) : v;
      }
      stbi_image_free(data);
    } else {
      // Not stbi_loadf: for 8-bit files it applies a pure 2.2 gamma, not the
      // sRGB curve. Decode the exact curve through a table of the 256 codes.
      stbi_uc* data = src.load(&img.width, &img.height, &channels_in_file);
      if (!data) return size_t(0);
      float table[256];
      for (int i = 0; i < 256; ++i) table[i] = srgb ? srgb_to_linear(i / 255.0f) : i / 255.0f;
      const size_t count = size_t(img.width) * img.height * 3;
      img.rgb.resize(count);
      for (size_t i = 0; i < count; ++i) img.rgb[i] = table[data[i]];
      stbi_image_free(data);
    }
    return img.rgb.size();
  }();
  if (n == 0) throw stb_error(what);
  return img;
}

// Textures and environment maps feed the renderer, which must never see a
// NaN, an Inf or negative radiance; such texels are zeroed here, once, and
// counted so the caller can warn.
void sanitize(RgbImage* img) {
  for (float& v : img->rgb) {
    if (!(v >= 0.0f) || std::isinf(v)) {
      v = 0.0f;
      ++img->sanitized_values;
    }
  }
}

}  // namespace

RgbImage load_rgb_image(const std::filesystem::path& path, bool srgb) {
  const std::string ext = lower_extension(path);
  note_input_file(path);  // a job's snapshot holds every image it reads
  RgbImage img;
  if (ext == ".exr") {
    img = load_exr_rgb(path);
  } else if (ext == ".hdr") {
    img = load_stb_rgb(StbSource{&path}, quoted(path), /*hdr=*/true, srgb);
  } else if (ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".tga" || ext == ".bmp") {
    img = load_stb_rgb(StbSource{&path}, quoted(path), /*hdr=*/false, srgb);
  } else {
    throw RuntimeError("cannot read image " + quoted(path) + ": unknown extension '" + ext +
                       "' (expected .exr, .hdr, .png, .jpg, .jpeg, .tga or .bmp)");
  }
  sanitize(&img);
  return img;
}

RgbImage decode_rgb_image(const void* data, size_t size, const std::string& name, bool srgb) {
  const std::string what = std::string(1, '"').append(name).append(1, '"');
  if (size == 0 || size > size_t(std::numeric_limits<int>::max()))
    throw RuntimeError("cannot read image " + what + ": " + std::to_string(size) + " bytes");
  StbSource src{nullptr, static_cast<const stbi_uc*>(data), int(size)};
  const bool hdr = stbi_is_hdr_from_memory(src.data, src.size) != 0;
  RgbImage img = load_stb_rgb(src, what, hdr, srgb);
  sanitize(&img);
  return img;
}

namespace {

std::vector<float> stb_alpha(const StbSource& src, const std::string& what) {
  int w = 0, h = 0, channels = 0;
  const bool ok = src.path ? stbi_info(src.path->c_str(), &w, &h, &channels)
                           : stbi_info_from_memory(src.data, src.size, &w, &h, &channels);
  if (!ok) throw stb_error(what);
  if (channels != 2 && channels != 4) return {};  // grey or RGB: no alpha
  stbi_uc* data = src.path ? stbi_load(src.path->c_str(), &w, &h, &channels, 4)
                           : stbi_load_from_memory(src.data, src.size, &w, &h, &channels, 4);
  if (!data) throw stb_error(what);
  std::vector<float> alpha(size_t(w) * h);
  for (size_t i = 0; i < alpha.size(); ++i) alpha[i] = data[4 * i + 3] / 255.0f;
  stbi_image_free(data);
  return alpha;
}

}  // namespace

std::vector<float> load_image_alpha(const std::filesystem::path& path) {
  const std::string ext = lower_extension(path);
  if (ext == ".exr" || ext == ".hdr") return {};
  return stb_alpha(StbSource{&path}, quoted(path));
}

std::vector<float> decode_image_alpha(const void* data, size_t size, const std::string& name) {
  const std::string what = std::string(1, '"').append(name).append(1, '"');
  if (size == 0 || size > size_t(std::numeric_limits<int>::max()))
    throw RuntimeError("cannot read image " + what + ": " + std::to_string(size) + " bytes");
  StbSource src{nullptr, static_cast<const stbi_uc*>(data), int(size)};
  if (stbi_is_hdr_from_memory(src.data, src.size)) return {};
  return stb_alpha(src, what);
}

// IEC 61966-2-1: linear segment below the knee, 2.4 power above it.
float srgb_to_linear(float v) {
  if (v <= 0.04045f) return v / 12.92f;
  return std::pow((v + 0.055f) / 1.055f, 2.4f);
}

float linear_to_srgb(float v) {
  if (v <= 0.0031308f) return v * 12.92f;
  return 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

}  // namespace dofarm
