// Frames to denoise, from any renderer, as the FrameBuffers that
// read_frame_exr() gives for dofarm's own EXRs (common/image.h): the network's
// input is then built from them exactly as for a dofarm frame (inference.h,
// FrameDenoiser). Three sources (docs/trainer.md, "Denoising other renderers'
// frames"):
//
//   dofarm   a frame EXR of `dofarm render` (docs/exr_format.md), as it is;
//   cycles   a Blender/Cycles multilayer EXR with the view layer's Combined,
//            Denoising Albedo, Denoising Normal and Depth (or Denoising
//            Depth) passes;
//   files    a colour image with separate albedo, normal and depth files, as
//            Open Image Denoise's tools take them (EXR or PFM).
//
// Foreign frames are converted to dofarm's conventions: one noisy version;
// the albedo as both `albedo.0` and `albedo_ref`; normals in view space
// (x right, y up, z towards the viewer), unit length; depth as view-space z
// with 0 where the ray escapes; the circle of confusion computed from the
// depth and the lens with the renderer's formula (common/thin_lens.h);
// a constant roughness (no renderer writes GGX roughness as a pass).
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "common/image.h"

namespace dofarm::trainer {

// The camera's lens, Blender's way. Unset values come from the file's
// metadata (Blender's "Lens" stamp, dofarm.lens.* attributes), then from the
// defaults named in docs/trainer.md.
struct LensOptions {
  std::optional<double> fstop;            // f-number; 0 = pinhole
  std::optional<double> focal_length_mm;  // mm
  std::optional<double> sensor_width_mm;  // mm, spans the longer image side (Blender: 36)
  std::optional<double> focus_distance;   // scene units (metres) from the camera
  std::optional<double> clip_start;       // Cycles' Denoising Depth origin (Blender: 0.1 m)
};

enum class NormalSpace {
  kView,    // x right, y up, z towards the viewer (dofarm, OpenGL camera space)
  kCycles,  // x right, y up, z away from the viewer (Cycles' camera space)
};

struct ForeignInputs {
  std::filesystem::path input;                    // IN: any of the three sources
  std::filesystem::path albedo, normal, depth;    // separate files (source `files`)
  std::string view_layer;                         // Cycles view layer ("" = the only one)
  NormalSpace normal_space = NormalSpace::kView;  // of a separate normal file
  LensOptions lens;
  float roughness = 0.5f;  // for sources without a roughness pass
};

struct DenoiseInput {
  FrameBuffers frame;              // a dofarm tile keeps its rect
  std::string source;              // "dofarm", "cycles" or "files"
  std::vector<float> alpha;        // H*W to carry to the output (Cycles' Combined.A), or empty
  std::vector<std::string> notes;  // what was assumed or converted, for the log
};

// Reads and converts. Throws SpecError naming the file, channel or option
// on bad input (a missing pass, mismatched sizes, a lens the model needs but
// nobody gave, a malformed PFM); RuntimeError when a file cannot be read.
// `needs_coc`: the model takes the circle of confusion.
DenoiseInput load_denoise_input(const ForeignInputs& in, bool needs_coc);

}  // namespace dofarm::trainer
