// The coordinator's notion of time, injected so that lease expiry, back-off
// and rates are tested by advancing a FakeClock, never by sleeping.
//
// Times are seconds since the Unix epoch. They are stored in the job store
// (lease expiries, back-off deadlines), so they must mean the same thing after
// a coordinator restart: that rules out steady_clock, whose epoch is the boot.
#pragma once

#include <chrono>

namespace dofarm::coordinator {

class Clock {
 public:
  virtual ~Clock() = default;
  virtual double now() const = 0;  // seconds since the Unix epoch
};

class SystemClock final : public Clock {
 public:
  double now() const override {
    return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch())
        .count();
  }
};

// Starts at a fixed, realistic epoch time so that stored values look like
// real ones; moves only when told to.
class FakeClock final : public Clock {
 public:
  explicit FakeClock(double start = 1.7e9) : now_(start) {}
  double now() const override { return now_; }
  void advance(double seconds) { now_ += seconds; }
  void set(double t) { now_ = t; }

 private:
  double now_;
};

}  // namespace dofarm::coordinator
