// What dofarm and dofarm-train share around their subcommands: the Command
// pair and the one place where a command line is parsed, logging set up, the
// chosen command run, and every failure mapped to an exit status (STYLE.md 3):
//   0 success, 2 bad input (SpecError, CLI11 parse errors), 1 anything else,
// with the error as one line "<program>: error: <message>" on stderr.
#pragma once

#include <CLI/CLI.hpp>
#include <cstdio>
#include <functional>
#include <string>
#include <vector>

#include "common/error.h"
#include "common/log.h"

namespace dofarm {

// A declared subcommand and what to do when it was chosen.
struct Command {
  CLI::App* app;
  std::function<int()> run;
};

inline void print_cli_error(const std::string& program, const std::string& message) {
  std::fprintf(stderr, "%s: error: %s\n", program.c_str(), message.c_str());
}

// Adds --version and --log-level to `app`, declares the commands with
// `declare(app)`, parses and runs the chosen one.
inline int run_cli(CLI::App& app, const std::string& program, int argc, char** argv,
                   const std::function<std::vector<Command>(CLI::App&)>& declare) {
  app.set_version_flag("--version", std::string(DOFARM_VERSION));
  app.require_subcommand(1);
  app.fallthrough();  // global options are also accepted after the subcommand's name
  std::string log_level = "info";
  app.add_option("--log-level", log_level, "log verbosity")
      ->check(CLI::IsMember(log_level_names()))
      ->capture_default_str();
  const std::vector<Command> commands = declare(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version arrive as "errors" with exit code 0.
    if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) return app.exit(e);
    print_cli_error(program, e.what());
    return kExitBadInput;
  }
  try {
    init_logging(log_level, /*to_stderr=*/true);
    for (const Command& c : commands)
      if (c.app->parsed()) return c.run();
    print_cli_error(program, "no command given (see " + program + " --help)");
    return kExitBadInput;
  } catch (const SpecError& e) {
    print_cli_error(program, e.what());
    return kExitBadInput;
  } catch (const std::exception& e) {
    print_cli_error(program, e.what());
    return kExitRuntime;
  } catch (...) {
    print_cli_error(program, "unknown failure");
    return kExitRuntime;
  }
}

}  // namespace dofarm
