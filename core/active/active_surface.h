// Active implicit surfaces (Desbrun & Cani-Gascuel 1998; docs/ALGORITHMS.md §4): a discrete potential f on a sparse
// narrow band of a grid (inside f > 0, surface f = 0, values clamped to [-1, 1]) evolved so that its zero set moves
// with a chosen normal speed (tracking a target, surface tension, area/volume control) or is carried by a velocity
// field. Modes used by the `active` job: coat (particle sequences), morph (shape A -> shape B), advect (velocity).
//
// Conventions
// * Fields passed in are normalized (core/scene/scene.h): negative inside. The engine's own potential is the paper's:
//   f > 0 inside, n = -grad f / |grad f| points out, and a positive normal speed s moves the surface outward:
//   df/dt = s |grad f|.
// * Normal speed (ALGORITHMS §4, "Motion strategy"), for a target field g (normalized, negative inside):
//     s = alpha * (-g)  -  beta * kappa  +  gamma * (A0 - A) / A0  +  delta * (V0 - V) / V0
//   -g is the paper's (G_target - iso) for potential targets (g = iso - G), so inside the target the skin inflates.
//   kappa = div(n) (> 0 on convex parts) from central differences (the formula of ALGORITHMS §4), so the tension
//   speed -beta * kappa shrinks a sphere of radius r with dr/dt = -2 beta / r (the CHOICE of sign made there).
//   Units: alpha [length / (time * unit of g)], beta [length^2 / time], gamma and delta [length / time].
// * Advection: df/dt = -u . grad f for a velocity u (the material derivative of f vanishes), i.e. the normal speed
//   s = u . n. A uniform u translates the surface by u t whatever the sign convention of f. The motion strategy's
//   terms act on top (ALGORITHMS §4, "Advection"): df/dt = -u . grad f + s |grad f|, so delta holds the volume an
//   advection scheme loses, beta smooths, gamma holds the area (alpha needs a target: set_target).
//
// Engine (core/active/engine.h and its parts; the choices and their measurements are explained atop
// core/active/active_surface.cpp):
// * Storage: a hash of 8^3-node blocks (core/active/sparse_grid.h) allocated around the band only, so memory grows
//   with the surface area and the grid is unbounded; about 8.5 KB per block (4 float channels + bookkeeping).
// * Potential profile: f = clamp(-d / (band_width h), -1, 1), d the signed distance (negative inside). Nodes with
//   |f| < 1, or with a 6-neighbour of the other sign, form the band; the active nodes are the band and its
//   6-neighbours (woken nodes). Nodes outside the active set keep their value; blocks are allocated around band
//   blocks and freed when they and their neighbours leave the band.
// * Speed extension (paper §4.3): the speed is evaluated once per sub-step at the surface sample points (edge
//   crossings of the current potential, the vertices of its Marching Cubes polygonization): g once per crossing
//   (stamped), kappa interpolated along the edge. A node incident to crossed edges takes their mean; the others take
//   the mean of already-assigned 6-neighbours, layer by layer outward, so the band moves with the surface and
//   df/dt -> 0 at rest. Nodes out of reach fall back to the speed at the node itself.
// * Upwinding: grad f from fifth-order HJ-WENO one-sided differences (Jiang & Peng 2000) with WENO-Z weights
//   (Borges et al. 2008): Godunov's Hamiltonian for s |grad f|, per-axis upwinding for u . grad f. Time: third-order
//   TVD Runge-Kutta (Shu & Osher 1988) in every mode; in normal-speed modes the speed is frozen over a sub-step.
//   Updates are Jacobi (every stage reads the previous stage only).
// * Time step: dt = min(cfl * min(h / V, h^2 / (6 D), 1 / (alpha max|grad g|), A0 / (gamma kbar A)), V0 / (delta A))
//   with V = max |s| (or max |u|) over the active nodes, D = beta (the coefficient of the second derivatives in
//   -beta kappa |grad f|; the 3-D explicit bound, ALGORITHMS §4 CHOICE) and the last three the relaxation rates of
//   the tracking, area and volume controllers (kbar = mean |kappa| at the sample points; volume control alone on top
//   of an advection is limited in gain instead of bounding dt: ALGORITHMS §4, "Controller bounds"); an advecting step
//   also caps dt at twice the previous step and rejects a step whose second stage sees |u| dt > h. Several sub-steps
//   per output frame; the last one is shortened to land on the frame time.
// * Reinitialization every reinit_interval sub-steps to the clamped distance profile (PDE, second-order ENO
//   Godunov). It must not move the surface: the interface nodes and their 6-neighbours keep their values unless the
//   gradient there is off by more than 50% (then Russo & Smereka's subcell fix rescales them).
// * Area A and volume V (for gamma, delta and the frame statistics) come from the Marching Cubes surface of f on the
//   grid; A0 and V0 are measured at construction (see set_reference_measures). The components count too.
// * A domain box closes the surface half a cell outside the last nodes inside it, with a regular ramp (f = min(f,
//   wall ramp)), so reinitialization does not erode a solid touching the box.
// * Deterministic: every result is the same whatever `threads` (work is split by block, reductions run in block
//   order; the AVX2 and baseline kernels compute the same IEEE operations).
// * Threads call a VelocityFn and the target Field concurrently: both must be thread-safe (read-only).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/polygonize/polygonize.h"
#include "core/scene/scene.h"
#include "core/util/run_control.h"

namespace surfacer {

struct ActiveSurfaceOptions {
  // Grid spacing, > 0, in scene units.
  double h = 0.02;
  // When set, the solid is confined to this box: f = min(f, ramp of the box grown by half a cell), so the surface
  // closes just outside the last nodes inside the box. Required when the initial shape is unbounded. When unset the
  // grid is unbounded and the initial solid must be bounded (Field::bounds()). Grid nodes lie at
  // domain.min + h * (i, j, k) (or h * (i, j, k) without a domain).
  std::optional<Aabb> domain;
  // Half-width w of the potential's linear ramp, in units of h: f = clamp(-d / (w h), -1, 1); in [2, 8]. The band
  // of active nodes is about 2 w + 2 nodes thick. The default 3 lets the 3-node HJ-WENO stencils of the nodes next
  // to the surface reach the clamp only at their far end (measured: w = 5 changes the Enright volume by < 1%).
  double band_width = 3.0;
  // Motion strategy (see above), each finite and >= 0.
  double alpha = 0.0;  // tracking (needs set_target); the tracking modes (coat, morph) default to kTrackingAlpha
  static constexpr double kTrackingAlpha = 1.0;
  double beta = 0.0;   // surface tension
  double gamma = 0.0;  // area preservation
  double delta = 0.0;  // volume preservation
  // Time step factor in (0, 1] (see "Time step" above). When nullopt every frame takes `substeps_per_frame` equal
  // sub-steps, shortened further where one would exceed the stability bound (cfl = 1).
  std::optional<double> cfl = 0.5;
  int substeps_per_frame = 10;  // used when cfl is nullopt; >= 1
  // A frame needing more sub-steps throws ResourceLimit("max_substeps_per_frame").
  int max_substeps_per_frame = 100000;  // >= 1
  // Reinitialize the ramp every this many sub-steps (>= 1); nullopt: kReinitInterval, or kCompensatedReinitInterval
  // with error_compensation (reinitialization_interval() resolves it). Rarer reinitialization keeps more volume under
  // strong stretching (each one perturbs the WENO stencils) but lets the band widen (more active nodes).
  std::optional<int> reinit_interval;
  static constexpr int kReinitInterval = 16;
  // With error compensation rarer reinitialization keeps the shape markedly better (Enright test at 100^3;
  // docs/ALGORITHMS.md §4, "Error compensation").
  static constexpr int kCompensatedReinitInterval = 64;
  int reinitialization_interval() const {
    return reinit_interval.value_or(error_compensation ? kCompensatedReinitInterval : kReinitInterval);
  }
  // Advecting only: back-and-forth error compensation of every sub-step (BFECC, Dupont & Liu 2003): three Runge-Kutta
  // passes (forward, backward, forward from the corrected start) instead of one, so about 3 times the work per
  // sub-step for markedly less numerical loss (docs/ALGORITHMS.md §4, "Error compensation"), and one more float
  // channel per block (2 KB). Best with cfl 0.9 (as accurate as 0.5, 0.57 times the sub-steps). Ignored in
  // normal-speed modes.
  bool error_compensation = false;
  // Clamp of |kappa| (curvature the grid can carry), in units of 1/h; > 0.
  double max_curvature = 1.0;
  Polygonizer polygonizer = Polygonizer::kTiles;
  bool normals = false;  // per-vertex unit normals in polygonize()
  int threads = 0;       // 0: hardware threads
  // polygonize() keeps each vertex this far from both ends of its grid edge (at most a quarter of the edge; scene
  // units, >= 0): a few quantization steps for quantized frames (docs/ALGORITHMS.md §5 "Clean on the grid"). 0: off.
  double vertex_margin = 0.0;
  // Allocated blocks (8^3 nodes, about 8.5 KB each) above this throw ResourceLimit("max_blocks").
  std::int64_t max_blocks = std::int64_t{1} << 16;
};

// Throws InvalidInput naming the option ("h", "band_width", "alpha", "cfl", ...) with the fix, ResourceLimit("domain")
// for a domain of more than 2^23 nodes per axis.
void validate(const ActiveSurfaceOptions& options);
// The grid checks ActiveSurface's constructor makes on its initial shape, for a caller to make first: throws
// ResourceLimit("h") when a surface in `region` (every place the surface will occupy, clipped to options.domain) needs
// grid nodes beyond the 2^23 per axis the engine addresses at options.h, ResourceLimit("domain") when the box scanned
// for the initial shape (`initial_bounds`, nullopt when unbounded) holds more than 2^24 blocks, and what the
// constructor throws for those bounds (InvalidInput "domain", "initial_shape") and validate(options).
void check_grid_reach(const std::optional<Aabb>& initial_bounds, const Aabb& region,
                      const ActiveSurfaceOptions& options);

struct ActiveFrameStats {
  double time = 0.0;    // simulated time at the end of the frame
  double volume = 0.0;  // enclosed by the Marching Cubes surface of f on the grid
  double area = 0.0;    // of that surface
  std::int64_t active_nodes = 0;
  std::int64_t allocated_blocks = 0;
  int substeps = 0;                    // sub-steps taken in this frame
  std::int64_t active_node_steps = 0;  // sum over the frame's sub-steps of the active nodes updated
  double dt = 0.0;                     // mean sub-step (frame duration / substeps)
  double min_dt = 0.0;        // smallest CFL sub-step of the frame (the shortened last step excluded when possible)
  double max_dfdt = 0.0;      // max |df/dt| over the active nodes at the frame's last sub-step (units of f per time)
  double max_speed = 0.0;     // max |s| (or |u|) over the active nodes at the last sub-step (length per time)
  int components = 0;         // connected components of the surface
  int reinitializations = 0;  // in this frame
  std::size_t memory_bytes = 0;
};

// Velocity u(x, t) for the advect mode, scene units per time unit. Called for every active node at every Runge-Kutta
// stage.
using VelocityFn = std::function<Vec3(const Vec3& position, double time)>;
// A velocity u(x, t) = time_scale(t) spatial(x) (steady when time_scale is empty). The engine evaluates spatial(x)
// once per node while the node stays allocated (3 more float channels per block) and time_scale once per stage.
struct SeparableVelocity {
  std::function<Vec3(const Vec3& position)> spatial;
  std::function<double(double time)> time_scale;
};

namespace active_detail {
struct Engine;  // core/active/engine.h
}

class ActiveSurface {
 public:
  // Converts the normalized initial shape (negative inside) into the clamped potential: samples it on the nodes of
  // the blocks around its surface (all blocks of its bounds, or of `domain`, are visited once), sets
  // f = clamp(-value / (|grad value| w h), -1, 1) and reinitializes. Throws InvalidInput for bad options
  // ("h", "band_width", "alpha", ..., with a hint), for an unbounded shape without `domain` ("domain") or a shape
  // with no surface in the domain ("initial_shape"); ResourceLimit("max_blocks"); Cancelled.
  ActiveSurface(const Field& initial_shape, const ActiveSurfaceOptions& options, const RunControl& control = {});
  ~ActiveSurface();
  ActiveSurface(ActiveSurface&&) noexcept;
  ActiveSurface& operator=(ActiveSurface&&) noexcept;

  // Tracking target g (normalized, negative inside): for coating, the summed particle kernels
  // (make_particle_target); for a morph, shape B. nullptr clears it. Evaluated only at the surface sample points
  // (value and gradient; the gradient bounds the time step), or at band nodes the speed extension does not reach.
  void set_target(FieldPtr target);
  // Advect mode: the surface is carried by u, plus the motion strategy's normal speed when any of its terms is on
  // (see "Advection" above). An empty function returns to the normal-speed mode.
  void set_velocity(VelocityFn velocity);
  // The same for a separable velocity (cached per node). Throws InvalidInput("velocity") without a spatial part.
  void set_velocity(SeparableVelocity velocity);
  // Reference area and volume for gamma and delta; by default those of the initial surface.
  void set_reference_measures(double area, double volume);

  // Advances the simulated time by `duration` (> 0) in sub-steps and returns the statistics of the new state.
  // Throws InvalidInput("duration"), ResourceLimit("max_substeps_per_frame" / "max_blocks"), Cancelled (checked
  // before every sub-step pass; the potential then keeps the state of the last completed sub-step).
  ActiveFrameStats advance(double duration, const RunControl& control = {});
  // Exactly `substeps` (>= 1) sub-steps of the CFL size (no landing on a frame time).
  ActiveFrameStats advance_substeps(int substeps, const RunControl& control = {});

  // The surface f = 0: Marching Tiles of the trilinear potential or Marching Cubes on the grid (options.polygonizer),
  // closed, oriented outward, welded. Deterministic.
  Mesh polygonize(const RunControl& control = {}) const;
  Mesh polygonize(Polygonizer polygonizer, const RunControl& control = {}) const;

  // Statistics of the current state without advancing (substeps = 0).
  ActiveFrameStats stats() const;
  double time() const;
  // Trilinear potential at p (f > 0 inside). Away from the band (no block allocated) +-1: the sign of the first
  // allocated node along +x, or -1 when there is none.
  double potential(const Vec3& p) const;
  const ActiveSurfaceOptions& options() const;

  // Checkpoint (core/active/state.cpp): a versioned binary blob (magic "SACT", version 1, FNV-1a checksum)
  // of the state the next advance() depends on: the allocated blocks in order with their potential channel (f only;
  // the ramp's saturated nodes as bits), the simulated time, the reference area and volume, the sub-steps since the
  // last reinitialization and the last sub-step's figures (dt, which bounds the next advecting step). Derived
  // channels (stage scratch, extended speeds, the velocity cache) are recomputed. The target and the velocity are
  // not saved: set them again after from_state(). Grid geometry (h, band_width, domain) is saved for validation.
  std::string save_state() const;
  // The surface saved by save_state(); with the saved run's options, target and velocity, advance() continues
  // bit-identically to the uninterrupted run. Throws InvalidInput("state") for a truncated, corrupted or foreign
  // blob, or one whose grid does not match `options` (h, band_width, domain); InvalidInput for bad options;
  // ResourceLimit("max_blocks").
  static ActiveSurface from_state(std::string_view state, const ActiveSurfaceOptions& options,
                                  const RunControl& control = {});

 private:
  explicit ActiveSurface(std::unique_ptr<active_detail::Engine> impl);
  std::unique_ptr<active_detail::Engine> impl_;
};

// --- Velocity fields --------------------------------------------------------------------------------------------

// Enright/LeVeque deformation test field on the unit cube (Enright et al. 2002, §5.3), time-reversing with `period`:
//   u = 2 sin^2(pi x) sin(2 pi y) sin(2 pi z) cos(pi t / T)
//   v = -sin(2 pi x) sin^2(pi y) sin(2 pi z) cos(pi t / T)
//   w = -sin(2 pi x) sin(2 pi y) sin^2(pi z) cos(pi t / T)
// The standard test: sphere of radius 0.15 at (0.35, 0.35, 0.35), T = 3; at t = T the exact solution is the sphere.
Vec3 enright_velocity(const Vec3& p, double t, double period);
// The standard test's period T.
inline constexpr double kEnrightPeriod = 3.0;
// The same field as spatial part and time scale cos(pi t / T) (identical values, evaluated once per node).
SeparableVelocity enright_separable_velocity(double period);

// A velocity sampled on a regular grid (uploaded velocity data), trilinear; positions outside the grid use the
// nearest boundary sample (clamped). Time-independent.
struct VelocityGrid {
  Vec3 origin = Vec3::Zero();
  Vec3 spacing = Vec3::Ones();  // > 0 each
  int nx = 0, ny = 0, nz = 0;   // >= 2 each
  std::vector<float> values;    // 3 * nx * ny * nz floats: (u, v, w) per point, x fastest

  // At most this many points per axis (a bound on the grid before its values are read).
  static constexpr int kMaxPointsPerAxis = 100000;
  // Throws InvalidInput("spacing" / "origin" / "nx") for a spacing that is not finite and > 0, an origin that is not
  // finite, or an axis with fewer than 2 or more than kMaxPointsPerAxis points: what can be checked before the values.
  void validate_geometry() const;
  // validate_geometry(), then InvalidInput("values") for a count other than 3 * nx * ny * nz or a value that is not
  // finite.
  void validate() const;
  Vec3 operator()(const Vec3& p) const;
};
// As a VelocityFn, or as a steady SeparableVelocity (cached per node; the better choice for the engine). Validated;
// the grid is shared, not copied per call.
VelocityFn make_velocity_fn(const std::shared_ptr<const VelocityGrid>& grid);
SeparableVelocity make_separable_velocity(const std::shared_ptr<const VelocityGrid>& grid);

// --- Targets ------------------------------------------------------------------------------------------------------

struct ParticleTargetOptions {
  double radius = 0.1;  // kernel support R, > 0
  double iso = 0.5;     // the skin's target level T of sum K, > 0
  BlobKernel kernel = BlobKernel::kWyvill;
};
// G(x) = sum_i K(|x - p_i| / R) with K(r) = (1 - r^2)^3 (Wyvill, compact) as a normalized field T - G
// (core/scene/scene.h make_blobs with point skeletons: a uniform grid of cell R, so a query visits only nearby
// particles). Throws InvalidInput("particles") for an empty set, "radius", "iso".
FieldPtr make_particle_target(std::span<const Vec3> particles, const ParticleTargetOptions& options);
// Throws InvalidInput("radius" / "iso") unless each is finite and > 0.
void validate(const ParticleTargetOptions& options);

// --- One-shot helpers for the three modes (each output frame is polygonized and handed to `sink`) -----------------

struct ActiveFrame {
  Mesh mesh;
  ActiveFrameStats stats;
  int index = 0;  // in the run: 0 is the initial surface (a resumed run starts at its checkpoint's next frame)
};
using ActiveFrameSink = std::function<void(ActiveFrame&& frame)>;

// Checkpoints of the mode helpers, so that a run killed after frame k - 1 resumes with frame k instead of starting
// over. The state is a blob (magic "SAMD", version 1: the mode, the next frame and ActiveSurface::save_state()).
struct ActiveCheckpoints {
  // Called right after frame next_frame - 1 was handed to the sink, every `every` frames (>= 1) and not after the
  // last frame; `state` resumes the run at next_frame.
  std::function<void(int next_frame, std::string state)> save;
  int every = 1;
  // When set (not owned; must outlive the call): a state passed to `save` by a run of the same mode with the same
  // inputs and options. The run then continues at its next frame with the same frames as the uninterrupted run
  // (bit-identical: the engine is deterministic). An unreadable state throws InvalidInput("resume_state") before
  // any frame is emitted.
  const std::string* resume_state = nullptr;
};

struct CoatOptions {
  ParticleTargetOptions kernel;
  double frame_duration = 1.0;  // simulated time between particle frames, > 0
  ActiveCheckpoints checkpoints;
};
// One skin per particle frame: the skin starts on the target of frame 0 and follows the targets of the next frames
// (set_target between frames, advance(frame_duration)). options.alpha must be > 0. frames[i] must be non-empty.
// Returns the number of frames emitted (by this call, when resumed).
int coat_particles(std::span<const std::vector<Vec3>> frames, const CoatOptions& coat,
                   const ActiveSurfaceOptions& options, const ActiveFrameSink& sink, const RunControl& control = {});
// What coat_particles() checks before it starts: throws InvalidInput("kernel.radius", "kernel.iso",
// "frame_duration", "alpha", "checkpoints.every").
void validate(const CoatOptions& coat, const ActiveSurfaceOptions& options);

struct MorphOptions {
  double frame_duration = 0.1;  // simulated time per output frame, > 0
  int max_frames = 100;         // >= 1
  // Stop after the first frame whose max |df/dt| over the active nodes falls below this (units of f per time;
  // with the ramp profile the surface speed is band_width * h times that); >= 0.
  double tolerance = 1e-2;
  ActiveCheckpoints checkpoints;
};
// Shape A -> shape B: the potential starts from A and tracks B (options.alpha > 0). Emits one frame per
// frame_duration (the first is A itself, time 0) until the tolerance or the frame budget is reached.
// Returns the number of frames emitted (by this call, when resumed).
int morph_shapes(const Field& from, FieldPtr to, const MorphOptions& morph, const ActiveSurfaceOptions& options,
                 const ActiveFrameSink& sink, const RunControl& control = {});
// What morph_shapes() checks before it starts: throws InvalidInput("frame_duration", "max_frames", "tolerance",
// "alpha", "checkpoints.every").
void validate(const MorphOptions& morph, const ActiveSurfaceOptions& options);

struct AdvectOptions {
  double frame_interval = 0.1;  // simulated time between output frames, > 0
  int frames = 10;              // frames after the initial one, >= 1
  ActiveCheckpoints checkpoints;
};
// Shape carried by u: emits the initial frame and `frames` more, frame_interval apart. options.beta, gamma and delta
// act on top of the advection (volume-controlled advection with delta); options.alpha must be 0 (there is no target
// to track: InvalidInput("alpha")). Returns frames emitted (by this call, when resumed).
// The options advect_shape refuses beyond validate(options): throws InvalidInput("alpha") for alpha > 0.
void validate_advect(const ActiveSurfaceOptions& options);
int advect_shape(const Field& shape, VelocityFn velocity, const AdvectOptions& advect,
                 const ActiveSurfaceOptions& options, const ActiveFrameSink& sink, const RunControl& control = {});
int advect_shape(const Field& shape, SeparableVelocity velocity, const AdvectOptions& advect,
                 const ActiveSurfaceOptions& options, const ActiveFrameSink& sink, const RunControl& control = {});
// What advect_shape() checks of its options before it starts: throws InvalidInput("frame_interval", "frames",
// "checkpoints.every").
void validate(const AdvectOptions& advect);

}  // namespace surfacer
