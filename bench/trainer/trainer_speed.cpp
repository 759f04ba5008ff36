// Speed of the denoiser: per-frame inference time by resolution (the thesis's
// "interactive" claim, table 5.1's time column) and training-step time, for
// the thesis widths with and without the CoC input and the recurrent variant.
// Prints a Markdown table; never asserts. Usage: trainer_speed [repeats]
#include <torch/torch.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "trainer/losses.h"
#include "trainer/model.h"
#include "trainer/train.h"

using namespace dofarm::trainer;

namespace {

double now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

void sync(torch::Device d) {
  if (d.is_cuda()) torch::cuda::synchronize();
}

// Median of `reps` timings of f(), after one warm-up call.
template <typename F>
double median_seconds(int reps, torch::Device d, F&& f) {
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
  return t[t.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  const int reps = argc > 1 ? std::max(1, std::atoi(argv[1])) : 5;
  const torch::Device dev = pick_device("auto");
  std::printf("device %s, %d intra-op threads, median of %d\n\n", dev.str().c_str(),
              torch::get_num_threads(), reps);
  std::printf("| model | params | 256x256 ms | 512x512 ms | train step ms (4 x 7 x 64^2) |\n");
  std::printf("| --- | --- | --- | --- | --- |\n");
  struct Variant {
    const char* name;
    bool dof, recurrent;
  } variants[] = {
      {"no DOF", false, false}, {"DOF (CoC input)", true, false}, {"DOF, recurrent", true, true}};
  for (const Variant& v : variants) {
    ModelConfig mc;
    mc.dof = v.dof;
    mc.recurrent = v.recurrent;
    torch::manual_seed(0);
    Denoiser m(mc);
    m->to(dev);
    double infer[2];
    int sizes[2] = {256, 512};
    for (int k = 0; k < 2; ++k) {
      m->eval();
      torch::NoGradGuard ng;
      torch::Tensor x = torch::rand({1, mc.input_channels(), sizes[k], sizes[k]}, dev);
      std::vector<torch::Tensor> state;
      infer[k] = median_seconds(reps, dev, [&] { m->forward_frame(x, state); });
    }
    m->train();
    LossConfig lc;
    torch::Tensor kernel = log_kernel(lc.log_sigma).to(dev);
    torch::optim::Adam opt(m->parameters(), torch::optim::AdamOptions(1e-4).betas({0.9, 0.99}));
    torch::Tensor in = torch::rand({4, 7, mc.input_channels(), 64, 64}, dev);
    torch::Tensor tg = torch::rand({4, 7, 3, 64, 64}, dev);
    double step = median_seconds(reps, dev, [&] {
      opt.zero_grad();
      torch::Tensor l = denoiser_loss(m->forward(in), tg, lc, kernel).total;
      l.backward();
      opt.step();
    });
    std::printf("| %s | %lld | %.1f | %.1f | %.0f |\n", v.name,
                static_cast<long long>(parameter_count(*m)), infer[0] * 1e3, infer[1] * 1e3,
                step * 1e3);
  }
  return 0;
}
