#include "core/mesh/decimate.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <string>

#include "core/mesh/grid_cleanup.h"
#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_repair.h"
#include "core/particles/particle_surfacer.h"
#include "core/polygonize/polygonize.h"
#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "tests/support/error_expectations.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using testing::kClosedManifold;
using testing::mesh_has;

struct Case {
  std::string name;
  Mesh mesh;
  SurfacePointRule rule;
  std::vector<double> tolerances;
  FieldPtr field;  // kept alive for the rule
  std::vector<Vec3> particles;
};

// A jittered cubic lattice of nx x ny x nz particles at spacing d (jitter +-d/10, as bench/particles_bench's block).
std::vector<Vec3> block(int nx, int ny, int nz, double d, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-d / 10, d / 10);
  std::vector<Vec3> p;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) p.emplace_back(i * d + jitter(rng), j * d + jitter(rng), k * d + jitter(rng));
  return p;
}

// Balls of jittered lattice particles (radius 2-4 d) apart from each other: droplets.
std::vector<Vec3> droplets(double d, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Vec3> p;
  for (int k = 0; k < 8; ++k) {
    const Vec3 c = Vec3(k % 2, (k / 2) % 2, k / 4) * 12.0 * d;
    const double radius = d * (2.0 + 2.0 * u(rng));
    const int n = static_cast<int>(radius / d);
    for (int z = -n; z <= n; ++z)
      for (int y = -n; y <= n; ++y)
        for (int x = -n; x <= n; ++x) {
          const Vec3 q = c + Vec3(x, y, z) * d + (Vec3(u(rng), u(rng), u(rng)) - Vec3::Constant(0.5)) * (d / 3);
          if ((q - c).norm() <= radius) p.push_back(q);
        }
  }
  return p;
}

Case field_case(const std::string& name, FieldPtr field, Polygonizer method, int cells, double scale) {
  Case c{name, testing::polygonized(field, method, cells), {}, {}, field, {}};
  c.tolerances = {0.0, 0.001 * scale, 0.003 * scale, 0.01 * scale, 0.03 * scale};
  return c;
}

Case particle_case(const std::string& name, std::vector<Vec3> particles, double r_inner) {
  ParticleSurfacingOptions options;
  options.r_inner = r_inner;
  options.min_angle_degrees = 10.0;
  ParticleSurfacingStats stats;
  Case c{name, surface_particles(particles, {}, options, {}, &stats), {}, {}, nullptr, std::move(particles)};
  c.tolerances = {0.0, 0.03 * r_inner, 0.1 * r_inner, 0.3 * r_inner};
  return c;
}

std::vector<Case> cases() {
  std::vector<Case> out;
  out.push_back(field_case("sphere tiles", make_sphere(Vec3::Zero(), 1.0), Polygonizer::kTiles, 48, 1.0));
  out.push_back(
      field_case("torus cubes", make_torus(Vec3::Zero(), Vec3::UnitZ(), 1.0, 0.35), Polygonizer::kCubes, 64, 1.0));
  for (int cells : {48}) {
    out.push_back(field_case("gyroid tiles " + std::to_string(cells),
                             make_csg(CsgOp::kIntersection, {make_gyroid(1.0, 0.12), make_sphere(Vec3::Zero(), 1.5)}),
                             Polygonizer::kTiles, cells, 1.0));
  }
  out.push_back(particle_case("particle block", block(16, 10, 12, 0.01, 7), 0.006));
  out.push_back(particle_case("droplets", droplets(0.01, 3), 0.006));
  for (Case& c : out) {
    if (c.field) {
      c.rule = {};  // set per tolerance below
    } else {
      c.rule = particle_band_rule(c.particles, {}, 0.006, 0.012);
    }
  }
  return out;
}

// Squared distance from p to triangle (a, b, c): the nearest of the plane's foot (when inside) and the three edges.
double squared_distance(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const auto to_segment = [&](const Vec3& u, const Vec3& v) {
    const Vec3 e = v - u;
    const double t = std::clamp((p - u).dot(e) / std::max(e.squaredNorm(), 1e-300), 0.0, 1.0);
    return (u + t * e - p).squaredNorm();
  };
  double best = std::min({to_segment(a, b), to_segment(b, c), to_segment(c, a)});
  const Vec3 n = (b - a).cross(c - a);
  const double n2 = n.squaredNorm();
  if (n2 > 0.0) {
    const Vec3 foot = p - n * ((p - a).dot(n) / n2);
    if ((b - a).cross(foot - a).dot(n) >= 0.0 && (c - b).cross(foot - b).dot(n) >= 0.0 &&
        (a - c).cross(foot - c).dot(n) >= 0.0) {
      best = std::min(best, (foot - p).squaredNorm());
    }
  }
  return best;
}

// The largest distance from a vertex of `input`'s triangles to the triangles of `output` (the one-sided Hausdorff
// distance at the input's vertices), through a grid of cells of edge `cell` over the triangles' boxes grown by `reach`;
// a vertex with no triangle within `reach` counts as infinitely far.
double largest_vertex_distance(const Mesh& input, const Mesh& output, double reach) {
  Eigen::Array3d lo = Eigen::Array3d::Constant(1e300);
  for (const Vec3& p : input.vertices) lo = lo.min(p.array());
  double cell = reach;
  for (const Triangle& t : output.triangles) {
    for (int k = 0; k < 3; ++k) cell = std::max(cell, (output.vertices[t[k]] - output.vertices[t[(k + 1) % 3]]).norm());
  }
  const auto key = [&](const Eigen::Array3d& p) {
    const Eigen::Array3d c = ((p - lo) / cell).floor();
    return std::array<std::int64_t, 3>{static_cast<std::int64_t>(c[0]), static_cast<std::int64_t>(c[1]),
                                       static_cast<std::int64_t>(c[2])};
  };
  std::map<std::array<std::int64_t, 3>, std::vector<std::uint32_t>> cells;
  for (std::uint32_t t = 0; t < output.triangles.size(); ++t) {
    Eigen::Array3d a = Eigen::Array3d::Constant(1e300), b = -a;
    for (const std::uint32_t v : output.triangles[t]) {
      a = a.min(output.vertices[v].array());
      b = b.max(output.vertices[v].array());
    }
    const auto k0 = key(a - reach), k1 = key(b + reach);
    for (std::int64_t i = k0[0]; i <= k1[0]; ++i)
      for (std::int64_t j = k0[1]; j <= k1[1]; ++j)
        for (std::int64_t k = k0[2]; k <= k1[2]; ++k) cells[{i, j, k}].push_back(t);
  }
  std::vector<bool> used(input.vertices.size(), false);
  for (const Triangle& t : input.triangles) {
    for (const std::uint32_t v : t) used[v] = true;
  }
  double largest = 0.0;
  for (std::size_t v = 0; v < input.vertices.size(); ++v) {
    if (!used[v]) continue;
    const Vec3& p = input.vertices[v];
    double best = std::numeric_limits<double>::infinity();
    const auto found = cells.find(key(p.array()));
    if (found != cells.end()) {
      for (const std::uint32_t t : found->second) {
        const Triangle& tri = output.triangles[t];
        best = std::min(best,
                        squared_distance(p, output.vertices[tri[0]], output.vertices[tri[1]], output.vertices[tri[2]]));
      }
    }
    largest = std::max(largest, std::sqrt(best));
  }
  return largest;
}

TEST(Decimate, FewerTrianglesWithToleranceEveryVertexKeptEveryNewTriangleAcceptable) {
  for (Case& c : cases()) {
    SCOPED_TRACE(c.name);
    const MeshReport input = check_mesh(c.mesh);
    ASSERT_TRUE(mesh_has(input, kClosedManifold));
    std::map<std::array<double, 3>, std::uint32_t> index_of;
    for (std::uint32_t v = 0; v < c.mesh.vertices.size(); ++v) {
      const Vec3& p = c.mesh.vertices[v];
      index_of[{p.x(), p.y(), p.z()}] = v;
    }
    std::size_t previous = c.mesh.triangles.size() + 1;
    for (double tolerance : c.tolerances) {
      SCOPED_TRACE("tolerance " + std::to_string(tolerance));
      const SurfacePointRule rule = c.field ? zero_set_rule(*c.field, tolerance) : c.rule;
      DecimateStats stats;
      const Mesh out = decimate(c.mesh, {.tolerance = tolerance}, rule, {}, &stats);
      EXPECT_EQ(stats.triangles_before, c.mesh.triangles.size());
      EXPECT_EQ(stats.triangles_after, out.triangles.size());
      if (tolerance == 0.0) {
        EXPECT_EQ(out.vertices, c.mesh.vertices);
        EXPECT_EQ(out.triangles, c.mesh.triangles);
      }
      EXPECT_LE(out.triangles.size(), previous);
      previous = out.triangles.size();
      const MeshReport report = check_mesh(out);
      EXPECT_TRUE(mesh_has(report, kClosedManifold));
      EXPECT_EQ(report.components, input.components);
      EXPECT_EQ(report.euler_characteristic, input.euler_characteristic);
      EXPECT_GE(report.min_angle_degrees, std::min(10.0, input.min_angle_degrees) - 1e-9);
      // Every vertex is an input vertex, where it was: faithful when it was.
      std::size_t moved = 0, unfaithful = 0, unacceptable_triangles = 0;
      for (const Vec3& p : out.vertices) {
        if (!index_of.contains({p.x(), p.y(), p.z()})) ++moved;
        if (!c.field && !rule(p)) ++unfaithful;
      }
      EXPECT_EQ(moved, 0u);
      EXPECT_EQ(unfaithful, 0u);
      // Every triangle the decimation made has an acceptable centroid (those of the input are not ours to judge).
      std::map<std::array<std::uint32_t, 3>, int> input_triangles;
      for (const Triangle& t : c.mesh.triangles) input_triangles[{t[0], t[1], t[2]}] = 1;
      for (const Triangle& t : out.triangles) {
        const Vec3& a = out.vertices[t[0]];
        const Vec3& b = out.vertices[t[1]];
        const Vec3& d = out.vertices[t[2]];
        const auto orig = [&](const Vec3& p) { return index_of.at({p.x(), p.y(), p.z()}); };
        if (input_triangles.contains({orig(a), orig(b), orig(d)})) continue;
        if (!rule((a + b + d) / 3.0)) ++unacceptable_triangles;
      }
      EXPECT_EQ(unacceptable_triangles, 0u);
      // Every removed vertex stays within the tolerance of the decimated surface (measured to its triangles: the
      // nearest vertex bounds it from above only where the surface is flat).
      if (tolerance > 0.0) {
        EXPECT_LT(out.triangles.size(), c.mesh.triangles.size());
        EXPECT_LE(largest_vertex_distance(c.mesh, out, 2.0 * tolerance), tolerance * (1.0 + 1e-9));
      }
      // The target of particle frames: at TOL = 0.1 r_inner, at least 4x fewer triangles.
      if (!c.field && std::abs(tolerance - 0.1 * 0.006) < 1e-12) {
        EXPECT_GE(c.mesh.triangles.size(), 4 * out.triangles.size());
      }
      std::printf("%-18s tol %-8.4g triangles %8zu -> %8zu (%.2fx) min angle %.2f -> %.2f, %.3f s\n", c.name.c_str(),
                  tolerance, c.mesh.triangles.size(), out.triangles.size(),
                  static_cast<double>(c.mesh.triangles.size()) / std::max<std::size_t>(out.triangles.size(), 1),
                  input.min_angle_degrees, report.min_angle_degrees, stats.seconds);
    }
  }
}

// With the frame's grid, the angles a decimation keeps above its floor are those of the decoded corners: no triangle
// it makes has an angle below min_angle_degrees once snapped to the grid, from coarse grids (edges of a few steps) to
// fine ones, at floors of 10 and 20 degrees. Without the grid, coarse grids show such triangles.
TEST(Decimate, NewTrianglesKeepTheFloorOnTheFramesGrid) {
  std::size_t below_without_grid = 0;
  for (Case& c : cases()) {
    SCOPED_TRACE(c.name);
    const double tolerance = c.tolerances[2];
    const SurfacePointRule rule = c.field ? zero_set_rule(*c.field, tolerance) : c.rule;
    std::map<std::array<std::uint32_t, 3>, int> input_triangles;
    for (const Triangle& t : c.mesh.triangles) input_triangles[{t[0], t[1], t[2]}] = 1;
    std::map<std::array<double, 3>, std::uint32_t> index_of;
    for (std::uint32_t v = 0; v < c.mesh.vertices.size(); ++v) {
      const Vec3& p = c.mesh.vertices[v];
      index_of[{p.x(), p.y(), p.z()}] = v;
    }
    const Aabb box = Aabb::of(c.mesh.vertices);
    for (const int bits : {9, 12}) {
      for (const double floor : {10.0, 20.0}) {
        for (const bool on_grid : {true, false}) {
          SCOPED_TRACE(std::to_string(bits) + " bits, floor " + std::to_string(floor) + (on_grid ? "" : ", no grid"));
          const QuantizationGrid grid = QuantizationGrid::of(box, bits);
          DecimateOptions options{.tolerance = tolerance, .min_angle_degrees = floor};
          if (on_grid) options.grid = grid;
          const Mesh out = decimate(c.mesh, options, rule);
          ASSERT_LT(out.triangles.size(), c.mesh.triangles.size());
          std::vector<Vec3> shown = out.vertices;
          snap_to_grid(shown, grid, 1);
          std::size_t below = 0;
          for (const Triangle& t : out.triangles) {
            const auto orig = [&](std::uint32_t v) {
              const Vec3& p = out.vertices[v];
              return index_of.at({p.x(), p.y(), p.z()});
            };
            if (input_triangles.contains({orig(t[0]), orig(t[1]), orig(t[2])})) continue;  // not made here
            below += min_angle_degrees(shown[t[0]], shown[t[1]], shown[t[2]]) < floor - 1e-6;
          }
          if (on_grid) {
            EXPECT_EQ(below, 0u);
          } else {
            below_without_grid += below;
          }
        }
      }
    }
  }
  EXPECT_GT(below_without_grid, 0u);
}

// Meshes of several regions (decimated in parallel, DecimateStats::regions > 1) give the same bytes whatever the
// number of threads.
TEST(Decimate, SameMeshWithOneOrTwoThreads) {
  for (Case& c : cases()) {
    if (c.field) continue;
    SCOPED_TRACE(c.name);
    DecimateStats one, two;
    const Mesh a = decimate(c.mesh, {.tolerance = 0.0006, .threads = 1}, c.rule, {}, &one);
    const Mesh b = decimate(c.mesh, {.tolerance = 0.0006, .threads = 2}, c.rule, {}, &two);
    EXPECT_GT(one.regions, 1u);
    EXPECT_EQ(one.regions, two.regions);
    EXPECT_EQ(a.vertices, b.vertices);
    EXPECT_EQ(a.triangles, b.triangles);
  }
}

// A surface folded into several sheets per region cell (a gyroid): its regions still hold about 8 k triangles each
// (at most 1.5 times that on average), and the guarantees and the thread independence hold across their seams.
TEST(Decimate, FoldedSurfaceGetsRegionsOfTheTargetSize) {
  const FieldPtr field = make_csg(CsgOp::kIntersection, {make_gyroid(1.0, 0.12), make_sphere(Vec3::Zero(), 1.5)});
  const Mesh mesh = testing::polygonized(field, Polygonizer::kCubes, 96);
  const double tolerance = 0.004;
  const SurfacePointRule rule = zero_set_rule(*field, tolerance);
  DecimateStats one, two;
  const Mesh a = decimate(mesh, {.tolerance = tolerance, .threads = 1}, rule, {}, &one);
  const Mesh b = decimate(mesh, {.tolerance = tolerance, .threads = 2}, rule, {}, &two);
  std::printf("folded gyroid: %zu -> %zu triangles, %zu regions\n", mesh.triangles.size(), a.triangles.size(),
              one.regions);
  EXPECT_GE(static_cast<double>(one.regions), static_cast<double>(mesh.triangles.size()) / (1.5 * 8192.0));
  EXPECT_EQ(a.vertices, b.vertices);
  EXPECT_EQ(a.triangles, b.triangles);
  EXPECT_LT(a.triangles.size(), mesh.triangles.size());
  EXPECT_TRUE(mesh_has(check_mesh(a), kClosedManifold));
  EXPECT_LE(largest_vertex_distance(mesh, a, 2.0 * tolerance), tolerance * (1.0 + 1e-9));
}

// An open mesh of several regions: its boundary stays exactly as it was (boundary vertices are locked, and so are
// vertices shared by regions until the last pass), the rest stays manifold and within the tolerance.
TEST(Decimate, OpenMeshKeepsItsBoundaryAcrossRegions) {
  const Mesh sphere = testing::icosphere(6);
  Mesh cap;
  cap.vertices = sphere.vertices;
  for (const Triangle& t : sphere.triangles) {
    const Vec3 centroid = (sphere.vertices[t[0]] + sphere.vertices[t[1]] + sphere.vertices[t[2]]) / 3.0;
    if (centroid.z() < 0.5) cap.triangles.push_back(t);
  }
  const auto boundary = [](const Mesh& mesh) {
    std::map<std::pair<std::uint32_t, std::uint32_t>, int> edges;
    for (const Triangle& t : mesh.triangles) {
      for (int k = 0; k < 3; ++k) ++edges[std::minmax(t[k], t[(k + 1) % 3])];
    }
    std::vector<std::array<double, 6>> out;
    for (const auto& [edge, count] : edges) {
      if (count != 1) continue;
      const Vec3 &a = mesh.vertices[edge.first], &b = mesh.vertices[edge.second];
      out.push_back(a.x() < b.x() ? std::array{a.x(), a.y(), a.z(), b.x(), b.y(), b.z()}
                                  : std::array{b.x(), b.y(), b.z(), a.x(), a.y(), a.z()});
    }
    std::sort(out.begin(), out.end());
    return out;
  };
  DecimateStats stats;
  const Mesh out = decimate(cap, {.tolerance = 0.01, .threads = 2}, {}, {}, &stats);
  EXPECT_GT(stats.regions, 1u);
  EXPECT_LT(4 * out.triangles.size(), cap.triangles.size());
  const MeshReport report = check_mesh(out);
  EXPECT_TRUE(report.edge_manifold && report.vertex_manifold && report.oriented);
  EXPECT_EQ(report.components, check_mesh(cap).components);
  EXPECT_EQ(boundary(out), boundary(cap));
  EXPECT_LE(largest_vertex_distance(cap, out, 0.02), 0.01 * (1.0 + 1e-9));
  const Mesh one = decimate(cap, {.tolerance = 0.01, .threads = 1});
  EXPECT_EQ(one.triangles, out.triangles);
}

TEST(Decimate, KeepsNormalsAndAttributesOfTheKeptVertices) {
  Mesh mesh = testing::icosphere(4);
  Attribute index{"index", 1, {}};
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    index.values.push_back(static_cast<float>(v));
    mesh.normals.push_back(mesh.vertices[v].normalized());
  }
  mesh.attributes.push_back(index);
  const Mesh out = decimate(mesh, {.tolerance = 0.02});
  ASSERT_LT(out.vertices.size(), mesh.vertices.size());
  ASSERT_EQ(out.normals.size(), out.vertices.size());
  ASSERT_EQ(out.attributes.size(), 1u);
  ASSERT_EQ(out.attributes[0].count(), out.vertices.size());
  for (std::size_t v = 0; v < out.vertices.size(); ++v) {
    const auto original = static_cast<std::size_t>(out.attributes[0].values[v]);
    EXPECT_EQ(out.vertices[v], mesh.vertices[original]);
    EXPECT_EQ(out.normals[v], mesh.normals[original]);
  }
}

TEST(Decimate, RefusesBadOptionsNamingTheField) {
  const Mesh mesh = testing::icosphere(1);
  EXPECT_TRUE(testing::throws_invalid_input([&] { decimate(mesh, {.tolerance = -1.0}); }, "tolerance"));
  EXPECT_TRUE(testing::throws_invalid_input(
      [&] { decimate(mesh, {.tolerance = std::numeric_limits<double>::infinity()}); }, "tolerance"));
  EXPECT_TRUE(testing::throws_invalid_input([&] { decimate(mesh, {.tolerance = 0.1, .min_angle_degrees = 45.0}); },
                                            "min_angle_degrees"));
  EXPECT_TRUE(testing::throws_invalid_input([&] { decimate(mesh, {.tolerance = 0.1, .threads = -1}); }, "threads"));
}

TEST(Decimate, StopsWhenCancelled) {
  const Mesh mesh = testing::icosphere(6);
  CancelToken cancel;
  cancel.cancel();
  RunControl control;
  control.cancel = &cancel;
  EXPECT_TRUE(
      testing::throws_error([&] { decimate(mesh, {.tolerance = 0.01}, {}, control); }, ErrorKind::kCancelled, ""));
}

}  // namespace
}  // namespace surfacer
