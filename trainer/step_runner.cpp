#include "trainer/step_runner.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstdlib>
#include <exception>
#include <mutex>
#include <thread>

#include "common/cpus.h"
#include "common/error.h"
#include "trainer/losses.h"
#include "trainer/precision.h"

namespace dofarm::trainer {

double clip_gradients(const std::vector<torch::Tensor>& params, double max_norm) {
  double sum_sq = 0;
  for (const torch::Tensor& p : params)
    if (p.grad().defined()) sum_sq += p.grad().to(torch::kDouble).pow(2).sum().item<double>();
  const double norm = std::sqrt(sum_sq);
  if (max_norm > 0 && norm > max_norm) {
    torch::NoGradGuard no_grad;
    const double scale = max_norm / norm;
    for (const torch::Tensor& p : params)
      if (p.grad().defined()) p.grad().mul_(scale);
  }
  return norm;
}

StepOutcome compute_gradients(Denoiser& model, const Batch& batch, const LossConfig& loss_cfg,
                              const torch::Tensor& kernel,
                              const std::function<torch::Tensor(const torch::Tensor&)>& hook,
                              Precision precision) {
  // Gradients set, not added to zeros: no memset and no accumulation pass.
  model->zero_grad(/*set_to_none=*/true);
  torch::Tensor y = float_output(precision, batch.input.device(),
                                 [&] { return model->forward(batch.input); });
  torch::Tensor loss = denoiser_loss(y, batch.target, loss_cfg, kernel, batch.coc).total;
  if (hook) loss = hook(loss);
  StepOutcome r;
  r.loss = loss.item<double>();
  r.finite = std::isfinite(r.loss);
  if (!r.finite) return r;
  loss.backward();
  // One device sync for all gradients, not one per parameter.
  std::vector<torch::Tensor> finite;
  for (const auto& p : model->parameters())
    if (p.grad().defined()) finite.push_back(torch::isfinite(p.grad()).all());
  r.finite = finite.empty() || torch::stack(finite).all().item<bool>();
  return r;
}

// One replica's thread: runs one job at a time, handed over by start().
struct StepRunner::Worker {
  explicit Worker(int threads) : thread_([this, threads] { loop(threads); }) {}
  ~Worker() {
    {
      std::lock_guard<std::mutex> l(mu_);
      quit_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  void start(std::function<void()> job) {
    std::lock_guard<std::mutex> l(mu_);
    job_ = std::move(job);
    error_ = nullptr;
    pending_ = busy_ = true;
    cv_.notify_all();
  }
  void wait() {
    std::unique_lock<std::mutex> l(mu_);
    cv_.wait(l, [this] { return !busy_; });
    if (error_) std::rethrow_exception(error_);
  }

 private:
  void loop(int threads) {
    // This thread's own OpenMP team size, before its first kernel (oneDNN
    // reads it from the calling thread, not from ATen's global setting).
    at::set_num_threads(threads);
    std::unique_lock<std::mutex> l(mu_);
    for (;;) {
      cv_.wait(l, [this] { return pending_ || quit_; });
      if (!pending_) return;
      pending_ = false;
      std::function<void()> job = std::move(job_);
      l.unlock();
      std::exception_ptr error;
      try {
        job();
      } catch (...) {
        error = std::current_exception();
      }
      l.lock();
      error_ = error;
      busy_ = false;
      cv_.notify_all();
    }
  }

  std::mutex mu_;
  std::condition_variable cv_;
  std::function<void()> job_;
  std::exception_ptr error_;
  bool pending_ = false, busy_ = false, quit_ = false;
  std::thread thread_;  // last: started once the state above exists
};

IntraOpThreads choose_intra_op_threads(int requested) {
  if (requested > 0) return {requested, "--threads"};
  if (const char* env = std::getenv("OMP_NUM_THREADS")) {
    char* end = nullptr;
    const long n = std::strtol(env, &end, 10);
    if (end != env && *end == '\0' && n > 0 && n <= 4096) return {int(n), "OMP_NUM_THREADS"};
  }
  return {cpus_available(), "CPUs this process may use"};
}

int step_replicas(int configured, torch::Device device, int threads, int batch,
                  Precision precision) {
  if (!device.is_cpu()) return 1;
  // Auto: under bf16 one model on all threads is faster than two 1-thread
  // halves (its oneDNN kernels scale across threads; docs/trainer.md).
  const bool split = threads >= 2 && !autocast_applies(precision, device);
  int r = configured > 0 ? configured : (split ? 2 : 1);
  return std::max(1, std::min(r, batch));
}

StepRunner::StepRunner(Denoiser model, int replicas, Precision precision)
    : model_(std::move(model)), precision_(precision) {
  DOFARM_CHECK(replicas >= 1);
  if (replicas == 1) return;
  saved_threads_ = at::get_num_threads();
  const int per = std::max(1, saved_threads_ / replicas);
  at::set_num_threads(per);
  const torch::Device device = model_->parameters().front().device();
  for (int k = 1; k < replicas; ++k) {
    Denoiser copy(model_->config());
    copy->to(device);
    copy->set_memory_format(model_->memory_format());
    copies_.push_back(copy);
    workers_.push_back(std::make_unique<Worker>(per));
  }
}

StepRunner::~StepRunner() {
  workers_.clear();  // joins the threads
  if (saved_threads_ > 0) at::set_num_threads(saved_threads_);
}

StepOutcome StepRunner::run(const Batch& batch, const LossConfig& loss, const torch::Tensor& kernel,
                            const std::function<torch::Tensor(const torch::Tensor&)>& hook) {
  if (copies_.empty()) return compute_gradients(model_, batch, loss, kernel, hook, precision_);
  const int r = replicas();
  const int64_t b = batch.input.size(0);
  DOFARM_CHECK(b >= r);
  // Part k: sequences [b k / r, b (k + 1) / r), weight n_k / n.
  std::vector<int64_t> begin(static_cast<size_t>(r) + 1);
  for (int k = 0; k <= r; ++k) begin[size_t(k)] = b * k / r;
  std::vector<double> weight(static_cast<size_t>(r));
  for (int k = 0; k < r; ++k)
    weight[size_t(k)] = double(begin[size_t(k) + 1] - begin[size_t(k)]) / double(b);
  auto part = [&](int k) {
    const int64_t start = begin[size_t(k)], count = begin[size_t(k) + 1] - start;
    Batch p;
    p.input = batch.input.narrow(0, start, count);
    p.target = batch.target.narrow(0, start, count);
    if (batch.coc.defined()) p.coc = batch.coc.narrow(0, start, count);
    return p;
  };
  const std::vector<torch::Tensor> params = model_->parameters();
  std::vector<StepOutcome> out(static_cast<size_t>(r));
  for (int k = 1; k < r; ++k) {
    workers_[size_t(k) - 1]->start([&, k] {
      Denoiser& copy = copies_[size_t(k) - 1];
      {
        torch::NoGradGuard no_grad;  // the replica takes the model's current weights
        std::vector<torch::Tensor> dst = copy->parameters();
        for (size_t i = 0; i < params.size(); ++i) dst[i].copy_(params[i]);
      }
      out[size_t(k)] = compute_gradients(copy, part(k), loss, kernel, hook, precision_);
    });
  }
  std::exception_ptr error;
  try {
    out[0] = compute_gradients(model_, part(0), loss, kernel, hook, precision_);
  } catch (...) {
    error = std::current_exception();
  }
  for (auto& w : workers_) {
    try {
      w->wait();
    } catch (...) {
      if (!error) error = std::current_exception();
    }
  }
  if (error) std::rethrow_exception(error);

  StepOutcome total;
  total.finite = true;
  for (int k = 0; k < r; ++k) {
    total.loss += weight[size_t(k)] * out[size_t(k)].loss;
    total.finite = total.finite && out[size_t(k)].finite;
  }
  if (!total.finite) return total;
  // g = sum_k (n_k / n) g_k, in replica order.
  torch::NoGradGuard no_grad;
  std::vector<std::vector<torch::Tensor>> copy_params;
  for (auto& c : copies_) copy_params.push_back(c->parameters());
  std::vector<torch::Tensor> finite;
  for (size_t i = 0; i < params.size(); ++i) {
    torch::Tensor g = params[i].grad();
    if (!g.defined()) continue;
    g.mul_(weight[0]);
    for (int k = 1; k < r; ++k) g.add_(copy_params[size_t(k) - 1][i].grad(), weight[size_t(k)]);
    finite.push_back(torch::isfinite(g).all());
  }
  total.finite = finite.empty() || torch::stack(finite).all().item<bool>();
  return total;
}

}  // namespace dofarm::trainer
