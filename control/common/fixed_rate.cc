#include "control/common/fixed_rate.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "common/clock.h"

namespace kinevis::control {
namespace {

// Order statistic at fraction f of a sorted vector (nearest rank).
double Quantile(const std::vector<double>& sorted, double f) {
  if (sorted.empty()) return 0.0;
  const size_t k = std::min(
      sorted.size() - 1,
      static_cast<size_t>(std::ceil(f * static_cast<double>(sorted.size()))) - (f > 0 ? 1 : 0));
  return sorted[k];
}

}  // namespace

std::string PeriodStatistics::Describe() const {
  char text[512];
  std::snprintf(
      text, sizeof text,
      "target %.1f us, %llu periods: mean %.1f us (%.1f Hz), std %.1f us, min %.1f, "
      "p50 %.1f, p99 %.1f, max %.1f us; lateness p50 %.1f p99 %.1f max %.1f us, %llu late > "
      "10%%, %llu "
      "missed; I/O mean %.1f p99 %.1f max %.1f us; compute mean %.2f p99 %.2f max "
      "%.2f us",
      target_s * 1e6, static_cast<unsigned long long>(periods), mean_s * 1e6, rate_hz(),
      std_s * 1e6, min_s * 1e6, p50_s * 1e6, p99_s * 1e6, max_s * 1e6, p50_lateness_s * 1e6,
      p99_lateness_s * 1e6, max_lateness_s * 1e6, static_cast<unsigned long long>(late_cycles),
      static_cast<unsigned long long>(missed_deadlines), io_mean_s * 1e6, io_p99_s * 1e6,
      io_max_s * 1e6, compute_mean_s * 1e6, compute_p99_s * 1e6, compute_max_s * 1e6);
  return text;
}

PeriodStatistics ComputePeriodStatistics(double target_s, std::vector<double> periods,
                                         std::vector<double> lateness, std::vector<double> io,
                                         std::vector<double> compute, uint64_t missed_deadlines) {
  PeriodStatistics s;
  s.target_s = target_s;
  s.missed_deadlines = missed_deadlines;
  s.periods = periods.size();
  if (!periods.empty()) {
    double sum = 0.0;
    for (double p : periods) sum += p;
    s.mean_s = sum / periods.size();
    double var = 0.0;
    for (double p : periods) var += (p - s.mean_s) * (p - s.mean_s);
    s.std_s = periods.size() > 1 ? std::sqrt(var / (periods.size() - 1)) : 0.0;
    std::sort(periods.begin(), periods.end());
    s.min_s = periods.front();
    s.max_s = periods.back();
    s.p50_s = Quantile(periods, 0.5);
    s.p99_s = Quantile(periods, 0.99);
  }
  for (double l : lateness) {
    s.max_lateness_s = std::max(s.max_lateness_s, l);
    if (l > 0.1 * target_s) ++s.late_cycles;
  }
  std::sort(lateness.begin(), lateness.end());
  s.p50_lateness_s = Quantile(lateness, 0.5);
  s.p99_lateness_s = Quantile(lateness, 0.99);
  const auto summarize = [](std::vector<double>& v, double* mean, double* p99, double* max) {
    if (v.empty()) return;
    double sum = 0.0;
    for (double x : v) sum += x;
    *mean = sum / v.size();
    std::sort(v.begin(), v.end());
    *p99 = Quantile(v, 0.99);
    *max = v.back();
  };
  summarize(io, &s.io_mean_s, &s.io_p99_s, &s.io_max_s);
  summarize(compute, &s.compute_mean_s, &s.compute_p99_s, &s.compute_max_s);
  return s;
}

DeadlineGrid::DeadlineGrid(common::Clock* clock, common::Duration period, common::Duration start)
    : clock_(clock), period_(period), next_(start) {
  if (clock == nullptr) throw std::invalid_argument("DeadlineGrid: null clock");
  if (period <= common::Duration::zero()) {
    throw std::invalid_argument("DeadlineGrid: period = " + std::to_string(period.count()) +
                                " ns (must be > 0)");
  }
}

DeadlineGrid::Wake DeadlineGrid::Next() {
  next_ += period_;
  clock_->SleepUntil(next_);
  Wake wake;
  wake.time = clock_->Now();
  const common::Duration late = wake.time - next_;
  if (late > period_) {  // woke more than a period late: re-synchronise the grid
    missed_ += static_cast<uint64_t>(late / period_);
    next_ = wake.time;
  }
  wake.lateness_s = std::max(0.0, common::ToSeconds(late));
  wake.first = !woke_before_;
  wake.period_s = woke_before_ ? common::ToSeconds(wake.time - previous_wake_) : 0.0;
  previous_wake_ = wake.time;
  woke_before_ = true;
  return wake;
}

CycleTimingRecorder::CycleTimingRecorder(size_t capacity) : capacity_(capacity) {
  for (std::vector<double>* v : {&periods_, &lateness_, &io_, &compute_}) v->reserve(capacity);
}

void CycleTimingRecorder::Wake(const DeadlineGrid::Wake& wake) {
  if (!wake.first && periods_.size() < capacity_) periods_.push_back(wake.period_s);
  if (lateness_.size() < capacity_) lateness_.push_back(wake.lateness_s);
}

void CycleTimingRecorder::Io(double seconds) {
  if (io_.size() < capacity_) io_.push_back(seconds);
}

void CycleTimingRecorder::Compute(double seconds) {
  if (compute_.size() < capacity_) compute_.push_back(seconds);
}

PeriodStatistics CycleTimingRecorder::Statistics(double target_s, uint64_t missed_deadlines) {
  return ComputePeriodStatistics(target_s, std::move(periods_), std::move(lateness_),
                                 std::move(io_), std::move(compute_), missed_deadlines);
}

PeriodStatistics MeasureLoopTiming(common::Clock* clock, double period_s, double duration_s) {
  if (clock == nullptr) throw std::invalid_argument("MeasureLoopTiming: null clock");
  if (!(period_s > 0.0 && period_s <= 1.0)) {
    throw std::invalid_argument("MeasureLoopTiming: period = " + std::to_string(period_s) +
                                " s (must be in (0, 1])");
  }
  if (!(duration_s >= period_s && duration_s <= 3600.0)) {
    throw std::invalid_argument("MeasureLoopTiming: duration = " + std::to_string(duration_s) +
                                " s (must be in [period, 3600])");
  }
  const auto period =
      std::chrono::duration_cast<common::Duration>(std::chrono::duration<double>(period_s));
  const size_t cycles = static_cast<size_t>(std::ceil(duration_s / period_s));
  CycleTimingRecorder recorder(cycles);
  const common::Duration start = clock->Now();
  const common::Duration end = start + std::chrono::duration_cast<common::Duration>(
                                           std::chrono::duration<double>(duration_s));
  DeadlineGrid grid(clock, period, start);
  for (size_t k = 1;; ++k) {
    const DeadlineGrid::Wake wake = grid.Next();
    recorder.Wake(wake);
    if (wake.time >= end || k >= cycles) break;
  }
  return recorder.Statistics(period_s, grid.missed_deadlines());
}

std::string SteadyRateProblem(const PeriodStatistics& s) {
  std::ostringstream out;
  if (s.periods == 0) return "no period measured";
  if (s.missed_deadlines > 0) {
    out << s.missed_deadlines << " deadline(s) missed (max lateness " << s.max_lateness_s * 1e3
        << " ms)";
  }
  if (s.p99_s > 1.1 * s.target_s) {
    out << (out.tellp() > 0 ? "; " : "") << "p99 period " << s.p99_s * 1e3 << " ms > 1.1 x "
        << s.target_s * 1e3 << " ms";
  }
  return out.str();
}

}  // namespace kinevis::control
