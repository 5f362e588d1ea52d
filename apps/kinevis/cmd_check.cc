// kinevis check timing: how steadily this host paces an empty fixed-rate loop (the DeadlineGrid
// the control loops use), with the same real-time options as `servo diamond`. Run it on the
// robot's host before a control job: a control loop can be no steadier than this.

#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "common/clock.h"
#include "control/common/fixed_rate.h"
#include "hal/common/realtime.h"

namespace kinevis::cli {
namespace {

struct TimingOptions {
  double rate_hz = 1000.0;
  double seconds = 5.0;
  int rt_priority = 0;
  int rt_cpu = -1;
  bool rt_lock_memory = false;
  long timer_slack_ns = 1;
};

int RunCheckTiming(const TimingOptions& o) {
  hal::RealtimeRequest rt;
  rt.priority = o.rt_priority;
  rt.cpu = o.rt_cpu;
  rt.lock_memory = o.rt_lock_memory;
  rt.timer_slack_ns = o.timer_slack_ns;
  if (const std::string bad = rt.Validate(); !bad.empty()) {
    std::fprintf(stderr, "kinevis check timing: %s\n", bad.c_str());
    return kExitUsage;
  }
  const hal::ScopedRealtime scheduled(rt);
  const hal::RealtimeGrant& grant = scheduled.grant();
  std::printf("scheduling: %s\n", grant.message.empty() ? "normal" : grant.message.c_str());
  std::printf("pacing an empty loop at %.1f Hz for %.1f s ...\n", o.rate_hz, o.seconds);
  std::fflush(stdout);
  const control::PeriodStatistics s =
      control::MeasureLoopTiming(&common::SteadyClock::Instance(), 1.0 / o.rate_hz, o.seconds);
  std::printf(
      "periods: %llu, mean %.1f us (%.1f Hz), std %.1f us, min %.1f, p50 %.1f, p99 %.1f, max "
      "%.1f us\n",
      static_cast<unsigned long long>(s.periods), s.mean_s * 1e6, s.rate_hz(), s.std_s * 1e6,
      s.min_s * 1e6, s.p50_s * 1e6, s.p99_s * 1e6, s.max_s * 1e6);
  std::printf(
      "wake-ups: lateness p50 %.1f, p99 %.1f, max %.1f us; %llu later than 10%% of the "
      "period, %llu deadlines missed\n",
      s.p50_lateness_s * 1e6, s.p99_lateness_s * 1e6, s.max_lateness_s * 1e6,
      static_cast<unsigned long long>(s.late_cycles),
      static_cast<unsigned long long>(s.missed_deadlines));
  const std::string problem = control::SteadyRateProblem(s);
  if (problem.empty()) {
    std::printf("steady: this host holds %.1f Hz (no missed deadline, p99 within 10%%)\n",
                o.rate_hz);
    return kExitOk;
  }
  std::printf(
      "NOT steady at %.1f Hz: %s. A control loop on this host can be no steadier; see "
      "docs/diamond-control.md (real-time scheduling)\n",
      o.rate_hz, problem.c_str());
  return kExitJobFailed;
}

}  // namespace

void AddCheckCommands(const Parents& parents, CommandList* commands) {
  CLI::App& app = *parents.app;
  CLI::App* check = app.add_subcommand("check", "Checks of this host before a job on hardware");
  check->require_subcommand(1);
  auto o = std::make_shared<TimingOptions>();
  CLI::App* timing = check->add_subcommand(
      "timing",
      "Pace an empty loop at a fixed rate on the steady clock (the deadline grid of the control "
      "loops) and report the periods, lateness and missed deadlines. Exit 0 when steady (no "
      "missed deadline, p99 period within 10 % of the target), 1 when not");
  timing->add_option("--rate", o->rate_hz, "Loop rate (Hz, default 1000: the DIAMOND's loop)")
      ->check(CLI::Range(1.0, 100000.0));
  timing->add_option("--seconds", o->seconds, "How long to measure (s, default 5)")
      ->check(CLI::Range(0.01, 3600.0));
  timing
      ->add_option("--rt-priority", o->rt_priority,
                   "SCHED_FIFO priority (1-99) of the loop's thread; needs CAP_SYS_NICE or an "
                   "rtprio limit, else reported as refused (default 0: normal)")
      ->check(CLI::Range(0, 99));
  timing->add_option("--rt-cpu", o->rt_cpu, "Pin the loop's thread to this CPU (default -1: any)")
      ->check(CLI::Range(-1, 1023));
  timing->add_flag("--rt-lock-memory", o->rt_lock_memory, "mlockall the process during the run");
  timing
      ->add_option("--timer-slack-ns", o->timer_slack_ns,
                   "Timer slack of the loop's thread (ns; default 1, as `servo diamond` uses; "
                   "-1: the kernel's default, 50 us on Linux)")
      ->check(CLI::Range(-1L, 1000000000L));
  commands->push_back({timing, [o] {
                         try {
                           return RunCheckTiming(*o);
                         } catch (const std::invalid_argument& e) {
                           std::fprintf(stderr, "kinevis check timing: %s\n", e.what());
                           return static_cast<int>(kExitUsage);
                         }
                       }});
}

}  // namespace kinevis::cli
