// dofarm: the render-farm executable (DESIGN.md, "Command line").
//
// Each subcommand is one add_<name>() function that declares its options on
// CLI11 and returns the action to run once the command line is parsed
// (render here, the farm's in cmd_farm.cpp); run_cli() (apps/cli_main.h)
// dispatches and maps failures to exit statuses. To add a subcommand, write
// its add_<name>() and list it in run_main().
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <charconv>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "common/error.h"
#include "common/jobspec.h"
#include "common/log.h"
#include "worker/job_resolve.h"
#include "worker/render/render_job.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;

}  // namespace

void add_set_option(CLI::App* cmd, std::vector<std::string>& sets) {
  cmd->add_option("--set", sets,
                  "override a job-spec key, checked like the file: KEY=VALUE, e.g. "
                  "image.width=64 or camera.key.0.aperture=0.1 (repeatable)")
      ->type_name("KEY=VALUE")
      ->allow_extra_args(false);
}

namespace {

// ---------------------------------------------------------------------------
// dofarm render JOB.toml --frame N [--tile X,Y,W,H] --out FRAME.exr

// "X,Y,W,H" -> Rect; bad text is a located input error.
Rect parse_tile(const std::string& text) {
  const FileLoc loc{"--tile " + text};
  int v[4];
  const char* p = text.data();
  const char* end = text.data() + text.size();
  for (int i = 0; i < 4; ++i) {
    auto [next, ec] = std::from_chars(p, end, v[i]);
    bool sep_ok = i < 3 ? (next < end && *next == ',') : next == end;
    if (ec != std::errc() || !sep_ok) {
      throw SpecError(loc, "", "expected X,Y,W,H (four integers in pixels)");
    }
    p = next + 1;
  }
  return Rect{v[0], v[1], v[2], v[3]};
}

void check_tile(const Rect& t, const std::string& text, const JobSpec& spec) {
  const FileLoc loc{"--tile " + text};
  if (t.w <= 0 || t.h <= 0) throw SpecError(loc, "", "tile width and height must be positive");
  // 64-bit sums: x + w must not overflow for a hostile command line.
  if (t.x < 0 || t.y < 0 || int64_t(t.x) + t.w > spec.width || int64_t(t.y) + t.h > spec.height) {
    throw SpecError(loc, "",
                    "tile " + std::to_string(t.w) + "x" + std::to_string(t.h) + " at (" +
                        std::to_string(t.x) + ", " + std::to_string(t.y) + ") lies outside the " +
                        std::to_string(spec.width) + "x" + std::to_string(spec.height) + " image");
  }
}

Command add_render(CLI::App& app) {
  struct Args {
    std::string job;
    int frame = 0;
    std::string tile;
    std::string out;
    int threads = 0;
    std::vector<std::string> sets;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "render", "Render one frame (or one tile of it) of a job: every buffer as an EXR layer");
  cmd->add_option("job", args->job, "job spec (TOML, see jobs/README.md)")
      ->type_name("JOB.toml")
      ->required();
  cmd->add_option("--frame", args->frame, "frame to render, within the job's [frames] range")
      ->type_name("N")
      ->required();
  cmd->add_option("--tile", args->tile, "render only this rectangle of the frame (pixels)")
      ->type_name("X,Y,W,H");
  cmd->add_option("--out", args->out, "output EXR file (folders are created)")
      ->type_name("FRAME.exr")
      ->required();
  cmd->add_option("--threads", args->threads, "render threads; 0 = the CPUs this process may use")
      ->type_name("N")
      ->check(CLI::Range(0, 4096))
      ->capture_default_str();
  add_set_option(cmd, args->sets);

  return {
      cmd, [args]() {
        JobSpec spec = load_job_spec(args->job, args->sets);
        if (args->frame < spec.frame_start || args->frame > spec.frame_end) {
          throw SpecError(FileLoc{"--frame " + std::to_string(args->frame)}, "",
                          "frame " + std::to_string(args->frame) +
                              " is outside the job's frames [" + std::to_string(spec.frame_start) +
                              ", " + std::to_string(spec.frame_end) + "]");
        }
        std::optional<Rect> tile;
        if (!args->tile.empty()) tile = parse_tile(args->tile);
        // The scene and environment map are content too: loaded (and any
        // problem reported against the spec) before anything is written.
        // The image size may follow the scene camera: the tile is checked
        // against the completed spec.
        auto scene = worker::load_scene_checked(spec);
        worker::complete_spec_from_scene(spec, *scene);
        if (tile) check_tile(*tile, args->tile, spec);
        // All input is checked: only now touch the filesystem.
        fs::path out(args->out);
        if (out.has_parent_path()) {
          std::error_code ec;
          fs::create_directories(out.parent_path(), ec);
          if (ec) {
            throw RuntimeError("cannot create " + out.parent_path().string() + ": " + ec.message());
          }
        }
        render::RenderOptions options;
        options.threads = args->threads;
        options.progress = true;
        spdlog::info("rendering {} frame {}{} -> {}", args->job, args->frame,
                     args->tile.empty() ? "" : " tile " + args->tile, out.string());
        render::render_frame_to_exr(spec, args->frame, tile, out, options, scene.get());
        spdlog::info("wrote {}", out.string());
        return kExitOk;
      }};
}

int run_main(int argc, char** argv) {
  CLI::App app{
      "dofarm: renders depth-of-field training data for a neural denoiser, locally or "
      "as a render farm",
      "dofarm"};
  return run_cli(app, "dofarm", argc, argv, [](CLI::App& a) {
    return std::vector<Command>{
        add_render(a),  add_run(a),    add_coordinator(a), add_worker(a), add_submit(a),
        add_status(a),  add_events(a), add_resume(a),      add_cancel(a), add_priority(a),
        add_inspect(a), add_keygen(a), add_verify(a),
    };
  });
}

}  // namespace
}  // namespace dofarm

int main(int argc, char** argv) { return dofarm::run_main(argc, argv); }
