#include "core/mesh/mesh_checks.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>

#include "core/util/errors.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

TEST(MeshChecks, UnitCube) {
  const MeshReport r = check_mesh(testing::unit_cube());
  EXPECT_TRUE(r.closed);
  EXPECT_TRUE(r.edge_manifold);
  EXPECT_TRUE(r.vertex_manifold);
  EXPECT_TRUE(r.oriented);
  EXPECT_EQ(r.euler_characteristic, 2);
  EXPECT_EQ(r.components, 1);
  EXPECT_EQ(r.boundary_edges, 0);
  EXPECT_EQ(r.non_manifold_edges, 0);
  EXPECT_EQ(r.degenerate_triangles, 0);
  EXPECT_NEAR(r.volume, 1.0, 1e-12);
  EXPECT_NEAR(r.area, 6.0, 1e-12);
  EXPECT_NEAR(r.min_angle_degrees, 45.0, 1e-9);
  EXPECT_NEAR(r.max_angle_degrees, 90.0, 1e-9);
  // Diagonals through corners 0 and 7: those have 6 neighbours, the other six corners 4.
  const std::vector<std::int64_t> expected = {0, 0, 0, 0, 6, 0, 2};
  EXPECT_EQ(r.valence_histogram, expected);
  EXPECT_EQ(r.min_valence, 4);
  EXPECT_EQ(r.max_valence, 6);
}

TEST(MeshChecks, IcosphereValences) {
  const Mesh m = testing::icosphere(2);
  const MeshReport r = check_mesh(m);
  EXPECT_TRUE(r.closed && r.edge_manifold && r.vertex_manifold && r.oriented);
  EXPECT_EQ(r.euler_characteristic, 2);
  ASSERT_EQ(r.valence_histogram.size(), 7u);
  EXPECT_EQ(r.valence_histogram[5], 12);
  EXPECT_EQ(r.valence_histogram[6], static_cast<std::int64_t>(m.vertices.size()) - 12);
  EXPECT_EQ(r.min_valence, 5);
  EXPECT_EQ(r.max_valence, 6);
  EXPECT_GT(r.volume, 0.9 * testing::sphere_volume(1.0));
  EXPECT_LT(r.volume, testing::sphere_volume(1.0));
}

TEST(MeshChecks, TorusHasEulerZero) {
  const MeshReport r = check_mesh(testing::torus_mesh(1.0, 0.3, 24, 12));
  EXPECT_TRUE(r.closed && r.edge_manifold && r.vertex_manifold && r.oriented);
  EXPECT_EQ(r.euler_characteristic, 0);
  EXPECT_EQ(r.components, 1);
  EXPECT_GT(r.volume, 0.0);
  const double exact = testing::torus_volume(1.0, 0.3);
  EXPECT_NEAR(r.volume, exact, 0.07 * exact);  // inscribed polygons: -5.6%
}

TEST(MeshChecks, OpenSquare) {
  const MeshReport r = check_mesh(testing::open_square());
  EXPECT_FALSE(r.closed);
  EXPECT_TRUE(r.edge_manifold);
  EXPECT_TRUE(r.vertex_manifold);  // half-disks on the boundary
  EXPECT_TRUE(r.oriented);
  EXPECT_EQ(r.boundary_edges, 4);
  EXPECT_EQ(r.euler_characteristic, 1);
  EXPECT_NEAR(r.area, 1.0, 1e-12);
  EXPECT_NEAR(r.volume, 0.0, 1e-12);
}

TEST(MeshChecks, NonManifoldEdge) {
  const MeshReport r = check_mesh(testing::non_manifold_edge());
  EXPECT_FALSE(r.edge_manifold);
  EXPECT_FALSE(r.vertex_manifold);
  EXPECT_FALSE(r.oriented);
  EXPECT_EQ(r.non_manifold_edges, 1);
  EXPECT_EQ(r.boundary_edges, 6);
  EXPECT_EQ(r.components, 1);
}

TEST(MeshChecks, BowtieIsNotVertexManifold) {
  const MeshReport r = check_mesh(testing::bowtie());
  EXPECT_TRUE(r.edge_manifold);
  EXPECT_FALSE(r.vertex_manifold);
  EXPECT_TRUE(r.oriented);
  EXPECT_FALSE(r.closed);
  EXPECT_EQ(r.components, 1);
  EXPECT_EQ(r.valence_histogram[6], 1);  // the shared vertex
}

TEST(MeshChecks, TetrahedraTouchingAtAVertex) {
  const MeshReport r = check_mesh(testing::double_tetrahedron());
  EXPECT_TRUE(r.closed);
  EXPECT_TRUE(r.edge_manifold);
  EXPECT_FALSE(r.vertex_manifold);
  EXPECT_TRUE(r.oriented);
  EXPECT_GT(r.volume, 0.0);
  EXPECT_EQ(r.euler_characteristic, 3);  // 7 - 12 + 8: one vertex short of two spheres
}

TEST(MeshChecks, FlippedTriangleIsNotOriented) {
  const MeshReport r = check_mesh(testing::flipped_triangle());
  EXPECT_TRUE(r.closed);
  EXPECT_TRUE(r.edge_manifold);
  EXPECT_TRUE(r.vertex_manifold);
  EXPECT_FALSE(r.oriented);
}

TEST(MeshChecks, DegenerateTriangles) {
  Mesh m = testing::unit_cube();
  m.triangles.push_back({0, 0, 1});  // repeated index: counted, otherwise ignored
  m.vertices.emplace_back(0.5, 0.0, 0.0);
  m.vertices.emplace_back(0.25, 0.0, 0.0);
  m.triangles.push_back({8, 9, 0});  // collinear: zero area
  const MeshReport r = check_mesh(m);
  EXPECT_EQ(r.degenerate_triangles, 2);
  EXPECT_NEAR(r.min_angle_degrees, 45.0, 1e-9);  // angles skip degenerate triangles
}

TEST(MeshChecks, ComponentsAndUnreferencedVertices) {
  Mesh a = testing::icosphere(1);
  const Mesh b = testing::icosphere(1, 0.5, Vec3(3, 0, 0));
  const auto offset = static_cast<std::uint32_t>(a.vertices.size());
  a.vertices.emplace_back(10, 10, 10);  // unreferenced: not counted anywhere
  for (const Vec3& p : b.vertices) a.vertices.push_back(p);
  for (Triangle t : b.triangles) a.triangles.push_back({t[0] + offset + 1, t[1] + offset + 1, t[2] + offset + 1});
  const MeshReport r = check_mesh(a);
  EXPECT_EQ(r.components, 2);
  EXPECT_EQ(r.euler_characteristic, 4);
  EXPECT_TRUE(r.closed && r.vertex_manifold && r.oriented);
}

TEST(MeshChecks, EmptyMesh) {
  const MeshReport r = check_mesh(Mesh{});
  EXPECT_EQ(r.components, 0);
  EXPECT_EQ(r.euler_characteristic, 0);
  EXPECT_TRUE(r.valence_histogram.empty());
  EXPECT_EQ(r.area, 0.0);
}

TEST(MeshChecks, OutOfRangeIndexThrows) {
  Mesh m = testing::unit_cube();
  m.triangles.push_back({0, 1, 8});
  try {
    check_mesh(m);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
    EXPECT_EQ(e.field(), "triangles");
  }
}

TEST(MeshChecks, MillionTrianglesQuickly) {
  const Mesh m = testing::icosphere(8);  // 1.3 M triangles
  const auto start = std::chrono::steady_clock::now();
  const MeshReport r = check_mesh(m);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_TRUE(r.closed && r.vertex_manifold && r.oriented);
  EXPECT_EQ(r.euler_characteristic, 2);
#ifdef NDEBUG
  EXPECT_LT(seconds, 2.0);  // ~0.15 s expected in Release; generous for loaded machines
#else
  EXPECT_LT(seconds, 20.0);  // Debug / sanitizer builds
#endif
  RecordProperty("seconds", std::to_string(seconds));
}

}  // namespace
}  // namespace surfacer
