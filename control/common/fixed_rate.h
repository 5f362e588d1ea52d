#pragma once

// Fixed-rate pacing shared by the control loops (issue 8: the DIAMOND's 1 kHz loop), and a check
// of how steadily this host can pace an empty loop (`kinevis check timing`), so that the jitter a
// control loop reports can be compared with what the machine itself allows.
//
// DeadlineGrid: deadlines on a fixed grid start + k·period. Next() sleeps to the next deadline on
// the loop's common::Clock and returns the wake-up: the period since the previous wake-up and the
// lateness past the deadline. A wake-up more than one period late re-synchronises the grid to the
// wake-up time instead of bursting through the missed deadlines; those are counted.
//
// PeriodStatistics: order statistics of the periods, the lateness, and (for a control loop) the
// time spent in I/O and in compute per cycle.

#include <cstdint>
#include <string>
#include <vector>

#include "common/clock.h"

namespace kinevis::control {

// Period statistics of a run (s). p99 etc. are order statistics of the periods.
struct PeriodStatistics {
  double target_s = 0.0;
  uint64_t periods = 0;  // number of periods measured (cycles − 1)
  double mean_s = 0.0, std_s = 0.0, min_s = 0.0, p50_s = 0.0, p99_s = 0.0, max_s = 0.0;
  // Lateness of the wake-ups past their deadlines: max, and how many were later than 10 % of
  // the period; deadlines missed entirely (woke more than one period late: grid re-synchronised).
  double max_lateness_s = 0.0, p50_lateness_s = 0.0, p99_lateness_s = 0.0;
  uint64_t late_cycles = 0;
  uint64_t missed_deadlines = 0;
  // Time spent in the bus Cycle() (I/O) and in the law + safety (compute) per cycle.
  double io_mean_s = 0.0, io_p99_s = 0.0, io_max_s = 0.0;
  double compute_mean_s = 0.0, compute_p99_s = 0.0, compute_max_s = 0.0;
  // Achieved rate 1 / mean period (Hz).
  double rate_hz() const { return mean_s > 0 ? 1.0 / mean_s : 0.0; }
  std::string Describe() const;  // one line, in µs
};

// Period statistics from per-cycle samples (exposed for tests and the bench).
PeriodStatistics ComputePeriodStatistics(double target_s, std::vector<double> periods,
                                         std::vector<double> lateness, std::vector<double> io,
                                         std::vector<double> compute, uint64_t missed_deadlines);

class DeadlineGrid {
 public:
  struct Wake {
    common::Duration time{0};  // the clock's time at the wake-up
    double period_s = 0.0;     // since the previous wake-up; 0 for the first
    double lateness_s = 0.0;
    bool first = true;
  };

  // period > 0; the clock must outlive the grid. The grid starts at `start` (the first deadline
  // is start + period).
  DeadlineGrid(common::Clock* clock, common::Duration period, common::Duration start);

  Wake Next();
  uint64_t missed_deadlines() const { return missed_; }

 private:
  common::Clock* clock_;
  common::Duration period_;
  common::Duration next_;
  common::Duration previous_wake_{0};
  bool woke_before_ = false;
  uint64_t missed_ = 0;
};

// The per-cycle timing samples of a run, reserved before it: recording never allocates in the
// cycle (samples beyond the capacity are not kept). Statistics() turns them into
// PeriodStatistics.
class CycleTimingRecorder {
 public:
  explicit CycleTimingRecorder(size_t capacity);
  void Wake(const DeadlineGrid::Wake& wake);  // the period (not for the first) and the lateness
  void Io(double seconds);                    // time in the bus Cycle()
  void Compute(double seconds);               // time in the law and the safety layer
  PeriodStatistics Statistics(double target_s, uint64_t missed_deadlines);  // empties the samples

 private:
  size_t capacity_;
  std::vector<double> periods_, lateness_, io_, compute_;
};

// How steadily this host paces an empty loop at `period_s` for `duration_s` on `clock` (the same
// DeadlineGrid the control loops use; nothing else runs in the cycle, so io and compute stay 0).
// Throws std::invalid_argument unless 0 < period_s <= 1 and period_s <= duration_s <= 3600.
PeriodStatistics MeasureLoopTiming(common::Clock* clock, double period_s, double duration_s);

// Whether a run held its rate: no missed deadline and a p99 period within 10 % of the target.
// Empty when it did, else what failed, with the figures.
std::string SteadyRateProblem(const PeriodStatistics& s);

}  // namespace kinevis::control
