// Logging setup shared by every executable: one spdlog logger, levels named as
// on the command line (--log-level), thread-safe sinks because render threads
// and the network loop log concurrently.
#pragma once

#include <string>
#include <vector>

namespace dofarm {

// The accepted --log-level names, most verbose first.
const std::vector<std::string>& log_level_names();

// Installs the default logger. `level` is one of log_level_names(); anything
// else is a SpecError naming "--log-level". Logs go to stderr when `to_stderr`
// (keeping stdout for results such as a batch id or --json), else to stdout.
void init_logging(const std::string& level, bool to_stderr = true);

}  // namespace dofarm
