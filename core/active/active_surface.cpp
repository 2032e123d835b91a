// Active implicit surface engine (core/active/active_surface.h; docs/ALGORITHMS.md §4). Choices beyond the paper:
//
// * Clamped distance profile. The paper thresholds an arbitrary potential at +-1. Here f is kept close to
//   clamp(-d / (w h), -1, 1) (w = band_width): a linear ramp w nodes wide on each side of the surface, so the
//   one-sided WENO stencils of the nodes next to the surface see a smooth function and |grad f| = 1 / (w h) is
//   known. The ramp is restored by reinitialization (below); in normal-speed modes the speed extension moves the
//   whole band with the surface, so the profile barely drifts.
// * Band and activity (paper §4.5). A node is in the band when |f| < 1 or when a 6-neighbour has the other sign (a
//   steep interface without an unsaturated node must still move). Active nodes = band plus its 6-neighbours, the
//   "woken" nodes, which may enter (-1, 1) as the surface approaches; a node whose value is clamped back to +-1 with
//   no band neighbour drops out. Blocks of 8^3 nodes exist around every band block (its 26 neighbours), so the
//   3-node WENO aprons of active nodes always read stored values; the surface moves less than one node per
//   sub-step (CFL), so the allocation, redone after every sub-step, keeps up. A new block takes the sign of its
//   parent band block's node nearest to it: blocks are missing only where f is saturated, so their sign is uniform.
// * Speed extension (paper §4.3) goes beyond the voxels next to the surface: nodes with no crossed incident edge take
//   the mean speed of already-assigned 6-neighbours, one layer per pass, so the whole band moves
//   with the surface speed (Adalsteinsson & Sethian 1999 in spirit) and df/dt vanishes when the surface is at rest.
//   Evaluating the target at far band nodes instead would fight the clamp and keep max |df/dt| from ever falling.
// * Tension is part of the extended speed: kappa is evaluated at the two nodes of each crossed edge and interpolated
//   to the sample point, so only nodes next to the surface (whose stencils are clear of the clamp) matter.
// * Space and time: HJ-WENO5 with WENO-Z weights, TVD-RK3 in every mode (the speed is frozen over a sub-step in
//   normal-speed modes: one polygonization and one target evaluation per crossing per sub-step). The stage kernels
//   run densely over the 512 nodes of each block with an active node (vectorized), keeping only active results.
// * Time-dependent velocities: the step is chosen from |u| at the step's start, at most twice the previous step, and
//   rejected (recomputed with a smaller dt) when |u| at the second stage breaks the CFL limit of 1.
// * Error compensation (error_compensation, advecting only; not in the paper): every sub-step taken back and forth
//   (BFECC, Dupont & Liu 2003), the forward pass repeated from f0 + (f0 - f2) / 2, f2 the backward pass's result; the
//   ramp is then reinitialized every 64 sub-steps (ActiveSurfaceOptions::kCompensatedReinitInterval).
// * Control terms on top of advection (not in the paper, nor in OpenVDB's LevelSetAdvection): with beta, gamma or
//   delta (or alpha and a target) the extended normal speed s is added, df/dt = -u . grad f + s |grad f|, each term
//   upwinded on its own (one WENO pass for both), s frozen over the sub-step, the CFL speed |u| + |s|, and the
//   controllers' step bounds as in the normal-speed modes, except volume control alone: its speed is uniform (measured,
//   not sampled or extended) and limited to move at most the volume deficit in the sub-step instead of bounding it.
//   Volume control then holds the volume the advection scheme loses (Enright test) at about the plain run's cost.
// * Reinitialization every reinit_interval sub-steps: d_tau = -S(d0) (|grad d| - 1) in grid units, Godunov with
//   second-order ENO differences, pseudo-time step 1/2, ceil(2 (w - 1)) + 2 iterations over all allocated blocks. The
//   surface must not move, and every rescaling of the nodes at a crossed edge moves the linearly interpolated
//   crossing (the two ends see slightly different gradients); repeated reinitializations let that creep pile up
//   (measured: a static sphere grew by several % over tens of reinitializations with Russo & Smereka's fix, and
//   the thin sheets of the Enright test gained or lost tens of %). So the interface nodes (a 6-neighbour of the other
//   sign) and their 6-neighbours keep their values while the interface gradient is within kInterfaceSlack of the
//   ramp's; only where it is not are the interface nodes rescaled, d <- d0 / |grad d0| (Russo & Smereka 2000 with
//   per-axis differences chosen to avoid kinks: central where both sides agree, else across the crossing, else the
//   larger one-sided difference), relaxed toward with d <- d - dtau (S |d| - D).
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "core/active/engine.h"
#include "core/polygonize/edge_margin.h"
#include "core/util/errors.h"
#include "core/util/format.h"

namespace surfacer {
namespace {

constexpr double kMinBandWidth = 2.0, kMaxBandWidth = 8.0;  // ActiveSurfaceOptions::band_width, grid spacings
constexpr double kInf = std::numeric_limits<double>::infinity();

const ActiveSurfaceOptions& validated(const ActiveSurfaceOptions& options) {
  validate(options);
  return options;
}

}  // namespace

void validate(const ActiveSurfaceOptions& o) {
  const ActiveSurfaceOptions defaults;
  if (!(o.h > 0.0) || !std::isfinite(o.h))
    throw InvalidInput("h", "h (" + format_number(o.h) + ") must be a finite spacing > 0");
  if (o.domain) {
    const Aabb& d = *o.domain;
    if (!d.min.allFinite() || !d.max.allFinite() || !d.valid()) {
      throw InvalidInput("domain", "domain must be a finite box with min < max on every axis");
    }
    for (int a = 0; a < 3; ++a) {
      if ((d.max[a] - d.min[a]) / o.h > double(sparse::kCoordLimit) * sparse::kBlockSize) {
        throw ResourceLimit("domain", "domain spans more than 2^23 nodes per axis; coarsen h or shrink the domain");
      }
    }
  }
  if (!(o.band_width >= kMinBandWidth) || !(o.band_width <= kMaxBandWidth)) {
    throw InvalidInput("band_width", "band_width (" + format_number(o.band_width) + ") must be in [" +
                                         format_number(kMinBandWidth) + ", " + format_number(kMaxBandWidth) +
                                         "] grid spacings; the default is " + format_number(defaults.band_width));
  }
  const std::pair<const char*, double> coeffs[] = {
      {"alpha", o.alpha}, {"beta", o.beta}, {"gamma", o.gamma}, {"delta", o.delta}};
  for (const auto& [name, v] : coeffs) {
    if (!(v >= 0.0) || !std::isfinite(v)) {
      throw InvalidInput(name, std::string(name) + " (" + format_number(v) + ") must be finite and >= 0");
    }
  }
  if (o.cfl && !(*o.cfl > 0.0 && *o.cfl <= 1.0)) {
    throw InvalidInput(
        "cfl", "cfl (" + format_number(*o.cfl) + ") must be in (0, 1]; the default is " + format_number(*defaults.cfl));
  }
  if (o.substeps_per_frame < 1) throw InvalidInput("substeps_per_frame", "substeps_per_frame must be >= 1");
  if (o.max_substeps_per_frame < 1) throw InvalidInput("max_substeps_per_frame", "max_substeps_per_frame must be >= 1");
  if (o.reinit_interval && *o.reinit_interval < 1) {
    throw InvalidInput("reinit_interval", "reinit_interval must be >= 1; the default is " +
                                              std::to_string(ActiveSurfaceOptions::kReinitInterval) + " (" +
                                              std::to_string(ActiveSurfaceOptions::kCompensatedReinitInterval) +
                                              " with error_compensation)");
  }
  if (!(o.max_curvature > 0.0) || !std::isfinite(o.max_curvature)) {
    throw InvalidInput("max_curvature", "max_curvature must be > 0 (in units of 1/h); the default is " +
                                            format_number(defaults.max_curvature));
  }
  if (o.threads < 0) throw InvalidInput("threads", "threads must be >= 0 (0: all hardware threads)");
  if (o.max_blocks < 1) throw InvalidInput("max_blocks", "max_blocks must be >= 1");
  check_vertex_margin(o.vertex_margin);
  if (o.polygonizer != Polygonizer::kCubes && o.polygonizer != Polygonizer::kTiles) {
    throw InvalidInput("polygonizer", "polygonizer must be tiles or cubes");
  }
}

void check_grid_reach(const std::optional<Aabb>& initial_bounds, const Aabb& region,
                      const ActiveSurfaceOptions& options) {
  const active_detail::NarrowBand band(validated(options));
  std::int64_t lo[3], hi[3], dims[3];
  band.covering_blocks(region, lo, hi);
  band.initial_blocks(initial_bounds, lo, dims);
}

// ------------------------------------------------------------------------------------------------------------------
// The engine's parts.

active_detail::Engine::Engine(const ActiveSurfaceOptions& options_in)
    : options(validated(options_in)), band(options), motion(options), stepper(options) {}

ActiveFrameStats active_detail::Engine::make_stats() const {
  ActiveFrameStats s;
  s.time = stepper.time();
  s.active_nodes = band.active_count();
  s.allocated_blocks = band.block_count();
  s.max_dfdt = stepper.last_max_dfdt();
  s.max_speed = stepper.last_max_speed();
  s.memory_bytes = band.memory_bytes();
  return s;
}

// ------------------------------------------------------------------------------------------------------------------
// Public class.

ActiveSurface::ActiveSurface(const Field& initial_shape, const ActiveSurfaceOptions& options, const RunControl& control)
    : impl_(std::make_unique<active_detail::Engine>(options)) {
  active_detail::Engine& m = *impl_;
  m.band.init(initial_shape, control);
  const ActiveMeasures initial = m.band.measure(control);
  m.motion.measures().set_last(initial);
  m.motion.measures().set_reference(initial.area, initial.volume);
}

ActiveSurface::~ActiveSurface() = default;
ActiveSurface::ActiveSurface(ActiveSurface&&) noexcept = default;
ActiveSurface& ActiveSurface::operator=(ActiveSurface&&) noexcept = default;

void ActiveSurface::set_target(FieldPtr target) { impl_->motion.set_target(std::move(target)); }

void ActiveSurface::set_velocity(VelocityFn velocity) {
  impl_->motion.set_velocity(std::move(velocity));
  impl_->stepper.velocity_changed();
}

void ActiveSurface::set_velocity(SeparableVelocity velocity) {
  if (!velocity.spatial) throw InvalidInput("velocity", "a separable velocity needs its spatial part u(x)");
  impl_->motion.set_velocity(std::move(velocity), impl_->band);
  impl_->stepper.velocity_changed();
}

void ActiveSurface::set_reference_measures(double area, double volume) {
  if (!(area > 0.0) || !std::isfinite(area)) throw InvalidInput("area", "reference area must be finite and > 0");
  if (!(volume > 0.0) || !std::isfinite(volume)) {
    throw InvalidInput("volume", "reference volume must be finite and > 0");
  }
  impl_->motion.measures().set_reference(area, volume);
}

double ActiveSurface::time() const { return impl_->stepper.time(); }
const ActiveSurfaceOptions& ActiveSurface::options() const { return impl_->options; }

ActiveFrameStats ActiveSurface::advance(double duration, const RunControl& control) {
  active_detail::Engine& m = *impl_;
  if (!(duration > 0.0) || !std::isfinite(duration)) {
    throw InvalidInput("duration", "duration (" + format_number(duration) + ") must be finite and > 0");
  }
  const double t_end = m.stepper.time() + duration;
  const double eps = 1e-12 * std::max(1.0, std::abs(t_end));
  const double fixed = m.options.cfl ? kInf : duration / m.options.substeps_per_frame;
  int substeps = 0, reinits = 0;
  std::int64_t node_steps = 0;
  double min_dt = kInf;
  while (t_end - m.stepper.time() > eps) {
    if (substeps >= m.options.max_substeps_per_frame) {
      throw ResourceLimit("max_substeps_per_frame",
                          "the frame needs more than max_substeps_per_frame (" +
                              std::to_string(m.options.max_substeps_per_frame) +
                              ") sub-steps at the CFL limit; raise the limit, shorten the frame or lower the speeds");
    }
    const double remaining = t_end - m.stepper.time();
    const active_detail::Stepper::SubStep done = m.stepper.step(std::min(remaining, fixed), m.band, m.motion, control);
    node_steps += done.node_steps;
    if (done.reinitialized) ++reinits;
    ++substeps;
    if (done.dt < remaining - eps || substeps == 1) min_dt = std::min(min_dt, done.dt);
  }
  m.stepper.land(t_end);
  ActiveFrameStats s = m.make_stats();
  s.substeps = substeps;
  s.dt = duration / substeps;
  s.min_dt = min_dt;
  s.active_node_steps = node_steps;
  s.reinitializations = reinits;
  m.band.surface_stats(s, control);
  return s;
}

ActiveFrameStats ActiveSurface::advance_substeps(int substeps, const RunControl& control) {
  active_detail::Engine& m = *impl_;
  if (substeps < 1) throw InvalidInput("substeps", "substeps must be >= 1");
  const double t0 = m.stepper.time();
  int reinits = 0;
  std::int64_t node_steps = 0;
  double min_dt = kInf;
  for (int i = 0; i < substeps; ++i) {
    const active_detail::Stepper::SubStep done = m.stepper.step(kInf, m.band, m.motion, control);
    min_dt = std::min(min_dt, done.dt);
    node_steps += done.node_steps;
    if (done.reinitialized) ++reinits;
  }
  ActiveFrameStats s = m.make_stats();
  s.substeps = substeps;
  s.dt = (m.stepper.time() - t0) / substeps;
  s.min_dt = min_dt;
  s.active_node_steps = node_steps;
  s.reinitializations = reinits;
  m.band.surface_stats(s, control);
  return s;
}

ActiveFrameStats ActiveSurface::stats() const {
  const active_detail::Engine& m = *impl_;
  ActiveFrameStats s = m.make_stats();
  m.band.surface_stats(s, {});
  return s;
}

Mesh ActiveSurface::polygonize(const RunControl& control) const {
  return polygonize(impl_->options.polygonizer, control);
}

Mesh ActiveSurface::polygonize(Polygonizer polygonizer, const RunControl& control) const {
  if (polygonizer == Polygonizer::kTiles) return impl_->band.tiles_mesh(impl_->options.normals, control);
  return impl_->band.cubes_mesh(impl_->options.normals, control);
}

double ActiveSurface::potential(const Vec3& p) const { return impl_->band.trilinear(p, nullptr); }

}  // namespace surfacer
