// EXR and image-file IO.
//
// Frames: write_frame_exr() stores every buffer of a FrameBuffers in one
// multi-layer, 32-bit float, ZIP-compressed EXR laid out as
// docs/exr_format.md describes (schema "dofarm.frame/2"): the reference as
// the default layer R, G, B (A = 1), the depth as Z, the other buffers as
// named layers (noisy.<v>.R/G/B, albedo.<v>.R/G/B, albedo_ref.R/G/B,
// reference_var.Y, normal.R/G/B, roughness.Y, coc.Y), the camera and
// "dofarm.*" attributes in the header. A tile's data window is its place
// inside the frame's display window. Written to a temporary name, fsynced
// and renamed: a reader never sees half a file. read_frame_exr() reads it
// back exactly (bit for bit), and reads version 1 files too.
//
// Images: load_rgb_image() reads .exr (RGB or RGBA, any pixel type) and, via
// stb_image, .hdr (linear) and .png/.jpg/.tga/.bmp (8-bit; sRGB-decoded when
// `srgb` is true). Throws RuntimeError naming the file on failure.
// NaN, Inf and negative values are replaced by 0 (the renderer must never see
// them) and counted in RgbImage::sanitized_values so the caller can warn.
// read_exr_image() reads any EXR's channels as they are (another renderer's
// frame), write_rgb_exr_like() writes an image with another file's header.
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

// The alpha channel of an image stb_image reads (PNG, TGA, ...; 8 bits),
// per texel in [0, 1], row 0 = top, as load_rgb_image() lays out its texels;
// empty when the image has no alpha channel, and for EXR and HDR files,
// whose alpha is not read. Throws RuntimeError naming the file on failure.
// For glTF's alphaMode MASK (worker/render/scene_data.h).
std::vector<float> load_image_alpha(const std::filesystem::path& path);
std::vector<float> decode_image_alpha(const void* data, size_t size, const std::string& name);

// Returns the XXH64 checksum (common/checksum.h) of the file's bytes, computed
// over the encoded bytes before they are written, so that checksum_file() of
// the result gives the same value without reading it back.
// Throws RuntimeError, leaving no file behind, when a buffer holds NaN/Inf
// (naming the buffers and counts), an attribute key collides with a header
// attribute, or the write fails. Creates parent directories.
// `frame` is the size of the whole frame (the display window) a tile
// belongs to; 0 = the smallest frame that holds fb.rect. An empty fb.rect
// means the whole image at 0,0. A frame whose `reference` (and
// `reference_var`) are empty is written without them: the root R, G, B then
// show the mean of the noisy versions and dofarm.rgb says "noisy_mean".
struct FrameExtent {
  int width = 0, height = 0;
};
uint64_t write_frame_exr(const std::filesystem::path& path, const FrameBuffers& fb,
                         const std::map<std::string, std::string>& attributes = {},
                         FrameExtent frame = {});

struct ExrFrame {
  FrameBuffers buffers;  // rect from the data window; reference empty if the file has none
  FrameExtent frame;     // the display window
  std::map<std::string, std::string> attributes;  // string attributes but the schema's own
};
// Throws RuntimeError naming the file when it is missing, not a dofarm frame,
// truncated or corrupt, or lacks a channel. The file is read once; when
// `file_checksum` is given it receives the XXH64 of exactly the bytes decoded
// (the staged-tile check of a pack costs no second read).
ExrFrame read_frame_exr(const std::filesystem::path& path, uint64_t* file_checksum = nullptr);

// Writes an RGB image as a plain float EXR (debugging, reports), atomically
// like write_frame_exr(). Non-finite values are kept, to be seen.
void write_rgb_exr(const std::filesystem::path& path, const RgbImage& img);

// The name of channel `c` of buffer `buffer` in a frame EXR as written now
// (docs/exr_format.md): "R" for the reference's red, "Z" for the depth,
// "normal.R" for the normal's x. A per-version buffer's layer carries
// `version` ("0", or a placeholder such as "<v>").
std::string frame_exr_channel(const std::string& buffer, int c, const std::string& version = "0");

// Any single-part flat EXR (scanline or tiled), every channel converted to
// float: another renderer's frame. Channels are H x W planes of the data
// window, row 0 at its top; values as stored (NaN/Inf kept: the caller
// decides). Throws RuntimeError naming the file when it cannot be read, is
// incomplete, deep, or has subsampled channels.
struct ExrImage {
  int width = 0, height = 0;  // of the data window
  Rect data_window;           // in pixel space (the display window's coordinates)
  FrameExtent display;        // display window size (its origin is assumed 0,0)
  std::map<std::string, std::vector<float>> channels;
  std::map<std::string, std::string> strings;  // string attributes
  std::map<std::string, double> numbers;       // int, float and double attributes
  bool has(const std::string& channel) const { return channels.count(channel) != 0; }
};
ExrImage read_exr_image(const std::filesystem::path& path);

// Writes `img` (R, G, B; and A when `alpha` is not empty, one value a pixel)
// as a float EXR, atomically, keeping the header attributes of the EXR
// `like` that describe the picture (camera, lens, renderer metadata; its
// data and display windows when the sizes agree) and dropping those of its
// layout (channels, the dofarm.* schema attributes, BlenderMultiChannel),
// then adding `attributes` as strings (replacing same-named ones). Refuses
// NaN/Inf values. Throws RuntimeError naming the file.
void write_rgb_exr_like(const std::filesystem::path& path, const RgbImage& img,
                        const std::vector<float>& alpha, const std::filesystem::path& like,
                        const std::map<std::string, std::string>& attributes);

// sRGB transfer curve (IEC 61966-2-1), per value.
float srgb_to_linear(float v);
float linear_to_srgb(float v);

}  // namespace dofarm
