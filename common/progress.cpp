#include "common/progress.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace dofarm {

Progress::Progress(std::string label, int64_t total, std::string unit, ProgressOptions options)
    : label_(std::move(label)),
      unit_(std::move(unit)),
      total_(std::max<int64_t>(total, 0)),
      options_(std::move(options)) {
  mode_ = options_.mode;
  if (mode_ == ProgressOptions::Mode::kAuto) {
    mode_ = isatty(fileno(stderr)) ? ProgressOptions::Mode::kBar : ProgressOptions::Mode::kLog;
  }
  start_s_ = now();
  last_report_s_ = start_s_;
}

Progress::~Progress() { finish(); }

double Progress::now() const {
  if (options_.clock) return options_.clock();
  using namespace std::chrono;
  return duration<double>(steady_clock::now().time_since_epoch()).count();
}

void Progress::advance(int64_t n) {
  done_.fetch_add(n, std::memory_order_relaxed);
  if (mode_ == ProgressOptions::Mode::kOff) return;
  // Threads that find the output busy skip drawing: the next caller shows
  // their work anyway, and nobody waits on the terminal.
  std::unique_lock<std::mutex> lock(mutex_, std::try_to_lock);
  if (!lock.owns_lock() || finished_) return;
  double interval =
      mode_ == ProgressOptions::Mode::kBar ? options_.bar_interval_s : options_.log_interval_s;
  if (now() - last_report_s_ < interval) return;
  report(false);
}

void Progress::resume_from(int64_t n) {
  std::lock_guard<std::mutex> lock(mutex_);
  before_ = std::max<int64_t>(n, 0);
  done_.store(before_, std::memory_order_relaxed);
}

void Progress::finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  finished_ = true;
  if (mode_ != ProgressOptions::Mode::kOff) report(true);
}

void Progress::fail(const std::string& why) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  finished_ = true;
  if (mode_ != ProgressOptions::Mode::kOff) report(true, why.empty() ? "failed" : why);
}

// Called with mutex_ held.
void Progress::report(bool final, const std::string& failure) {
  double t = now();
  last_report_s_ = t;
  int64_t done = done_.load(std::memory_order_relaxed);
  double elapsed = t - start_s_;
  const std::string counted =
      fmt::format("{}/{}{}", done, total_, unit_.empty() ? "" : " " + unit_);
  // Never "done" for work that failed: a failed batch whose every task has
  // ended is 3/3 tasks, but not done.
  const std::string end =
      failure.empty() ? fmt::format("done in {}", format_duration(elapsed))
                      : fmt::format("failed after {}: {}", format_duration(elapsed), failure);
  if (mode_ == ProgressOptions::Mode::kBar) {
    std::string line =
        format_progress(label_, done, total_, elapsed, options_.bar_width, unit_, before_);
    if (final) line += " " + end;
    // \r and "erase to end of line" redraw in place.
    std::fprintf(options_.bar_out, "\r%s\x1b[K%s", line.c_str(), final ? "\n" : "");
    std::fflush(options_.bar_out);
  } else if (final && failure.empty()) {
    spdlog::info("{}: {} {}", label_, counted, end);
  } else if (final) {
    spdlog::warn("{}: {} {}", label_, counted, end);
  } else {
    spdlog::info("{}", format_progress(label_, done, total_, elapsed, 0, unit_, before_));
  }
}

std::string format_duration(double seconds) {
  if (!(seconds >= 0) || !std::isfinite(seconds)) return "?";
  // An early, tiny rate can predict absurd times; do not pretend precision.
  if (seconds >= 100 * 3600.0) return ">100h";
  auto s = static_cast<int64_t>(std::llround(seconds));
  if (s < 60) return fmt::format("{}s", s);
  if (s < 3600) return fmt::format("{}m{:02}s", s / 60, s % 60);
  return fmt::format("{}h{:02}m", s / 3600, (s % 3600) / 60);
}

double estimate_eta(int64_t done, int64_t total, double elapsed_s, int64_t before) {
  if (done >= total && total > 0) return 0;
  const int64_t this_run = done - before;
  if (this_run <= 0 || elapsed_s < 0) return -1;
  return elapsed_s * static_cast<double>(total - done) / static_cast<double>(this_run);
}

std::string format_progress(const std::string& label, int64_t done, int64_t total, double elapsed_s,
                            int bar_width, const std::string& unit, int64_t before) {
  double frac = total > 0 ? std::clamp(double(done) / double(total), 0.0, 1.0) : 1.0;
  std::string bar;
  if (bar_width > 0) {
    int filled = static_cast<int>(frac * bar_width);
    bar = "[";
    bar.append(filled, '=');
    if (filled < bar_width) {
      bar += '>';
      bar.append(bar_width - filled - 1, ' ');
    }
    bar += "] ";
  }
  return fmt::format("{} {}{:3}% {}/{}{} ETA {}", label, bar, static_cast<int>(frac * 100), done,
                     total, unit.empty() ? "" : " " + unit,
                     format_duration(estimate_eta(done, total, elapsed_s, before)));
}

}  // namespace dofarm
