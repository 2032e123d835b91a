// The time stepping of the active surface (core/active/active_surface.h; docs/ALGORITHMS.md §4, "Time step"): the
// simulated time, the sub-step's size, the TVD-RK3 stages (Shu & Osher 1988), the reinitialization counter and the
// last sub-step's figures. Internal to core/active; steps a NarrowBand with a Motion.
#pragma once

#include <cstdint>

#include "core/active/active_surface.h"
#include "core/active/motion.h"
#include "core/active/narrow_band.h"

namespace surfacer::active_detail {

class Stepper {
 public:
  // The reinitialization interval of `options` (validated by the caller).
  explicit Stepper(const ActiveSurfaceOptions& options)
      : reinit_interval_(options.reinitialization_interval()), compensate_(options.error_compensation) {}

  // What a checkpoint holds of the stepper (core/active/state.cpp).
  struct Record {
    double time = 0.0;
    double last_dt = 0.0;  // >= 0
    double last_max_dfdt = 0.0;
    double last_max_speed = 0.0;
    int steps_since_reinit = 0;  // >= 0
    std::int64_t last_node_steps = 0;
  };
  Record record() const;
  // Continues from a checkpoint: until the next sub-step, a new velocity keeps last_dt (the saved run's velocity is
  // assumed), so the next step is bounded as in the uninterrupted run.
  void restore(const Record& record);

  // What one sub-step did.
  struct SubStep {
    double dt = 0.0;
    std::int64_t node_steps = 0;  // active nodes updated
    bool reinitialized = false;
  };
  // One sub-step of at most dt_limit (infinity: the CFL step): the extended speed (normal-speed modes and
  // Motion::advect_controls()), the three stages, the topology, and a reinitialization every reinit_interval
  // sub-steps. Throws ResourceLimit("max_blocks"), Cancelled.
  SubStep step(double dt_limit, NarrowBand& band, Motion& motion, const RunControl& control);

  double time() const { return time_; }
  // Sets the time to a frame's end reached within rounding by the sub-steps.
  void land(double frame_end) { time_ = frame_end; }
  // The velocity changed: the next advecting step is not bounded by the last one (unless restored and not stepped).
  void velocity_changed() {
    if (!restored_) last_dt_ = 0.0;
  }
  // Max |df/dt| and max speed over the active nodes at the last sub-step.
  double last_max_dfdt() const { return last_max_dfdt_; }
  double last_max_speed() const { return last_max_speed_; }

 private:
  // TVD-RK3 over [t_start, t_start + dt] (reverse: back to t_start - dt, velocity and normal speed negated), from f
  // and the stage-1 rates in rate_channel, into kChanA; may_retry: an advecting step whose stage-2 speed breaks the CFL
  // bound is retried shorter. Returns the dt taken.
  double runge_kutta(double dt, int rate_channel, double t_start, bool reverse, bool may_retry, NarrowBand& band,
                     const Motion& motion, const RunControl& control);
  // Stage 1: the rates L(f) of kChanF at time t (reverse: backward in time) into rate_channel at the active nodes (f
  // elsewhere); per block, the largest speed into max_speed and the largest |L| into max_rate when they are given
  // (one element per block).
  void stage_one_rates(double t, bool reverse, int rate_channel, NarrowBand& band, const Motion& motion,
                       const RunControl& control, double* max_speed = nullptr, double* max_rate = nullptr) const;
  // Back-and-forth error compensation of an advecting sub-step of dt whose forward result is in kChanA (ALGORITHMS
  // §4, "Error compensation"): the compensated result into kChanA, kChanF then scratch.
  void compensate(double dt, int rate_channel, NarrowBand& band, const Motion& motion, const RunControl& control);

  int reinit_interval_;
  bool compensate_;        // options.error_compensation
  int keep_channel_ = -1;  // f at the sub-step's start during compensate(), or -1 before its first use
  double time_ = 0.0;
  int steps_since_reinit_ = 0;
  double last_dt_ = 0.0;
  std::int64_t last_node_steps_ = 0;
  double last_max_dfdt_ = 0.0;
  double last_max_speed_ = 0.0;
  bool restored_ = false;  // restored from a checkpoint and not stepped since
};

}  // namespace surfacer::active_detail
