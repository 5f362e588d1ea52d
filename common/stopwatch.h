#pragma once

// Wall time of a job's step, for the `wall_seconds` of its report: the steady clock of this
// process, never a simulated world's clock (a stepped world's time says nothing about how long
// the user waited).

#include <chrono>

namespace kinevis::common {

class Stopwatch {
 public:
  Stopwatch() : start_(std::chrono::steady_clock::now()) {}
  // Seconds since construction.
  double Seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::chrono::steady_clock::time_point start_;
};

}  // namespace kinevis::common
