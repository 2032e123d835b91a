// Area and volume control of the active surface (docs/ALGORITHMS.md §4, "Motion strategy" and "Time step";
// Desbrun & Cani-Gascuel 1998, §5.1-5.2): the reference measures A0, V0 and the surface's latest measures, and what
// the controls derive from them. Internal to core/active.
#pragma once

#include <algorithm>
#include <cstdint>
#include <limits>

namespace surfacer {

struct ActiveMeasures {
  double area = 0.0;
  double volume = 0.0;
  std::int64_t crossings = 0;  // crossed grid edges (surface sample points)
  // Filled when sampling speeds: max |grad g| of the target at the sample points, and the mean |kappa| there.
  double max_target_gradient = 0.0;
  double mean_abs_curvature = 0.0;
};

namespace active_detail {

class MeasureControl {
 public:
  // A0 and V0, the measures the controls hold (the initial surface's unless the caller sets others); 0: no control.
  void set_reference(double area, double volume) {
    area0_ = area;
    volume0_ = volume;
  }
  double reference_area() const { return area0_; }
  double reference_volume() const { return volume0_; }

  // The surface's latest measures (those of the sub-step being taken, once extend_speed has measured it).
  void set_last(const ActiveMeasures& measures) { last_ = measures; }
  const ActiveMeasures& last() const { return last_; }

  // The uniform normal speed of the controls, gamma (A0 - A) / A0 + delta (V0 - V) / V0 with the last measures; a
  // term is 0 when its coefficient or its reference is 0.
  double speed(double gamma, double delta) const {
    double s = 0.0;
    if (gamma > 0.0 && area0_ > 0.0) s += gamma * (area0_ - last_.area) / area0_;
    if (delta > 0.0 && volume0_ > 0.0) s += delta * (volume0_ - last_.volume) / volume0_;
    return s;
  }
  // The controls' bound on an explicit step: the smaller of V0 / (delta A) (no cfl: with its speed frozen over the
  // sub-step, volume control is forward Euler on V, monotone up to there) and cfl A0 / (gamma kbar A)
  // (kbar the mean |kappa| at the sample points); infinity when neither acts.
  double stable_dt(double gamma, double delta, double cfl) const {
    double dt = std::numeric_limits<double>::infinity();
    if (delta > 0.0 && volume0_ > 0.0 && last_.area > 0.0) dt = std::min(dt, volume0_ / (delta * last_.area));
    if (gamma > 0.0 && area0_ > 0.0 && last_.area > 0.0 && last_.mean_abs_curvature > 0.0) {
      dt = std::min(dt, cfl * area0_ / (gamma * last_.mean_abs_curvature * last_.area));
    }
    return dt;
  }

 private:
  double area0_ = 0.0, volume0_ = 0.0;
  ActiveMeasures last_;
};

}  // namespace active_detail
}  // namespace surfacer
