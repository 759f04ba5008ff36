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
// The image is the buffers' own width x height (a tile is stored as a small
// image, data window at 0,0); the header records
//   dofarm.schema                 string  "dofarm.frame/1" (the reader refuses others)
//   dofarm.rect                   box2i   where it sits in the frame: min (x, y),
//                                         max (x + w - 1, y + h - 1)
//   dofarm.versions               int     V
//   dofarm.camera.frame           int
//   dofarm.camera.time            float   seconds
//   dofarm.camera.position        v3f
//   dofarm.camera.rotation        floatvector  quaternion w, x, y, z
//   dofarm.camera.fov             float   degrees
//   dofarm.camera.focal_distance  float
//   dofarm.camera.aperture        float
// and one string attribute per entry of `attributes`, named by its key.
//
// Images: load_rgb_image() reads .exr (RGB or RGBA, any pixel type) and, via
// stb_image, .hdr (linear) and .png/.jpg/.tga/.bmp (8-bit; sRGB-decoded when
// `srgb` is true). Throws RuntimeError naming the file on failure.
// NaN, Inf and negative values are replaced by 0 (the renderer must never see
// them) and counted in RgbImage::sanitized_values so the caller can warn.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "common/image.h"

namespace dofarm {

struct RgbImage {
  int width = 0, height = 0;
  std::vector<float> rgb;       // interleaved, row 0 = top
  size_t sanitized_values = 0;  // NaN/Inf/negative values load_rgb_image() set to 0
};

RgbImage load_rgb_image(const std::filesystem::path& path, bool srgb = true);

// The same decoding for an encoded image held in memory (PNG, JPEG, TGA, BMP,
// HDR: stb_image tells them apart by their bytes), e.g. a texture embedded in
// a glTF. `name` names the image in errors. Same sRGB handling and
// sanitising as load_rgb_image(); notes no input file (the bytes belong to a
// file that was noted already).
RgbImage decode_rgb_image(const void* data, size_t size, const std::string& name, bool srgb = true);

// Returns the XXH64 checksum (common/checksum.h) of the file's bytes, computed
// over the encoded bytes before they are written, so that checksum_file() of
// the result gives the same value without reading it back.
// Throws RuntimeError, leaving no file behind, when a buffer holds NaN/Inf
// (naming the buffers and counts), an attribute key collides with a header
// attribute, or the write fails. Creates parent directories.
uint64_t write_frame_exr(const std::filesystem::path& path, const FrameBuffers& fb,
                     const std::map<std::string, std::string>& attributes = {});

struct ExrFrame {
  FrameBuffers buffers;
  std::map<std::string, std::string> attributes;
};
// Throws RuntimeError naming the file when it is missing, not a dofarm frame,
// truncated or corrupt, or lacks a channel. The file is read once; when
// `file_checksum` is given it receives the XXH64 of exactly the bytes decoded
// (the staged-tile check of a pack costs no second read).
ExrFrame read_frame_exr(const std::filesystem::path& path, uint64_t* file_checksum = nullptr);

// Writes an RGB image as a plain float EXR (debugging, reports), atomically
// like write_frame_exr(). Non-finite values are kept, to be seen.
void write_rgb_exr(const std::filesystem::path& path, const RgbImage& img);

// sRGB transfer curve (IEC 61966-2-1), per value.
float srgb_to_linear(float v);
float linear_to_srgb(float v);

}  // namespace dofarm
