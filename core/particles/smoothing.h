// Mesh smoothing pieces of the particle surfacer (core/particles/particle_surfacer.h, steps 3-6): vertex graphs, the
// integrated Bilaplacian B = W^T D^-1 W (Williams 2008 eq. 3.2) as a compact sparse matrix, and Gauss-Seidel sweeps in
// a fixed order that runs blocks of vertices in parallel. Exposed for the tests; not a stable API.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/util/run_control.h"

namespace surfacer::particle_smoothing {

// Compressed rows: the neighbours of vertex i are cols[offsets[i] .. offsets[i + 1]).
struct Graph {
  std::vector<std::uint32_t> offsets{0};
  std::vector<std::uint32_t> cols;
  std::size_t rows() const { return offsets.size() - 1; }
  std::size_t degree(std::size_t i) const { return offsets[i + 1] - offsets[i]; }
};

// The 1-ring of every vertex (sorted, without repeats, without the vertex itself). Triangles with a repeated index
// contribute only their distinct edges.
Graph one_ring(std::size_t vertices, std::span<const Triangle> triangles);

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

// B = W^T D^-1 W for the mesh (x, triangles) with 1-ring `ring`: W_ij = -(cot a_ij + cot b_ij) / 2 over the (one or
// two) triangles sharing edge ij, W_ii = -sum_j W_ij; D_kk = sum of the areas of the triangles incident to k, and
// B_ij = sum_k W_ik W_kj / D_kk over k in {i} + 1-ring(i) with D_kk > 0 (a vertex whose triangles all have zero area
// has an all-zero W row, so skipping it changes nothing). Rows are assembled in parallel (Gustavson: a counting pass,
// then a fill pass into exactly sized arrays), the columns of a row in first-touch order: deterministic whatever
// `threads`. control.check() per pass and worker.
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
// The Bilaplacian for moves along fixed unit normals only: x = x0 + t n (t one offset per vertex). With
// Bn_ij = B_ij (n_i . n_j) and g_i = n_i . (B x0)_i, the energy summed over the coordinates is t^T Bn t + 2 g^T t +
// const. Built from B in place (the same graph; the diagonal is unchanged, n_i . n_i = 1).
struct OffsetSystem {
  SparseMatrix matrix;
  std::vector<double> g;
};
OffsetSystem offset_system(SparseMatrix b, std::span<const Vec3> x0, std::span<const Vec3> normals, int threads);
// One sweep of t_i <- t_i + omega (-(g_i + sum_{j != i} Bn_ij t_j) / Bn_ii - t_i), clamped to [lo_i, hi_i] when
// bounds are given (projected SOR: omega in (0, 2), 1 is plain Gauss-Seidel).
void offset_sweep(std::vector<double>& t, const OffsetSystem& system, std::span<const double> lo,
                  std::span<const double> hi, double omega, const SweepPlan& plan, int threads);

// t^T Bn t + 2 g^T t (the offset energy without its constant).
double offset_energy(const OffsetSystem& system, std::span<const double> t);
// sum over the three coordinates of x^T B x.
double energy(const SparseMatrix& b, std::span<const Vec3> x);

// Area-weighted unit vertex normals (zero for vertices without area).
std::vector<Vec3> vertex_normals(std::span<const Vec3> x, std::span<const Triangle> triangles);

}  // namespace surfacer::particle_smoothing
