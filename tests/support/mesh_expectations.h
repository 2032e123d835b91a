// Expectations on meshes shared by the test binaries: the properties of check_mesh's report as one gtest predicate
// that names every property that does not hold, the same for a mesh file, unit outward normals, and decoding with
// Debian's draco_decoder. Use with EXPECT_TRUE / ASSERT_TRUE.
#pragma once

#include <gtest/gtest.h>

#include <array>
#include <filesystem>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_checks.h"
#include "core/mesh/quantization.h"

namespace surfacer::testing {

// The mesh's triangles as sorted triples of grid points (each in its smallest rotation, so the orientation is kept):
// equal for two meshes with the same quantized surface whatever their vertex and corner order. Triangles with a
// repeated index are left out.
std::vector<std::array<std::array<std::uint32_t, 3>, 3>> quantized_triangles(const Mesh& m,
                                                                             const QuantizationGrid& grid);

// Every topological figure of two reports is the same (closed, manifold, oriented, Euler, components, boundary and
// non-manifold edges, valences); `what` names the pair in failures.
void expect_same_topology(const MeshReport& a, const MeshReport& b, const std::string& what);

// What a test may require of a mesh; combine with |.
enum MeshProperty : unsigned {
  kClosed = 1u << 0,                 // no boundary edges
  kOpen = 1u << 1,                   // some boundary edges
  kEdgeManifold = 1u << 2,           // no edge with more than two triangles
  kVertexManifold = 1u << 3,         // every vertex's triangles form one fan
  kOriented = 1u << 4,               // every interior edge is traversed once in each direction
  kNoDegenerateTriangles = 1u << 5,  // no repeated index, no zero area
  kPositiveVolume = 1u << 6,         // encloses a positive signed volume (outward-oriented when closed)
};

// A closed, edge- and vertex-manifold, consistently oriented mesh.
inline constexpr unsigned kClosedManifold = kClosed | kEdgeManifold | kVertexManifold | kOriented;
// The same with a boundary (a surface cut off by the polygonization bounds, a disk).
inline constexpr unsigned kOpenManifold = kOpen | kEdgeManifold | kVertexManifold | kOriented;

// Success when `report` shows every property in `properties` and a minimum valence of at least `min_valence`;
// otherwise a failure naming each one that does not hold, with the report's figures.
::testing::AssertionResult mesh_has(const MeshReport& report, unsigned properties, int min_valence = 0);

// The mesh in `file` (read_mesh: .ply, .obj, .drc, .glb) has triangles and `properties`; its report in *report.
::testing::AssertionResult mesh_file_has(const std::filesystem::path& file, unsigned properties,
                                         MeshReport* report = nullptr);

// One normal per vertex, each of unit length within `length_tolerance`, and each at a cosine above `min_cosine`
// with the direction from `center` to its vertex (outward on a sphere around `center`).
::testing::AssertionResult normals_point_away_from(const Mesh& mesh, const Vec3& center, double length_tolerance,
                                                   double min_cosine);

// Debian's draco_decoder (an independent decoder) decodes `drc` into `ply`.
::testing::AssertionResult draco_decoder_decodes(const std::filesystem::path& drc, const std::filesystem::path& ply);

}  // namespace surfacer::testing
