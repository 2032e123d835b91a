// Error-bounded level of detail (docs/ALGORITHMS.md §5, CHOICE "Decimation"): halfedge collapses on an OpenMesh
// TriMesh in the order of Garland-Heckbert quadrics (the cheapest collapse first), each accepted only when
//  * every input vertex removed so far stays within `tolerance` of the decimated surface (each is held by one face
//    within `tolerance` of it; a collapse must find such a face among the new ones for each sample it moves),
//  * no face normal turns by more than kMaxNormalDeviationDegrees (no fold-overs),
//  * no angle of a new triangle is below min_angle_degrees,
//  * the engine's own rule for a surface point (`acceptable`) holds at the centroid of every new triangle and at the
//    midpoint of every new edge (particle frames: the band r_inner <= d <= r_outer; fields: |f| / |grad f| <=
//    tolerance),
//  * the link condition holds (as OpenMesh's is_collapse_ok): a closed manifold mesh stays closed and manifold.
// Large meshes are decimated by regions in parallel (vertices shared by regions frozen), then across the seams; the
// result does not depend on the number of threads.
// Halfedge collapses keep every surviving vertex at its position, so a vertex that satisfied the engine's rule still
// does, and per-vertex data (normals, attributes) is kept by index (compacted with the vertices).
#pragma once

#include <cstddef>
#include <functional>
#include <optional>
#include <span>

#include "core/mesh/mesh.h"
#include "core/mesh/quantization.h"
#include "core/util/run_control.h"

namespace surfacer {

class Field;

struct DecimateOptions {
  // The largest distance (scene units, finite, >= 0) from an original vertex to the decimated surface; 0: off (the
  // mesh is returned unchanged).
  double tolerance = 0.0;
  // No new triangle gets a smaller angle (degrees, in [0, 30]). Triangles of the input below it are left as they
  // are unless a collapse removes them.
  double min_angle_degrees = 10.0;
  // When set, those angles are the ones of the corners' points on this grid, as a decoder of the frame reads them
  // (quantization moves a corner by up to half a step).
  std::optional<QuantizationGrid> grid{};
  // Threads for the regions of a large mesh (0: hardware threads). The result does not depend on it.
  int threads = 0;
  // Largest turn of a face normal by one collapse, in degrees.
  static constexpr double kMaxNormalDeviationDegrees = 45.0;
};

// Throws InvalidInput("tolerance" / "min_angle_degrees" / "threads") naming the value and the range.
void validate(const DecimateOptions& options);

struct DecimateStats {
  std::size_t vertices_before = 0, triangles_before = 0;
  std::size_t vertices_after = 0, triangles_after = 0;
  std::size_t collapses = 0;
  std::size_t regions = 0;  // of the first pass over regions; 1 when the mesh was decimated whole
  double seconds = 0.0;
};

// Whether a point (scene units) may lie on the decimated surface. Called from several threads at once.
using SurfacePointRule = std::function<bool(const Vec3&)>;

// `mesh` decimated under `options` (see the header comment): vertices a subset of the input's in their input order,
// with their normals and attributes. An empty `acceptable` accepts every point. With tolerance 0 the result is `mesh`.
// Throws InvalidInput for bad options or a triangle index out of range, Cancelled.
Mesh decimate(const Mesh& mesh, const DecimateOptions& options, const SurfacePointRule& acceptable = {},
              const RunControl& control = {}, DecimateStats* stats = nullptr);

// The rule of particle frames (docs/ALGORITHMS.md §1, thesis eq. 3.4): r_inner_i <= |x - p_i| for every particle and
// |x - p_j| <= r_outer_j for some, with r_inner_i = radii[i] and r_outer_i = radii[i] * r_outer / r_inner when `radii`
// is not empty, else r_inner and r_outer for all (relative tolerance 1e-9, as the surfacer's faithful fraction). The
// rule keeps its own spatial hash; `particles` and `radii` must outlive it.
SurfacePointRule particle_band_rule(std::span<const Vec3> particles, std::span<const double> radii, double r_inner,
                                    double r_outer);

// The rule of implicit surfaces: |f(x)| / |grad f(x)| <= tolerance (the first-order distance to the zero set; a
// point where the gradient vanishes is accepted only where f = 0). `field` must outlive the rule.
SurfacePointRule zero_set_rule(const Field& field, double tolerance);

}  // namespace surfacer
