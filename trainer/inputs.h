// The network's input channels as one table (STYLE.md 18).
//
// Every input the trainer can feed is a row: the input's name, an encoding,
// the buffer of the farm's table (common/image.h, buffer_infos()) it is made
// from, the transform as text (for the export contract and docs) and the
// function that applies it. `model.inputs` in the training config lists the
// inputs in channel order as "name" (the input's first row: its default
// encoding) or "name:encoding"; the width of each input is its buffer's
// channel count, so the network's input width, the shard datasets read, the
// `denoise` inputs, the non-finite check and the export contract all follow
// from the list. A new auxiliary buffer is a row of buffer_infos() plus a
// row here.
//
// The radiance input also fixes the space the network is trained in: the
// target is the reference through the same encoding and the output goes back
// through radiance_inverse() (thesis 4.3.2: demodulated by the albedo).
#pragma once

#include <cstddef>
#include <map>
#include <string>
#include <vector>

#include "trainer/config.h"

namespace dofarm::trainer {

// What an encoding reads for one frame (or crop) of `pixels` pixels.
struct EncodeArgs {
  const float* src = nullptr;     // the source buffer's planes (channels x pixels)
  const float* albedo = nullptr;  // 3 planes: the albedo radiance is demodulated by
  size_t pixels = 0;
  float focal_distance = 1;  // of the frame's camera, scene units
  const DataConfig* data = nullptr;
};

struct InputEncoding {
  const char* input;     // "radiance", "albedo", "normal", "depth", "roughness", "coc"
  const char* encoding;  // the first row of an input is its default encoding
  // Row of buffer_infos() it is made from. For per-version buffers the
  // noisy version being denoised is used. "albedo_ref" stands for the
  // demodulation albedo, which data.albedo may switch to the version's `albedo`.
  const char* buffer;
  const char* formula;  // the transform as text
  void (*encode)(const EncodeArgs& args, float* out);
};
const std::vector<InputEncoding>& input_encodings();

// "name:encoding" for a model.inputs entry ("name" = the default encoding),
// or "" with `error` set ("unknown input 'x'; inputs are radiance, ...").
std::string normalise_input(const std::string& entry, std::string* error);

// model.inputs resolved against the table, in channel order.
struct ResolvedInput {
  const InputEncoding* row = nullptr;
  std::string buffer;  // actual buffer (data.albedo applied)
  int channels = 0;
  int offset = 0;  // first channel of this input
};
std::vector<ResolvedInput> resolve_inputs(const ModelConfig& model, const DataConfig& data);
int input_width(const std::vector<std::string>& inputs);

// The buffer radiance is demodulated by: albedo_ref, or the version's albedo.
std::string demodulation_buffer(const DataConfig& data);

// The buffers a training sample needs: the inputs' sources, the
// demodulation albedo, the reference (target) and the CoC (loss weights).
std::vector<std::string> sample_buffers(const ModelConfig& model, const DataConfig& data);

// The radiance space of the network: encoding of the `radiance` input.
enum class RadianceSpace {
  kLog1p,   // log1p(max(x, 0)): HDR compressed, the project's default
  kLinear,  // x as is (thesis 4.3.2: demodulated, no tone curve)
};
RadianceSpace radiance_space(const ModelConfig& model);
float radiance_forward(float demodulated, RadianceSpace space);
float radiance_inverse(float transformed, RadianceSpace space);
// The inverse transform as text (contract).
const char* radiance_inverse_formula(RadianceSpace space);

// Thesis section 4.2.4 CoC encoding through the physical CoC c in pixels: 1
// where c <= sharp (acceptably sharp), else (max - c) / max.
float coc_thesis(float coc_px, float sharp_px, float max_px);

}  // namespace dofarm::trainer
