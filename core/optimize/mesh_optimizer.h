// Dynamic mesh optimization of a polygonized implicit surface (Ohtake, Belyaev, Pasko 2002, "Dynamic Mesh
// Optimization for Polygonized Implicit Surfaces with Sharp Features"; docs/ALGORITHMS.md §3).
//
// Given a field f (negative inside, exact gradient) and a start mesh of {f = 0} (usually Marching Cubes or Tiles),
// the vertices are moved by three flows until they lie on f = 0 and the triangle normals match ∇f/|∇f|, so the
// sharp edges and corners that a polygonizer chamfers come back. Notation below: P a vertex, T a triangle, A(T)
// its area, C_T its centroid, n_T its unit normal, m(X) = ∇f(X)/|∇f(X)|, A(P) = Σ_{T∋P} A(T), Q_j the 1-ring.
//
// One iteration applies the flows as Jacobi sweeps (every vertex moves from the positions of the previous sweep),
// in the paper's order N ∘ D ∘ T (T first, then D, then N; each sweep sees the result of the one before):
//   T-flow (§2.3, eq. 6)  P += c_t [U - (U·n_P) n_P],  U = (1/k) Σ_j Q_j - P,  n_P = area-weighted vertex normal.
//                         Only at interior manifold vertices (boundary vertices would shrink the boundary).
//   D-flow (§2.1, eq. 3)  P += c_d F_D,  F_D = -f(P) ∇f(P) / (|∇f(P)|² + ε)  (Newton projection, ε = 1e-12),
//                         clamped to the step bound (eq. 5, CFL analogue) |c_d F_D| <= step_bound · sqrt(A(P)).
//   N-flow (§2.2)         P += c_n Σ_T A(T) v_T / Σ_T A(T),  v_T = ((C_T - P)·m(C_T)) m(C_T)  over T ∋ P.
//   modified N-flow (§3.1, used instead of the N-flow once the T-flow is off when `modified_flows`):
//                         φ(T) = A(T) (1 - n_T·m(C_T)) (triangle area minus the area of its projection on the plane
//                         ⟂ m), E(P) = Σ_{T∋P} φ(T); five gradient steps P -= (c_n / deg P) ∇_P E with m(C_T) frozen
//                         for the iteration and the neighbours fixed, ∇_P φ(T) = ½ (n_T - m) × (Q_2 - Q_1) for
//                         T = (P, Q_1, Q_2) counter-clockwise; each step clamped to c_n · step_bound · sqrt(A(P)) /
//                         deg P (the D-flow's bound shared by degree) and halved until E(P) decreases (CHOICE: φ has a
//                         kink where a strip of triangles collapses onto a feature line, so a fixed step oscillates
//                         across it). Combined with the D-flow as N ∘ D.
// Schedule (§2.4): N ∘ D ∘ T first; the T-flow rounds sharp edges off (Fig. 10), so it is switched off after
// `t_flow_iterations` iterations, or, when that is not given, once E_d has stabilised (CHOICE):
//   after >= 10 T-flow iterations (and k >= 5), E_d(k) > 0.95 · E_d(k - 5) (less than 5 % decrease over the last 5
//   iterations), or E_d(k)
//   <= 1e-20 · L² (L = start bounding-box diagonal), or k >= max_iterations / 2 (half the run is left for N ∘ D).
// Then N ∘ D (or modified N ∘ D) until `max_iterations` or `tolerance`.
//
// Error metrics (§2.4), reported after every iteration:
//   E_d = Σ_P A(P) f(P)² / |∇f(P)|² / Σ_P A(P)     (area-weighted mean squared first-order distance; scene units²)
//   E_n = Σ_T A(T) |n_T - m(C_T)|² / Σ_T A(T)      (area-weighted normal deviation; dimensionless, 0..4)
//
// Flip guard (not in the paper; so that no triangle ever faces against ∇f): a triangle's score is s(T) = n_T·m(C_T)
// (-2 when degenerate: area <= 1e-12 L²). After each sweep, with the field normals from before the sweep, and once
// more at the end of the iteration with the exact normals at the new centroids, a move is accepted for a triangle
// when s_new >= min(0.02, s_old); otherwise the moves of its three vertices are halved (up to three times, then
// dropped) and the check repeats. So a committed triangle never turns against the field, and one that started that
// way never gets worse.
//
// Connectivity repair (`repair_connectivity`; CHOICE, beyond the paper, with the standard local remeshing operations
// edge flip and edge collapse): the vertex flows alone get stuck where the start mesh's connectivity cannot follow
// the features. The N-flow collapses the one-cell chamfer strips that Marching Cubes
// leaves along grid-aligned edges onto the feature line, leaving zero-area caps and needles, and near corners a
// triangle may span two faces whatever its vertices do. After every iteration (core/optimize/cleanup.h):
// caps (largest angle > 170°) have their longest edge flipped, triangles with |n_T - m(C_T)|² > 0.1 have the edge
// flipped that lowers Σ A |n - m|² of the pair, and needles (an edge < 0.02 × the other two) are collapsed (link
// condition; the removed vertex stays in `vertices`, unreferenced). Every change keeps the mesh closed, manifold and
// oriented and passes the flip guard's test with exact field normals.
//
// Adaptive subdivision (§3.2), when `subdivision_threshold` is set, every `subdivision_interval` iterations:
//   δ(T) = Σ_{k=1..4} A(T_k) |n_T - m(C_k)|²  over the four triangles of T's imagined 1-to-4 split (A(T_k) = A(T)/4),
// in scene units². Triangles with δ(T) > threshold are split 1-to-4 at their edge midpoints (red); red–green closure
// keeps the mesh conforming: a triangle with two or more split edges is split red, one with one split edge is
// bisected (green). Green pairs are never split again: when one must be refined, the pair is merged back into its
// parent, which is split red instead (Bank–Sherman–Weiser red–green refinement), so angles do not degrade. The
// refined mesh stays closed and manifold when the start mesh is. With `triangle_budget`, or the step's
// control.triangles (core/util/triangle_limit.h: a server's --max-triangles), the smaller, the round is cut to the
// triangles with the largest δ that fit (halving the request until the closed result fits); never beyond it: a trial
// stops at its first red-green pass whose result would not fit, before building it, and the hook of control.triangles
// reserves each pass's triangles before they are built. New
// vertices start at edge midpoints; the flows take them to the surface in the following iterations. Children are
// coplanar with their parent, so a child whose centroid lies on another face than its parent's centroid could face
// against ∇f there (not seen on the test shapes); the guard then keeps it from getting worse.
//
// Vertex indices: the start mesh's vertices keep their indices (new ones are appended; collapsed ones stay,
// unreferenced). Work per iteration: V + 2 F field gradient evaluations (2 V + 2 F while the T-flow is on; a
// subdivision round adds 3 F + the new mesh's V + F), all sweeps parallel over `threads` (Jacobi: results are the
// same whatever the thread count).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "core/mesh/mesh.h"
#include "core/polygonize/polygonize.h"
#include "core/util/run_control.h"

namespace surfacer {

class Field;

// The start mesh when none is given: Marching Cubes at 64 cells along the longest axis, the paper's setting (its
// chamfered edges are what the flows restore).
inline PolygonizeOptions default_start_polygonize() {
  PolygonizeOptions options;
  options.method = Polygonizer::kCubes;
  options.cells = 64;
  return options;
}

// Iterations a run may ask for (a bound on the work and on the frames a snapshot schedule can produce).
inline constexpr int kMaxIterations = 1'000'000;

struct MeshOptimizerOptions {
  bool d_flow = true;  // distance flow (vertices onto f = 0)
  bool n_flow = true;  // normal flow (triangle normals onto ∇f/|∇f|)
  bool t_flow = true;  // tangential relaxation (mesh regularity) in the first phase
  // Flow coefficients, dimensionless, each in (0, 1]: the fraction of the flow's displacement taken per iteration.
  double c_d = 1.0;  // 1: a full Newton projection onto f = 0 (before the step bound)
  double c_n = 1.0;  // 1: the full area-weighted projection onto the centroid tangent planes
  double c_t = 0.1;  // the paper's C_T = 0.1 times the tangential umbrella vector
  // c in |c_d F_D(P)| <= c sqrt(A(P)) (ALGORITHMS.md §3; the paper uses 0.1..0.25); in (0, 1].
  double step_bound = 0.2;
  // Use the paper's §3.1 local-energy gradient descent instead of the N-flow once the T-flow is off.
  bool modified_flows = false;
  // T-flow for exactly this many iterations (>= 0); when not given it is switched off once E_d stabilises (above).
  std::optional<int> t_flow_iterations;
  int max_iterations = 200;  // 0..kMaxIterations
  // Stop early when, more than 5 iterations after the T-flow went off and after the last subdivision, neither E_d nor
  // E_n improved by more than this fraction on the best of the previous 5 iterations (E_n need not fall
  // monotonically), or both are at round-off level (E_d <= 1e-24 L², E_n <= 1e-24); in (0, 1), e.g. 1e-3.
  std::optional<double> tolerance;
  // Adaptive 1-to-4 subdivision where δ(T) > threshold (scene units², > 0). δ(T) ≈ A(T) θ² for a triangle whose
  // normal is off by θ radians, so with grid spacing h (triangles of area ~h²/2) 0.004 h² refines triangles off by
  // more than about 5°. Checked every `subdivision_interval` iterations (>= 1), except on the last iteration.
  std::optional<double> subdivision_threshold;
  int subdivision_interval = 10;
  // Never subdivide beyond this many triangles (> 0); unlimited when not given.
  std::optional<std::int64_t> triangle_budget;
  // optimize_mesh(): a snapshot every this many iterations (>= 0; 0: only the final mesh).
  int snapshot_every = 0;
  // Cap flips, normal-improving flips and needle collapses after every iteration; see "Connectivity repair" above.
  bool repair_connectivity = true;
  // Per-vertex unit normals in the output (normalized ∇f at the vertex).
  bool normals = false;
  int threads = 0;  // 0: hardware threads
};

struct OptimizerIterationStats {
  int iteration = 0;               // iterations done (0: the start mesh)
  double e_d = 0.0;                // scene units²
  double e_n = 0.0;                // dimensionless
  double max_distance = 0.0;       // max over used vertices of |f| / |∇f| (scene units)
  double rms_distance = 0.0;       // root mean square over used vertices of |f| / |∇f| (scene units)
  double min_angle_degrees = 0.0;  // smallest triangle angle (degenerate triangles skipped)
  std::int64_t triangles = 0;
  std::int64_t vertices = 0;         // used by some triangle
  bool t_flow_on = false;            // the T-flow was applied in this iteration
  std::int64_t limited_moves = 0;    // vertex moves shortened or dropped by the flip guard in this iteration
  std::int64_t triangles_added = 0;  // by adaptive subdivision in this iteration
  std::int64_t flips = 0;            // edge flips of the connectivity repair in this iteration
  std::int64_t collapses = 0;        // needle collapses of the connectivity repair in this iteration
};

// Stateful optimizer: keeps the mesh, its adjacency, the schedule and the red–green hierarchy across iterations.
// Keeps a reference to `field`, which must outlive it (Field is thread-safe for concurrent const calls).
// Throws InvalidInput naming the option ("c_d", "step_bound", "max_iterations", ...) with the fix.
void validate(const MeshOptimizerOptions& options);
// Throws InvalidInput("start") for a start mesh the optimizer cannot take: no triangles, an index out of range, a
// repeated index in a triangle, a non-finite vertex; ResourceLimit("start") beyond 2^31 vertices.
void validate_start_mesh(const Mesh& start);

// Throws InvalidInput from the constructor for bad options ("c_d", "step_bound", ...) or a bad start mesh ("start":
// no triangles, an index out of range, a repeated index in a triangle, a non-finite vertex).
class MeshOptimizer {
 public:
  MeshOptimizer(const Field& field, Mesh start, const MeshOptimizerOptions& options);
  ~MeshOptimizer();
  MeshOptimizer(MeshOptimizer&&) noexcept;
  MeshOptimizer& operator=(MeshOptimizer&&) noexcept;

  // One iteration (flows, then a subdivision round when due). Strong guarantee: when control's token fires
  // (checked every ~4096 vertices or triangles of every sweep) it throws Cancelled and the optimizer is left exactly
  // as after the previous iteration. May be called after done() (it then just keeps iterating).
  OptimizerIterationStats step(const RunControl& control = {});
  // The current mesh (the start mesh before the first step).
  const Mesh& mesh() const;
  // Figures of the current mesh (iteration 0: the start mesh).
  const OptimizerIterationStats& stats() const;
  // True once max_iterations are done or the tolerance criterion holds.
  bool done() const;
  bool t_flow_on() const;  // whether the next step applies the T-flow

  // Checkpoint: a versioned binary blob (magic "SOPT", version 1, FNV-1a checksum) holding everything the next
  // step() depends on: the exact mesh (double positions, triangles), the iteration stats, the schedule (T-flow phase
  // and count, E_d / E_n history, last disruption, convergence), the length scale and the red-green hierarchy (so
  // green pairs still merge back on a later subdivision round). The field values and normals are recomputed on
  // load. About 24 bytes per vertex + 16 per triangle (+ the hierarchy's midpoints after subdivision).
  std::string save_state() const;
  // The optimizer saved by save_state(), ready to continue: step() then gives bit-identical results to the
  // uninterrupted run, provided `field` and `options` are the saved run's (they are not part of the blob).
  // Throws InvalidInput("state") for a blob that is truncated, corrupted, of another version or inconsistent (an
  // index out of range, a non-finite position), and the constructor's InvalidInput for bad options.
  static MeshOptimizer from_state(const Field& field, std::string_view state, const MeshOptimizerOptions& options);

 private:
  struct State;
  explicit MeshOptimizer(std::unique_ptr<State> state);
  std::unique_ptr<State> state_;
};

using OptimizerSnapshotFn = std::function<void(const Mesh&, const OptimizerIterationStats&)>;

// Runs a MeshOptimizer until done(). `on_snapshot(mesh, stats)` is called every `snapshot_every` iterations and once
// for the final mesh (never twice for the same iteration); the final call's mesh is the return value. control.report
// ("optimize", iteration / max_iterations) after every iteration.
// On cancel it throws Cancelled (promptly: within one sweep of ~4096 items): the last snapshot the caller received
// stays the latest complete result, so a job streaming snapshots as frames keeps them.
Mesh optimize_mesh(const Field& field, Mesh start, const MeshOptimizerOptions& options,
                   const OptimizerSnapshotFn& on_snapshot = {}, const RunControl& control = {});

}  // namespace surfacer
