#include "core/mesh/mesh_repair.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>
#include <set>

#include "core/mesh/grid_cleanup.h"
#include "core/mesh/mesh_checks.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

std::int64_t count_below(const Mesh& m, double degrees) {
  std::int64_t n = 0;
  for (const Triangle& t : m.triangles) {
    n += min_angle_degrees(m.vertices[t[0]], m.vertices[t[1]], m.vertices[t[2]]) < degrees;
  }
  return n;
}

// Triangles whose corners, on the grid, are collinear: zero area once decoded (up to float rounding).
std::int64_t count_degenerate_on(const Mesh& m, const QuantizationGrid& grid) {
  std::int64_t n = 0;
  for (const Triangle& t : m.triangles) {
    Eigen::Matrix<std::int64_t, 3, 1> q[3];
    for (int k = 0; k < 3; ++k) {
      const auto g = grid.quantize(m.vertices[t[k]]);
      q[k] = Eigen::Matrix<std::int64_t, 3, 1>(g[0], g[1], g[2]);
    }
    n += (q[1] - q[0]).cross(q[2] - q[0]).isZero();
  }
  return n;
}

// Triangles (u, v, x) of the mesh, one per directed edge u -> v.
struct Corner {
  std::uint32_t u, v, x;
};
std::vector<Corner> corners(const Mesh& m) {
  std::vector<Corner> out;
  for (const Triangle& t : m.triangles) {
    for (int k = 0; k < 3; ++k) out.push_back({t[k], t[(k + 1) % 3], t[(k + 2) % 3]});
  }
  return out;
}

// A sphere with `count` slivers made by moving vertices: caps (a vertex pushed onto the middle of its opposite edge)
// and needles (a vertex pulled next to a neighbour), each `closeness` of the edge length away, with no two
// disturbances sharing a triangle.
Mesh sphere_with_slivers(int seed, int count, double closeness, bool caps, bool needles) {
  Mesh m = testing::icosphere(3);
  std::mt19937 rng(static_cast<unsigned>(seed));
  std::vector<Corner> all = corners(m);
  std::shuffle(all.begin(), all.end(), rng);
  std::vector<std::set<std::uint32_t>> ring(m.vertices.size());
  for (const Triangle& t : m.triangles) {
    for (int k = 0; k < 3; ++k) {
      ring[t[k]].insert(t[(k + 1) % 3]);
      ring[t[k]].insert(t[(k + 2) % 3]);
    }
  }
  std::vector<bool> used(m.vertices.size(), false);
  auto claim = [&](std::uint32_t v) {
    for (const std::uint32_t w : ring[v]) {
      for (const std::uint32_t y : ring[w]) used[y] = true;
      used[w] = true;
    }
    used[v] = true;
  };
  int made = 0;
  for (const Corner& c : all) {
    if (made == count) break;
    if (used[c.u] || used[c.v] || used[c.x]) continue;
    const bool cap = caps && (!needles || made % 2 == 0);
    if (cap) {
      const Vec3 mid = 0.5 * (m.vertices[c.u] + m.vertices[c.v]);
      m.vertices[c.x] = mid + closeness * (m.vertices[c.x] - mid);
    } else {
      m.vertices[c.v] = m.vertices[c.u] + closeness * (m.vertices[c.v] - m.vertices[c.u]);
    }
    claim(c.u);
    claim(c.v);
    claim(c.x);
    ++made;
  }
  EXPECT_EQ(made, count);
  return m;
}

// Every vertex of `after` is a vertex of `before`, in the same order (repairs never move a vertex).
bool vertices_are_a_subsequence(const Mesh& after, const Mesh& before) {
  std::size_t j = 0;
  for (const Vec3& v : after.vertices) {
    while (j < before.vertices.size() && before.vertices[j] != v) ++j;
    if (j == before.vertices.size()) return false;
    ++j;
  }
  return true;
}

TEST(MeshRepair, MinAngleOfKnownTriangles) {
  EXPECT_NEAR(min_angle_degrees(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0.5, std::sqrt(0.75), 0)), 60.0, 1e-9);
  EXPECT_NEAR(min_angle_degrees(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)), 45.0, 1e-9);
  EXPECT_NEAR(min_angle_degrees(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0.5, 0.01, 0)), std::atan(0.02) * 180 / M_PI, 1e-9);
  EXPECT_EQ(min_angle_degrees(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(2, 0, 0)), 0.0);
  EXPECT_EQ(min_angle_degrees(Vec3(0, 0, 0), Vec3(0, 0, 0), Vec3(2, 1, 0)), 0.0);
}

// The repair's candidates are exactly the triangles whose smallest angle (min_angle_degrees) is below the threshold,
// also within 1e-7 degrees of it, at any corner and orientation, for thresholds across the allowed range.
TEST(MeshRepair, CandidatesAreExactlyTheTrianglesBelowTheThreshold) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (double threshold : {0.5, 1.0, 7.0, 20.0, 30.0}) {
    Mesh m;
    for (int i = 0; i < 600; ++i) {
      // An isosceles-free triangle whose smallest angle, at a random corner, is the threshold plus a small offset.
      const double offsets[] = {-1e-3, -1e-7, 1e-7, 1e-3, 1.0, -0.5 * threshold};
      const double angle = (threshold + offsets[i % 6]) * M_PI / 180.0;
      const double length = 1.0 + 0.5 * std::abs(unit(rng));
      const Vec3 origin(unit(rng), unit(rng), unit(rng));
      const Eigen::Matrix3d rotation =
          Eigen::AngleAxisd(M_PI * unit(rng), Vec3(unit(rng), unit(rng), 1.0).normalized()).toRotationMatrix();
      // Corner at the origin with the smallest angle between edges of lengths 1 and `length` (> 1 keeps the other
      // angles larger as long as the angle stays below 60 degrees).
      const Vec3 a = origin, b = origin + rotation * Vec3(1.0, 0.0, 0.0),
                 c = origin + rotation * (length * Vec3(std::cos(angle), std::sin(angle), 0.0));
      const auto base = static_cast<std::uint32_t>(m.vertices.size());
      m.vertices.insert(m.vertices.end(), {a, b, c});
      const std::uint32_t k = static_cast<std::uint32_t>(i % 3);  // which corner comes first
      const std::array<std::uint32_t, 3> order{base + k, base + (k + 1) % 3, base + (k + 2) % 3};
      m.triangles.push_back(i % 2 == 0 ? Triangle{order[0], order[1], order[2]}
                                       : Triangle{order[0], order[2], order[1]});
    }
    Mesh repaired = m;
    const SliverReport r = repair_slivers(repaired, {.min_angle_degrees = threshold, .max_passes = 0});
    EXPECT_EQ(r.candidates, count_below(m, threshold)) << threshold;
    EXPECT_GT(r.candidates, 0);
    EXPECT_LT(r.candidates, static_cast<std::int64_t>(m.triangles.size()));
  }
}

TEST(MeshRepair, LeavesAGoodMeshUntouched) {
  for (const Mesh& good : {testing::icosphere(3), testing::torus_mesh(1.0, 0.3)}) {
    Mesh m = good;
    const SliverReport r = repair_slivers(
        m, {.min_angle_degrees = 10.0, .grid = QuantizationGrid::of(Aabb{Vec3(-2, -2, -2), Vec3(2, 2, 2)}, 14)});
    EXPECT_EQ(r.candidates, 0);
    EXPECT_EQ(r.flips + r.collapses + r.remaining, 0);
    EXPECT_EQ(m.vertices, good.vertices);
    EXPECT_EQ(m.triangles, good.triangles);
  }
}

// Caps, needles and both mixed, over seeds and closeness: no sliver left, the mesh as closed, manifold and oriented as
// before with the same topology, vertices never moved, valence 5 kept, the volume nearly unchanged, and a second
// repair finds nothing.
TEST(MeshRepair, RemovesCapsAndNeedlesKeepingTheMeshValid) {
  struct Kind {
    bool caps, needles;
  };
  for (const Kind kind : {Kind{true, false}, Kind{false, true}, Kind{true, true}}) {
    for (const double closeness : {1e-2, 1e-4, 1e-7}) {
      for (int seed = 0; seed < 6; ++seed) {
        SCOPED_TRACE(::testing::Message() << "caps " << kind.caps << " needles " << kind.needles << " closeness "
                                          << closeness << " seed " << seed);
        const Mesh before = sphere_with_slivers(seed, 12, closeness, kind.caps, kind.needles);
        const MeshReport rb = check_mesh(before);
        ASSERT_GT(count_below(before, 1.0), 0);
        Mesh m = before;
        const SliverReport r = repair_slivers(m, SliverOptions());
        EXPECT_EQ(r.candidates, count_below(before, 1.0));
        EXPECT_EQ(r.remaining, 0);
        EXPECT_EQ(count_below(m, 1.0), 0);
        if (!kind.caps) {
          EXPECT_GT(r.collapses, 0);  // a needle's short edge can only be collapsed
        }
        if (!kind.needles) {
          EXPECT_GT(r.flips, 0);  // a cap is mostly flipped away
        }
        EXPECT_EQ(m.vertices.size(), before.vertices.size() - static_cast<std::size_t>(r.collapses));
        EXPECT_EQ(m.triangles.size(), before.triangles.size() - 2 * static_cast<std::size_t>(r.collapses));
        const MeshReport ra = check_mesh(m);
        EXPECT_TRUE(testing::mesh_has(ra, testing::kClosedManifold | testing::kPositiveVolume, 5));
        EXPECT_EQ(ra.euler_characteristic, rb.euler_characteristic);
        EXPECT_EQ(ra.components, 1);
        EXPECT_NEAR(ra.volume, rb.volume, 0.01 * rb.volume);
        EXPECT_TRUE(vertices_are_a_subsequence(m, before));
        const Mesh once = m;
        const SliverReport again = repair_slivers(m, SliverOptions());
        EXPECT_EQ(again.candidates, 0);
        EXPECT_EQ(m.triangles, once.triangles);
      }
    }
  }
}

SliverOptions with_threads(int threads) {
  SliverOptions o;
  o.threads = threads;
  return o;
}

TEST(MeshRepair, SameResultOnAnyThreadCount) {
  const Mesh before = sphere_with_slivers(11, 20, 1e-3, true, true);
  Mesh one = before, four = before;
  const SliverReport r1 = repair_slivers(one, with_threads(1));
  const SliverReport r4 = repair_slivers(four, with_threads(4));
  EXPECT_EQ(r1.flips, r4.flips);
  EXPECT_EQ(r1.collapses, r4.collapses);
  EXPECT_EQ(one.vertices, four.vertices);
  EXPECT_EQ(one.triangles, four.triangles);
}

// Normals, when present, stay with their vertices through collapses.
TEST(MeshRepair, NormalsFollowTheirVertices) {
  Mesh m = sphere_with_slivers(4, 10, 1e-5, false, true);
  m.normals.clear();
  for (const Vec3& v : m.vertices) m.normals.push_back(v.normalized());
  const SliverReport r = repair_slivers(m, {});
  ASSERT_GT(r.collapses, 0);
  ASSERT_EQ(m.normals.size(), m.vertices.size());
  for (std::size_t i = 0; i < m.vertices.size(); ++i) EXPECT_EQ(m.normals[i], m.vertices[i].normalized());
}

// Thin triangles (a few degrees, above any angle threshold) whose edges span a few steps of a coarse output grid
// quantize to collinear points (zero area once decoded); with the grid given, the repair removes every one.
TEST(MeshRepair, TrianglesDegenerateOnTheOutputGridAreRepaired) {
  std::int64_t found = 0;
  for (const int bits : {6, 7, 8}) {
    for (const double closeness : {0.02, 0.05, 0.1}) {
      for (int seed = 0; seed < 4; ++seed) {
        SCOPED_TRACE(::testing::Message() << "bits " << bits << " closeness " << closeness << " seed " << seed);
        const Mesh before = sphere_with_slivers(seed, 12, closeness, true, true);
        const QuantizationGrid grid = QuantizationGrid::of(Aabb{Vec3(-1, -1, -1), Vec3(1, 1, 1)}, bits);
        const std::int64_t degenerate_before = count_degenerate_on(before, grid);
        found += degenerate_before;
        Mesh m = before;
        const SliverReport r = repair_slivers(m, {.min_angle_degrees = 0.0, .grid = grid});
        EXPECT_EQ(r.candidates, degenerate_before);
        EXPECT_EQ(r.remaining, 0);
        EXPECT_EQ(count_degenerate_on(m, grid), 0);
        EXPECT_TRUE(testing::mesh_has(check_mesh(m), testing::kClosedManifold | testing::kPositiveVolume));
        EXPECT_TRUE(vertices_are_a_subsequence(m, before));
      }
    }
  }
  EXPECT_GT(found, 20);  // the inputs do have such triangles
}

// With an output grid, the angles are those a reader of the frame sees: of the corners as Draco decodes their grid
// points. Quantization moves a corner by up to half a step, so on grids where an edge spans 10-50 steps a triangle
// above the threshold in double can show one below it, and the reverse; the repair leaves none below it as shown.
TEST(MeshRepair, AnglesAreThoseOfTheDecodedGridPoints) {
  std::int64_t hidden = 0;  // triangles at or above the threshold in double, below it as shown on the grid
  for (const int bits : {7, 8, 9}) {
    for (const double threshold : {5.0, 10.0, 15.0}) {
      for (int seed = 0; seed < 3; ++seed) {
        SCOPED_TRACE(::testing::Message() << "bits " << bits << " threshold " << threshold << " seed " << seed);
        const Mesh before = sphere_with_slivers(seed, 12, 0.1, true, true);
        const QuantizationGrid grid = QuantizationGrid::of(Aabb{Vec3(-1, -1, -1), Vec3(1, 1, 1)}, bits);
        const auto decoded = [&](const Mesh& m) {
          Mesh out = m;
          snap_to_grid(out.vertices, grid);
          return out;
        };
        const Mesh shown_before = decoded(before);
        for (std::size_t t = 0; t < before.triangles.size(); ++t) {
          const Triangle& f = before.triangles[t];
          hidden +=
              min_angle_degrees(before.vertices[f[0]], before.vertices[f[1]], before.vertices[f[2]]) >= threshold &&
              min_angle_degrees(shown_before.vertices[f[0]], shown_before.vertices[f[1]], shown_before.vertices[f[2]]) <
                  threshold;
        }
        Mesh m = before;
        const SliverReport r = repair_slivers(m, {.min_angle_degrees = threshold, .grid = grid});
        EXPECT_EQ(r.candidates, count_below(shown_before, threshold));
        EXPECT_EQ(r.remaining, count_below(decoded(m), threshold));
        EXPECT_LE(r.remaining, r.candidates / 10);
        EXPECT_TRUE(testing::mesh_has(check_mesh(m), testing::kClosedManifold | testing::kPositiveVolume));
      }
    }
  }
  EXPECT_GT(hidden, 10);  // the grids do turn triangles below the threshold
}

// Many bad triangles side by side (a sphere whose vertices are pushed about along its surface, repaired at thresholds
// up to 30 degrees, with and without a grid): a repair in a pass removes triangles that the pass found bad earlier,
// which the next pass must not read. The mesh stays closed and manifold, and `remaining` counts what is bad at the end.
TEST(MeshRepair, CrowdedSliversOverSeveralPasses) {
  for (int seed = 0; seed < 6; ++seed) {
    for (const double threshold : {10.0, 20.0, 30.0}) {
      for (const bool on_grid : {false, true}) {
        SCOPED_TRACE(::testing::Message() << "seed " << seed << " threshold " << threshold << " grid " << on_grid);
        Mesh m = testing::icosphere(3);
        std::mt19937 rng(static_cast<unsigned>(seed));
        std::normal_distribution<double> jitter(0.0, 0.06);
        for (Vec3& v : m.vertices) v = (v + Vec3(jitter(rng), jitter(rng), jitter(rng))).normalized();
        SliverOptions o{.min_angle_degrees = threshold};
        if (on_grid) o.grid = QuantizationGrid::of(Aabb{Vec3(-1, -1, -1), Vec3(1, 1, 1)}, 9);
        const SliverReport r = repair_slivers(m, o);
        EXPECT_GT(r.candidates, 50);
        EXPECT_GT(r.collapses + r.flips, 0);
        Mesh shown = m;
        if (o.grid) snap_to_grid(shown.vertices, *o.grid);
        EXPECT_EQ(r.remaining, count_below(shown, threshold));
        EXPECT_TRUE(testing::mesh_has(check_mesh(m), testing::kClosedManifold | testing::kPositiveVolume));
      }
    }
  }
}

// The valence floor: a repair never takes a vertex at or above min_valence below it.
TEST(MeshRepair, KeepsTheValenceFloor) {
  for (int seed = 0; seed < 4; ++seed) {
    Mesh m = sphere_with_slivers(seed, 16, 1e-4, true, true);
    SliverOptions floor6;
    floor6.min_valence = 6;
    (void)repair_slivers(m, floor6);
    // icosphere vertices have valence 5 (twelve of them) or 6; those at 6 may not drop below it.
    const MeshReport r = check_mesh(m);
    EXPECT_TRUE(testing::mesh_has(r, testing::kClosedManifold));
    std::int64_t below_six = 0;
    for (std::size_t v = 0; v < std::min<std::size_t>(6, r.valence_histogram.size()); ++v) {
      below_six += r.valence_histogram[v];
    }
    EXPECT_LE(below_six, 12) << seed;
  }
}

// On an icosahedron every vertex has valence 5: every flip and collapse would take one below the floor. A needle there
// is repaired only by moving a vertex, and only where `place` allows it (here: back onto the sphere).
TEST(MeshRepair, MovesAVertexWhereTheValenceFloorBlocksEveryFlipAndCollapse) {
  for (const double closeness : {1e-2, 1e-4, 1e-6}) {
    for (std::uint32_t v = 0; v < 12; v += 5) {
      SCOPED_TRACE(::testing::Message() << "closeness " << closeness << ", vertex " << v);
      Mesh needle = testing::icosphere(0);
      const Triangle& t = *std::find_if(needle.triangles.begin(), needle.triangles.end(),
                                        [v](const Triangle& t) { return t[0] == v || t[1] == v || t[2] == v; });
      const std::uint32_t w = t[0] == v ? t[1] : t[0];
      needle.vertices[v] = (needle.vertices[w] + closeness * (needle.vertices[v] - needle.vertices[w])).normalized();
      ASSERT_GT(count_below(needle, 1.0), 0);

      Mesh fixed_in_place = needle;
      const SliverReport stuck = repair_slivers(fixed_in_place, {});
      EXPECT_EQ(stuck.flips + stuck.collapses + stuck.moves, 0);
      EXPECT_GT(stuck.remaining, 0);
      EXPECT_EQ(fixed_in_place.vertices, needle.vertices);

      SliverOptions refuse;
      refuse.place = [](std::uint32_t, Vec3&, const Vec3&) { return false; };
      Mesh refused = needle;
      EXPECT_GT(repair_slivers(refused, refuse).remaining, 0);
      EXPECT_EQ(refused.vertices, needle.vertices);

      SliverOptions on_sphere;
      on_sphere.place = [](std::uint32_t, Vec3& x, const Vec3& n) {
        EXPECT_NEAR(n.norm(), 1.0, 1e-12);
        x.normalize();
        return true;
      };
      Mesh moved = needle;
      const SliverReport r = repair_slivers(moved, on_sphere);
      EXPECT_EQ(r.remaining, 0);
      EXPECT_GT(r.moves, 0);
      EXPECT_EQ(count_below(moved, 1.0), 0);
      for (const Vec3& x : moved.vertices) EXPECT_NEAR(x.norm(), 1.0, 1e-12);
      const MeshReport report = check_mesh(moved);
      EXPECT_TRUE(testing::mesh_has(report, testing::kClosedManifold | testing::kPositiveVolume));
      EXPECT_EQ(report.min_valence, 5);
      EXPECT_EQ(moved.triangles, needle.triangles);  // no flip, no collapse
    }
  }
}

TEST(MeshRepair, StopsWhenCancelled) {
  Mesh m = sphere_with_slivers(2, 8, 1e-4, true, true);
  CancelToken token;
  token.cancel();
  RunControl control;
  control.cancel = &token;
  try {
    (void)repair_slivers(m, {}, control);
    ADD_FAILURE() << "not cancelled";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kCancelled);
  }
}

}  // namespace
}  // namespace surfacer
