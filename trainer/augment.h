// Network inputs and the sequence augmentation of thesis 4.3.3.
//
// Inputs, per frame, in the channel order of model.inputs, each made from its
// buffer by its encoding (trainer/inputs.h; docs/trainer.md lists them).
// Target: the reference demodulated by the same albedo as the input and put
// through the radiance input's encoding, so that remodulating the inverse of
// the target is the reference exactly; the network is trained in that space.
//
// Augmentation draws a SequencePlan once per sample (STYLE.md 11) and applies
// the same crop, rotation and frame order to every frame and to the target.
#pragma once

#include <cstdint>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "trainer/config.h"
#include "trainer/inputs.h"

namespace dofarm::trainer {

inline constexpr int kRadianceChannels = 3;

// Demodulation by albedo and its inverse (thesis 4.3.2; Chaitanya 2017 sec. 4.1).
// The eps keeps black albedo (absorbers, escaped rays) from dividing by zero;
// remodulate(demodulate(x)) == x up to float rounding for every albedo >= 0.
inline float demodulate(float radiance, float albedo, float eps) {
  return radiance / (albedo + eps);
}
inline float remodulate(float demodulated, float albedo, float eps) {
  return demodulated * (albedo + eps);
}

// The planes of one frame (or crop) of `pixels` pixels, by buffer name
// (buffer_infos()): for per-version buffers, the chosen version's planes.
struct FrameView {
  std::map<std::string, const float*> buffers;
  const float* albedo = nullptr;  // 3 planes: the albedo demodulation uses
  float focal_distance = 1;
  size_t pixels = 0;
  // Throws RuntimeError naming the buffer when it is not there.
  const float* at(const std::string& buffer) const;
};

// Points view.albedo at the demodulation albedo (demodulation_buffer(data)),
// replaced by its CoC-sized prefilter (prefilter.h) when data.albedo_prefilter
// asks for one, stored in `storage`, so that every later read of that buffer
// through `view` (inputs, target, remodulation) sees the filtered one: the
// same in training, eval and denoise. width x height: the view's image.
void bind_demodulation_albedo(FrameView& view, const DataConfig& data, int width, int height,
                              std::vector<float>& storage);

// Writes the model input of one frame (ModelConfig::input_channels() planes).
void make_input(const FrameView& frame, const DataConfig& data,
                const std::vector<ResolvedInput>& inputs, float* out);
// Writes the transformed, demodulated target (3 planes).
void make_target(const float* reference, const float* albedo, size_t pixels, const DataConfig& data,
                 RadianceSpace space, float* out);

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
// returns them, by buffer name: per-version buffers (F, V, C, S, S), of which
// only the (frame, version) pairs the plan shows need be filled; the others
// (F, C, S, S).
struct RawCrop {
  int frames = 0, versions = 0, size = 0;
  std::map<std::string, std::vector<float>> buffers;
  std::vector<float> focal_distance;  // F
};

// One training sample: T frames of a square crop, ready for the model.
struct Sample {
  int frames = 0, channels = 0, size = 0;
  std::vector<float> input;   // T, C, S, S
  std::vector<float> target;  // T, 3, S, S (transformed, demodulated)
  std::vector<float> albedo;  // T, 3, S, S (what remodulation multiplies by)
  std::vector<float> coc;     // T, 1, S, S: CoC in pixels (focus-weighted loss); empty without
};

// Applies `plan` to `raw` (whose frame 0 is plan.first_frame, whose crop is
// the plan's): frame order, stops, versions, rotation, demodulation.
// `raw` holds sample_buffers(model, data).
Sample build_sample(const RawCrop& raw, const SequencePlan& plan, const DataConfig& data,
                    const ModelConfig& model);

// Rotates `planes` square planes of side `size` in place by quarter turns
// counter-clockwise as displayed (row 0 at the top).
void rotate_planes(float* data, int planes, int size, int quarter_turns);

}  // namespace dofarm::trainer
