#include "trainer/export_contract.h"

#include <cmath>
#include <nlohmann/json.hpp>

#include "trainer/model.h"

namespace dofarm::trainer {

using nlohmann::json;

std::string denoiser_contract(const LoadedRun& run) {
  const TrainConfig& cfg = run.config;
  const DataConfig& d = cfg.data;
  const bool own_albedo = d.albedo == AlbedoSource::kVersion;
  const std::string albedo = own_albedo ? "albedo.<v>" : "albedo_ref";
  json inputs = json::array();
  auto add = [&](const std::string& name, const std::string& layer, const std::string& transform) {
    inputs.push_back({{"index", inputs.size()}, {"name", name}, {"layer", layer},
                      {"transform", transform}});
  };
  for (const char* c : {"R", "G", "B"})
    add(std::string("radiance.") + c, std::string("noisy.<v>.") + c + ", " + albedo + "." + c,
        std::string("log1p(max(noisy.") + c + " / (" + albedo + "." + c + " + demod_eps), 0))");
  for (const char* c : {"R", "G", "B"})
    add(std::string("albedo.") + c, albedo + "." + c, "as stored");
  // Frame EXR layers as docs/exr_format.md names them (normal x, y, z in R, G, B).
  for (int c = 0; c < 3; ++c)
    add(std::string("normal.") + "XYZ"[c], std::string("normal.") + "RGB"[c], "as stored (camera space: x right, y up, z towards the viewer; unit)");
  add("depth", "Z, header dofarm.camera.focal_distance",
      "z / (z + focal_distance) where z > 0 and finite, else 1 (0.5 on the focal plane)");
  add("roughness", "roughness.Y", "as stored");
  if (cfg.model.dof) add("coc", "coc.Y", "log1p(max(coc, 0)) / coc_log_scale (coc in pixels)");

  json j = {
      {"format", kContractFormat},
      {"dofarm_version", DOFARM_VERSION},
      {"checkpoint",
       {{"file", run.checkpoint.string()},
        {"epoch", run.state.epoch},
        {"step", run.state.step},
        {"best_loss", std::isfinite(run.state.best) ? json(run.state.best) : json()}}},
      {"input_channels", cfg.model.input_channels()},
      {"inputs", inputs},
      {"layout", "NCHW float32, one frame [B, C, H, W], channel order as in inputs"},
      {"size", {{"any", true},
                {"multiple", kSizeMultiple},
                {"rule", "H and W are padded by edge replication to the next multiple inside "
                         "forward() and the output is cropped back"}}},
      {"constants", {{"demod_eps", d.demod_eps}, {"coc_log_scale", d.coc_log_scale}}},
      {"noisy_version", "<v>: any noisy version of the frame (0 by default)"},
      {"output",
       {{"channels", {"R", "G", "B"}},
        {"transform", "radiance.c = expm1(max(y.c, 0)) * (" + albedo + ".c + demod_eps)"}}},
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
