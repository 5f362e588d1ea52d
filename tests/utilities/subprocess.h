#pragma once

// Running whole programs from tests: the kinevis CLI under test, or third-party tools (mbpoll,
// candump) against the project's simulators. Every call is bounded in time: a child that does
// not finish is killed and the test sees that it timed out.

#include <chrono>
#include <string>
#include <vector>

namespace kinevis::testing {

struct ProcessResult {
  int exit_code = -1;  // exit status, or -1 when killed by a signal or timed out
  bool timed_out = false;
  std::string out;  // everything the child wrote to stdout
  std::string err;  // everything the child wrote to stderr
};

// Runs argv[0] (looked up in PATH) with the arguments, no stdin, and collects its output.
ProcessResult RunProcess(const std::vector<std::string>& argv,
                         std::chrono::milliseconds timeout = std::chrono::seconds(30));

// A child running in the background (a simulator): its stdout is read line by line.
class BackgroundProcess {
 public:
  explicit BackgroundProcess(const std::vector<std::string>& argv);
  ~BackgroundProcess();  // SIGTERM, then SIGKILL after 2 s
  BackgroundProcess(const BackgroundProcess&) = delete;
  BackgroundProcess& operator=(const BackgroundProcess&) = delete;

  // The next line of stdout without its newline; empty string and false on timeout or EOF.
  bool ReadLine(std::string* line, std::chrono::milliseconds timeout);
  // Sends `signal` and waits for the exit; returns the exit code (-1 if killed or timed out).
  int Stop(int signal, std::chrono::milliseconds timeout = std::chrono::seconds(5));
  int pid() const { return pid_; }

 private:
  int pid_ = -1;
  int out_fd_ = -1;
  std::string buffer_;
  bool exited_ = false;
  int exit_code_ = -1;
};

// Path of the kinevis executable built with the tests.
std::string KinevisCliPath();

// Runs `kinevis ARGS...` (the executable built with the tests) to completion.
ProcessResult RunKinevis(std::vector<std::string> args,
                         std::chrono::milliseconds timeout = std::chrono::seconds(60));

// True when the program is on PATH.
bool HaveProgram(const std::string& name);

}  // namespace kinevis::testing
