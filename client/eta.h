// Time left in a job, from its fraction done: the average rate since the first report, extrapolated. Pure logic.
#pragma once

#include <algorithm>
#include <chrono>
#include <optional>

namespace surfacer::client {

class EtaEstimator {
 public:
  using Clock = std::chrono::steady_clock;

  // Seconds left after reporting `fraction` (0..1) at `now`; nullopt until at least 1 % more of the job and half a
  // second have passed since the first report (too little to extrapolate), 0 once the fraction reaches 1. A
  // fraction below the largest seen (parallel frames report their own stages) counts as the largest.
  std::optional<double> update(double fraction, Clock::time_point now) {
    best_ = std::max(best_, fraction);
    fraction = best_;
    if (fraction >= 1.0) return 0.0;
    if (!start_) {
      start_ = now;
      start_fraction_ = fraction;
      return std::nullopt;
    }
    const double done = fraction - start_fraction_;
    const double elapsed = std::chrono::duration<double>(now - *start_).count();
    if (done < 0.01 || elapsed < 0.5) return std::nullopt;
    return elapsed / done * (1.0 - fraction);
  }

 private:
  std::optional<Clock::time_point> start_;
  double start_fraction_ = 0;
  double best_ = 0;
};

}  // namespace surfacer::client
