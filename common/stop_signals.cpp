// SIGINT/SIGTERM as a graceful stop (common/stop_signals.h).
#include "common/stop_signals.h"

#include <signal.h>

#include <csignal>

namespace dofarm {
namespace {

// Read by the handler: set before the handler is installed.
std::atomic<bool> g_repeat_terminates{false};

extern "C" void on_stop_signal(int sig) {
  if (stop_requested().exchange(true) && g_repeat_terminates.load()) {
    // A signal after the first: the default action (terminate), now.
    std::signal(sig, SIG_DFL);
    std::raise(sig);
  }
}

}  // namespace

std::atomic<bool>& stop_requested() {
  static std::atomic<bool> flag{false};
  return flag;
}

void install_stop_signals(RepeatedSignal repeated) {
  g_repeat_terminates.store(repeated == RepeatedSignal::kTerminates);
  struct sigaction sa = {};
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

}  // namespace dofarm
