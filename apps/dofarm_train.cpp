// dofarm-train: trains and applies the denoiser (DESIGN.md, "Command line").
//
//   dofarm-train train --data DIR --run RUNDIR [--preset NAME] [--config TRAIN.toml]
//                      [--set K=V]... [--save-every STEPS]
//   dofarm-train eval --run RUNDIR --data DIR --out REPORTDIR [--checkpoint best|last|PATH]
//                     [--validation-only] [--time-size N] [--time-reps R]
//   dofarm-train denoise --run RUNDIR IN OUT.exr [--checkpoint ...] [--repair-nonfinite]
//                        [--albedo F --normal F --depth F] [--fstop N --focal-length MM
//                        --sensor-width MM --focus-distance D] (other renderers' frames)
//   dofarm-train export --run RUNDIR --out MODEL.pt [--checkpoint ...]
//
// A global --threads N sets the intra-op threads (0 = OMP_NUM_THREADS, else
// every CPU the process may use).
//
// Exit status: 0 success, 2 bad input (SpecError, CLI11 parse errors), 1 any
// other failure, with the error as one line "dofarm-train: error: ..." on
// stderr; 3 (kExitStopped) when `train` stopped on SIGINT/SIGTERM after
// finishing its step and writing last.pt (run the same command to resume).
// A second signal ends the process at once, as the signal's default does.
#include <ATen/Parallel.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "apps/cli_main.h"
#include "common/error.h"
#include "common/exr_io.h"
#include "common/file_bytes.h"
#include "common/log.h"
#include "common/stop_signals.h"
#include "trainer/config.h"
#include "trainer/eval.h"
#include "trainer/export_contract.h"
#include "trainer/foreign_frame.h"
#include "trainer/inputs.h"
#include "trainer/precision.h"
#include "trainer/run_folder.h"
#include "trainer/step_runner.h"
#include "trainer/train.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;
using namespace dofarm::trainer;

// `train` stopped on request with its checkpoint written.
constexpr int kExitStopped = 3;

void add_precision_option(CLI::App* cmd, std::string* which) {
  cmd->add_option("--precision", *which,
                  "the network's arithmetic: fp32, or bf16 (bfloat16 autocast, CPU only; "
                  "docs/trainer.md)")
      ->capture_default_str()
      ->check(CLI::IsMember(names_of(precision_names())));
}

// --checkpoint and --weights: which file of a run, and which of its weights.
void add_checkpoint_option(CLI::App* cmd, std::string* which, std::string* weights) {
  cmd->add_option("--checkpoint", *which,
                  "best (lowest validation loss), last, or a checkpoint file")
      ->capture_default_str();
  cmd->add_option("--weights", *weights,
                  "auto (the moving average when the run kept one, train.ema), averaged, or raw "
                  "(the trained weights after the checkpoint's last step)")
      ->capture_default_str()
      ->check(CLI::IsMember(names_of(weights_names())));
}

Weights parse_weights(const std::string& name) {
  return value_of(weights_names(), name, "--weights");
}

Command add_train(CLI::App& app) {
  auto* cmd = app.add_subcommand("train", "train a denoiser; resumes when RUNDIR holds a run");
  struct Opts {
    std::string data, run, config, preset;
    std::vector<std::string> sets;
    int64_t save_every = 0;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--data", o->data, "farm output folder (manifest.json or *.h5 shards)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cmd->add_option("--run", o->run, "run folder: config, checkpoints, logs")->required();
  cmd->add_option("--preset", o->preset,
                  "start from a built-in config: default, or thesis (every value the thesis "
                  "states; docs/trainer.md); --config and --set apply over it");
  cmd->add_option("--config", o->config, "training config (TOML; docs/trainer.md)")
      ->check(CLI::ExistingFile);
  cmd->add_option("--set", o->sets,
                  "override a config key, checked like the file: KEY=VALUE, e.g. "
                  "train.epochs=2 (repeatable)")
      ->type_name("KEY=VALUE")
      ->allow_extra_args(false);
  cmd->add_option("--save-every", o->save_every,
                  "also write a checkpoint every this many steps, kept as "
                  "checkpoints/step-NNNNNNNN.pt (0 = at the end of each epoch only)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  return {cmd, [o] {
            TrainOptions t;
            t.data_dir = o->data;
            t.run_dir = o->run;
            const fs::path stored = t.run_dir / "config.toml";
            if (fs::exists(stored)) {
              // A resumed run keeps its settings: --config and --set change
              // only the keys they name, and each change is logged.
              const TrainConfig saved = parse_train_config(read_file_bytes(stored), stored);
              const TrainConfig base = o->preset.empty() ? saved : apply_preset(o->preset, saved);
              t.config = load_train_config(o->config, o->sets, &base);
              for (const std::string& c : config_changes(saved, t.config))
                spdlog::info("resume with a changed setting: {}", c);
            } else {
              const TrainConfig base = o->preset.empty() ? TrainConfig{} : apply_preset(o->preset);
              t.config = load_train_config(o->config, o->sets, &base);
            }
            t.save_every = o->save_every;
            t.stop = &stop_requested();
            install_stop_signals(RepeatedSignal::kTerminates);
            TrainResult r = train(t);
            spdlog::info("{} epochs ({} steps); best loss {:.5f}; {} skipped steps, {} rollbacks",
                         r.epochs, r.steps, r.best_val, r.skipped_steps, r.rollbacks);
            return r.stopped ? kExitStopped : kExitOk;
          }};
}

Command add_eval(CLI::App& app) {
  auto* cmd = app.add_subcommand("eval", "score the run on its validation frames (report)");
  struct Opts {
    std::string run, data, out, checkpoint = "best", precision = "fp32", weights = "auto";
    int frames = 0, images = 8, version = 0, time_size = 0, time_reps = 3, crops = 2,
        crop_size = 64;
    bool validation_only = false;
    bool held_out = false;
    float coc_override = NAN;
    std::vector<std::string> flatten_inputs;
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
  add_checkpoint_option(cmd, &o->checkpoint, &o->weights);
  add_precision_option(cmd, &o->precision);
  cmd->add_flag("--validation-only", o->validation_only,
                "score only the validation frames (by default the report also has a table over "
                "all frames, as thesis table 5.1)");
  cmd->add_flag("--held-out", o->held_out,
                "every frame of --data is a validation frame: frames rendered apart from the "
                "run's training data (e.g. at cleaner references); a shard the run trained on "
                "is refused");
  cmd->add_option("--time-size", o->time_size,
                  "also time the denoise of an N x N frame (the first validation frame repeated "
                  "to that size; 0 = off)")
      ->capture_default_str()
      ->check(CLI::Range(0, 16384));
  cmd->add_option("--crops", o->crops,
                  "side-by-side crops (noisy, denoised, reference) of the smallest- and "
                  "largest-CoC windows of this many most blurred validation frames (those with "
                  "a sharp window first; every shard's best before any shard's second; crops/; "
                  "0 = none)")
      ->capture_default_str()
      ->check(CLI::Range(0, 10000));
  cmd->add_option("--crop-size", o->crop_size, "crop window side in pixels (drawn 2x)")
      ->capture_default_str()
      ->check(CLI::Range(4, 4096));
  cmd->add_option("--time-reps", o->time_reps,
                  "timed runs at --time-size (median; after a warm-up)")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  cmd->add_option("--coc-override", o->coc_override,
                  "probe the CoC input: feed the network this circle of confusion (pixels) at "
                  "every pixel instead of the frame's own (0 = all in focus); the in-focus and "
                  "out-of-focus regions still come from the frame's own CoC")
      ->check(CLI::Validator(
          [](std::string& v) {
            // Range passes NaN (no comparison holds); NaN would mean "off".
            char* end = nullptr;
            const float x = std::strtof(v.c_str(), &end);
            return std::isfinite(x) ? std::string() : "expected a finite number, got " + v;
          },
          "PX"))
      ->check(CLI::Range(0.0f, 1e4f));
  cmd->add_option("--flatten-input", o->flatten_inputs,
                  "probe which inputs the network uses: feed it this buffer (e.g. depth, coc, "
                  "normal) as the frame's mean, channel by channel, instead of its own; may be "
                  "given several times");
  return {cmd, [o] {
            EvalOptions e{o->run, o->data, o->out, o->frames, o->images, o->version, o->checkpoint};
            e.coc_override = o->coc_override;
            e.flatten_inputs = o->flatten_inputs;
            e.all_frames = !o->validation_only;
            e.held_out = o->held_out;
            e.time_side = o->time_size;
            e.time_reps = o->time_reps;
            e.precision = parse_precision(o->precision, "--precision");
            e.weights = parse_weights(o->weights);
            e.crops = o->crops;
            e.crop_side = o->crop_size;
            EvalSummary s = evaluate(e);
            std::printf(
                "%d frames: SSIM %.4f  PSNR %.2f dB  relMSE %.4f  flicker %.4g  %.2f ms/frame\n",
                s.frames, s.ssim, s.psnr, s.rel_mse, s.flicker, s.ms);
            if (e.time_side > 0)
              std::printf("%.2f ms per %dx%d frame\n", s.ms_at_size, e.time_side, e.time_side);
            if (e.all_frames)
              std::printf("all %d frames (training + validation, thesis table 5.1): SSIM %.4f\n",
                          s.frames_all, s.ssim_all);
            return kExitOk;
          }};
}

Command add_denoise(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "denoise",
      "denoise one frame: a dofarm frame EXR, a Blender/Cycles multilayer EXR, or a colour "
      "image with --albedo/--normal/--depth files (docs/trainer.md)");
  struct Opts {
    std::string run, in, out, checkpoint = "best", weights = "auto", albedo, normal, depth,
                              view_layer;
    std::string normal_space = "view", device = "auto", precision = "fp32";
    int version = 0;
    bool repair = false;
    std::optional<double> fstop, focal_length, sensor_width, focus_distance, clip_start;
    float roughness = 0.5f;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--run", o->run, "run folder")->required()->check(CLI::ExistingDirectory);
  cmd->add_option("IN", o->in, "frame to denoise (.exr; .pfm with --albedo/--normal/--depth)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd->add_option("OUT", o->out, "denoised RGB(A) EXR, with IN's header attributes")->required();
  cmd->add_option("--noisy-version", o->version, "noisy version to denoise (dofarm frames)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  add_checkpoint_option(cmd, &o->checkpoint, &o->weights);
  cmd->add_option("--device", o->device,
                  "where the network runs: auto (CUDA when usable), cpu or cuda")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "cpu", "cuda"}));
  add_precision_option(cmd, &o->precision);
  cmd->add_flag("--repair-nonfinite", o->repair,
                "set NaN/Inf input values to 0 (counted in the log) instead of refusing the frame");
  auto* files = cmd->add_option_group("separate passes",
                                      "a colour image's passes as files, as "
                                      "Open Image Denoise's tools take them");
  files->add_option("--albedo", o->albedo, "albedo image (.exr R,G,B or .pfm)")
      ->check(CLI::ExistingFile);
  files->add_option("--normal", o->normal, "normal image (.exr R,G,B or X,Y,Z, or .pfm)")
      ->check(CLI::ExistingFile);
  files->add_option("--depth", o->depth, "view-space depth (.exr Z, Y or R, or .pfm); 0 = no hit")
      ->check(CLI::ExistingFile);
  files
      ->add_option("--normal-space", o->normal_space,
                   "the normal file's axes: view (x right, y up, z towards the viewer) or "
                   "cycles (z away from the viewer)")
      ->capture_default_str()
      ->check(CLI::IsMember({"view", "cycles"}));
  cmd->add_option("--view-layer", o->view_layer,
                  "the view layer of a multilayer EXR with several (default: the only one)");
  auto* lens = cmd->add_option_group(
      "lens",
      "the camera of a frame from another renderer (Blender's settings; unset: from the "
      "header, else the defaults)");
  lens->add_option("--fstop", o->fstop, "f-number (0 = pinhole); needed by a DOF model")
      ->check(CLI::NonNegativeNumber);
  lens->add_option("--focal-length", o->focal_length,
                   "focal length in mm (default: the header's 'Lens' stamp)")
      ->check(CLI::PositiveNumber);
  lens->add_option("--sensor-width", o->sensor_width,
                   "sensor width in mm across the longer image side (default 36)")
      ->check(CLI::PositiveNumber);
  lens->add_option("--focus-distance", o->focus_distance, "focus distance in scene units (m)")
      ->check(CLI::PositiveNumber);
  lens->add_option("--clip-start", o->clip_start,
                   "camera clip start (m), the origin of Cycles' Denoising Depth (default 0.1)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--roughness", o->roughness,
                  "roughness given to every pixel of a frame without a roughness pass")
      ->capture_default_str()
      ->check(CLI::Range(0.0f, 1.0f));
  return {
      cmd, [o] {
        // Never over an input: same path, or another name of the same file.
        for (const std::string& input : {o->in, o->albedo, o->normal, o->depth}) {
          if (input.empty()) continue;
          std::error_code ec;
          if (fs::weakly_canonical(input, ec) == fs::weakly_canonical(o->out, ec) ||
              fs::equivalent(input, o->out, ec))
            throw SpecError(FileLoc{o->out}, "OUT",
                            "is an input (" + input +
                                "); denoise writes a new file and never replaces its input");
        }
        FrameDenoiser den(o->run, pick_device(o->device), o->checkpoint,
                          parse_precision(o->precision, "--precision"), parse_weights(o->weights));
        ForeignInputs fi;
        fi.input = o->in;
        fi.albedo = o->albedo;
        fi.normal = o->normal;
        fi.depth = o->depth;
        fi.view_layer = o->view_layer;
        fi.normal_space = o->normal_space == "cycles" ? NormalSpace::kCycles : NormalSpace::kView;
        fi.lens = {o->fstop, o->focal_length, o->sensor_width, o->focus_distance, o->clip_start};
        fi.roughness = o->roughness;
        DenoiseInput input = load_denoise_input(fi, den.config().model.has_coc());
        for (const std::string& note : input.notes) spdlog::info("{}: {}", o->in, note);
        FrameBuffers& fb = input.frame;
        for (const ResolvedInput& in : resolve_inputs(den.config().model, den.config().data))
          if (buffer_data(fb, in.buffer).empty())
            throw SpecError(FileLoc{o->in}, in.buffer, "the model needs a " + in.buffer + " layer");
        if (o->version >= fb.versions)
          throw SpecError(FileLoc{"--noisy-version"}, "",
                          "the frame has " + std::to_string(fb.versions) + " noisy versions");
        const auto bad = non_finite_inputs(fb, o->version, den.config(), o->repair);
        if (!bad.empty()) {
          std::string list;
          for (const auto& [layer, count] : bad)
            list += (list.empty() ? "" : ", ") + layer + ": " + std::to_string(count);
          if (!o->repair)
            throw SpecError(FileLoc{o->in}, "",
                            "non-finite input values (" + list +
                                "); the frame is damaged (or pass --repair-nonfinite to "
                                "set them to 0)");
          spdlog::warn("{}: set non-finite input values to 0 ({})", o->in, list);
        }
        double sec = 0;
        std::vector<float> out = den.denoise(fb, o->version, &sec);
        RgbImage img;
        img.width = fb.width;
        img.height = fb.height;
        img.rgb.resize(out.size());
        const size_t n = fb.plane();
        for (size_t p = 0; p < n; ++p)
          for (int c = 0; c < 3; ++c) img.rgb[p * 3 + c] = out[c * n + p];
        // The input's header, and what made this file from it.
        const LoadedRun& run = den.run();
        const std::map<std::string, std::string> made_by = {
            {"Software", std::string("dofarm-train denoise ") + DOFARM_VERSION},
            {"dofarm.denoise.input", fs::path(o->in).filename().string()},
            {"dofarm.denoise.source", input.source},
            {"dofarm.denoise.noisy_version", std::to_string(o->version)},
            {"dofarm.denoise.run", fs::absolute(o->run).lexically_normal().string()},
            {"dofarm.denoise.checkpoint", run.checkpoint.string()},
            {"dofarm.denoise.step", std::to_string(run.state.step)},
            {"dofarm.denoise.weights", run.weights_label()},
        };
        write_rgb_exr_like(o->out, img, input.alpha, o->in, made_by);
        spdlog::info("denoised {}x{} ({} frame) in {:.1f} ms -> {}", fb.width, fb.height,
                     input.source, sec * 1e3, o->out);
        return kExitOk;
      }};
}

Command add_export(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "export", "write the trained model as TorchScript, or its weights alone as a checkpoint");
  struct Opts {
    std::string run, out, checkpoint = "best", weights = "auto", format = "torchscript";
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--run", o->run, "run folder")->required()->check(CLI::ExistingDirectory);
  cmd->add_option("--out", o->out, "the file to write")->required();
  cmd->add_option("--format", o->format,
                  "torchscript (torch.jit.load, with its contract) or checkpoint (the chosen "
                  "weights without the optimizer state, for eval/denoise --checkpoint FILE on "
                  "another machine; training cannot resume from it)")
      ->check(CLI::IsMember({"torchscript", "checkpoint"}));
  add_checkpoint_option(cmd, &o->checkpoint, &o->weights);
  return {cmd, [o] {
            LoadedRun r = load_run(o->run, torch::kCPU, o->checkpoint, parse_weights(o->weights));
            if (o->format == "checkpoint") {
              save_weights_checkpoint(o->out, r);
              spdlog::info("wrote the {} weights of {} (step {}) to {}",
                           r.averaged ? "averaged" : "trained", r.checkpoint.string(), r.state.step,
                           o->out);
              return kExitOk;
            }
            r.model->export_torchscript(o->out, {{kContractFile, denoiser_contract(r)}});
            spdlog::info("exported {}{} ({} parameters{}) to {}", r.checkpoint.string(),
                         r.averaged ? " (moving average)" : "", parameter_count(*r.model),
                         r.config.model.recurrent ? ", recurrent: forward(x, s0..s4)" : "", o->out);
            return kExitOk;
          }};
}

int run_main(int argc, char** argv) {
  CLI::App app{"dofarm-train: trains and applies the depth-of-field denoiser", "dofarm-train"};
  int threads = 0;
  return run_cli(app, "dofarm-train", argc, argv, [&threads](CLI::App& a) {
    a.add_option("--threads", threads,
                 "intra-op threads of every command; 0 = OMP_NUM_THREADS when set, else the "
                 "CPUs this process may use (libtorch's own default can be fewer)")
        ->check(CLI::Range(0, 4096))
        ->capture_default_str();
    std::vector<Command> commands{add_train(a), add_eval(a), add_denoise(a), add_export(a)};
    // Set before the command's first kernel; the train command's replicas
    // follow from it (train.cpu_replicas).
    for (Command& c : commands)
      c.run = [run = std::move(c.run), &threads] {
        const IntraOpThreads t = choose_intra_op_threads(threads);
        at::set_num_threads(t.threads);
        spdlog::info("{} intra-op thread(s) ({})", t.threads, t.source);
        return run();
      };
    return commands;
  });
}

}  // namespace
}  // namespace dofarm

int main(int argc, char** argv) { return dofarm::run_main(argc, argv); }
