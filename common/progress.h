// Progress of long work (rendering a frame, a batch) with an ETA (DESIGN.md,
// "Users"): on a terminal one bar line that updates in place, otherwise a
// plain log line every few seconds and one at the end, so logs of a farm stay
// readable. advance() may be called from any thread.
#pragma once

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <mutex>
#include <string>

namespace dofarm {

struct ProgressOptions {
  enum class Mode { kAuto, kBar, kLog, kOff };
  Mode mode = Mode::kAuto;      // kAuto: kBar when stderr is a terminal, else kLog
  double log_interval_s = 5.0;  // at most one log line this often (kLog)
  double bar_interval_s = 0.1;  // at most one redraw this often (kBar)
  int bar_width = 30;           // characters of the bar itself
  // Seconds on a monotonic clock; injectable so tests need not sleep.
  std::function<double()> clock;
  std::FILE* bar_out = stderr;  // where the bar is drawn (kBar)
};

class Progress {
 public:
  // `unit` names what is counted ("tasks", "blocks", "steps"): every line says it.
  Progress(std::string label, int64_t total, std::string unit, ProgressOptions options = {});
  Progress(std::string label, int64_t total, ProgressOptions options = {})
      : Progress(std::move(label), total, "", std::move(options)) {}
  ~Progress();  // finish()
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  // Records `n` more units done; thread-safe and cheap when nothing is drawn.
  void advance(int64_t n = 1);
  // Work resumed with `n` units already done before this run: they count in
  // the percentage but not in the rate, so the ETA is this run's own (a
  // resumed batch at 153/1542 must not predict its rest from 153 tasks
  // "done" in its first second). Call before the first advance().
  void resume_from(int64_t n);
  // Prints the final line once ("... done in 6s"); later calls do nothing.
  void finish();
  // The work ended without succeeding: the final line says "failed after 6s:
  // <why>" (at warning level in a log) instead of "done".
  void fail(const std::string& why);

  int64_t done() const { return done_.load(std::memory_order_relaxed); }
  int64_t total() const { return total_; }

 private:
  double now() const;
  // `outcome`: empty while running; "done", or the failure's text, at the end.
  void report(bool final, const std::string& failure = "");

  std::string label_;
  std::string unit_;
  int64_t total_;
  ProgressOptions options_;
  ProgressOptions::Mode mode_;
  double start_s_;
  std::atomic<int64_t> done_{0};
  int64_t before_ = 0;  // done before this run (resume_from)
  std::mutex mutex_;  // guards what follows and the output
  double last_report_s_;
  bool finished_ = false;
};

// The pieces of a progress line, separate so they can be checked exactly.
// "12s", "3m05s", "1h02m"; "?" for a negative (unknown) duration.
std::string format_duration(double seconds);
// Remaining seconds at this run's mean rate, (done - before) units in
// elapsed_s; -1 while this run has done nothing.
double estimate_eta(int64_t done, int64_t total, double elapsed_s, int64_t before = 0);
// "label  42% 21/50 tiles ETA 12s", with "[=====>    ] " before the
// percentage when bar_width > 0 (no unit word when `unit` is empty). The ETA
// is in format_duration's form, as in `dofarm status`; `before` units were
// done before elapsed_s began (estimate_eta).
std::string format_progress(const std::string& label, int64_t done, int64_t total, double elapsed_s,
                            int bar_width, const std::string& unit = "", int64_t before = 0);

}  // namespace dofarm
