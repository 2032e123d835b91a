// The engine behind ActiveSurface (core/active/active_surface.h), held privately by it, composed of three parts with
// state of their own:
// * NarrowBand (narrow_band.h): the block grid and its frame, the band and active nodes, block allocation and release,
//   reinitialization, the measures and meshes of the surface;
// * Motion (motion.h): target, velocity and its cache, the motion strategy's coefficients with area and volume control,
//   speed extension and stage rates;
// * Stepper (stepper.h): time, sub-steps and their Runge-Kutta stages, the reinitialization counter, the last
//   sub-step's figures.
// Checkpoints (state.cpp) save and restore them through their interfaces.
#pragma once

#include "core/active/active_surface.h"
#include "core/active/motion.h"
#include "core/active/narrow_band.h"
#include "core/active/stepper.h"

namespace surfacer::active_detail {

struct Engine {
  // The parts for `options`, validated first (throws InvalidInput naming the option, as validate()).
  explicit Engine(const ActiveSurfaceOptions& options);

  // The statistics of the current state that need no measuring: time, active nodes, blocks, the last sub-step's
  // maxima, memory.
  ActiveFrameStats make_stats() const;

  const ActiveSurfaceOptions options;
  NarrowBand band;
  Motion motion;
  Stepper stepper;
};

}  // namespace surfacer::active_detail
