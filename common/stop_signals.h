// SIGINT and SIGTERM as a request to stop gracefully (Ctrl-C; Slurm's
// preemption and the end of a job's time send SIGTERM first): the first one
// sets stop_requested(), which the command's loop polls to finish its step,
// hand back its work and exit. Shared by dofarm's farm commands and
// dofarm-train.
#pragma once

#include <atomic>

namespace dofarm {

// What a signal after the first does.
enum class RepeatedSignal {
  kAsksAgain,   // nothing more: the stop already asked for goes on
  kTerminates,  // the signal's default action, at once (a second Ctrl-C ends the process)
};

// Set by SIGINT/SIGTERM once install_stop_signals() ran; never cleared.
std::atomic<bool>& stop_requested();

// Installs the handler of SIGINT and SIGTERM (sigaction; the handler only
// touches lock-free atomics, so it is async-signal-safe).
void install_stop_signals(RepeatedSignal repeated);

}  // namespace dofarm
