#include "hal/common/realtime.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>
#include <sys/prctl.h>

#include <stdexcept>
#include <thread>

namespace kinevis::hal {
namespace {

using ::testing::HasSubstr;

int Policy() {
  int policy = 0;
  sched_param p{};
  pthread_getschedparam(pthread_self(), &policy, &p);
  return policy;
}

// Whatever the machine allows: the grant says what the kernel did, and the thread's policy agrees
// with it; restoring brings SCHED_OTHER back. Runs in its own thread so the test runner's main
// thread is never touched.
TEST(Realtime, GrantMatchesWhatTheKernelDid) {
  std::thread t([] {
    RealtimeRequest r;
    r.priority = 10;
    r.cpu = 0;
    const RealtimeGrant g = ApplyRealtime(r);
    EXPECT_THAT(g.message, HasSubstr("SCHED_FIFO 10: "));
    EXPECT_THAT(g.message, HasSubstr("cpu 0: "));
    EXPECT_EQ(Policy() == SCHED_FIFO, g.priority_set) << g.message;
    if (!g.priority_set) {
      EXPECT_THAT(g.message, HasSubstr("refused"));
    }
    if (g.cpu_set) {
      cpu_set_t set;
      CPU_ZERO(&set);
      ASSERT_EQ(pthread_getaffinity_np(pthread_self(), sizeof(set), &set), 0);
      EXPECT_EQ(CPU_COUNT(&set), 1);
      EXPECT_TRUE(CPU_ISSET(0, &set));
    }
    RestoreNormalScheduling(g);
    EXPECT_EQ(Policy(), SCHED_OTHER);
  });
  t.join();
}

TEST(Realtime, NothingRequestedChangesNothing) {
  std::thread t([] {
    const RealtimeGrant g = ApplyRealtime(RealtimeRequest());
    EXPECT_FALSE(g.priority_set || g.cpu_set || g.memory_locked);
    EXPECT_THAT(g.message, HasSubstr("nothing requested"));
    EXPECT_EQ(Policy(), SCHED_OTHER);
  });
  t.join();
}

// Timer slack needs no privilege: set, read back, and restored to what it was.
TEST(Realtime, TimerSlackIsSetAndRestored) {
  std::thread t([] {
    const int before = prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0);
    RealtimeRequest r;
    r.timer_slack_ns = 1;
    const RealtimeGrant g = ApplyRealtime(r);
    EXPECT_THAT(g.message, HasSubstr("timer slack 1 ns: set"));
    EXPECT_EQ(prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0), 1);
    EXPECT_EQ(g.previous_timer_slack_ns, before);
    RestoreNormalScheduling(g);
    EXPECT_EQ(prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0), before);
  });
  t.join();
}

TEST(Realtime, BadRequestsAreNamed) {
  RealtimeRequest r;
  r.priority = 120;
  r.cpu = 100000;
  EXPECT_THAT([&] { ApplyRealtime(r); },
              ::testing::ThrowsMessage<std::invalid_argument>(
                  ::testing::AllOf(HasSubstr("priority = 120"), HasSubstr("cpu = 100000"))));
  r = RealtimeRequest();
  r.priority = -1;
  EXPECT_THROW(ApplyRealtime(r), std::invalid_argument);
  r = RealtimeRequest();
  r.timer_slack_ns = -5;
  EXPECT_THAT([&] { ApplyRealtime(r); },
              ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr("timer_slack_ns = -5")));
}

}  // namespace
}  // namespace kinevis::hal
