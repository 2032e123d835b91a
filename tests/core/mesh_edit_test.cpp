#include "core/mesh/mesh_edit.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <set>
#include <vector>

#include "core/mesh/mesh_checks.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using testing::icosphere;
using testing::kClosedManifold;
using testing::mesh_has;
using testing::torus_mesh;

// The live triangles (the editor marks removed ones with kNone), for check_mesh.
Mesh live(const Mesh& mesh) {
  Mesh out;
  out.vertices = mesh.vertices;
  for (const Triangle& t : mesh.triangles) {
    if (t[0] != MeshEditor::kNone) out.triangles.push_back(t);
  }
  return out;
}

// Brute force over the flat list: v's distinct neighbours, sorted.
std::vector<std::uint32_t> neighbours_of(const Mesh& mesh, std::uint32_t v) {
  std::set<std::uint32_t> out;
  for (const Triangle& t : mesh.triangles) {
    if (std::find(t.begin(), t.end(), v) == t.end()) continue;
    for (const std::uint32_t w : t) {
      if (w != v) out.insert(w);
    }
  }
  return {out.begin(), out.end()};
}

std::uint32_t third(const Triangle& t, std::uint32_t a, std::uint32_t b) {
  for (const std::uint32_t w : t) {
    if (w != a && w != b) return w;
  }
  return MeshEditor::kNone;
}

// An icosphere with every vertex moved off the sphere a little: no symmetry for the random edits to lean on.
Mesh jittered_sphere() {
  Mesh m = icosphere(3);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> d(-0.02, 0.02);
  for (Vec3& p : m.vertices) p += Vec3(d(rng), d(rng), d(rng));
  return m;
}

TEST(MeshEdit, EdgeKeyIsOnePerUndirectedEdge) {
  EXPECT_EQ(edge_key(3, 7), edge_key(7, 3));
  EXPECT_NE(edge_key(3, 7), edge_key(3, 8));
  EXPECT_NE(edge_key(1, 0x100000000ull - 1), edge_key(0, 0x100000000ull - 1));
  EXPECT_EQ(edge_key(2, 1), (std::uint64_t{1} << 32) | 2u);
}

TEST(MeshEdit, VertexTrianglesListsEveryCornerInIndexOrder) {
  const Mesh m = torus_mesh(1.0, 0.3, 12, 8);
  const VertexTriangles a = vertex_triangles(m.vertices.size(), m.triangles);
  ASSERT_EQ(a.offsets.size(), m.vertices.size() + 1);
  EXPECT_EQ(a.triangles.size(), 3 * m.triangles.size());
  for (std::uint32_t v = 0; v < m.vertices.size(); ++v) {
    std::vector<std::uint32_t> expected;
    for (std::uint32_t t = 0; t < m.triangles.size(); ++t) {
      if (std::find(m.triangles[t].begin(), m.triangles[t].end(), v) != m.triangles[t].end()) expected.push_back(t);
    }
    const auto row = a.of(v);
    EXPECT_EQ(std::vector<std::uint32_t>(row.begin(), row.end()), expected) << "vertex " << v;
  }
}

// Random flips and collapses through the editor: every one it allows keeps the mesh closed, manifold and oriented
// with its Euler characteristic; it allows exactly the flips whose new edge is new and the collapses whose ends share
// exactly the two opposite vertices (the link condition); its queries agree with the flat list after every edit.
void random_edits(Mesh mesh, unsigned seed) {
  const MeshReport before = check_mesh(mesh);
  ASSERT_TRUE(mesh_has(before, kClosedManifold));
  const VertexTriangles adjacency = vertex_triangles(mesh.vertices.size(), mesh.triangles);
  MeshEditor editor(mesh.triangles, adjacency, mesh.vertices.size());
  std::mt19937 rng(seed);
  int flips = 0, collapses = 0, refused_flips = 0, refused_collapses = 0;
  for (int step = 0; step < 400; ++step) {
    const auto t = static_cast<std::uint32_t>(rng() % mesh.triangles.size());
    if (editor.removed(t)) continue;
    const Triangle tri = mesh.triangles[t];
    const int k = static_cast<int>(rng() % 3);
    const std::uint32_t u = tri[k], v = tri[(k + 1) % 3], x = tri[(k + 2) % 3];
    std::uint32_t y = MeshEditor::kNone, across = MeshEditor::kNone;
    for (std::uint32_t s = 0; s < mesh.triangles.size(); ++s) {
      const Triangle& q = mesh.triangles[s];
      for (int j = 0; j < 3; ++j) {
        if (q[j] == v && q[(j + 1) % 3] == u) {
          across = s;
          y = q[(j + 2) % 3];
        }
      }
    }
    ASSERT_NE(across, MeshEditor::kNone);
    const std::vector<std::uint32_t> nu = neighbours_of(mesh, u), nv = neighbours_of(mesh, v);
    if (rng() % 2 == 0) {
      const std::vector<std::uint32_t> nx = neighbours_of(mesh, x);
      const bool expected = !std::binary_search(nx.begin(), nx.end(), y);
      const std::optional<MeshEditor::Across> site = editor.flip_site(t, u, v);
      ASSERT_EQ(site.has_value(), expected) << "flip of (" << u << ", " << v << ")";
      if (!site) {
        ++refused_flips;
        continue;
      }
      EXPECT_EQ(site->triangle, across);
      EXPECT_EQ(site->vertex, y);
      editor.flip(t, u, v);
      EXPECT_EQ(mesh.triangles[t], (Triangle{u, y, x}));
      EXPECT_EQ(mesh.triangles[across], (Triangle{y, v, x}));
      ++flips;
    } else {
      std::vector<std::uint32_t> common;
      std::set_intersection(nu.begin(), nu.end(), nv.begin(), nv.end(), std::back_inserter(common));
      const bool expected = common == std::vector<std::uint32_t>{std::min(x, y), std::max(x, y)};
      const std::optional<MeshEditor::Across> site = editor.collapse_site(t, u, v);
      ASSERT_EQ(site.has_value(), expected) << "collapse of (" << u << ", " << v << ")";
      if (!site) {
        ++refused_collapses;
        continue;
      }
      EXPECT_EQ(site->triangle, across);
      EXPECT_EQ(third(mesh.triangles[across], u, v), y);
      editor.collapse(t, u, v);
      EXPECT_TRUE(editor.removed(t));
      EXPECT_TRUE(editor.removed(across));
      EXPECT_TRUE(neighbours_of(mesh, v).empty());
      ++collapses;
    }
    // The editor's view of the vertices it touched (loaded) and of one it did not matches the flat list.
    for (const std::uint32_t w : {u, x, y, static_cast<std::uint32_t>(rng() % mesh.vertices.size())}) {
      const std::vector<std::uint32_t> n = editor.neighbours(w);
      EXPECT_EQ(n, neighbours_of(mesh, w)) << "vertex " << w;
      if (n.empty()) continue;
      EXPECT_EQ(editor.triangle_count(w), n.size());
      EXPECT_EQ(editor.triangles_around(w).size(), n.size());
      EXPECT_EQ(editor.edge_triangle_count(w, n[0]), 2);
      EXPECT_FALSE(editor.on_boundary(w));
    }
    const MeshReport now = check_mesh(live(mesh));
    ASSERT_TRUE(mesh_has(now, kClosedManifold)) << "after step " << step;
    ASSERT_EQ(now.euler_characteristic, before.euler_characteristic);
  }
  EXPECT_GT(flips, 20);
  EXPECT_GT(collapses, 20);
  EXPECT_GT(refused_flips + refused_collapses, 0);
}

TEST(MeshEdit, RandomFlipsAndCollapsesOnASphereKeepItClosedManifoldOriented) { random_edits(icosphere(2), 1); }
TEST(MeshEdit, RandomFlipsAndCollapsesOnATorusKeepItClosedManifoldOriented) {
  random_edits(torus_mesh(1.0, 0.4, 16, 8), 2);
}
TEST(MeshEdit, RandomFlipsAndCollapsesOnAJitteredSphereKeepItClosedManifoldOriented) {
  random_edits(jittered_sphere(), 3);
}

TEST(MeshEdit, BoundaryEdgesAreCountedAndNeverFlipped) {
  Mesh m = testing::open_square();
  const VertexTriangles adjacency = vertex_triangles(m.vertices.size(), m.triangles);
  MeshEditor editor(m.triangles, adjacency, m.vertices.size());
  const Triangle t = m.triangles[0];
  int interior = 0;
  for (int k = 0; k < 3; ++k) {
    const std::uint32_t u = t[k], v = t[(k + 1) % 3];
    const int count = editor.edge_triangle_count(u, v);
    EXPECT_TRUE(count == 1 || count == 2);
    interior += count == 2;
    EXPECT_EQ(editor.across(0, u, v).has_value(), count == 2);
    EXPECT_EQ(editor.flip_site(0, u, v).has_value(), count == 2);  // the diagonal flips, a boundary edge never
    EXPECT_FALSE(editor.collapse_site(0, u, v).has_value());       // every vertex is on the boundary
    EXPECT_TRUE(editor.on_boundary(u));
    EXPECT_EQ(editor.edge_triangle_count(u, v), count);  // the same once loaded
  }
  EXPECT_EQ(interior, 1);
}

TEST(MeshEdit, AVertexAtANonManifoldEdgeIsLeftAlone) {
  Mesh m = testing::non_manifold_edge();  // three triangles on edge (0, 1)
  const VertexTriangles adjacency = vertex_triangles(m.vertices.size(), m.triangles);
  MeshEditor editor(m.triangles, adjacency, m.vertices.size());
  EXPECT_EQ(editor.neighbours(0).size(), 4u);  // queries still answer, from the flat list
  EXPECT_EQ(editor.edge_triangle_count(0, 1), 3);
  EXPECT_FALSE(editor.across(0, 0, 1).has_value());
  const std::vector<Triangle> before = m.triangles;
  for (std::uint32_t t = 0; t < before.size(); ++t) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_FALSE(editor.flip_site(t, before[t][k], before[t][(k + 1) % 3]).has_value());
      EXPECT_FALSE(editor.collapse_site(t, before[t][k], before[t][(k + 1) % 3]).has_value());
    }
  }
  EXPECT_EQ(editor.edge_triangle_count(0, 1), 3);  // vertex 0 unusable, its fan answered from the flat list
  EXPECT_EQ(m.triangles, before);
}

}  // namespace
}  // namespace surfacer
