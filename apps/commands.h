// Shared pieces of the dofarm subcommands: each add_<name>() declares its
// options on CLI11 and returns the action to run once parsed.
#pragma once

#include <CLI/CLI.hpp>
#include <atomic>
#include <functional>
#include <string>
#include <vector>

#include "apps/cli_main.h"

namespace dofarm {

// --set KEY=VALUE, shared by every command that reads a job spec.
void add_set_option(CLI::App* cmd, std::vector<std::string>& sets);

Command add_run(CLI::App& app);
Command add_coordinator(CLI::App& app);
Command add_worker(CLI::App& app);
Command add_submit(CLI::App& app);
Command add_status(CLI::App& app);
Command add_events(CLI::App& app);
Command add_resume(CLI::App& app);
Command add_cancel(CLI::App& app);
Command add_priority(CLI::App& app);
Command add_inspect(CLI::App& app);
Command add_keygen(CLI::App& app);
Command add_verify(CLI::App& app);

}  // namespace dofarm
