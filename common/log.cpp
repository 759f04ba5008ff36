#include "common/log.h"

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <memory>

#include "common/error.h"

namespace dofarm {

const std::vector<std::string>& log_level_names() {
  static const std::vector<std::string> kNames = {"trace", "debug", "info", "warn", "error", "off"};
  return kNames;
}

void init_logging(const std::string& level, bool to_stderr) {
  // spdlog::level::from_str() maps unknown names to "off", which would hide
  // a typo; check against our own list instead.
  const auto& names = log_level_names();
  if (std::find(names.begin(), names.end(), level) == names.end()) {
    std::string list;
    for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
    throw SpecError(FileLoc{"--log-level"}, "",
                    "expected one of " + list + ", got \"" + level + "\"");
  }
  // Calling again (tests, a subcommand changing the level) replaces the logger.
  spdlog::drop("dofarm");
  std::shared_ptr<spdlog::logger> logger;
  if (to_stderr) {
    logger = spdlog::stderr_color_mt("dofarm");
  } else {
    logger = spdlog::stdout_color_mt("dofarm");
  }
  logger->set_pattern("[%Y-%m-%d %H:%M:%S.%e] [%^%l%$] %v");
  logger->set_level(spdlog::level::from_str(level));
  // Warnings and errors reach the terminal at once even when stderr is a pipe.
  logger->flush_on(spdlog::level::warn);
  spdlog::set_default_logger(logger);
}

}  // namespace dofarm
