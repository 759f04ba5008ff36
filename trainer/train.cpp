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
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "common/error.h"
#include "common/file_bytes.h"
#include "common/progress.h"
#include "trainer/dataset.h"
#include "trainer/inference.h"
#include "trainer/losses.h"
#include "trainer/metrics.h"
#include "trainer/precision.h"
#include "trainer/run_folder.h"

namespace dofarm::trainer {

namespace {
// Whole validation frames scoring this much SSIM below the validation crops
// are reported in events.log (a warning, not a stop).
constexpr double kWholeFrameGap = 0.2;
// How far whole frames may score below the same frames as crop-sized tiles
// before the trainer warns: sound models score their whole frames 0.005 to
// 0.015 above their tiles, the failing one of docs/results.md 0.077 below.
constexpr double kExtentGap = 0.02;
}  // namespace

namespace fs = std::filesystem;

FrameFailure whole_frame_failure(double frames, double crops, double tiles) {
  if (!std::isfinite(frames)) return FrameFailure::kNonFinite;
  if (std::isfinite(crops) && frames < crops - kWholeFrameGap) return FrameFailure::kBelowCrops;
  if (std::isfinite(tiles) && frames < tiles - kExtentGap) return FrameFailure::kBelowTiles;
  return FrameFailure::kNone;
}

double ema_decay(double ema, int64_t step) {
  const double t = double(std::max<int64_t>(step - 1, 0));
  return std::min(ema, (1.0 + t) / (10.0 + t));
}

void update_average(Denoiser& average, Denoiser& model, double d) {
  torch::NoGradGuard no_grad;
  const auto w = model->parameters();
  auto a = average->parameters();
  for (size_t i = 0; i < a.size(); ++i) a[i].mul_(d).add_(w[i], 1.0 - d);
}

double thesis_learning_rate(int64_t pass) {
  // Thesis eq. 4.5: a tenfold geometric rise over passes 0..9 (1.25893 =
  // 10^(1/10)), then 0.0001 * 10 / sqrt(E).
  if (pass <= 9) return 1e-4 * std::pow(1.25893, double(pass));
  return 1e-4 * 10.0 / std::sqrt(double(pass));
}

double learning_rate(const OptimConfig& o, int64_t step, int epoch, int64_t steps_per_pass) {
  if (o.schedule == Schedule::kThesis)
    return thesis_learning_rate(step / std::max<int64_t>(1, steps_per_pass));
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

}  // namespace

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

// Optimizer steps of one pass over the training sequences: ceil(N / batch)
// with N the training sequences of the split when the run started, kept in
// RUN/passes.json so that shards arriving later do not stretch a pass
// (and with it eq. 4.5's E) in a resumed run.
template <typename Log>
int64_t steps_per_pass_of(const fs::path& run, const SequenceStream& stream, int batch, bool used,
                          Log& log) {
  const fs::path file = run / "passes.json";
  int64_t n = 0;
  if (fs::exists(file)) {
    try {
      n = nlohmann::json::parse(read_file_bytes(file)).at("training_sequences").get<int64_t>();
    } catch (const nlohmann::json::exception& e) {
      throw RuntimeError(file.string() + ": unreadable: " + e.what());
    }
    if (n < 1) throw RuntimeError(file.string() + ": training_sequences must be positive");
  } else {
    n = std::max<int64_t>(1, stream.training_sequences());
    write_text_atomic(file, nlohmann::json{{"training_sequences", n}}.dump() + "\n");
  }
  const int64_t steps = (n + batch - 1) / batch;
  if (used)
    log(spdlog::level::info, "one pass over the training data: {} sequences, {} steps of {}", n,
        steps, batch);
  return steps;
}

// SSIM and PSNR of the validation frames (as eval scores them: remodulated,
// sRGB-encoded, clamped), so the report can plot them over training.
class ImageScores {
 public:
  // `albedo`: the samples' demodulation albedo, [B, T, 3, S, S].
  void add(const torch::Tensor& y, const Batch& b, const torch::Tensor& albedo, float eps,
           RadianceSpace space) {
    auto radiance = [&](const torch::Tensor& t) {
      const int64_t s = t.size(-1);
      return (radiance_inverse(t.to(torch::kCPU, torch::kFloat32), space) * (albedo + eps))
          .reshape({-1, 3, s, s})
          .to(torch::kCPU, torch::kFloat32)
          .contiguous();
    };
    const torch::Tensor p = radiance(y), r = radiance(b.target);
    const int64_t n = p.size(0), s = p.size(-1);
    for (int64_t i = 0; i < n; ++i) {
      ImageView a{p.data_ptr<float>() + i * 3 * s * s, 3, int(s), int(s)};
      ImageView c{r.data_ptr<float>() + i * 3 * s * s, 3, int(s), int(s)};
      const std::vector<float> da = display_encode(a), dc = display_encode(c);
      const ImageView ea{da.data(), 3, int(s), int(s)}, ec{dc.data(), 3, int(s), int(s)};
      ssim_ += trainer::ssim(ea, ec);
      psnr_ += trainer::psnr(ea, ec);
      ++frames_;
    }
  }
  double ssim() const { return frames_ ? ssim_ / frames_ : NAN; }
  double psnr() const { return frames_ ? psnr_ / frames_ : NAN; }

 private:
  double ssim_ = 0, psnr_ = 0;
  int64_t frames_ = 0;
};

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
  bool frames_failed = false;  // some epoch of this call failed whole-frame validation
  TrainResult result;

  // The run folder is the unit of resume (STYLE.md 10).
  if (fs::exists(run / "config.toml")) {
    TrainConfig saved =
        parse_train_config(read_file_bytes(run / "config.toml"), run / "config.toml");
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
  // The weights' moving average (train.ema): what validation judges.
  Denoiser average{nullptr};
  Denoiser* avg = nullptr;
  if (cfg.train.ema > 0) {
    average = Denoiser(cfg.model);
    average->to(device);
    average->set_memory_format(format);
    copy_weights(average, model);
    for (auto& p : average->parameters()) p.set_requires_grad(false);
    avg = &average;
  }
  Denoiser& judged = avg ? average : model;
  RunState st;
  if (result.resumed) {
    bool had_average = false;
    st = load_checkpoint(last, model, &adam, device, avg, &had_average);
    log(spdlog::level::info, "resumed at epoch {} step {} from {}", st.epoch, st.step,
        last.string());
    if (avg && !had_average)
      log(spdlog::level::info,
          "train.ema is on but {} holds no moving average: it starts from the weights of step {}",
          last.string(), st.step);
  } else {
    save_checkpoint(last, model, adam, st, cfg, avg);  // something to roll back to from step 0
    log(spdlog::level::info, "new run: {} parameters on {}", parameter_count(*model), device.str());
  }

  SequenceStream stream(opt_in.data_dir, run, cfg.data, cfg.model, cfg.train.seed,
                        uint64_t(st.sample_index));
  const int64_t steps_per_pass = steps_per_pass_of(
      run, stream, cfg.train.batch,
      cfg.train.schedule == Schedule::kThesis || cfg.train.steps_per_epoch == 0, log);
  const int64_t steps_per_epoch =
      cfg.train.steps_per_epoch > 0 ? int64_t(cfg.train.steps_per_epoch) : steps_per_pass;
  const RadianceSpace space = radiance_space(cfg.model);
  const torch::Tensor kernel = log_kernel(cfg.loss.log_sigma).to(device);
  const bool new_csv = !fs::exists(run / "loss.csv");
  std::ofstream csv(run / "loss.csv", std::ios::app);
  if (new_csv)
    csv << "epoch,step,train_loss,val_loss,lr,skipped,seconds,val_ssim,val_psnr,val_frame_ssim,"
           "val_tile_ssim\n";
  // One row per step (the report's per-step curves). Rows past the checkpoint
  // (a process killed before it could save) are dropped: those steps run again.
  {
    std::vector<std::string> keep;
    std::ifstream in(run / "steps.csv");
    std::string line;
    std::getline(in, line);
    while (std::getline(in, line))
      if (!line.empty() && std::stoll(line.substr(0, line.find(','))) <= st.step) keep.push_back(line);
    std::string text = "step,loss,lr,grad_norm\n";
    for (const std::string& l : keep) text += l + "\n";
    write_text_atomic(run / "steps.csv", text);
  }
  std::ofstream steps_csv(run / "steps.csv", std::ios::app);

  int bad_in_a_row = 0;
  const int64_t total_steps = int64_t(cfg.train.epochs) * steps_per_epoch;
  Progress progress("train", std::max<int64_t>(0, total_steps - st.step), "steps");
  BatchPrefetcher batches(stream, cfg.train.batch, device, format);
  const int threads = at::get_num_threads();
  StepRunner runner(model,
                    step_replicas(cfg.train.cpu_replicas, device, threads, cfg.train.batch,
                                  cfg.train.precision),
                    cfg.train.precision);
  warn_if_not_applied(cfg.train.precision, device, "train.precision");
  if (runner.replicas() > 1)
    spdlog::info("training step split across {} model replicas, {} intra-op thread(s) each",
                 runner.replicas(), std::max(1, threads / runner.replicas()));
  while (st.epoch < cfg.train.epochs) {
    auto t0 = std::chrono::steady_clock::now();
    model->train();
    double loss_sum = 0;
    int good = 0, skipped = 0, clipped = 0;
    double lr = 0;
    // Counted from the step, so an epoch interrupted mid-way resumes where it was.
    while (st.step < (st.epoch + 1) * steps_per_epoch) {
      if (opt_in.stop_at_step >= 0 && st.step >= opt_in.stop_at_step) break;
      Batch batch = batches.next();  // the one after it is assembled meanwhile
      st.sample_index = int64_t(batch.next_index);
      lr = st.lr_scale * learning_rate(cfg.train, st.step, int(st.epoch), steps_per_pass);
      for (auto& group : adam.param_groups())
        static_cast<torch::optim::AdamOptions&>(group.options()).lr(lr);

      std::function<torch::Tensor(const torch::Tensor&)> hook;
      if (opt_in.loss_hook)
        hook = [&](const torch::Tensor& l) { return opt_in.loss_hook(st.step, l); };
      const StepOutcome outcome = runner.run(batch, cfg.loss, kernel, hook);
      const double loss_value = outcome.loss;
      const bool ok = outcome.finite;
      // The gradients are finite here when ok (compute_gradients checked).
      const double grad_norm = ok ? clip_gradients(model->parameters(), cfg.train.grad_clip) : NAN;
      if (ok && cfg.train.grad_clip > 0 && grad_norm > cfg.train.grad_clip) ++clipped;
      ++st.step;
      progress.advance();
      steps_csv << st.step << "," << (ok ? fmt::format("{:.6g}", loss_value) : "") << ","
                << fmt::format("{:.6g}", lr) << "," << (ok ? fmt::format("{:.6g}", grad_norm) : "")
                << "\n";
      if (ok) {
        adam.step();
        if (avg) update_average(average, model, ema_decay(cfg.train.ema, st.step));
        loss_sum += loss_value;
        ++good;
        bad_in_a_row = 0;
        if (opt_in.save_every > 0 && st.step % opt_in.save_every == 0) {
          steps_csv.flush();
          save_checkpoint(last, model, adam, st, cfg, avg);
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
        RunState back = load_checkpoint(last, model, &adam, device, avg);
        // From the current scale: repeated rollbacks within an epoch keep lowering it.
        st.lr_scale = std::min(st.lr_scale, back.lr_scale) * cfg.train.rollback_lr_factor;
        ++result.rollbacks;
        bad_in_a_row = 0;
        log(spdlog::level::warn,
            "rolled back to {} (epoch {} step {}) after {} non-finite steps; LR scale now {}",
            last.string(), back.epoch, back.step, cfg.train.max_bad_steps, st.lr_scale);
      }
    }
    const bool interrupted = st.step < (st.epoch + 1) * steps_per_epoch;
    if (interrupted) break;

    // Validation: the same sequences every epoch (while the shard set holds).
    double val = NAN, val_ssim = NAN, val_psnr = NAN;
    std::vector<Sample> vs = stream.validation(cfg.train.val_sequences);
    if (!vs.empty()) {
      torch::NoGradGuard no_grad;
      judged->eval();
      double sum = 0;
      ImageScores scores;
      for (size_t i = 0; i < vs.size(); i += cfg.train.batch) {
        std::vector<Sample> part(vs.begin() + i,
                                 vs.begin() + std::min(vs.size(), i + cfg.train.batch));
        Batch b = make_batch(part, device, format);
        torch::Tensor y =
            float_output(cfg.train.precision, device, [&] { return judged->forward(b.input); });
        sum += denoiser_loss(y, b.target, cfg.loss, kernel, b.coc).total.item<double>() *
               double(part.size());
        std::vector<torch::Tensor> albedo;
        for (const Sample& smp : part)
          albedo.push_back(torch::from_blob(const_cast<float*>(smp.albedo.data()),
                                            {smp.frames, 3, smp.size, smp.size}));
        scores.add(y, b, torch::stack(albedo), cfg.data.demod_eps, space);
      }
      val = sum / double(vs.size());
      val_ssim = scores.ssim();
      val_psnr = scores.psnr();
    }
    // Whole validation frames (the network saw only crops): a model can
    // score well on crops and fail on whole frames. The same frames cut
    // into crop-sized tiles tell a failure on the frame's extent from one
    // on its content.
    double val_frame_ssim = NAN, val_tile_ssim = NAN;
    FrameFailure frame_failure = FrameFailure::kNone;
    if (cfg.train.val_frames > 0 && !vs.empty()) {
      judged->eval();
      const FrameScores fs_scores =
          full_frame_scores(judged, cfg, device, opt_in.data_dir, stream.splits(),
                            cfg.train.val_frames, cfg.data.crop);
      val_frame_ssim = fs_scores.whole;
      val_tile_ssim = fs_scores.tiles;
      frame_failure = whole_frame_failure(val_frame_ssim, val_ssim, val_tile_ssim);
      frames_failed |= frame_failure != FrameFailure::kNone;
      if (frame_failure == FrameFailure::kNonFinite)
        log(spdlog::level::warn, "epoch {}: whole validation frames: non-finite output",
            st.epoch + 1);
      else if (frame_failure == FrameFailure::kBelowCrops)
        log(spdlog::level::warn,
            "epoch {}: whole validation frames score SSIM {:.3f} against {:.3f} on the "
            "validation crops: the network does not carry over from crops to whole frames; "
            "this epoch cannot become best.pt",
            st.epoch + 1, val_frame_ssim, val_ssim);
      else if (frame_failure == FrameFailure::kBelowTiles)
        log(spdlog::level::warn,
            "epoch {}: whole validation frames score SSIM {:.3f} against {:.3f} for the same "
            "frames denoised as {}-px tiles: the network fails far from the borders of its "
            "crops (docs/results.md, \"Where whole frames fail\"); this epoch cannot become "
            "best.pt",
            st.epoch + 1, val_frame_ssim, val_tile_ssim, cfg.data.crop);
    }
    double train_loss = good ? loss_sum / good : NAN;
    double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ++st.epoch;
    csv << st.epoch << "," << st.step << ","
        << (std::isfinite(train_loss) ? fmt::format("{:.6g}", train_loss) : "") << ","
        << (std::isfinite(val) ? fmt::format("{:.6g}", val) : "") << ","
        << fmt::format("{:.6g}", lr) << "," << skipped << "," << fmt::format("{:.3f}", seconds)
        << "," << (std::isfinite(val_ssim) ? fmt::format("{:.6g}", val_ssim) : "") << ","
        << (std::isfinite(val_psnr) ? fmt::format("{:.6g}", val_psnr) : "") << ","
        << (std::isfinite(val_frame_ssim) ? fmt::format("{:.6g}", val_frame_ssim) : "") << ","
        << (std::isfinite(val_tile_ssim) ? fmt::format("{:.6g}", val_tile_ssim) : "") << "\n";
    csv.flush();
    steps_csv.flush();
    spdlog::info("epoch {}/{}: train {:.5f} val {:.5f} lr {:.3g} ({:.1f} s)", st.epoch,
                 cfg.train.epochs, train_loss, val, lr, seconds);
    if (clipped > 0)
      log(spdlog::level::info, "epoch {}: {} of {} steps clipped to gradient norm {}", st.epoch,
          clipped, good, cfg.train.grad_clip);
    // Best by validation loss, or by training loss (train.best_by; thesis
    // 5.1), and always by training loss when there is no validation set.
    // A non-finite loss never makes a model "best".
    if (!vs.empty() && !std::isfinite(val))
      log(spdlog::level::warn, "epoch {}: non-finite validation loss", st.epoch);
    // "frames": 1 - SSIM of the whole validation frames (lower is better, as
    // a loss), so that best.pt is never a model that fails on whole frames
    // (train.val_frames > 0 is checked with the config).
    double score = vs.empty() || cfg.train.best_by == BestBy::kTraining ? train_loss : val;
    if (!vs.empty() && cfg.train.best_by == BestBy::kFrames) score = 1.0 - val_frame_ssim;
    // An epoch whose whole frames fail is never best, whatever its score.
    bool improved = std::isfinite(score) && score < st.best && frame_failure == FrameFailure::kNone;
    if (improved) st.best = score;
    save_checkpoint(last, model, adam, st, cfg, avg);
    if (improved) fs::copy_file(last, best, fs::copy_options::overwrite_existing);
    ++result.epochs;
  }
  steps_csv.flush();
  if (frames_failed && !fs::exists(best))
    log(spdlog::level::warn,
        "no epoch so far passed the whole-frame validation: no best.pt, and \"best\" reads "
        "last.pt");
  if (result.stopped) {
    save_checkpoint(last, model, adam, st, cfg, avg);
    log(spdlog::level::warn,
        "stopped on request at epoch {} step {}: {} written; run the same command to resume",
        st.epoch, st.step, last.string());
  } else if (opt_in.stop_at_step >= 0 && st.step >= opt_in.stop_at_step &&
             st.epoch < cfg.train.epochs) {
    save_checkpoint(last, model, adam, st, cfg, avg);
  }
  result.steps = st.step;
  result.best_val = st.best;
  return result;
}

}  // namespace

}  // namespace dofarm::trainer
