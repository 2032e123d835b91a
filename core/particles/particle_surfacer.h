// Particle surfacing (Williams 2008, "Fluid surface reconstruction from particles", ch. 3; docs/ALGORITHMS.md §1):
// a surface as smooth as possible while every vertex x stays faithful to the particles,
//     r_inner <= min_i |x - p_i| <= r_outer                                          (thesis eq. 3.4)
// i.e. outside the union of r_inner balls and inside the union of r_outer balls.
//
// Pipeline (thesis Fig. 3.2), one frame; the steps and every change from the thesis (CHOICE) are in
// docs/ALGORITHMS.md §1:
//  1. Spatial hash over the particles (core/particles/spatial_hash.h); the field f(x) = d(x) - r_outer, d = distance to
//     the nearest particle, is sampled lazily where Marching Tiles visits. Never a dense global grid.
//  2. Initial mesh: Marching Tiles (core/polygonize/marching_tiles.h) of f = 0, mean sample spacing h = spacing_factor
//     * r_inner. Closed, oriented, minimum valence >= 5.
//  3. laplacian_sweeps Gauss-Seidel sweeps on the uniform Laplacian energy (under-relaxed by `relaxation`)
//     (vertex_only_band: then the thesis' projection of every vertex to the band's nearest point).
//  4. A unit normal n per vertex fixed; every vertex outside the band moved along it to the line's nearest faithful
//     point (CHOICE "projection along the normals"); the band along each normal an exact interval of offsets t, its
//     top lowered below the lowest cusp of the r_outer spheres the vertex holds, and the vertex moved onto the planes
//     of the cusps around it, which fixes x0 (CHOICEs "cusps held", "a start on the cusps' planes"; not with
//     vertex_only_band).
//  5. bilaplacian_sweeps projected SOR sweeps on |W (x0 + t n)|^2 over D (B = W^T D^-1 W, eq. 3.2, applied through W),
//     each offset clamped into its interval: CHOICEs "constrained stages along the normals", "over-relaxed sweeps".
//  6. polish_sweeps of the same clamped to the container only, then (unless unconstrained_polish) every offset clamped
//     into its band interval again: every final vertex is faithful (CHOICE "faithful at the end").
//  7. Optional erosion x <- x - erosion * r_inner * n(x) (area-weighted vertex normal), then the container again.
//  8. Closed components spanning less than 2 r_inner that hold no particle (sub-particle bubbles) dropped; sliver
//     repair (core/mesh/mesh_repair.h): angles below min_angle_degrees, or triangles collinear on output_grid, removed
//     by flips and collapses, or, where the valence floor blocks both, by moving a vertex within the band.
//
// Container snapping wins over faithfulness: vertices held at a wall may be outside [r_inner, r_outer].
//
// What to expect (measured in tests/core/particle_surfacer_test.cpp and bench/particles_bench.cpp):
//  * Marching Tiles puts a vertex on every crossed lattice edge: about 5 vertices per h^2 of surface.
//  * Lattices where eq. 3.5 (square) or 3.6 (triangular) holds, in any orientation: a planar face (RMS height
//    deviation below 0.01% of r_inner on the bench's slabs) on the highest plane the band admits. With
//    vertex_only_band (the thesis' band) 0.6-2.7% of r_inner, above every admissible plane (docs/ALGORITHMS.md §1,
//    "Flat surfaces"). Curved fluid ends under the cusps between its particles: droplets enclose 4-15% less than
//    with the thesis' band, closer to their particles' volume.
//  * Every final vertex in the band (faithful_after_polish = 1) unless unconstrained_polish or the container says
//    otherwise; no triangle angle below min_angle_degrees on droplets, as the output grid shows them; thin sheets
//    keep a few in valence-5 knots of their rims (slivers_left counts them).
//
// Per-particle radii (radii non-empty): particle i gets r_inner_i = radii[i] and r_outer_i = k * radii[i], where
// k = r_outer / r_inner of the options (default 2) and the reference r_inner is options.r_inner when set, else the
// median radius (it sets the sample spacing and the erosion depth; derive_r_inner is ignored). The field is
// min_i(|x - p_i| - r_outer_i) (its zero set is the union of the r_outer_i balls), and faithfulness means
// min_i(|x - p_i| - r_inner_i) >= 0 >= min_i(|x - p_i| - r_outer_i); projection uses the particle attaining each
// minimum. The particles are searched in tiers of radii within a factor 2 (core/particles/particle_index.h), so one
// particle far larger than the rest costs about its own surface, not a search as wide as its radius for every vertex.
//
// Parallelism: vertices are renumbered along a Morton curve and cut into contiguous blocks (a count that depends only
// on the vertex count); a sweep first updates, in parallel, every block's interior vertices (whose matrix row reads
// only its own block), then the remaining "seam" vertices serially. That is exactly Gauss-Seidel in a fixed vertex
// order, so convergence is Gauss-Seidel's and the result is byte-identical whatever `threads`. The band
// intervals, W's assembly and Marching Tiles run in parallel too.
//
// Cancellation: control.check() at least once per sweep, per assembly chunk and inside Marching Tiles; progress is
// reported per stage: "distance_field", "polygonize", "laplacian", "build_b", "bilaplacian", "polish", "erosion",
// "cleanup".
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_repair.h"
#include "core/scene/scene.h"
#include "core/util/run_control.h"

namespace surfacer {

struct ParticleSurfacingOptions {
  // Inner radius (scene units, > 0): typically the simulation's particle radius. Required unless derive_r_inner or
  // per-particle radii are given.
  std::optional<double> r_inner;
  // r_inner := mean distance from a particle to its nearest neighbour (over a fixed sample of at most 65536 particles;
  // those whose nearest neighbour is farther than 4x the median are left out as stray spray). Needs >= 2 particles.
  bool derive_r_inner = false;
  // Outer radius, > r_inner; default kDefaultOuterRatio * r_inner. A planar face over a square lattice of spacing d
  // needs r_outer^2 >= r_inner^2 + d^2 / 2 (thesis eq. 3.5; triangular lattice: + d^2 / 3, eq. 3.6).
  std::optional<double> r_outer;
  static constexpr double kDefaultOuterRatio = 2.0;
  // Marching Tiles mean sample spacing / r_inner, in [kMinSpacingFactor, 10]. The floor bounds the initial tiling's
  // work per particle before it starts: its blocks near each particle grow as (r_outer / spacing)^3.
  double spacing_factor = 0.8;
  static constexpr double kMinSpacingFactor = 0.1;
  int laplacian_sweeps = 5;     // >= 0 each
  int bilaplacian_sweeps = 15;  // over-relaxed: 15 reach a lower energy than 25 plain ones (docs/ALGORITHMS.md §1)
  int polish_sweeps = 5;
  // Keep the thesis' unconstrained polish: without the final projection some vertices end outside the band.
  bool unconstrained_polish = false;
  // Keep the thesis' band at the vertices only: the cusps of the r_outer spheres are not held and the sweeps start
  // where the Laplacian stage left the vertices (fuller surfaces; faces over lattices are not flat).
  bool vertex_only_band = false;
  // Triangles with a smaller angle (degrees, in [0, 30]) are repaired at the end by edge flips and collapses
  // (core/mesh/mesh_repair.h); 0 switches the repair off. 10 by default (docs/ALGORITHMS.md §1, CHOICE "sliver repair
  // at 10°"): lattices give no angle below it, droplets a few hundred triangles per million.
  double min_angle_degrees = 10.0;
  // The grid the frames are quantized on (the job's Draco box and bits), when known: triangles degenerate on it are
  // repaired too.
  std::optional<QuantizationGrid> output_grid;
  double relaxation = 0.6;              // Laplacian under-relaxation, in (0, 1]
  std::optional<double> erosion;        // epsilon >= 0 in units of r_inner (thesis §3.9); off by default
  std::optional<Aabb> container_box;    // the surface is kept inside (valid box)
  FieldPtr container_solid;             // the surface is kept where container_solid <= 0 (negative inside)
  int min_particles_per_component = 0;  // drop particle clusters (r_outer balls chained by overlap) smaller than this
  bool normals = false;                 // output per-vertex unit normals (area-weighted, outward)
  int threads = 0;                      // 0: hardware threads
};

struct ParticleSurfacingStats {
  // Resolved parameters.
  double r_inner = 0.0, r_outer = 0.0, spacing = 0.0;
  std::size_t particles = 0;           // given
  std::size_t particles_used = 0;      // after min_particles_per_component
  std::size_t components_dropped = 0;  // particle clusters dropped
  std::size_t seeds = 0;               // particles passed to Marching Tiles as seeds
  // Seconds per stage. distance_field: spatial hash, radius derivation and component filter; the per-sample distance
  // queries run inside polygonize (lazily, where Marching Tiles visits).
  double seconds_distance_field = 0.0, seconds_polygonize = 0.0, seconds_laplacian = 0.0, seconds_build_b = 0.0,
         seconds_bilaplacian = 0.0, seconds_polish = 0.0, seconds_erosion = 0.0, seconds_total = 0.0;
  std::int64_t field_evaluations = 0;  // distance samples taken by Marching Tiles
  // The initial (Marching Tiles) mesh.
  std::size_t initial_vertices = 0, initial_triangles = 0;
  int initial_min_valence = 0;
  // Faithfulness: fraction of vertices with r_inner <= d <= r_outer (relative tolerance 1e-9) and the largest distance
  // outside that band (scene units), after the constrained sweeps (step 5) and at the end (after polish/erosion).
  double faithful_after_constrained = 0.0, faithful_after_polish = 0.0;
  double max_violation_after_constrained = 0.0, max_violation_after_polish = 0.0;
  // The same right after the polish sweeps, before the final projection (what the thesis' unconstrained polish
  // leaves), and the largest move of the final projection.
  double faithful_after_polish_sweeps = 0.0, max_violation_after_polish_sweeps = 0.0;
  double max_final_projection = 0.0;
  double max_polish_displacement = 0.0;  // largest vertex move during polish, final projection and erosion
  // The sliver repair: triangles found below min_angle_degrees (or degenerate on output_grid), edges flipped and
  // collapsed, vertices moved (within the band), and the bad triangles left (none unless a repair would break the
  // mesh), and its seconds.
  std::int64_t slivers_found = 0, sliver_flips = 0, sliver_collapses = 0, sliver_moves = 0, slivers_left = 0;
  double seconds_cleanup = 0.0;
  double seam_fraction = 0.0;  // vertices updated serially in the parallel Gauss-Seidel (see header)
  // Vertices whose upper bound a cusp of the r_outer spheres lowered (step 4).
  std::size_t cusp_vertices = 0;
  // Closed components spanning less than 2 r_inner that hold no particle, dropped (voids among the outer balls).
  std::size_t bubbles_dropped = 0;
  std::size_t vertices = 0, triangles = 0;
};

// Throws InvalidInput naming the option ("r_inner", "r_outer", "spacing_factor", "laplacian_sweeps", ...) with the fix.
void validate(const ParticleSurfacingOptions& options);

// Throws InvalidInput("r_inner") when a frame without per-particle radii would have no r_inner: the options give
// neither r_inner nor derive_r_inner. The one statement of "r_inner is required": the surfacer, the server's submit
// check (wire) and the client's upload of each frame call it.
void require_r_inner_source(bool frame_has_radii, bool has_r_inner, bool derive_r_inner);

// Keeps validated options and scratch buffers (spatial hash, matrices) between frames; not thread-safe: use one per
// worker. Throws InvalidInput from the constructor for bad options (message names the option and the fix).
class ParticleSurfacer {
 public:
  explicit ParticleSurfacer(const ParticleSurfacingOptions& options);
  ~ParticleSurfacer();
  ParticleSurfacer(ParticleSurfacer&&) noexcept;
  ParticleSurfacer& operator=(ParticleSurfacer&&) noexcept;

  // The whole pipeline for one frame. `radii` is empty or one radius per particle (finite, > 0).
  // An empty particle set (or one emptied by min_particles_per_component) gives an empty mesh.
  // Throws InvalidInput ("particles", "radii", "r_inner" when it cannot be derived), ResourceLimit (from Marching
  // Tiles / the spatial hash for extreme extents), Cancelled.
  Mesh surface(std::span<const Vec3> particles, std::span<const double> radii = {}, const RunControl& control = {},
               ParticleSurfacingStats* stats = nullptr);

  // Steps 1-2 only: the Marching Tiles mesh of d = r_outer before any smoothing or constraint (min valence >= 5).
  Mesh initial_surface(std::span<const Vec3> particles, std::span<const double> radii = {},
                       const RunControl& control = {}, ParticleSurfacingStats* stats = nullptr);

  const ParticleSurfacingOptions& options() const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

// One-shot forms.
Mesh surface_particles(std::span<const Vec3> particles, std::span<const double> radii,
                       const ParticleSurfacingOptions& options, const RunControl& control = {},
                       ParticleSurfacingStats* stats = nullptr);
Mesh initial_particle_surface(std::span<const Vec3> particles, std::span<const double> radii,
                              const ParticleSurfacingOptions& options, const RunControl& control = {},
                              ParticleSurfacingStats* stats = nullptr);

// The box every surfaced frame of a particle sequence fits in (a Draco quantization box shared by all frames, so
// that every frame uses one grid): the union of the particles' bounds, padded by 1.5 times how far the surface can
// reach. That reach is r_outer / r_inner times the largest particle radius; or r_outer (default 2 r_inner); or,
// when r_inner is derived per frame, 3 times the r_outer implied by the first frame's derived r_inner (the surfacer's
// own estimate of the particle spacing; `first_frame` is called only then). Clipped to `container` when given. The
// server and the scale-out client both use it, so a sequence split across servers is quantized exactly as on one
// server.
Aabb particle_sequence_box(const Aabb& particle_bounds, double max_radius, std::optional<double> r_inner,
                           std::optional<double> r_outer, const std::function<std::vector<Vec3>()>& first_frame,
                           const std::optional<Aabb>& container);

}  // namespace surfacer
