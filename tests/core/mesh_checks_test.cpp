#include "core/mesh/mesh_checks.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <random>
#include <set>

#include "core/mesh/mesh_repair.h"
#include "core/util/errors.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using testing::expect_same_topology;

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

// Triangles with an angle below a threshold, counted as a plain loop over the angles counts them (zero-area ones
// included, repeated-index ones not), for thresholds over the whole range, on a jittered sphere of several blocks,
// whatever the threads; nothing is counted without a threshold.
TEST(MeshChecks, TrianglesBelowAnAngle) {
  Mesh m = testing::icosphere(6);
  std::mt19937 random(5);
  std::uniform_real_distribution<double> jitter(-0.004, 0.004);
  for (Vec3& v : m.vertices) v += Vec3(jitter(random), jitter(random), jitter(random));
  m.triangles.push_back({0, 0, 1});  // repeated index
  m.vertices.emplace_back(m.vertices[0] + Vec3(1, 0, 0));
  m.vertices.emplace_back(m.vertices[0] + Vec3(2, 0, 0));
  const auto n = static_cast<std::uint32_t>(m.vertices.size());
  m.triangles.push_back({n - 2, n - 1, 0});  // collinear: zero area
  std::vector<double> smallest;
  for (std::size_t t = 0; t + 2 < m.triangles.size(); ++t) {
    const Triangle& f = m.triangles[t];
    smallest.push_back(min_angle_degrees(m.vertices[f[0]], m.vertices[f[1]], m.vertices[f[2]]));
  }
  EXPECT_EQ(check_mesh(m, 2).triangles_below_angle, 0);
  const auto [lowest, highest] = std::minmax_element(smallest.begin(), smallest.end());
  for (const double threshold : {0.5, *lowest + 1e-6, 20.0, 40.0, 50.0, *highest + 1e-6, 90.0}) {
    SCOPED_TRACE(threshold);
    const auto expected = std::count_if(smallest.begin(), smallest.end(), [&](double a) { return a < threshold; }) + 1;
    for (const int threads : {1, 3}) {
      EXPECT_EQ(check_mesh(m, threads, {}, threshold).triangles_below_angle, expected);
    }
  }
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

// Bad indices far apart (in different blocks, and in different threads' shares of the triangles): the error names
// the lowest triangle, whatever the threads.
TEST(MeshChecks, OutOfRangeIndexNamesTheFirstBadTriangleWhateverTheThreads) {
  const Mesh sphere = testing::icosphere(7);  // 327680 triangles: 5 blocks
  const auto nv = static_cast<std::uint32_t>(sphere.vertices.size());
  const std::size_t nf = sphere.triangles.size();
  for (const std::vector<std::size_t>& bad : std::vector<std::vector<std::size_t>>{
           {nf - 1}, {nf / 2, nf - 1}, {nf / 3, 2 * nf / 3}, {70000, 5, 300000}, {0}}) {
    Mesh m = sphere;
    for (std::size_t t : bad) m.triangles[t][t % 3] = nv + static_cast<std::uint32_t>(t);
    const std::size_t first = *std::min_element(bad.begin(), bad.end());
    for (int threads : {1, 2, 3, 8}) {
      SCOPED_TRACE("first bad " + std::to_string(first) + ", " + std::to_string(threads) + " threads");
      try {
        check_mesh(m, threads);
        ADD_FAILURE() << "no error";
      } catch (const Error& e) {
        EXPECT_EQ(e.field(), "triangles");
        EXPECT_NE(std::string(e.what()).find("triangle " + std::to_string(first) + " uses vertex " +
                                             std::to_string(nv + first)),
                  std::string::npos)
            << e.what();
      }
    }
  }
}

// A large closed mesh (1.3 M triangles, 20 blocks of vertices): its speed is measured by bench/service_bench.
TEST(MeshChecks, MillionTriangles) {
  const Mesh m = testing::icosphere(8);
  for (int threads : {1, 3}) {
    const MeshReport r = check_mesh(m, threads);
    EXPECT_TRUE(r.closed && r.vertex_manifold && r.oriented);
    EXPECT_EQ(r.euler_characteristic, 2);
    EXPECT_EQ(r.components, 1);
    EXPECT_EQ(r.min_valence, 5);
    EXPECT_EQ(r.max_valence, 6);
  }
}

// A plain reference for the topology (edge map, per-vertex link), to compare the fast paths against.
MeshReport reference_topology(const Mesh& m) {
  MeshReport r;
  struct EdgeUse {
    int count = 0;
    int forward = 0;  // uses from the smaller vertex to the larger
  };
  std::map<std::pair<std::uint32_t, std::uint32_t>, EdgeUse> edges;
  std::vector<std::set<std::uint32_t>> neighbours(m.vertices.size());
  std::vector<std::vector<std::pair<std::uint32_t, std::uint32_t>>> links(m.vertices.size());
  std::int64_t faces = 0;
  for (const Triangle& t : m.triangles) {
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) continue;
    ++faces;
    for (int c = 0; c < 3; ++c) {
      const std::uint32_t u = t[c], w = t[(c + 1) % 3];
      EdgeUse& e = edges[{std::min(u, w), std::max(u, w)}];
      ++e.count;
      e.forward += u < w;
      neighbours[u].insert(w);
      neighbours[w].insert(u);
      links[t[c]].push_back({t[(c + 1) % 3], t[(c + 2) % 3]});
    }
  }
  std::vector<std::uint32_t> parent(m.vertices.size());
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t x) {
    while (parent[x] != x) x = parent[x];
    return x;
  };
  r.oriented = true;
  for (const auto& [key, use] : edges) {
    parent[find(key.first)] = find(key.second);
    if (use.count == 1) ++r.boundary_edges;
    if (use.count > 2) ++r.non_manifold_edges;
    if (use.count > 2 || (use.count == 2 && use.forward != 1)) r.oriented = false;
  }
  std::int64_t referenced = 0;
  bool fans = true;
  r.min_valence = 0;
  for (std::size_t v = 0; v < m.vertices.size(); ++v) {
    if (links[v].empty()) continue;
    ++referenced;
    if (find(static_cast<std::uint32_t>(v)) == v) ++r.components;
    const int valence = static_cast<int>(neighbours[v].size());
    if (r.valence_histogram.size() <= static_cast<std::size_t>(valence)) r.valence_histogram.resize(valence + 1);
    ++r.valence_histogram[valence];
    r.min_valence = referenced == 1 ? valence : std::min(r.min_valence, valence);
    r.max_valence = std::max(r.max_valence, valence);
    // One fan: the link (neighbours joined by one edge per triangle) is connected, every neighbour in <= 2 triangles.
    std::map<std::uint32_t, int> uses;
    std::map<std::uint32_t, std::uint32_t> link_parent;
    std::function<std::uint32_t(std::uint32_t)> link_find = [&](std::uint32_t x) {
      return link_parent[x] == x ? x : link_find(link_parent[x]);
    };
    for (auto [a, b] : links[v]) {
      ++uses[a];
      ++uses[b];
      link_parent.emplace(a, a);
      link_parent.emplace(b, b);
    }
    for (auto [a, b] : links[v]) link_parent[link_find(a)] = link_find(b);
    std::set<std::uint32_t> roots;
    for (const auto& [w, n] : uses) {
      roots.insert(link_find(w));
      if (n > 2) fans = false;
    }
    if (roots.size() != 1) fans = false;
  }
  r.closed = r.boundary_edges == 0;
  r.edge_manifold = r.non_manifold_edges == 0;
  r.vertex_manifold = fans && r.edge_manifold;
  r.euler_characteristic = referenced - static_cast<std::int64_t>(edges.size()) + faces;
  return r;
}

// Meshes with every kind of defect, from clean to badly broken: triangles removed (boundaries), flipped
// (misoriented), duplicated or sharing an edge with a third (non-manifold), glued at a vertex (bowties).
std::vector<std::pair<std::string, Mesh>> defective_meshes() {
  std::vector<std::pair<std::string, Mesh>> out = {{"cube", testing::unit_cube()},
                                                   {"torus", testing::torus_mesh(1.0, 0.3, 24, 12)},
                                                   {"square", testing::open_square()},
                                                   {"non-manifold edge", testing::non_manifold_edge()},
                                                   {"bowtie", testing::bowtie()},
                                                   {"double tetrahedron", testing::double_tetrahedron()},
                                                   {"flipped", testing::flipped_triangle()},
                                                   {"empty", Mesh{}}};
  std::mt19937 rng(7);
  for (int subdivisions = 0; subdivisions <= 4; ++subdivisions) {
    for (double rate : {0.0, 0.001, 0.01, 0.1}) {
      Mesh m = testing::icosphere(subdivisions);
      std::uniform_real_distribution<double> u(0.0, 1.0);
      std::uniform_int_distribution<std::uint32_t> vertex(0, static_cast<std::uint32_t>(m.vertices.size() - 1));
      std::vector<Triangle> triangles;
      for (Triangle t : m.triangles) {
        const double x = u(rng);
        if (x < rate) continue;                                     // removed
        if (x < 2 * rate) std::swap(t[1], t[2]);                    // flipped
        if (x < 3 * rate && x >= 2 * rate) triangles.push_back(t);  // duplicated
        if (x < 4 * rate && x >= 3 * rate) t[0] = vertex(rng);      // rewired (bowties, repeats)
        if (x < 5 * rate && x >= 4 * rate) triangles.push_back({t[0], t[1], vertex(rng)});  // a third triangle
        triangles.push_back(t);
      }
      m.triangles = std::move(triangles);
      out.emplace_back("icosphere(" + std::to_string(subdivisions) + ") defects " + std::to_string(rate), m);
    }
  }
  return out;
}

TEST(MeshChecks, TopologyMatchesAPlainReferenceOnDefectiveMeshes) {
  for (const auto& [name, mesh] : defective_meshes()) {
    expect_same_topology(check_mesh(mesh), reference_topology(mesh), name);
  }
}

// Components and topology do not depend on the vertex order: disjoint spheres (several blocks of vertices) with their
// vertices in creation order, then randomly permuted with their triangles (most edges then join different blocks), on
// 1 to 4 threads, give the report of the plain reference.
TEST(MeshChecks, ComponentsWhateverTheVertexOrder) {
  std::mt19937 rng(11);
  for (int spheres : {1, 4, 7}) {
    Mesh m;
    for (int k = 0; k < spheres; ++k) {
      const Mesh s = testing::icosphere(k % 2 == 0 ? 5 : 4);  // 10242 or 2562 vertices
      const auto base = static_cast<std::uint32_t>(m.vertices.size());
      for (const Vec3& v : s.vertices) m.vertices.push_back(v + Vec3(3.0 * k, 0.0, 0.0));
      for (const Triangle& t : s.triangles) m.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
    }
    Mesh shuffled = m;
    std::vector<std::uint32_t> new_of_old(m.vertices.size());
    std::iota(new_of_old.begin(), new_of_old.end(), 0u);
    std::shuffle(new_of_old.begin(), new_of_old.end(), rng);
    for (std::size_t v = 0; v < m.vertices.size(); ++v) shuffled.vertices[new_of_old[v]] = m.vertices[v];
    for (Triangle& t : shuffled.triangles) {
      for (std::uint32_t& v : t) v = new_of_old[v];
    }
    std::shuffle(shuffled.triangles.begin(), shuffled.triangles.end(), rng);
    const MeshReport reference = reference_topology(m);
    EXPECT_EQ(reference.components, spheres);
    for (const Mesh* mesh : {&m, &shuffled}) {
      const std::string name = std::to_string(spheres) + (mesh == &m ? " spheres" : " spheres, shuffled");
      for (int threads : {1, 2, 4}) {
        expect_same_topology(check_mesh(*mesh, threads), reference,
                             name + " on " + std::to_string(threads) + " threads");
      }
    }
  }
}

TEST(MeshChecks, SameBitsWhateverTheThreads) {
  auto meshes = defective_meshes();
  meshes.emplace_back("icosphere(7)", testing::icosphere(7));  // several blocks of triangles and vertices
  for (const auto& [name, mesh] : meshes) {
    SCOPED_TRACE(name);
    const MeshReport one = check_mesh(mesh);
    for (int threads : {2, 3, 8}) {
      const MeshReport r = check_mesh(mesh, threads);
      expect_same_topology(r, one, name + " on " + std::to_string(threads) + " threads");
      EXPECT_EQ(r.area, one.area);
      EXPECT_EQ(r.volume, one.volume);
      EXPECT_EQ(r.min_angle_degrees, one.min_angle_degrees);
      EXPECT_EQ(r.max_angle_degrees, one.max_angle_degrees);
      EXPECT_EQ(r.degenerate_triangles, one.degenerate_triangles);
    }
  }
}

TEST(MeshChecks, CancelledBetweenBlocks) {
  const Mesh m = testing::icosphere(6);
  CancelToken token;
  token.cancel();
  RunControl control;
  control.cancel = &token;
  EXPECT_THROW(check_mesh(m, 2, control), Error);
}

}  // namespace
}  // namespace surfacer
