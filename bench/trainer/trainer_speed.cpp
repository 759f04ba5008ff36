// Speed of the denoiser: per-frame inference time by resolution (the thesis's
// "interactive" claim, table 5.1's time column) and training-step time, for
// the thesis widths with and without the CoC input and the recurrent variant,
// with NCHW and channels-last (NHWC) tensors; and the full training loop
// (dofarm-train's data path and step) on a shard. Prints Markdown tables;
// never asserts.
//
//   trainer_speed [--reps N] [--models all|dof] [--formats nchw,nhwc] [--no-infer]
//                 [--precisions fp32,bf16] [--padding zeros,replicate] [--replicas N]
//                 [--loop SHARD.h5 [--steps N] [--readers N] [--only-loop]]
//
// --padding: each row again per model.padding (default: zeros only).
// --precisions: each row again per precision (trainer/precision.h; bf16 =
// bfloat16 autocast of the network on the CPU, as train.precision = "bf16"
// and `denoise --precision bf16` run it).
//
// Training steps run as dofarm-train runs them, through StepRunner with
// --replicas model copies (0, the default, = train.cpu_replicas's auto).
//
// --loop: the DOF model trained on SHARD with the data path of dofarm-train
// (SequenceStream readers, BatchPrefetcher, compute_gradients, Adam), the
// same batch (4 x 7 x 64^2); prints the mean time per step over --steps steps
// after two warm-up steps, and how much of it the loop waited for data.
#include <spdlog/spdlog.h>
#include <torch/torch.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "trainer/dataset.h"
#include "trainer/losses.h"
#include "trainer/model.h"
#include "trainer/precision.h"
#include "trainer/train.h"

using namespace dofarm::trainer;
namespace fs = std::filesystem;

namespace {

double now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

void sync(torch::Device d) {
  if (d.is_cuda()) torch::cuda::synchronize();
}

// Median of `reps` timings of f(), after one warm-up call; `best` gets the
// fastest (the least disturbed by other work on the machine).
template <typename F>
double median_seconds(int reps, torch::Device d, F&& f, double* best = nullptr) {
  f();
  sync(d);
  std::vector<double> t;
  for (int i = 0; i < reps; ++i) {
    double t0 = now();
    f();
    sync(d);
    t.push_back(now() - t0);
  }
  std::sort(t.begin(), t.end());
  if (best) *best = t.front();
  return t[t.size() / 2];
}

const char* format_name(torch::MemoryFormat f) {
  return f == torch::MemoryFormat::ChannelsLast ? "NHWC" : "NCHW";
}

struct Options {
  int reps = 5;
  bool all_models = true;
  bool infer = true;
  bool kernels = true;  // false: the loop only
  std::vector<torch::MemoryFormat> formats = {torch::MemoryFormat::Contiguous,
                                              torch::MemoryFormat::ChannelsLast};
  std::vector<Precision> precisions = {Precision::kFp32};
  std::vector<PaddingMode> paddings = {PaddingMode::kZeros};
  std::string loop_shard;
  int steps = 20;
  int readers = 2;
  int replicas = 0;  // train.cpu_replicas
};

int replicas_for(const Options& o, torch::Device dev, Precision prec) {
  return step_replicas(o.replicas, dev, torch::get_num_threads(), 4, prec);
}

void kernels(const Options& o, torch::Device dev) {
  std::printf(
      "| model | params | format, precision, padding | 256x256 ms | 512x512 ms | train step ms (4 "
      "x 7 x 64^2) | "
      "fastest step ms |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- |\n");
  struct Variant {
    const char* name;
    bool dof, recurrent;
  } variants[] = {
      {"no DOF", false, false}, {"DOF (CoC input)", true, false}, {"DOF, recurrent", true, true}};
  for (const Variant& v : variants) {
    if (!o.all_models && !(v.dof && !v.recurrent)) continue;
    for (torch::MemoryFormat fmt : o.formats)
      for (Precision prec : o.precisions)
        for (PaddingMode pad : o.paddings) {
          ModelConfig mc;
          if (!v.dof) std::erase(mc.inputs, std::string("coc:log"));
          mc.recurrent = v.recurrent;
          mc.padding = pad;
          torch::manual_seed(0);
          Denoiser m(mc);
          m->to(dev);
          m->set_memory_format(fmt);
          double infer[2] = {0, 0};
          int sizes[2] = {256, 512};
          for (int k = 0; o.infer && k < 2; ++k) {
            m->eval();
            c10::InferenceMode inference;  // as FrameDenoiser::denoise
            torch::Tensor x = torch::rand({1, mc.input_channels(), sizes[k], sizes[k]}, dev);
            std::vector<torch::Tensor> state;
            infer[k] = median_seconds(o.reps, dev, [&] {
              AutocastScope autocast(prec, dev);
              m->forward_frame(x, state);
            });
          }
          m->train();
          LossConfig lc;
          torch::Tensor kernel = log_kernel(lc.log_sigma).to(dev);
          torch::optim::Adam opt(m->parameters(),
                                 torch::optim::AdamOptions(1e-4).betas({0.9, 0.99}));
          // Inputs as make_batch lays them out: [B*T, C, S, S] frames in `fmt`.
          Batch batch;
          batch.input = torch::rand({28, mc.input_channels(), 64, 64}, dev)
                            .contiguous(fmt)
                            .view({4, 7, mc.input_channels(), 64, 64});
          batch.target = torch::rand({28, 3, 64, 64}, dev).contiguous(fmt).view({4, 7, 3, 64, 64});
          double best = 0;
          StepRunner runner(m, replicas_for(o, dev, prec), prec);
          double step = median_seconds(
              o.reps, dev,
              [&] {
                runner.run(batch, lc, kernel);
                opt.step();
              },
              &best);
          std::printf("| %s | %lld | %s %s %s | %.1f | %.1f | %.0f | %.0f |\n", v.name,
                      static_cast<long long>(parameter_count(*m)), format_name(fmt),
                      precision_name(prec), pad == PaddingMode::kZeros ? "zeros" : "replicate",
                      infer[0] * 1e3, infer[1] * 1e3, step * 1e3, best * 1e3);
        }
  }
}

void loop(const Options& o, torch::Device dev) {
  fs::path dir = fs::temp_directory_path() / ("dofarm_bench_loop_" + std::to_string(getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "data");
  fs::create_symlink(fs::absolute(o.loop_shard), dir / "data" / fs::path(o.loop_shard).filename());
  std::printf(
      "\nfull training loop on %s: DOF model, 4 x 7 x 64^2, %d reader(s), mean of %d "
      "steps\n\n",
      o.loop_shard.c_str(), o.readers, o.steps);
  std::printf(
      "| format, precision | ms/step | of which waiting for data, ms/step |\n| --- | --- | --- "
      "|\n");
  for (torch::MemoryFormat fmt : o.formats)
  for (Precision prec : o.precisions) {
    TrainConfig cfg;
    cfg.data.val_fraction = 0;  // every frame trains, as in the Python loop
    cfg.data.readers = o.readers;
    fs::remove_all(dir / "run");
    torch::manual_seed(0);
    Denoiser m(cfg.model);
    m->to(dev);
    m->set_memory_format(fmt);
    torch::optim::Adam opt(
        m->parameters(),
        torch::optim::AdamOptions(cfg.train.lr).betas({cfg.train.beta1, cfg.train.beta2}));
    torch::Tensor kernel = log_kernel(cfg.loss.log_sigma).to(dev);
    SequenceStream stream(dir / "data", dir / "run", cfg.data, cfg.model, cfg.train.seed);
    BatchPrefetcher batches(stream, cfg.train.batch, dev, fmt);
    StepRunner runner(m, replicas_for(o, dev, prec), prec);
    auto step = [&] {
      Batch b = batches.next();
      runner.run(b, cfg.loss, kernel);
      opt.step();
      sync(dev);
    };
    for (int i = 0; i < 2; ++i) step();  // warm-up: oneDNN primitives, reader queue
    double waited0 = batches.waited_seconds(), t0 = now();
    for (int i = 0; i < o.steps; ++i) step();
    double per_step = (now() - t0) / o.steps;
    double waited = (batches.waited_seconds() - waited0) / o.steps;
    std::printf("| %s %s | %.0f | %.1f |\n", format_name(fmt), precision_name(prec),
                per_step * 1e3, waited * 1e3);
  }
  fs::remove_all(dir);
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    std::string k = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "trainer_speed: %s needs a value\n", k.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (k == "--reps") {
      o.reps = std::max(1, std::atoi(value().c_str()));
    } else if (k == "--models") {
      o.all_models = value() != "dof";
    } else if (k == "--no-infer") {
      o.infer = false;
    } else if (k == "--only-loop") {
      o.kernels = false;
    } else if (k == "--formats") {
      o.formats.clear();
      std::stringstream ss(value());
      for (std::string f; std::getline(ss, f, ',');)
        o.formats.push_back(f == "nhwc" ? torch::MemoryFormat::ChannelsLast
                                        : torch::MemoryFormat::Contiguous);
    } else if (k == "--precisions") {
      o.precisions.clear();
      std::stringstream ss(value());
      for (std::string p; std::getline(ss, p, ',');)
        o.precisions.push_back(parse_precision(p, "--precisions"));
    } else if (k == "--padding") {
      o.paddings.clear();
      std::stringstream ss(value());
      for (std::string p; std::getline(ss, p, ',');) {
        if (p != "zeros" && p != "replicate") {
          std::fprintf(stderr, "trainer_speed: --padding: zeros or replicate, got %s\n", p.c_str());
          return 2;
        }
        o.paddings.push_back(p == "zeros" ? PaddingMode::kZeros : PaddingMode::kReplicate);
      }
    } else if (k == "--replicas") {
      o.replicas = std::max(0, std::atoi(value().c_str()));
    } else if (k == "--loop") {
      o.loop_shard = value();
    } else if (k == "--steps") {
      o.steps = std::max(1, std::atoi(value().c_str()));
    } else if (k == "--readers") {
      o.readers = std::max(1, std::atoi(value().c_str()));
    } else {
      std::fprintf(stderr,
                   "usage: trainer_speed [--reps N] [--models all|dof] [--formats nchw,nhwc] "
                   "[--no-infer] [--precisions fp32,bf16] [--padding zeros,replicate] [--replicas "
                   "N] [--loop SHARD.h5 [--steps N] [--readers N] "
                   "[--only-loop]]\n");
      return 2;
    }
  }
  spdlog::set_level(spdlog::level::warn);
  keep_freed_memory();  // as train() does
  const torch::Device dev = pick_device("auto");
  std::printf(
      "device %s, %d intra-op threads, training steps on %d model replica(s) in fp32, %d in "
      "bf16, median of %d\n\n",
      dev.str().c_str(), torch::get_num_threads(), replicas_for(o, dev, Precision::kFp32),
      replicas_for(o, dev, Precision::kBf16), o.reps);
  // What a bf16 row measures (trainer/precision.h): hardware bf16, libtorch's
  // emulation (forced), or fp32 again (bf16 is not applied on this CPU).
  if (std::find(o.precisions.begin(), o.precisions.end(), Precision::kBf16) != o.precisions.end())
    std::printf("bf16 rows: %s\n\n",
                !autocast_applies(Precision::kBf16, dev) ? "not applied (no AVX-512 BF16 or AMX "
                                                           "on this CPU): they run fp32"
                : cpu_runs_bf16_natively()               ? "AVX-512 BF16 / AMX"
                                                         : "emulated (DOFARM_BF16_EMULATED=1)");
  if (o.kernels) kernels(o, dev);
  if (!o.loop_shard.empty()) loop(o, dev);
  return 0;
}
