// Network inputs and the sequence augmentation of thesis 4.3.3.
//
// Inputs, per frame, channel order (docs/trainer.md):
//   0-2  noisy radiance, demodulated:  log1p(max(L, 0) / (albedo + eps))
//   3-5  albedo                        as stored, [0, 1]
//   6-8  view-space normal             as stored, [-1, 1]
//   9    depth                         z / (z + focal distance); 1 where the ray escapes
//   10   roughness                     as stored, [0, 1]
//   11   circle of confusion (DOF)     log1p(coc_px) / coc_log_scale
// Target: log1p(max(reference, 0) / (albedo + eps)) with the same albedo as the
// input, so that remodulate(target) is the reference exactly; the network is
// trained in that space and its output is remodulated by remodulate().
//
// Augmentation draws a SequencePlan once per sample (STYLE.md 11) and applies
// the same crop, rotation and frame order to every frame and to the target.
#pragma once

#include <cstdint>
#include <random>
#include <vector>

#include "trainer/config.h"

namespace dofarm::trainer {

inline constexpr int kRadianceChannels = 3;
inline constexpr int kNormalChannel = 6;  // first of the three normal channels

// Demodulation by albedo and its inverse (thesis 4.1; Chaitanya 2017 sec. 4.1).
// The eps keeps black albedo (absorbers, escaped rays) from dividing by zero;
// remodulate(demodulate(x)) == x up to float rounding for every albedo >= 0.
inline float demodulate(float radiance, float albedo, float eps) {
  return radiance / (albedo + eps);
}
inline float remodulate(float demodulated, float albedo, float eps) {
  return demodulated * (albedo + eps);
}
// The radiance transform of inputs and targets and its inverse.
float radiance_forward(float demodulated);
float radiance_inverse(float transformed);

// Pointers to the buffers of one frame (or crop) of `pixels` pixels, planar.
struct FrameView {
  const float* noisy = nullptr;   // 3 planes: the chosen 1-spp version
  const float* albedo = nullptr;  // 3 planes: the albedo demodulation uses
  const float* normal = nullptr;  // 3 planes
  const float* depth = nullptr;
  const float* roughness = nullptr;
  const float* coc = nullptr;  // may be null when the model has no CoC input
  float focal_distance = 1;
  size_t pixels = 0;
};

// Writes the model input of one frame (ModelConfig::input_channels() planes).
void make_input(const FrameView& frame, const DataConfig& data, bool dof, float* out);
// Writes the transformed, demodulated target (3 planes).
void make_target(const float* reference, const float* albedo, size_t pixels, const DataConfig& data,
                 float* out);

// What one training sequence is made of; drawn once per sample.
struct SequencePlan {
  int first_frame = 0;           // shard frame index of the earliest source frame
  int span = 0;                  // consecutive source frames the sequence touches
  std::vector<int> offset;       // per step: source frame = first_frame + offset
  std::vector<int> version;      // per step: noisy version
  std::vector<uint8_t> stopped;  // per step: the camera stopped (frame repeated)
  bool reversed = false;
  int crop_x = 0, crop_y = 0;
  int quarter_turns = 0;  // counter-clockwise rotation, 0..3
};

// Draws a plan for a sequence inside frames [frame_begin, frame_end) of a
// shard of `versions` versions and size width x height. The range must hold at
// least data.sequence frames and the image at least data.crop pixels a side.
SequencePlan draw_plan(std::mt19937_64& rng, const DataConfig& data, int frame_begin, int frame_end,
                       int versions, int width, int height);

// `span` consecutive frames of one square crop, as ShardReader::read_crop
// returns them (frame, [version,] channel, y, x).
struct RawCrop {
  int frames = 0, versions = 0, size = 0;
  std::vector<float> noisy, albedo;                  // F, V, 3, S, S
  std::vector<float> albedo_ref, reference, normal;  // F, 3, S, S
  std::vector<float> depth, roughness, coc;          // F, 1, S, S
  std::vector<float> focal_distance;                 // F
};

// One training sample: T frames of a square crop, ready for the model.
struct Sample {
  int frames = 0, channels = 0, size = 0;
  std::vector<float> input;   // T, C, S, S
  std::vector<float> target;  // T, 3, S, S (transformed, demodulated)
  std::vector<float> albedo;  // T, 3, S, S (what remodulation multiplies by)
  std::vector<float> coc;     // T, 1, S, S (pixels; splits in/out of focus)
};

// Applies `plan` to `raw` (whose frame 0 is plan.first_frame, whose crop is
// the plan's): frame order, stops, versions, rotation, demodulation.
Sample build_sample(const RawCrop& raw, const SequencePlan& plan, const DataConfig& data, bool dof);

// Rotates `planes` square planes of side `size` in place by quarter turns
// counter-clockwise as displayed (row 0 at the top).
void rotate_planes(float* data, int planes, int size, int quarter_turns);

}  // namespace dofarm::trainer
