// The motion of the active surface (core/active/active_surface.h; docs/ALGORITHMS.md §4, "Motion strategy" and
// "Advection"): what moves the potential (the tracking target, the advecting velocity and its per-node cache, the
// motion strategy's coefficients with the area and volume control), the speed extension, and the rate df/dt of a block
// with the largest stable step it allows. Internal to core/active; works on a NarrowBand's channels.
#pragma once

#include "core/active/active_surface.h"
#include "core/active/measure_control.h"
#include "core/active/narrow_band.h"

namespace surfacer::active_detail {

class Motion {
 public:
  // The motion strategy's coefficients, the curvature clamp and the CFL number of `options` (validated by the caller).
  explicit Motion(const ActiveSurfaceOptions& options);

  // The tracking target g (normalized, negative inside), or nullptr.
  void set_target(FieldPtr target) { target_ = std::move(target); }
  // A general velocity (empty: back to the normal-speed mode).
  void set_velocity(VelocityFn velocity);
  // A separable velocity (its spatial part given); spatial(x) is cached per node in 3 channels of `band`, added on
  // first use and cleared here.
  void set_velocity(SeparableVelocity velocity, NarrowBand& band);

  bool advecting() const { return static_cast<bool>(velocity_) || static_cast<bool>(separable_.spatial); }
  // Advecting with a normal speed on top (alpha with a target, beta, gamma or delta > 0): the extended normal speed
  // of those terms is then in kChanSpeed, as in the normal-speed modes, and the stage-1 rate in a channel of its own.
  bool advect_controls() const {
    return advecting() && ((target_ && alpha_ > 0.0) || beta_ > 0.0 || gamma_ > 0.0 || delta_ > 0.0);
  }
  // The channel of the stage-1 rate when advecting (a rejected step restarts from it); adds it to `band` on first
  // use.
  int prepare_rate_channel(NarrowBand& band);

  // A0, V0 and the last measures (area and volume control).
  const MeasureControl& measures() const { return measures_; }
  MeasureControl& measures() { return measures_; }

  // The normal speed over the active nodes into kChanSpeed (normal-speed modes and advect_controls()): sampled where
  // the surface crosses grid edges (tracking and tension at the crossings, plus the area and volume terms, with the
  // sub-step's measures), then extended outward layer by layer; nodes out of reach take the speed at the node.
  // Uses kChanA as scratch. Throws Cancelled.
  void extend_speed(NarrowBand& band, const RunControl& control);
  // The rate df/dt of block `block` from channel `in_channel` at time `stage_time` into rate[kBlockNodes] (kept at the
  // active nodes), and the block's largest speed (|u| + |s| when both act) into *max_speed when given. Fills the
  // velocity cache of the block's active nodes. `reverse` (advecting only): the rate of the motion run backward in
  // time (velocity and normal speed negated), for the backward pass of error compensation. Called concurrently for
  // distinct blocks.
  void stage_rate(NarrowBand& band, int block, int in_channel, double stage_time, float* rate, double* max_speed,
                  bool reverse = false) const;
  // The largest stable sub-step for speed vmax on grid spacing h: the CFL bound, and in normal-speed modes (or with
  // advect_controls()) the tension's and the controllers' bounds (ALGORITHMS §4, "Time step"); infinity when nothing
  // bounds it.
  double stable_dt(double vmax, double h) const;
  // Volume control alone on top of an advection (its speed uniform, set by extend_speed): when the controller's speed
  // would move more than the volume deficit in a sub-step of dt, sets the speed that moves exactly the deficit and
  // returns true (the stage-1 rate must then be computed again); else false. stable_dt then leaves out the volume
  // bound (ALGORITHMS §4, "Controller bounds").
  bool limit_control(double dt, NarrowBand& band);
  // cfl, or 1 when the options fix the sub-step count.
  double cfl() const { return cfl_; }

 private:
  // `speed` at the active nodes of kChanSpeed, NaN elsewhere.
  static void fill_speed(NarrowBand& band, float speed);

  double alpha_, beta_, gamma_, delta_;
  double max_curvature_;  // units of 1/h
  double cfl_;

  FieldPtr target_;
  VelocityFn velocity_;          // general advection velocity, called per active node per stage
  SeparableVelocity separable_;  // or u = time_scale(t) spatial(x), spatial cached per node
  int velocity_cache_ = -1;      // first of the 3 channels caching spatial(x) (NaN: not evaluated), or -1
  int advect_rate_ = -1;         // the stage-1 rate's channel under advect_controls(), or -1 before its first use
  MeasureControl measures_;
  bool uniform_control_ = false;                // the last extend_speed set the uniform volume speed while advecting
  std::vector<std::vector<float>> edge_speed_;  // per block (band blocks): speed per (node, axis), NaN: none
};

}  // namespace surfacer::active_detail
