// dofarm-train: trains and applies the denoiser (DESIGN.md, "Command line").
//
//   dofarm-train train --data DIR --run RUNDIR [--config TRAIN.toml] [--set K=V]...
//   dofarm-train eval --run RUNDIR --data DIR --out REPORTDIR
//   dofarm-train denoise --run RUNDIR IN.exr OUT.exr
//   dofarm-train export --run RUNDIR --out MODEL.pt
//
// Exit status: 0 success, 2 bad input (SpecError, CLI11 parse errors), 1 any
// other failure, with the error as one line "dofarm-train: error: ..." on stderr.
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "apps/cli_main.h"
#include "common/error.h"
#include "common/exr_io.h"
#include "common/log.h"
#include "trainer/config.h"
#include "trainer/eval.h"
#include "trainer/train.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;
using namespace dofarm::trainer;

Command add_train(CLI::App& app) {
  auto* cmd = app.add_subcommand("train", "train a denoiser; resumes when RUNDIR holds a run");
  struct Opts {
    std::string data, run, config;
    std::vector<std::string> sets;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--data", o->data, "farm output folder (manifest.json or *.h5 shards)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cmd->add_option("--run", o->run, "run folder: config, checkpoints, logs")->required();
  cmd->add_option("--config", o->config, "training config (TOML; docs/trainer.md)")
      ->check(CLI::ExistingFile);
  cmd->add_option("--set", o->sets,
                  "override a config key, checked like the file: KEY=VALUE, e.g. "
                  "train.epochs=2 (repeatable)")
      ->type_name("KEY=VALUE")
      ->allow_extra_args(false);
  return {cmd, [o] {
            TrainOptions t;
            t.data_dir = o->data;
            t.run_dir = o->run;
            t.config = load_train_config(o->config, o->sets);
            TrainResult r = train(t);
            spdlog::info("{} epochs ({} steps); best loss {:.5f}; {} skipped steps, {} rollbacks",
                         r.epochs, r.steps, r.best_val, r.skipped_steps, r.rollbacks);
            return kExitOk;
          }};
}

Command add_eval(CLI::App& app) {
  auto* cmd = app.add_subcommand("eval", "score the run on its validation frames (report)");
  struct Opts {
    std::string run, data, out;
    int frames = 0, images = 8, version = 0;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--run", o->run, "run folder")->required()->check(CLI::ExistingDirectory);
  cmd->add_option("--data", o->data, "farm output folder")
      ->required()
      ->check(CLI::ExistingDirectory);
  cmd->add_option("--out", o->out, "report folder (report.md, report.json, PNGs)")->required();
  cmd->add_option("--frames", o->frames, "at most this many frames (0 = all)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--images", o->images, "comparison PNGs to write")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--noisy-version", o->version, "noisy version fed to the network")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  return {cmd, [o] {
            EvalOptions e{o->run, o->data, o->out, o->frames, o->images, o->version};
            EvalSummary s = evaluate(e);
            std::printf("%d frames: SSIM %.4f  PSNR %.2f dB  relMSE %.4f  %.2f ms/frame\n",
                        s.frames, s.ssim, s.psnr, s.rel_mse, s.ms);
            return kExitOk;
          }};
}

Command add_denoise(CLI::App& app) {
  auto* cmd = app.add_subcommand("denoise", "denoise one frame EXR (as `dofarm render` writes)");
  struct Opts {
    std::string run, in, out;
    int version = 0;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--run", o->run, "run folder")->required()->check(CLI::ExistingDirectory);
  cmd->add_option("IN", o->in, "frame EXR with all buffers")->required()->check(CLI::ExistingFile);
  cmd->add_option("OUT", o->out, "denoised RGB EXR")->required();
  cmd->add_option("--noisy-version", o->version, "noisy version to denoise")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  return {cmd, [o] {
            FrameDenoiser den(o->run, pick_device("auto"));
            ExrFrame frame;
            try {
              frame = read_frame_exr(o->in);
            } catch (const RuntimeError& e) {
              // A file that is not a dofarm frame EXR is bad input, not a failure.
              throw SpecError(FileLoc{o->in}, "", e.what());
            }
            const FrameBuffers& fb = frame.buffers;
            if (o->version >= fb.versions)
              throw SpecError(FileLoc{"--noisy-version"}, "",
                              "the frame has " + std::to_string(fb.versions) + " noisy versions");
            if (den.config().model.dof && fb.coc.empty())
              throw SpecError(FileLoc{o->in}, "coc", "the model needs a coc layer");
            double sec = 0;
            std::vector<float> out = den.denoise(fb, o->version, &sec);
            RgbImage img;
            img.width = fb.width;
            img.height = fb.height;
            img.rgb.resize(out.size());
            const size_t n = fb.plane();
            for (size_t p = 0; p < n; ++p)
              for (int c = 0; c < 3; ++c) img.rgb[p * 3 + c] = out[c * n + p];
            write_rgb_exr(o->out, img);
            spdlog::info("denoised {}x{} in {:.1f} ms -> {}", fb.width, fb.height, sec * 1e3,
                         o->out);
            return kExitOk;
          }};
}

Command add_export(CLI::App& app) {
  auto* cmd = app.add_subcommand("export", "write the trained model as TorchScript");
  struct Opts {
    std::string run, out;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--run", o->run, "run folder")->required()->check(CLI::ExistingDirectory);
  cmd->add_option("--out", o->out, "TorchScript file (torch.jit.load)")->required();
  return {cmd, [o] {
            LoadedRun r = load_run(o->run, torch::kCPU);
            r.model->export_torchscript(o->out);
            spdlog::info("exported {} ({} parameters{}) to {}", r.checkpoint.string(),
                         parameter_count(*r.model),
                         r.config.model.recurrent ? ", recurrent: forward(x, s0..s4)" : "", o->out);
            return kExitOk;
          }};
}

int run_main(int argc, char** argv) {
  CLI::App app{"dofarm-train: trains and applies the depth-of-field denoiser", "dofarm-train"};
  return run_cli(app, "dofarm-train", argc, argv, [](CLI::App& a) {
    return std::vector<Command>{add_train(a), add_eval(a), add_denoise(a), add_export(a)};
  });
}

}  // namespace
}  // namespace dofarm

int main(int argc, char** argv) { return dofarm::run_main(argc, argv); }
