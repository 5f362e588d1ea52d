#pragma once

// Shared pieces of the kinevis command line: exit codes (docs/cli.md), the stop flag set by
// SIGINT/SIGTERM, and the mapping of exceptions to exit codes at the command boundary.

#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <string>

namespace kinevis::cli {

enum ExitCode : int {
  kExitOk = 0,         // the job succeeded
  kExitJobFailed = 1,  // the job ran and failed (a check did not pass, a target not reached)
  kExitUsage = 2,      // bad command line, backend string or configuration
  kExitHardware = 3,   // a device could not be reached or failed during the job
};

// Installs SIGINT/SIGTERM handlers that set the stop flag (first signal) and restore the default
// action, so a second Ctrl-C kills a stuck program.
void InstallStopHandlers();
bool StopRequested();
void RequestStop();

// Runs a command body; maps exceptions to exit codes and prints them on stderr as
// "kinevis <command>: <message>": common::ConfigError and other std::invalid_argument (bad
// files or parameters found by a library) -> 2, hal::HalError -> 3, other -> 1.
int RunGuarded(const std::string& command, const std::function<int()>& body);

// For `kinevis sim ...`: prints `backend` as the first line of standard output (flushed), then
// blocks until SIGINT/SIGTERM and returns kExitOk. `poll` runs every `period` meanwhile (for a
// simulator that needs stepping); it may return false to end early with kExitJobFailed.
int ServeUntilStopped(const std::string& backend, const std::function<bool()>& poll = {},
                      std::chrono::milliseconds period = std::chrono::milliseconds(10));

// Sets spdlog's level from "trace|debug|info|warn|error|critical|off"; false if unknown.
bool SetLogLevel(const std::string& level);

}  // namespace kinevis::cli
