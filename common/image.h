// Buffers of one frame (or one tile of it), channel-first float32 in the
// layout of the shard schema (DESIGN.md): index = ((v * C + c) * H + y) * W + x.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace dofarm {

struct Rect {
  int x = 0, y = 0, w = 0, h = 0;
  bool operator==(const Rect&) const = default;
};

// The camera of one frame, stored with every frame (shard `camera`, EXR header).
struct CameraState {
  int frame = 0;
  float time = 0;  // seconds = frame / fps
  float position[3] = {0, 0, 0};
  float rotation[4] = {1, 0, 0, 0};  // unit quaternion w, x, y, z
  float fov_deg = 40;                // vertical; 0 for an orthographic camera
  float focal_distance = 1;
  float aperture = 0;
  // An orthographic camera (glTF camera.orthographic, Blender's
  // Orthographic type): the height of its view in scene units; 0 for a
  // perspective camera.
  float ortho_height = 0;
  bool orthographic() const { return ortho_height > 0; }
};

struct FrameBuffers {
  int width = 0, height = 0;  // of this rect
  int versions = 0;
  Rect rect;  // where it sits in the full frame
  CameraState camera;
  std::vector<float> noisy;          // V, 3, H, W
  std::vector<float> albedo;         // V, 3, H, W
  std::vector<float> albedo_ref;     // 3, H, W
  std::vector<float> reference;      // 3, H, W
  std::vector<float> reference_var;  // 1, H, W: variance of the reference mean
  std::vector<float> normal;         // 3, H, W
  std::vector<float> depth;          // 1, H, W
  std::vector<float> roughness;      // 1, H, W
  std::vector<float> coc;            // 1, H, W
  // 3, H, W: mean of the first half of the reference's samples (an
  // independent half estimate; the second half is 2 * reference - this)
  std::vector<float> reference_half;

  void allocate(int w, int h, int v);
  size_t plane() const { return size_t(width) * height; }
  // Copies `tile` (whose rect lies inside this frame) into place.
  void paste(const FrameBuffers& tile);
  // Number of NaN/Inf values over all buffers (must be 0 for anything written).
  size_t count_non_finite() const;
};

// The buffer table (one row per buffer, in schema order): it drives the shard
// datasets, the EXR layers, `inspect` and the trainer's input table
// (trainer/inputs.h). A new auxiliary buffer is one row here, one member of
// FrameBuffers, and its renderer code.
struct BufferInfo {
  const char* name;
  int channels;
  bool per_version;
  const char* channel_names;               // "R,G,B", "X,Y,Z" or "Y" (EXR suffixes)
  std::vector<float> FrameBuffers::*data;  // where a frame keeps it
  // Added after shards were in use: a shard without it is read with the
  // buffer empty (reference_half: the reference ceiling is then unknown).
  bool optional_in_shards = false;
};
const std::vector<BufferInfo>& buffer_infos();
// The row named `name`; throws RuntimeError for an unknown name.
const BufferInfo& buffer_info(std::string_view name);
// Channel suffix `c` of a buffer ("R", "X", "Y", ...).
std::string channel_name(const BufferInfo& b, int c);
// The names are string_views, not const std::string&: a BufferInfo's
// const char* name then binds no temporary, which GCC 13's
// -Wdangling-reference took for a reference into that temporary.
std::vector<float>& buffer_data(FrameBuffers& fb, std::string_view name);
const std::vector<float>& buffer_data(const FrameBuffers& fb, std::string_view name);

}  // namespace dofarm
