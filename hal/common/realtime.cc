#include "hal/common/realtime.h"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace kinevis::hal {

std::string RealtimeRequest::Validate() const {
  std::string out;
  auto add = [&out](const std::string& s) { out += (out.empty() ? "" : "; ") + s; };
  if (priority < 0 || priority > 99) {
    add("priority = " + std::to_string(priority) + " (0 = off, or SCHED_FIFO 1..99)");
  } else if (priority > 0) {
    const int lo = sched_get_priority_min(SCHED_FIFO), hi = sched_get_priority_max(SCHED_FIFO);
    if (priority < lo || priority > hi) {
      add("priority = " + std::to_string(priority) + " (SCHED_FIFO here: " + std::to_string(lo) +
          ".." + std::to_string(hi) + ")");
    }
  }
  const long cpus = sysconf(_SC_NPROCESSORS_ONLN);
  if (cpu < -1 || (cpu >= 0 && cpu >= cpus)) {
    add("cpu = " + std::to_string(cpu) + " (-1 = any, or 0.." + std::to_string(cpus - 1) + ")");
  }
  if (timer_slack_ns < -1 || timer_slack_ns > 1000000000L) {
    add("timer_slack_ns = " + std::to_string(timer_slack_ns) + " (-1 = leave, or 0..1e9 ns)");
  }
  return out;
}

RealtimeGrant ApplyRealtime(const RealtimeRequest& request) {
  const std::string problems = request.Validate();
  if (!problems.empty()) throw std::invalid_argument("real-time scheduling: " + problems);
  RealtimeGrant g;
  auto note = [&g](const std::string& s) { g.message += (g.message.empty() ? "" : "; ") + s; };
  if (request.priority > 0) {
    sched_param p{};
    p.sched_priority = request.priority;
    const int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &p);
    g.priority_set = rc == 0;
    note("SCHED_FIFO " + std::to_string(request.priority) + ": " +
         (rc == 0 ? std::string("set")
                  : "refused (" + std::string(std::strerror(rc)) +
                        (rc == EPERM ? "; needs CAP_SYS_NICE or ulimit -r" : "") + ")"));
  }
  if (request.cpu >= 0) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(request.cpu, &set);
    const int rc = pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
    g.cpu_set = rc == 0;
    note("cpu " + std::to_string(request.cpu) + ": " +
         (rc == 0 ? std::string("set") : "refused (" + std::string(std::strerror(rc)) + ")"));
  }
  if (request.lock_memory) {
    const int rc = mlockall(MCL_CURRENT | MCL_FUTURE);
    const int err = errno;
    g.memory_locked = rc == 0;
    note(std::string("memory lock: ") +
         (rc == 0 ? std::string("set")
                  : "refused (" + std::string(std::strerror(err)) +
                        (err == ENOMEM || err == EPERM ? "; needs CAP_IPC_LOCK or ulimit -l" : "") +
                        ")"));
  }
  if (request.timer_slack_ns >= 0) {
    const int previous = prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0);
    // 0 means "the thread's default" to PR_SET_TIMERSLACK; 1 ns is the least that sticks.
    const long slack = std::max(1L, request.timer_slack_ns);
    const int rc = prctl(PR_SET_TIMERSLACK, static_cast<unsigned long>(slack), 0, 0, 0);
    const int err = errno;
    if (rc == 0 && previous >= 0) g.previous_timer_slack_ns = previous;
    note("timer slack " + std::to_string(slack) + " ns: " +
         (rc == 0 ? "set (was " + std::to_string(previous) + " ns)"
                  : "refused (" + std::string(std::strerror(err)) + ")"));
  }
  if (g.message.empty()) g.message = "normal scheduling (nothing requested)";
  return g;
}

void RestoreNormalScheduling(const RealtimeGrant& grant) {
  if (grant.priority_set) {
    sched_param p{};
    p.sched_priority = 0;
    pthread_setschedparam(pthread_self(), SCHED_OTHER, &p);
  }
  if (grant.cpu_set) {
    cpu_set_t set;
    CPU_ZERO(&set);
    const long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    for (long c = 0; c < cpus && c < CPU_SETSIZE; ++c) CPU_SET(static_cast<int>(c), &set);
    pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
  }
  if (grant.memory_locked) munlockall();
  if (grant.previous_timer_slack_ns >= 0) {
    prctl(PR_SET_TIMERSLACK, static_cast<unsigned long>(grant.previous_timer_slack_ns), 0, 0, 0);
  }
}

}  // namespace kinevis::hal
