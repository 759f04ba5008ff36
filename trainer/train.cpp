#include "trainer/train.h"

#include <ATen/Parallel.h>
#include <malloc.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>

#include "common/error.h"
#include "common/progress.h"
#include "trainer/dataset.h"
#include "trainer/losses.h"
#include "trainer/run_folder.h"

namespace dofarm::trainer {

namespace fs = std::filesystem;

double learning_rate(const OptimConfig& o, int64_t step, int epoch) {
  double warm = o.warmup_steps > 0 ? std::min(1.0, double(step + 1) / o.warmup_steps) : 1.0;
  double lr = double(o.lr) * warm * std::pow(double(o.lr_decay), epoch);
  return std::max(lr, double(o.lr_min));
}

namespace {

class EventLog {
 public:
  explicit EventLog(const fs::path& p) : out_(p, std::ios::app) {}
  template <typename... A>
  void operator()(spdlog::level::level_enum lvl, fmt::format_string<A...> f, A&&... a) {
    std::string msg = fmt::format(f, std::forward<A>(a)...);
    spdlog::log(lvl, "{}", msg);
    auto now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&now));
    out_ << buf << " " << msg << "\n";
    out_.flush();
  }

 private:
  std::ofstream out_;
};

// Planar (C, S, S) frames into `n` frames of a [N, C, S, S] tensor in
// `format`: NHWC is a transposing copy, NCHW a plain one. Plain loops: this
// runs beside the training step and must not take its intra-op threads.
void copy_frames(const float* src, int frames, int channels, int size, torch::MemoryFormat format,
                 float* dst) {
  const size_t plane = size_t(size) * size;
  if (format != torch::MemoryFormat::ChannelsLast) {
    std::copy(src, src + size_t(frames) * channels * plane, dst);
    return;
  }
  for (int f = 0; f < frames; ++f) {
    const float* s = src + size_t(f) * channels * plane;
    float* d = dst + size_t(f) * channels * plane;
    for (size_t p = 0; p < plane; ++p)
      for (int c = 0; c < channels; ++c) d[p * channels + c] = s[size_t(c) * plane + p];
  }
}

}  // namespace

Batch make_batch(const std::vector<Sample>& samples, torch::Device device,
                 torch::MemoryFormat format) {
  DOFARM_CHECK(!samples.empty());
  const Sample& first = samples[0];
  const int64_t b = int64_t(samples.size()), t = first.frames, s = first.size;
  const int64_t c = first.channels;
  auto frames = [&](int64_t channels) {
    return torch::empty({b * t, channels, s, s},
                        torch::TensorOptions().dtype(torch::kFloat32).memory_format(format));
  };
  torch::Tensor in = frames(c), tg = frames(3);
  const size_t in_stride = size_t(t) * c * s * s, tg_stride = size_t(t) * 3 * s * s;
  for (int64_t i = 0; i < b; ++i) {
    const Sample& x = samples[size_t(i)];
    DOFARM_CHECK(x.frames == t && x.channels == c && x.size == s);
    copy_frames(x.input.data(), int(t), int(c), int(s), format,
                in.data_ptr<float>() + size_t(i) * in_stride);
    copy_frames(x.target.data(), int(t), 3, int(s), format,
                tg.data_ptr<float>() + size_t(i) * tg_stride);
  }
  // [B*T, C, S, S] -> [B, T, C, S, S] splits the outer dimension: a view in
  // either format.
  Batch out;
  out.input = in.view({b, t, c, s, s}).to(device);
  out.target = tg.view({b, t, 3, s, s}).to(device);
  return out;
}

BatchPrefetcher::BatchPrefetcher(SequenceStream& stream, int batch, torch::Device device,
                                 torch::MemoryFormat format)
    : stream_(stream), batch_(batch), device_(device), format_(format) {
  pending_ = std::async(std::launch::async, [this] { return assemble(); });
}

BatchPrefetcher::~BatchPrefetcher() {
  if (pending_.valid()) pending_.wait();
}

Batch BatchPrefetcher::assemble() {
  std::vector<Sample> samples;
  for (int i = 0; i < batch_; ++i) samples.push_back(stream_.next());
  Batch b = make_batch(samples, device_, format_);
  b.next_index = stream_.next_index();
  return b;
}

Batch BatchPrefetcher::next() {
  auto t0 = std::chrono::steady_clock::now();
  Batch b = pending_.get();  // rethrows the stream's failure
  waited_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  pending_ = std::async(std::launch::async, [this] { return assemble(); });
  return b;
}

StepOutcome compute_gradients(Denoiser& model, const Batch& batch, const LossConfig& loss_cfg,
                              const torch::Tensor& kernel,
                              const std::function<torch::Tensor(const torch::Tensor&)>& hook) {
  // Gradients set, not added to zeros: no memset and no accumulation pass.
  model->zero_grad(/*set_to_none=*/true);
  torch::Tensor loss =
      denoiser_loss(model->forward(batch.input), batch.target, loss_cfg, kernel).total;
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

int step_replicas(int configured, torch::Device device, int threads, int batch) {
  if (!device.is_cpu()) return 1;
  int r = configured > 0 ? configured : (threads >= 2 ? 2 : 1);
  return std::max(1, std::min(r, batch));
}

StepRunner::StepRunner(Denoiser model, int replicas) : model_(std::move(model)) {
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
  if (copies_.empty()) return compute_gradients(model_, batch, loss, kernel, hook);
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
      out[size_t(k)] = compute_gradients(copy, part(k), loss, kernel, hook);
    });
  }
  std::exception_ptr error;
  try {
    out[0] = compute_gradients(model_, part(0), loss, kernel, hook);
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

void keep_freed_memory() {
  // 32 MiB is glibc's largest mmap threshold; the largest activation of the
  // thesis model at 4 x 7 x 64^2 is 16.5 MB.
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
}

namespace {

// Epoch rows in loss.csv (lines after the header).
int64_t csv_epochs(const fs::path& csv) {
  std::ifstream in(csv);
  std::string line;
  int64_t rows = -1;  // the header
  while (std::getline(in, line))
    if (!line.empty()) ++rows;
  return std::max<int64_t>(0, rows);
}

TrainResult train_in(const TrainOptions& opt_in);

}  // namespace

TrainResult train(const TrainOptions& opt_in) {
  const fs::path run = opt_in.run_dir;
  std::error_code ec;
  const bool existed = fs::exists(run);
  const bool fresh = !existed || fs::is_empty(run, ec);
  try {
    return train_in(opt_in);
  } catch (...) {
    // A start that failed before any step was saved leaves nothing behind:
    // the folder would otherwise pin its config on the retry.
    if (fresh) {
      bool progress = fs::exists(run / "loss.csv") && csv_epochs(run / "loss.csv") > 0;
      for (const auto& e : fs::directory_iterator(run / "checkpoints", ec))
        if (e.path().filename().string().rfind("step-", 0) == 0) progress = true;
      if (!progress) {
        spdlog::warn("{}: removed again: the run failed before saving any progress", run.string());
        if (existed) {  // the user's empty folder stays, empty again
          for (const auto& e : fs::directory_iterator(run, ec)) fs::remove_all(e.path(), ec);
        } else {
          fs::remove_all(run, ec);
        }
      }
    }
    throw;
  }
}

namespace {

TrainResult train_in(const TrainOptions& opt_in) {
  keep_freed_memory();
  const TrainConfig& cfg = opt_in.config;
  const fs::path run = opt_in.run_dir;
  const fs::path ckpt_dir = run / "checkpoints";
  const fs::path last = ckpt_dir / "last.pt", best = ckpt_dir / "best.pt";
  TrainResult result;

  // The run folder is the unit of resume (STYLE.md 10).
  if (fs::exists(run / "config.toml")) {
    TrainConfig saved =
        parse_train_config(read_text_file(run / "config.toml"), run / "config.toml");
    std::string why = incompatible_reason(saved, cfg);
    if (!why.empty())
      throw SpecError(FileLoc{(run / "config.toml").string()}, "",
                      "cannot resume this run with the given config: " + why);
    result.resumed = fs::exists(last);
  }
  if (!result.resumed && fs::exists(run / "loss.csv")) {
    const int64_t rows = csv_epochs(run / "loss.csv");
    if (rows > 0)
      throw RuntimeError(last.string() + ": missing, but " + (run / "loss.csv").string() +
                         " records " + std::to_string(rows) +
                         " epoch(s): the run's checkpoint is lost; restore it (or use a "
                         "checkpoints/step-*.pt copy as last.pt) or train into a new run folder");
  }
  fs::create_directories(ckpt_dir);
  write_text_atomic(run / "config.toml", to_toml(cfg));
  EventLog log(run / "events.log");

  const torch::Device device = pick_device(cfg.train.device);
  torch::manual_seed(cfg.train.seed);
  Denoiser model(cfg.model);
  model->to(device);
  const torch::MemoryFormat format = preferred_memory_format(device);
  model->set_memory_format(format);
  torch::optim::Adam adam(
      model->parameters(),
      torch::optim::AdamOptions(cfg.train.lr).betas({cfg.train.beta1, cfg.train.beta2}));
  RunState st;
  if (result.resumed) {
    st = load_checkpoint(last, model, &adam, device);
    log(spdlog::level::info, "resumed at epoch {} step {} from {}", st.epoch, st.step,
        last.string());
  } else {
    save_checkpoint(last, model, adam, st, cfg);  // something to roll back to from step 0
    log(spdlog::level::info, "new run: {} parameters on {}", parameter_count(*model), device.str());
  }

  SequenceStream stream(opt_in.data_dir, run, cfg.data, cfg.model.dof, cfg.train.seed,
                        uint64_t(st.sample_index));
  const torch::Tensor kernel = log_kernel(cfg.loss.log_sigma).to(device);
  const bool new_csv = !fs::exists(run / "loss.csv");
  std::ofstream csv(run / "loss.csv", std::ios::app);
  if (new_csv) csv << "epoch,step,train_loss,val_loss,lr,skipped,seconds\n";
  // One row per step (the report's per-step curves). Rows past the checkpoint
  // (a process killed before it could save) are dropped: those steps run again.
  {
    std::vector<std::string> keep;
    std::ifstream in(run / "steps.csv");
    std::string line;
    std::getline(in, line);
    while (std::getline(in, line))
      if (!line.empty() && std::stoll(line.substr(0, line.find(','))) <= st.step) keep.push_back(line);
    std::string text = "step,loss,lr\n";
    for (const std::string& l : keep) text += l + "\n";
    write_text_atomic(run / "steps.csv", text);
  }
  std::ofstream steps_csv(run / "steps.csv", std::ios::app);

  int bad_in_a_row = 0;
  const int64_t total_steps = int64_t(cfg.train.epochs) * cfg.train.steps_per_epoch;
  Progress progress("train", std::max<int64_t>(0, total_steps - st.step));
  BatchPrefetcher batches(stream, cfg.train.batch, device, format);
  const int threads = at::get_num_threads();
  StepRunner runner(model, step_replicas(cfg.train.cpu_replicas, device, threads, cfg.train.batch));
  if (runner.replicas() > 1)
    spdlog::info("training step split across {} model replicas, {} intra-op thread(s) each",
                 runner.replicas(), std::max(1, threads / runner.replicas()));
  while (st.epoch < cfg.train.epochs) {
    auto t0 = std::chrono::steady_clock::now();
    model->train();
    double loss_sum = 0;
    int good = 0, skipped = 0;
    double lr = 0;
    // Counted from the step, so an epoch interrupted mid-way resumes where it was.
    while (st.step < (st.epoch + 1) * int64_t(cfg.train.steps_per_epoch)) {
      if (opt_in.stop_at_step >= 0 && st.step >= opt_in.stop_at_step) break;
      Batch batch = batches.next();  // the one after it is assembled meanwhile
      st.sample_index = int64_t(batch.next_index);
      lr = st.lr_scale * learning_rate(cfg.train, st.step, int(st.epoch));
      for (auto& group : adam.param_groups())
        static_cast<torch::optim::AdamOptions&>(group.options()).lr(lr);

      std::function<torch::Tensor(const torch::Tensor&)> hook;
      if (opt_in.loss_hook)
        hook = [&](const torch::Tensor& l) { return opt_in.loss_hook(st.step, l); };
      const StepOutcome outcome = runner.run(batch, cfg.loss, kernel, hook);
      const double loss_value = outcome.loss;
      const bool ok = outcome.finite;
      ++st.step;
      progress.advance();
      steps_csv << st.step << "," << (ok ? fmt::format("{:.6g}", loss_value) : "") << ","
                << fmt::format("{:.6g}", lr) << "\n";
      if (ok) {
        adam.step();
        loss_sum += loss_value;
        ++good;
        bad_in_a_row = 0;
        if (opt_in.save_every > 0 && st.step % opt_in.save_every == 0) {
          steps_csv.flush();
          save_checkpoint(last, model, adam, st, cfg);
          const fs::path kept = ckpt_dir / fmt::format("step-{:08d}.pt", st.step);
          fs::copy_file(last, kept, fs::copy_options::overwrite_existing);
          log(spdlog::level::info, "step {}: checkpoint {}", st.step, kept.string());
        }
        if (opt_in.stop && opt_in.stop->load()) {
          result.stopped = true;
          break;
        }
        continue;
      }
      // Non-finite: never let it into the weights, the CSV or a checkpoint.
      ++skipped;
      ++result.skipped_steps;
      log(spdlog::level::warn, "step {}: non-finite loss or gradient, step skipped", st.step);
      if (++bad_in_a_row >= cfg.train.max_bad_steps) {
        RunState back = load_checkpoint(last, model, &adam, device);
        // From the current scale: repeated rollbacks within an epoch keep lowering it.
        st.lr_scale = std::min(st.lr_scale, back.lr_scale) * cfg.train.rollback_lr_factor;
        ++result.rollbacks;
        bad_in_a_row = 0;
        log(spdlog::level::warn,
            "rolled back to {} (epoch {} step {}) after {} non-finite steps; LR scale now {}",
            last.string(), back.epoch, back.step, cfg.train.max_bad_steps, st.lr_scale);
      }
    }
    const bool interrupted = st.step < (st.epoch + 1) * int64_t(cfg.train.steps_per_epoch);
    if (interrupted) break;

    // Validation: the same sequences every epoch (while the shard set holds).
    double val = NAN;
    std::vector<Sample> vs = stream.validation(cfg.train.val_sequences);
    if (!vs.empty()) {
      torch::NoGradGuard no_grad;
      model->eval();
      double sum = 0;
      for (size_t i = 0; i < vs.size(); i += cfg.train.batch) {
        std::vector<Sample> part(vs.begin() + i,
                                 vs.begin() + std::min(vs.size(), i + cfg.train.batch));
        Batch b = make_batch(part, device, format);
        sum += denoiser_loss(model->forward(b.input), b.target, cfg.loss, kernel)
                   .total.item<double>() *
               double(part.size());
      }
      val = sum / double(vs.size());
    }
    double train_loss = good ? loss_sum / good : NAN;
    double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ++st.epoch;
    csv << st.epoch << "," << st.step << ","
        << (std::isfinite(train_loss) ? fmt::format("{:.6g}", train_loss) : "") << ","
        << (std::isfinite(val) ? fmt::format("{:.6g}", val) : "") << ","
        << fmt::format("{:.6g}", lr) << "," << skipped << "," << fmt::format("{:.3f}", seconds)
        << "\n";
    csv.flush();
    steps_csv.flush();
    spdlog::info("epoch {}/{}: train {:.5f} val {:.5f} lr {:.3g} ({:.1f} s)", st.epoch,
                 cfg.train.epochs, train_loss, val, lr, seconds);
    // Best by validation loss; by training loss when there is no validation set.
    // A non-finite validation loss never makes a model "best".
    if (!vs.empty() && !std::isfinite(val))
      log(spdlog::level::warn, "epoch {}: non-finite validation loss", st.epoch);
    double score = vs.empty() ? train_loss : val;
    bool improved = std::isfinite(score) && score < st.best;
    if (improved) st.best = score;
    save_checkpoint(last, model, adam, st, cfg);
    if (improved) fs::copy_file(last, best, fs::copy_options::overwrite_existing);
    ++result.epochs;
  }
  steps_csv.flush();
  if (result.stopped) {
    save_checkpoint(last, model, adam, st, cfg);
    log(spdlog::level::warn,
        "stopped on request at epoch {} step {}: {} written; run the same command to resume",
        st.epoch, st.step, last.string());
  } else if (opt_in.stop_at_step >= 0 && st.step >= opt_in.stop_at_step &&
             st.epoch < cfg.train.epochs) {
    save_checkpoint(last, model, adam, st, cfg);
  }
  result.steps = st.step;
  result.best_val = st.best;
  return result;
}

}  // namespace

}  // namespace dofarm::trainer
