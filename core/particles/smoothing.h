// Mesh smoothing pieces of the particle surfacer (core/particles/particle_surfacer.h, steps 3-6): vertex graphs, the
// integrated Bilaplacian B = W^T D^-1 W (Williams 2008 eq. 3.2) as a compact sparse matrix, and Gauss-Seidel sweeps in
// a fixed order that runs blocks of vertices in parallel. Exposed for the tests; not a stable API.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/util/parallel.h"
#include "core/util/run_control.h"

namespace surfacer::particle_smoothing {

// Compressed rows: the neighbours of vertex i are cols[offsets[i] .. offsets[i + 1]).
struct Graph {
  std::vector<std::uint32_t> offsets{0};
  Buffer<std::uint32_t> cols;
  std::size_t rows() const { return offsets.size() - 1; }
  std::size_t degree(std::size_t i) const { return offsets[i + 1] - offsets[i]; }
};

// The 1-ring of every vertex (sorted, without repeats, without the vertex itself). Triangles with a repeated index
// contribute only their distinct edges. The same graph whatever `threads`.
Graph one_ring(std::size_t vertices, std::span<const Triangle> triangles, int threads = 1);

// Symmetric matrix: the diagonal apart (double), off-diagonal entries in `values` aligned with `graph.cols`, stored as
// float: a sweep streams the whole matrix, so half the bytes is most of the speed, and 1e-7 relative error in the
// coefficients of a smoothing energy is immaterial.
struct SparseMatrix {
  Graph graph;
  std::vector<float> values;
  std::vector<double> diagonal;
  std::size_t nonzeros() const { return values.size() + diagonal.size(); }
};

// Largest |cot| used for a cotangent weight (an angle below ~0.06 degrees or above 179.94 is clamped), and the
// relative |cross product| below which a triangle counts as degenerate and adds nothing to W (it still adds its
// area, ~0, to D).
inline constexpr double kMaxCotangent = 1e3;
inline constexpr double kDegenerateRelativeArea = 1e-12;

// W and D of B = W^T D^-1 W (Williams 2008 eq. 3.2) for the mesh (x, triangles) with 1-ring `ring`: W_ij =
// -(cot a_ij + cot b_ij) / 2 over the (one or two) triangles sharing edge ij, aligned with ring.cols; W_ii = -sum_j
// W_ij; 1 / D_kk with D_kk the sum of the areas of the triangles incident to k (0 where that sum is 0: such a vertex
// has an all-zero W row). Every vertex assembles its own row, in parallel: deterministic whatever `threads`. The
// off-diagonal W_ij are summed in double and stored as float, as the sweeps read them (see SparseMatrix).
struct Cotangent {
  Buffer<float> w;
  Buffer<double> w_diag;
  Buffer<double> inv_area;
};
Cotangent cotangent_laplacian(std::span<const Vec3> x, std::span<const Triangle> triangles, const Graph& ring,
                              int threads, const RunControl& control = {});

// B itself, B_ij = sum_k W_ik W_kj / D_kk over k in {i} + 1-ring(i), as a sparse matrix with 2-ring support (the
// reference the matrix-free sweeps are tested against). Rows are assembled in parallel chunks (Gustavson), the columns
// of a row in first-touch order: deterministic whatever `threads`. control.check() per pass and chunk.
SparseMatrix bilaplacian(std::span<const Vec3> x, std::span<const Triangle> triangles, const Graph& ring, int threads,
                         const RunControl& control = {});

// A fixed Gauss-Seidel order: vertices split into `blocks` contiguous index ranges; a vertex is interior when every
// column of its row lies in its own block. A sweep updates each block's interior vertices in ascending order (blocks
// in parallel: they read and write disjoint vertices), then the seam vertices in ascending order, serially.
struct SweepPlan {
  std::vector<std::uint32_t> block_begin{0};  // blocks + 1 offsets into interior
  std::vector<std::uint32_t> interior;
  std::vector<std::uint32_t> seams;
  std::size_t blocks() const { return block_begin.size() - 1; }
};
// About one block per 65536 vertices, 1..64: independent of the thread count, so results are too.
std::size_t default_block_count(std::size_t vertices);
SweepPlan plan_sweeps(const Graph& rows, std::size_t blocks);

// One sweep of x_i += relaxation * (centroid of the 1-ring - x_i) (uniform Laplacian, A = graph Laplacian).
void laplacian_sweep(std::vector<Vec3>& x, const Graph& ring, double relaxation, const SweepPlan& plan, int threads);
// The same order for sweeps whose update of vertex i reads and writes the 1-rings of i's neighbours (2-ring support):
// interior means the whole 2-ring lies in the block.
SweepPlan plan_two_ring_sweeps(const Graph& ring, std::size_t blocks, int threads = 1);

// Smoothing by moves along fixed unit normals only: x = x0 + t n, one offset t_i per vertex, minimizing the energy
// x^T B x (summed over the coordinates) with B applied through W, never formed: with z = W x,
//   x^T B x = sum_k |z_k|^2 / D_kk,   dE/dt_i = 2 sum_{k in {i} + ring(i)} W_ik (n_i . z_k) / D_kk,
//   d2E/dt_i^2 = 2 B_ii = 2 sum_k W_ik^2 / D_kk,
// and moving t_i by delta changes z_k by W_ki n_i delta for k in {i} + ring(i). A sweep streams W's 1-ring (about a
// third of B's 2-ring) and keeps z up to date. The offsets live here, beside z, so the two cannot disagree; they start
// at zero.
class OffsetSmoothing {
 public:
  // x0 and normals must outlive the smoothing (they are not copied).
  OffsetSmoothing(const Graph& ring, Cotangent cotangent, std::span<const Vec3> x0, std::span<const Vec3> normals,
                  std::size_t blocks, int threads = 1);
  // The same for W = cotangent_laplacian(x0, triangles, ring), assembled in place: W is never held twice.
  OffsetSmoothing(const Graph& ring, std::span<const Triangle> triangles, std::span<const Vec3> x0,
                  std::span<const Vec3> normals, std::size_t blocks, int threads, const RunControl& control = {});
  // One sweep of projected SOR, t_i <- clamp(t_i - omega (dE/dt_i) / (d2E/dt_i^2), lo_i, hi_i) (no clamp when the
  // bounds are empty; omega in (0, 2), 1 is plain Gauss-Seidel), in plan() order: block interiors in parallel, then
  // the seams. Never increases the energy; byte-identical results whatever `threads`.
  void sweep(std::span<const double> lo, std::span<const double> hi, double omega, int threads);
  // Every offset into [lo_i, hi_i]; returns the largest move.
  double clamp(std::span<const double> lo, std::span<const double> hi);
  std::span<const double> offsets() const { return offsets_; }
  // x^T B x summed over the coordinates, for x = x0 + t n (the current offsets when t is not given).
  double energy(std::span<const double> t) const;
  double energy() const { return energy(offsets_); }
  const SweepPlan& plan() const { return plan_; }

 private:
  void update_z(int threads);
  // rows_ and w_ from W (w_of(e), ring entry e), w_diag_, inv_area_ and the normals; w_ sized.
  template <class W>
  void pack(W&& w_of, int threads);

  // What one update reads: per vertex its normal and 1 / B_ii (packed), W_ii and 1 / D_ii; per ring entry W_ik
  // (aligned with ring.cols). W_ik / D_kk and W_ii / D_ii are formed from them as the sweep uses them (coefficient(),
  // diagonal_coefficient()), not stored: the same floats in half the bytes.
  struct Row {
    Eigen::Vector3f normal;
    float inv_diag;
  };
  // W_ik / D_kk for ring entry e (column k), rounded to float as the sweep uses it.
  float coefficient(std::uint32_t e) const {
    return static_cast<float>(static_cast<double>(w_[e]) * inv_area_[ring_.cols[e]]);
  }
  float diagonal_coefficient(std::size_t i) const { return static_cast<float>(w_diag_[i] * inv_area_[i]); }
  const Graph& ring_;
  Buffer<Row> rows_;
  Buffer<float> w_;
  Buffer<double> w_diag_, inv_area_;
  std::span<const Vec3> x0_, normals_;
  SweepPlan plan_;
  std::vector<double> offsets_;
  Buffer<Eigen::Vector3f> z_;  // float: the sweep's working set stays in cache; t and x stay double
  bool z_current_ = false;     // z == W (x0 + t n)
};

// sum over the three coordinates of x^T B x.
double energy(const SparseMatrix& b, std::span<const Vec3> x);

// Area-weighted unit vertex normals (zero for vertices without area); the same whatever `threads`.
std::vector<Vec3> vertex_normals(std::span<const Vec3> x, std::span<const Triangle> triangles, int threads = 1);

}  // namespace surfacer::particle_smoothing
