// What moves the active surface besides its own tension and area/volume terms (docs/ALGORITHMS.md §4, "Motion
// strategy"): the target it tracks (coat, morph) and the velocity that advects it (advect), either a general u(x, t)
// or a separable time_scale(t) spatial(x). Internal to core/active.
#pragma once

#include <utility>

#include "core/active/active_surface.h"

namespace surfacer::active_detail {

class Motion {
 public:
  void set_target(FieldPtr target) { target_ = std::move(target); }
  // The target when tracking acts (a target is set and alpha > 0), else nullptr.
  const Field* tracked(double alpha) const { return target_ && alpha > 0.0 ? target_.get() : nullptr; }

  // Each velocity replaces the other.
  void set_velocity(VelocityFn velocity) {
    separable_ = {};
    velocity_ = std::move(velocity);
  }
  void set_velocity(SeparableVelocity velocity) {
    velocity_ = {};
    separable_ = std::move(velocity);
  }
  bool advecting() const { return static_cast<bool>(velocity_) || static_cast<bool>(separable_.spatial); }
  bool separable() const { return static_cast<bool>(separable_.spatial); }
  // The general velocity u(p, t); only when advecting() and not separable().
  Vec3 velocity(const Vec3& p, double t) const { return velocity_(p, t); }
  // The separable velocity's spatial part at p (the engine caches it per node) and its time factor at t (1 when
  // steady); only when separable().
  Vec3 spatial(const Vec3& p) const { return separable_.spatial(p); }
  double time_scale(double t) const { return separable_.time_scale ? separable_.time_scale(t) : 1.0; }

 private:
  FieldPtr target_;
  VelocityFn velocity_;
  SeparableVelocity separable_;
};

}  // namespace surfacer::active_detail
