// Topological and geometric checks of a triangle mesh. Reported in every frame's stats and used by the tests.
#pragma once

#include <cstdint>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/util/run_control.h"

namespace surfacer {

struct MeshReport {
  bool closed = false;                    // no boundary edges
  bool edge_manifold = false;             // every edge has 1 or 2 incident triangles
  bool vertex_manifold = false;           // every vertex's incident triangles form one fan (disk or half-disk)
  bool oriented = false;                  // every interior edge is traversed once in each direction
  std::int64_t euler_characteristic = 0;  // V - E + F (over referenced vertices)
  int components = 0;                     // connected components (via shared vertices)
  std::int64_t boundary_edges = 0;
  std::int64_t non_manifold_edges = 0;          // edges with > 2 triangles
  std::int64_t degenerate_triangles = 0;        // repeated index or zero area
  std::vector<std::int64_t> valence_histogram;  // [v] = #vertices with v distinct neighbours
  int min_valence = 0;
  int max_valence = 0;
  double min_angle_degrees = 0.0;
  double max_angle_degrees = 0.0;
  // Triangles with an angle below check_mesh's `below_degrees`, zero-area ones included (0 when it is 0).
  std::int64_t triangles_below_angle = 0;
  double area = 0.0;
  double volume = 0.0;  // signed enclosed volume (divergence theorem); > 0 for outward-oriented closed meshes
};

// Conventions: triangles with a repeated vertex index count in degenerate_triangles and are otherwise ignored (no
// edges, not in F); zero-area triangles (area < 1e-14 * bbox diagonal^2) count as degenerate but keep their topology,
// and are skipped for the angles. Edges with > 2 triangles make the mesh neither oriented nor vertex-manifold.
// Unreferenced vertices are ignored everywhere. An empty mesh is vacuously closed/manifold/oriented with all counts 0.
// O(V + F) time (45-55 ns per triangle on one core, on polygonizer output) and about 4 bytes per triangle corner of
// scratch memory, plus 4 per vertex and thread (8 threads at most) and 8 per edge between blocks of 32768 vertices.
// Throws InvalidInput("triangles") when a triangle uses a vertex index >= vertices.size() (the lowest such triangle).
MeshReport check_mesh(const Mesh& mesh);
// The same report, bit for bit whatever the threads, with the work spread in blocks over up to `threads` (>= 1)
// threads; throws Cancelled between blocks when `control` fires. `below_degrees` > 0 also counts the triangles with an
// angle below it (MeshReport::triangles_below_angle).
MeshReport check_mesh(const Mesh& mesh, int threads, const RunControl& control = {}, double below_degrees = 0.0);

}  // namespace surfacer
