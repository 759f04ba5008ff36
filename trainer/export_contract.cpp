#include "trainer/export_contract.h"

#include <cmath>
#include <nlohmann/json.hpp>

#include "common/exr_io.h"
#include "common/image.h"
#include "trainer/inputs.h"
#include "trainer/model.h"

namespace dofarm::trainer {

using nlohmann::json;

std::string denoiser_contract(const LoadedRun& run) {
  const TrainConfig& cfg = run.config;
  const DataConfig& d = cfg.data;
  const std::string albedo = demodulation_buffer(d) == "albedo" ? "albedo.<v>" : "albedo_ref";
  const RadianceSpace space = radiance_space(cfg.model);
  // One entry per channel, from the input table (trainer/inputs.h): the
  // frame layers it is made from and its transform.
  json inputs = json::array();
  for (const ResolvedInput& in : resolve_inputs(cfg.model, d)) {
    const BufferInfo& b = buffer_info(in.buffer);
    for (int c = 0; c < in.channels; ++c) {
      const std::string ch = channel_name(b, c);
      std::string source = frame_exr_channel(b.name, c, "<v>");  // docs/exr_format.md
      if (std::string(in.row->input) == "radiance") source += ", " + albedo + "." + ch;
      if (std::string(in.row->input) == "depth" && std::string(in.row->encoding) == "focal")
        source += ", header dofarm.camera.focal_distance";
      inputs.push_back({{"index", inputs.size()},
                        {"name", std::string(in.row->input) + (in.channels > 1 ? "." + ch : "")},
                        {"input", in.row->input},
                        {"encoding", in.row->encoding},
                        {"layer", source},
                        {"transform", in.row->formula}});
    }
  }

  json j = {
      {"format", kContractFormat},
      {"dofarm_version", DOFARM_VERSION},
      {"checkpoint",
       {{"file", run.checkpoint.string()},
        {"epoch", run.state.epoch},
        {"step", run.state.step},
        {"weights", run.weights_label()},
        {"best_loss", std::isfinite(run.state.best) ? json(run.state.best) : json()}}},
      {"input_channels", cfg.model.input_channels()},
      {"inputs", inputs},
      {"layout", "NCHW float32, one frame [B, C, H, W], channel order as in inputs"},
      {"size",
       {{"any", true},
        {"multiple", kSizeMultiple},
        {"rule",
         "H and W are padded by edge replication to the next multiple inside "
         "forward() and the output is cropped back"}}},
      {"constants",
       {{"demod_eps", d.demod_eps},
        {"coc_log_scale", d.coc_log_scale},
        {"coc_sharp_px", d.coc_sharp_px},
        {"coc_max_px", d.coc_max_px},
        {"depth_scale", d.depth_scale},
        {"albedo_prefilter", d.albedo_prefilter == AlbedoPrefilter::kCoc ? "coc" : "none"},
        {"albedo_prefilter_scale", d.albedo_prefilter_scale}}},
      {"noisy_version", "<v>: any noisy version of the frame (0 by default)"},
      {"output",
       {{"channels", {"R", "G", "B"}},
        {"transform", std::string("radiance.c = ") + radiance_inverse_formula(space) + " * (" +
                          albedo + ".c + demod_eps)"}}},
      {"recurrent", cfg.model.recurrent},
      {"recurrent_state",
       cfg.model.recurrent
           ? json("forward(x, s0..s4) -> (y, s0..s4); s_i is [B, width_i, Hp / 2^i, Wp / 2^i] "
                  "with Hp, Wp the padded size; zeros on a sequence's first frame")
           : json()},
      {"model_config", to_toml(cfg)},
  };
  return j.dump(1) + "\n";
}

}  // namespace dofarm::trainer
