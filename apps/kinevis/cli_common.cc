#include "apps/kinevis/cli_common.h"

#include <spdlog/spdlog.h>

#include <csignal>
#include <iostream>
#include <thread>

#include "hal/common/error.h"

namespace kinevis::cli {
namespace {

std::atomic<bool> g_stop{false};

extern "C" void OnStopSignal(int signal) {
  g_stop.store(true);
  std::signal(signal, SIG_DFL);
}

}  // namespace

void InstallStopHandlers() {
  std::signal(SIGINT, OnStopSignal);
  std::signal(SIGTERM, OnStopSignal);
  std::signal(SIGPIPE, SIG_IGN);  // a closed pipe is an EPIPE error, not a silent death
}

bool StopRequested() { return g_stop.load(); }
void RequestStop() { g_stop.store(true); }

int RunGuarded(const std::string& command, const std::function<int()>& body) {
  try {
    return body();
  } catch (const common::ConfigError& e) {
    std::cerr << "kinevis " << command << ": " << e.what() << "\n";
    return kExitUsage;
  } catch (const hal::HalError& e) {
    std::cerr << "kinevis " << command << ": " << e.what() << "\n";
    return kExitHardware;
  } catch (const std::invalid_argument& e) {
    // Bad input found by a library (a robot description or camera file, model parameters).
    std::cerr << "kinevis " << command << ": " << e.what() << "\n";
    return kExitUsage;
  } catch (const std::exception& e) {
    std::cerr << "kinevis " << command << ": " << e.what() << "\n";
    return kExitJobFailed;
  }
}

int ServeUntilStopped(const std::string& backend, const std::function<bool()>& poll,
                      std::chrono::milliseconds period) {
  std::cout << backend << std::endl;  // endl: the first line must reach a pipe at once
  while (!StopRequested()) {
    if (poll && !poll()) return kExitJobFailed;
    std::this_thread::sleep_for(period);
  }
  spdlog::info("{}: stopped by signal", backend);
  return kExitOk;
}

bool SetLogLevel(const std::string& level) {
  auto l = spdlog::level::from_str(level);
  // from_str returns off for unknown names; accept "off" only when asked for.
  if (l == spdlog::level::off && level != "off") return false;
  spdlog::set_level(l);
  return true;
}

}  // namespace kinevis::cli
