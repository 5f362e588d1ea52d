#pragma once

// Real-time scheduling for a fixed-rate control loop (issue 8: the DIAMOND's 1 kHz loop): the
// calling thread to SCHED_FIFO at a priority, optionally pinned to one CPU, and the process's
// memory locked (no page faults in the loop). What the kernel granted is reported, not assumed:
// without CAP_SYS_NICE / an rtprio limit (ulimit -r) the priority is refused with EPERM and the
// loop runs as before, with the reason in the report.
//
// Threads created by the calling thread afterwards inherit its policy: apply it right before the
// loop, after the helper threads (camera worker, simulators) exist, and restore it after.

#include <string>

namespace kinevis::hal {

struct RealtimeRequest {
  int priority = 0;          // SCHED_FIFO priority 1..99; 0: leave the policy alone
  int cpu = -1;              // pin the calling thread to this CPU (>= 0); -1: leave it
  bool lock_memory = false;  // mlockall(MCL_CURRENT | MCL_FUTURE)
  // The calling thread's timer slack (prctl PR_SET_TIMERSLACK, ns; no privilege needed): how
  // much later than asked the kernel may wake a sleeping normal-policy thread to group wake-ups.
  // Linux's default is 50 µs, 5 % of a 1 kHz period, added to every wake-up. -1: leave it.
  long timer_slack_ns = -1;
  std::string Validate() const;  // empty when usable, else each bad field and its value
};

struct RealtimeGrant {
  bool priority_set = false;
  bool cpu_set = false;
  bool memory_locked = false;
  long previous_timer_slack_ns = -1;  // >= 0 when the slack was changed (restored from this)
  // One line: what was asked, granted and refused (with errno's text), e.g.
  // "SCHED_FIFO 80: refused (Operation not permitted; needs CAP_SYS_NICE or ulimit -r); cpu 1:
  // set".
  std::string message;
};

// Applies `request` to the calling thread (and, for lock_memory, the process). Throws
// std::invalid_argument for a request that fails Validate() (priority outside 0..99, a CPU that
// does not exist). Refusals by the kernel are reported in the grant, not thrown.
RealtimeGrant ApplyRealtime(const RealtimeRequest& request);

// Puts the calling thread back to SCHED_OTHER (nice 0), all CPUs, its previous timer slack, and
// unlocks memory, for what `grant` changed.
void RestoreNormalScheduling(const RealtimeGrant& grant);

// ApplyRealtime() for a scope: what was granted is restored (RestoreNormalScheduling) when the
// scope ends. Same throws as ApplyRealtime().
class ScopedRealtime {
 public:
  explicit ScopedRealtime(const RealtimeRequest& request) : grant_(ApplyRealtime(request)) {}
  ~ScopedRealtime() { RestoreNormalScheduling(grant_); }
  ScopedRealtime(const ScopedRealtime&) = delete;
  ScopedRealtime& operator=(const ScopedRealtime&) = delete;
  const RealtimeGrant& grant() const { return grant_; }

 private:
  RealtimeGrant grant_;
};

}  // namespace kinevis::hal
