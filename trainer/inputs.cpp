#include "trainer/inputs.h"

#include <algorithm>
#include <cmath>

#include "common/error.h"
#include "common/image.h"

namespace dofarm::trainer {

namespace {

// Radiance divided by the albedo (thesis 4.3.2; Chaitanya 2017 sec. 4.1),
// then through the radiance space's curve.
template <RadianceSpace S>
void encode_radiance(const EncodeArgs& a, float* out) {
  const float eps = a.data->demod_eps;
  for (size_t i = 0; i < 3 * a.pixels; ++i)
    out[i] = radiance_forward(a.src[i] / (a.albedo[i] + eps), S);
}

void copy_planes(const EncodeArgs& a, float* out, int channels) {
  std::copy(a.src, a.src + size_t(channels) * a.pixels, out);
}
void encode_as_stored3(const EncodeArgs& a, float* out) { copy_planes(a, out, 3); }
void encode_as_stored1(const EncodeArgs& a, float* out) { copy_planes(a, out, 1); }

// Thesis 4.2.4, listing 1: each camera-space component mapped to a colour
// channel in [0, 1], z negated. The listing's z line reads (-z + 0.5) * 0.5,
// which would map [-1, 1] to [-0.25, 0.75]; we take the evident intent,
// (1 - z) / 2, like x and y. (An affine map of one input channel that the
// first convolution absorbs, up to the zero padding at the border.)
void encode_normal_remap01(const EncodeArgs& a, float* out) {
  const size_t n = a.pixels;
  for (size_t p = 0; p < n; ++p) {
    out[p] = (a.src[p] + 1.0f) * 0.5f;
    out[n + p] = (a.src[n + p] + 1.0f) * 0.5f;
    out[2 * n + p] = (1.0f - a.src[2 * n + p]) * 0.5f;
  }
}

// Depth relative to this frame's focal plane: scale-free (no per-scene
// constant, identical for a crop and the full frame), 0.5 on the focal
// plane, -> 1 far away; escaped rays (stored as 0) are infinitely far.
void encode_depth_focal(const EncodeArgs& a, float* out) {
  const float focal = std::max(a.focal_distance, 1e-6f);
  for (size_t p = 0; p < a.pixels; ++p) {
    const float z = a.src[p];
    out[p] = z > 0.0f && std::isfinite(z) ? z / (z + focal) : 1.0f;
  }
}

// Thesis 4.2.4: depth divided by "an approximate total depth of the scene",
// set by hand per scene (data.depth_scale). The thesis divides the ray
// length; our depth buffer is view depth (docs/renderer.md), which is shorter
// by the cosine of the pixel's angle to the view axis. Escaped rays stay 0
// (the thesis evaluates the buffer only where the primary ray hits).
void encode_depth_scene(const EncodeArgs& a, float* out) {
  const float s = a.data->depth_scale;
  for (size_t p = 0; p < a.pixels; ++p) out[p] = a.src[p] / s;
}

// The project's CoC encoding: physical pixels on a log scale, so one scale
// serves every scene: 0 px -> 0, 1 px -> 0.2, 32 px -> 1 (coc_log_scale =
// ln 33), no clamp.
void encode_coc_log(const EncodeArgs& a, float* out) {
  for (size_t p = 0; p < a.pixels; ++p)
    out[p] = std::log1p(std::max(a.src[p], 0.0f)) / a.data->coc_log_scale;
}

void encode_coc_thesis(const EncodeArgs& a, float* out) {
  for (size_t p = 0; p < a.pixels; ++p)
    out[p] = coc_thesis(a.src[p], a.data->coc_sharp_px, a.data->coc_max_px);
}

}  // namespace

const std::vector<InputEncoding>& input_encodings() {
  static const std::vector<InputEncoding> rows = {
      {"radiance", "log1p", "noisy", "log1p(max(noisy.c / (albedo.c + demod_eps), 0))",
       encode_radiance<RadianceSpace::kLog1p>},
      {"radiance", "linear", "noisy", "noisy.c / (albedo.c + demod_eps)",
       encode_radiance<RadianceSpace::kLinear>},
      {"albedo", "as_stored", "albedo_ref", "as stored", encode_as_stored3},
      {"normal", "as_stored", "normal",
       "as stored (camera space: x right, y up, z towards the viewer; unit)", encode_as_stored3},
      {"normal", "remap01", "normal", "(x + 1) / 2, (y + 1) / 2, (1 - z) / 2 (thesis listing 1)",
       encode_normal_remap01},
      {"depth", "focal", "depth",
       "z / (z + focal_distance) where z > 0 and finite, else 1 (0.5 on the focal plane); "
       "focal_distance from the header dofarm.camera.focal_distance",
       encode_depth_focal},
      {"depth", "scene", "depth", "z / depth_scale (thesis 4.2.4; 0 where the ray escaped)",
       encode_depth_scene},
      {"roughness", "as_stored", "roughness", "as stored", encode_as_stored1},
      {"coc", "log", "coc", "log1p(max(coc, 0)) / coc_log_scale (coc in pixels)", encode_coc_log},
      {"coc", "thesis", "coc",
       "1 where coc <= coc_sharp_px, else (coc_max_px - coc) / coc_max_px (thesis 4.2.4, "
       "listing 2; coc in pixels)",
       encode_coc_thesis},
  };
  return rows;
}

std::string normalise_input(const std::string& entry, std::string* error) {
  const size_t colon = entry.find(':');
  const std::string name = entry.substr(0, colon);
  const std::string enc = colon == std::string::npos ? "" : entry.substr(colon + 1);
  std::vector<std::string> inputs;
  std::string encodings;
  for (const InputEncoding& r : input_encodings()) {
    if (std::find(inputs.begin(), inputs.end(), r.input) == inputs.end()) inputs.push_back(r.input);
    if (name != r.input) continue;
    if (enc.empty() || enc == r.encoding) return name + ":" + r.encoding;
    encodings += (encodings.empty() ? "" : ", ") + std::string(r.encoding);
  }
  if (encodings.empty()) {
    std::string list;
    for (const std::string& i : inputs) list += (list.empty() ? "" : ", ") + i;
    *error = "unknown input '" + name + "'; inputs are " + list;
  } else
    *error = "unknown encoding '" + enc + "' of input '" + name + "'; it takes " + encodings;
  return "";
}

std::string demodulation_buffer(const DataConfig& data) {
  return data.albedo == AlbedoSource::kVersion ? "albedo" : "albedo_ref";
}

namespace {
const InputEncoding& row_of(const std::string& normalised) {
  for (const InputEncoding& r : input_encodings())
    if (normalised == std::string(r.input) + ":" + r.encoding) return r;
  throw RuntimeError("model.inputs: '" + normalised + "' is not in the input table");
}
}  // namespace

std::vector<ResolvedInput> resolve_inputs(const ModelConfig& model, const DataConfig& data) {
  std::vector<ResolvedInput> out;
  int offset = 0;
  for (const std::string& e : model.inputs) {
    ResolvedInput r;
    r.row = &row_of(e);
    r.buffer =
        r.row->buffer == std::string("albedo_ref") ? demodulation_buffer(data) : r.row->buffer;
    r.channels = buffer_info(r.buffer).channels;
    r.offset = offset;
    offset += r.channels;
    out.push_back(r);
  }
  return out;
}

int input_width(const std::vector<std::string>& inputs) {
  int c = 0;
  for (const std::string& e : inputs) c += buffer_info(row_of(e).buffer).channels;
  return c;
}

std::vector<std::string> sample_buffers(const ModelConfig& model, const DataConfig& data) {
  // The CoC always: the focus-weighted loss and the eval masks use it
  // whether or not the network sees it (1 plane of ~20).
  std::vector<std::string> out = {demodulation_buffer(data), "reference", "coc"};
  for (const ResolvedInput& r : resolve_inputs(model, data))
    if (std::find(out.begin(), out.end(), r.buffer) == out.end()) out.push_back(r.buffer);
  return out;
}

RadianceSpace radiance_space(const ModelConfig& model) {
  for (const std::string& e : model.inputs)
    if (e == "radiance:linear") return RadianceSpace::kLinear;
  return RadianceSpace::kLog1p;
}

// log1p compresses the HDR range (1-spp fireflies reach 1e3 and more) so that
// L1 is not dominated by a few pixels; it is exact to invert.
float radiance_forward(float demodulated, RadianceSpace space) {
  return space == RadianceSpace::kLog1p ? std::log1p(std::max(demodulated, 0.0f)) : demodulated;
}
float radiance_inverse(float transformed, RadianceSpace space) {
  return space == RadianceSpace::kLog1p ? std::expm1(std::max(transformed, 0.0f))
                                        : std::max(transformed, 0.0f);
}
const char* radiance_inverse_formula(RadianceSpace space) {
  return space == RadianceSpace::kLog1p ? "expm1(max(y.c, 0))" : "max(y.c, 0)";
}

float coc_thesis(float coc_px, float sharp_px, float max_px) {
  // Listing 2 of the thesis, with its "mm" sizes replaced by pixels.
  return coc_px <= sharp_px ? 1.0f : (max_px - coc_px) / max_px;
}

}  // namespace dofarm::trainer
