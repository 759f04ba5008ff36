// EXR and image-file IO.
//
// Frames: write_frame_exr() stores every buffer of a FrameBuffers as named
// layers of one multi-layer, 32-bit float, ZIP-compressed EXR:
//   noisy.<v>.R/G/B, albedo.<v>.R/G/B, albedo_ref.R/G/B, reference.R/G/B,
//   reference_var.Y, normal.X/Y/Z, depth.Y, roughness.Y, coc.Y
// and the frame's camera (CameraState) plus free-form string attributes
// ("dofarm.*") in the header. Written to a temporary name, fsynced and
// renamed: a reader never sees half a file. read_frame_exr() reads it back
// exactly (bit for bit).
//
// Images: load_rgb_image() reads .exr (RGB or RGBA, any pixel type) and, via
// stb_image, .hdr (linear) and .png/.jpg/.tga/.bmp (8-bit; sRGB-decoded when
// `srgb` is true). Throws RuntimeError naming the file on failure.
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "common/image.h"

namespace dofarm {

struct RgbImage {
  int width = 0, height = 0;
  std::vector<float> rgb;  // interleaved, row 0 = top
};

RgbImage load_rgb_image(const std::filesystem::path& path, bool srgb = true);

void write_frame_exr(const std::filesystem::path& path, const FrameBuffers& fb,
                     const std::map<std::string, std::string>& attributes = {});

struct ExrFrame {
  FrameBuffers buffers;
  std::map<std::string, std::string> attributes;
};
ExrFrame read_frame_exr(const std::filesystem::path& path);

// Writes an RGB image as a plain EXR (debugging, reports).
void write_rgb_exr(const std::filesystem::path& path, const RgbImage& img);

// sRGB transfer curve (IEC 61966-2-1), per value.
float srgb_to_linear(float v);
float linear_to_srgb(float v);

}  // namespace dofarm
