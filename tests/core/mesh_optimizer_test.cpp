#include "core/optimize/mesh_optimizer.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <map>
#include <mutex>
#include <random>
#include <set>
#include <thread>

#include "core/mesh/mesh_checks.h"
#include "core/optimize/refine.h"
#include "core/polygonize/marching_cubes.h"
#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "tests/support/error_expectations.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using testing::kClosedManifold;
using testing::kOpenManifold;
using testing::mesh_has;
using testing::throws_invalid_input;

constexpr double kPi = 3.14159265358979323846;

double degrees(double radians) { return radians * 180.0 / kPi; }

// --- True feature lines and their measurement ---------------------------------------------------------------------

// A sharp edge of the true surface: a segment or a circle, with the angle between the two face normals along it.
struct FeatureCurve {
  bool circle = false;
  Vec3 a, b;            // segment ends; or circle centre (a) and unit axis (b)
  double radius = 0.0;  // circles
  double dihedral_degrees = 90.0;

  double length() const { return circle ? 2.0 * kPi * radius : (b - a).norm(); }
  // Distance from p to the curve, the curve's unit tangent at the nearest point, and (segments) the distance of the
  // nearest point from the nearer end.
  void project(const Vec3& p, double& distance, Vec3& tangent, double& from_end) const {
    if (!circle) {
      const double len = (b - a).norm();
      const Vec3 u = (b - a) / len;
      const double t = std::clamp((p - a).dot(u), 0.0, len);
      distance = (p - (a + t * u)).norm();
      tangent = u;
      from_end = std::min(t, len - t);
      return;
    }
    const Vec3 w = p - a;
    const double axial = w.dot(b);
    const Vec3 radial = w - axial * b;
    const double r = radial.norm();
    const Vec3 ru = r > 0.0 ? Vec3(radial / r) : Vec3(b.unitOrthogonal());
    distance = std::hypot(r - radius, axial);
    tangent = b.cross(ru);
    from_end = std::numeric_limits<double>::infinity();
  }
};

FeatureCurve segment(const Vec3& a, const Vec3& b) {
  FeatureCurve c;
  c.a = a;
  c.b = b;
  return c;
}

FeatureCurve circle(const Vec3& centre, const Vec3& axis, double radius) {
  FeatureCurve c;
  c.circle = true;
  c.a = centre;
  c.b = axis.normalized();
  c.radius = radius;
  return c;
}

std::vector<FeatureCurve> box_edges(const Vec3& centre, const Vec3& half) {
  std::vector<FeatureCurve> out;
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (int su = -1; su <= 1; su += 2) {
      for (int sv = -1; sv <= 1; sv += 2) {
        Vec3 a = centre, b = centre;
        a[axis] -= half[axis];
        b[axis] += half[axis];
        a[u] += su * half[u];
        b[u] += su * half[u];
        a[v] += sv * half[v];
        b[v] += sv * half[v];
        out.push_back(segment(a, b));
      }
    }
  }
  return out;
}

Vec3 unit_normal(const Mesh& m, const Triangle& t) {
  return (m.vertices[t[1]] - m.vertices[t[0]]).cross(m.vertices[t[2]] - m.vertices[t[0]]).normalized();
}

Vec3 centroid(const Mesh& m, const Triangle& t) {
  return (m.vertices[t[0]] + m.vertices[t[1]] + m.vertices[t[2]]) / 3.0;
}

Vec3 field_normal(const Field& f, const Vec3& p) {
  Vec3 g;
  f.value_and_gradient(p, g);
  return g.normalized();
}

struct FeatureReport {
  int edges = 0;           // mesh edges found along the feature lines
  double coverage = 0.0;   // their total length / the curves' length (outside the excluded ends)
  double max_error = 0.0;  // largest |dihedral - true dihedral|, degrees
};

// Mesh edges on a true feature line: both ends within `tol` of the curve (the midpoint within tol plus the chord's
// sagitta for circles), direction within 25 degrees of the curve's tangent, its midpoint farther than `exclude` from
// a segment's ends (corners, where three faces meet), and with the two adjacent triangles' centroids on different faces
// (field normals more than 30 degrees apart; an edge lying inside one face next to the line is not a feature edge). Its
// dihedral angle is the angle between the two triangle normals.
FeatureReport measure_features(const Mesh& mesh, const Field& field, const std::vector<FeatureCurve>& curves,
                               double tol, double exclude) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::vector<std::size_t>> edges;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) {
      edges[std::minmax(mesh.triangles[t][k], mesh.triangles[t][(k + 1) % 3])].push_back(t);
    }
  }
  FeatureReport r;
  double length = 0.0;
  for (const FeatureCurve& c : curves) length += c.circle ? c.length() : std::max(0.0, c.length() - 2.0 * exclude);
  for (const auto& [e, tris] : edges) {
    if (tris.size() != 2) continue;
    const Vec3 p = mesh.vertices[e.first], q = mesh.vertices[e.second];
    const Vec3 dir = (q - p).normalized();
    for (const FeatureCurve& c : curves) {
      double dp, dq, dm, end_p, end_q, end_m;
      Vec3 tangent;
      c.project(p, dp, tangent, end_p);
      c.project(q, dq, tangent, end_q);
      c.project(0.5 * (p + q), dm, tangent, end_m);
      const double sagitta = c.circle ? (q - p).squaredNorm() / (8.0 * c.radius) : 0.0;
      if (dp > tol || dq > tol || dm > tol + sagitta || end_m < exclude) continue;
      if (std::abs(dir.dot(tangent)) < std::cos(25.0 * kPi / 180.0)) continue;
      const Vec3 m0 = field_normal(field, centroid(mesh, mesh.triangles[tris[0]]));
      const Vec3 m1 = field_normal(field, centroid(mesh, mesh.triangles[tris[1]]));
      if (m0.dot(m1) > std::cos(30.0 * kPi / 180.0)) continue;
      const double cos_angle = std::clamp(
          unit_normal(mesh, mesh.triangles[tris[0]]).dot(unit_normal(mesh, mesh.triangles[tris[1]])), -1.0, 1.0);
      r.max_error = std::max(r.max_error, std::abs(degrees(std::acos(cos_angle)) - c.dihedral_degrees));
      r.coverage += (q - p).norm();
      ++r.edges;
      break;
    }
  }
  r.coverage = length > 0.0 ? r.coverage / length : 0.0;
  return r;
}

// --- Reference shapes -------------------------------------------------------------------------------------------

struct Reference {
  FieldPtr field;
  Mesh start;
  std::vector<FeatureCurve> curves;
  double diagonal = 0.0;  // of the true solid's bounding box
  double h = 0.0;         // start grid spacing
};

// The paper's sphere-to-cube (Fig. 11-12): a Marching Cubes sphere of radius 1.2 evolving toward the cube
// max(|x|,|y|,|z|) <= 1 (make_box: its exact signed distance).
Reference sphere_to_cube(int cells) {
  Reference r;
  r.field = make_box(Vec3::Zero(), Vec3::Ones());
  const FieldPtr sphere = make_sphere(Vec3::Zero(), 1.2);
  MarchingCubesOptions o;
  o.bounds = Aabb{Vec3::Constant(-1.5013), Vec3::Constant(1.4987)};  // grid planes off the cube's faces
  o.cells = {cells, cells, cells};
  r.start = marching_cubes(*sphere, o);
  r.curves = box_edges(Vec3::Zero(), Vec3::Ones());
  r.diagonal = 2.0 * std::sqrt(3.0);
  r.h = 3.0 / cells;
  return r;
}

// A CSG block: a slab with a box on top and a cylindrical boss (unions: concave edges), a vertical hole through boss
// and slab and a horizontal hole through the box (differences), min/max CSG. Every feature line has a 90 degree
// dihedral angle.
Reference csg_block(int cells) {
  Reference r;
  const FieldPtr slab = make_box(Vec3(0, 0, 0), Vec3(1.0, 0.7, 0.35));
  const FieldPtr top = make_box(Vec3(0.3, 0, 0.5), Vec3(0.45, 0.45, 0.35));
  const FieldPtr boss = make_cylinder(Vec3(-0.55, 0, 0), Vec3(-0.55, 0, 0.6), 0.3);
  const FieldPtr hole = make_cylinder(Vec3(-0.55, 0, -0.5), Vec3(-0.55, 0, 0.8), 0.15);
  const FieldPtr cross_hole = make_cylinder(Vec3(-0.2, 0, 0.56), Vec3(0.9, 0, 0.56), 0.14);
  r.field = make_csg(CsgOp::kDifference, {make_csg(CsgOp::kUnion, {slab, top, boss}), hole, cross_hole});
  MarchingCubesOptions o;
  o.bounds = Aabb{Vec3::Constant(-1.1013), Vec3::Constant(1.0987)};
  o.cells = {cells, cells, cells};
  r.start = marching_cubes(*r.field, o);
  r.h = 2.2 / cells;
  r.diagonal = Vec3(2.0, 1.4, 1.2).norm();
  r.curves = box_edges(Vec3(0, 0, 0), Vec3(1.0, 0.7, 0.35));
  const double x0 = -0.15, x1 = 0.75, y0 = -0.45, y1 = 0.45, z_top = 0.85, z_slab = 0.35;
  for (double z : {z_top, z_slab}) {  // top box: its top rim (convex) and its foot on the slab (concave)
    r.curves.push_back(segment({x0, y0, z}, {x1, y0, z}));
    r.curves.push_back(segment({x0, y1, z}, {x1, y1, z}));
    r.curves.push_back(segment({x0, y0, z}, {x0, y1, z}));
    r.curves.push_back(segment({x1, y0, z}, {x1, y1, z}));
  }
  for (double x : {x0, x1}) {
    for (double y : {y0, y1}) r.curves.push_back(segment({x, y, z_slab}, {x, y, z_top}));
  }
  r.curves.push_back(circle({x0, 0, 0.56}, Vec3::UnitX(), 0.14));  // cross hole rims
  r.curves.push_back(circle({x1, 0, 0.56}, Vec3::UnitX(), 0.14));
  r.curves.push_back(circle({-0.55, 0, 0.6}, Vec3::UnitZ(), 0.3));     // boss rim
  r.curves.push_back(circle({-0.55, 0, 0.6}, Vec3::UnitZ(), 0.15));    // hole rim on the boss
  r.curves.push_back(circle({-0.55, 0, 0.35}, Vec3::UnitZ(), 0.3));    // boss foot (concave)
  r.curves.push_back(circle({-0.55, 0, -0.35}, Vec3::UnitZ(), 0.15));  // hole rim under the slab
  return r;
}

// An upper bound on each vertex's distance to {f = 0}: the nearest sign change of f along -sign(f) ∇f, its sums with
// the axes, and the 26 lattice directions (a sign change at distance t puts a surface point within t; several
// directions because at an edge or corner the other side lies in a wedge), bisected.
double max_surface_distance(const Mesh& mesh, const Field& field, double search) {
  double worst = 0.0;
  std::vector<bool> used(mesh.vertices.size(), false);
  for (const Triangle& t : mesh.triangles) {
    for (std::uint32_t v : t) used[v] = true;
  }
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    if (!used[v]) continue;
    const Vec3 p = mesh.vertices[v];
    Vec3 g;
    const double f0 = field.value_and_gradient(p, g);
    if (f0 == 0.0) continue;
    const bool outside = f0 > 0.0;
    auto differs = [&](const Vec3& x) {
      const double f = field.value(x);
      return outside ? f <= 0.0 : f >= 0.0;
    };
    double best = std::numeric_limits<double>::infinity();
    std::vector<Vec3> directions;
    for (int i = 0; i < 27; ++i) {
      const Vec3 d(i % 3 - 1, (i / 3) % 3 - 1, i / 9 - 1);
      if (i != 13) directions.push_back(d.normalized());
    }
    if (g.norm() > 0.0) {
      const Vec3 down = -(outside ? 1.0 : -1.0) * g.normalized();
      directions.push_back(down);
      for (int axis = 0; axis < 3; ++axis) {
        directions.push_back((down + Vec3::Unit(axis)).normalized());
        directions.push_back((down - Vec3::Unit(axis)).normalized());
      }
    }
    for (const Vec3& dir : directions) {
      double hi = std::max(std::abs(f0), 1e-12);
      while (!differs(p + hi * dir) && hi < std::min(search, best)) hi *= 2.0;
      if (!differs(p + hi * dir)) continue;
      double lo = 0.0;
      for (int i = 0; i < 60; ++i) {
        const double mid = 0.5 * (lo + hi);
        (differs(p + mid * dir) ? hi : lo) = mid;
      }
      best = std::min(best, hi);
    }
    worst = std::max(worst, best);
  }
  return worst;
}

// Triangles whose normal points against ∇f at their centroid (n·∇f <= 0).
int triangles_against_field(const Mesh& mesh, const Field& field) {
  int count = 0;
  for (const Triangle& t : mesh.triangles) {
    const Vec3 n = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    Vec3 g;
    field.value_and_gradient(centroid(mesh, t), g);
    if (!(n.dot(g) > 0.0)) ++count;
  }
  return count;
}

// Closed, edge- and vertex-manifold, oriented.
::testing::AssertionResult watertight(const Mesh& mesh) { return mesh_has(check_mesh(mesh), kClosedManifold); }

struct OptimizedRun {
  Mesh mesh;
  std::vector<OptimizerIterationStats> snapshots;
  int snapshots_not_watertight = 0;
  int snapshots_against_field = 0;
};

OptimizedRun run(const Reference& ref, const MeshOptimizerOptions& o) {
  OptimizedRun out;
  out.mesh = optimize_mesh(*ref.field, ref.start, o, [&](const Mesh& m, const OptimizerIterationStats& s) {
    out.snapshots.push_back(s);
    if (!watertight(m)) ++out.snapshots_not_watertight;
    out.snapshots_against_field += triangles_against_field(m, *ref.field);
  });
  return out;
}

// The acceptance figures of a run, against the start mesh: E_d falls 100-fold and E_n 10-fold, every vertex lies
// within 0.25% of the true solid's bounding-box diagonal from its surface, and the snapshots and the result are
// watertight with no triangle facing against the field.
void expect_converged(const Reference& ref, const OptimizedRun& r, const MeshOptimizer& start_figures) {
  const OptimizerIterationStats& s0 = start_figures.stats();
  const OptimizerIterationStats& s1 = r.snapshots.back();
  EXPECT_LE(s1.e_d, s0.e_d / 100.0) << "E_d " << s0.e_d << " -> " << s1.e_d;
  EXPECT_LE(s1.e_n, s0.e_n / 10.0) << "E_n " << s0.e_n << " -> " << s1.e_n;
  const double distance = max_surface_distance(r.mesh, *ref.field, 0.1 * ref.diagonal);
  EXPECT_LE(distance, 0.0025 * ref.diagonal) << "max vertex distance " << distance;
  EXPECT_LE(s1.max_distance, 0.0025 * ref.diagonal);
  EXPECT_EQ(triangles_against_field(r.mesh, *ref.field), 0);
  EXPECT_EQ(r.snapshots_not_watertight, 0);
  EXPECT_EQ(r.snapshots_against_field, 0);
  EXPECT_TRUE(watertight(r.mesh));
}

// --- Flows and schedule on the reference shapes -----------------------------------------------------------------

TEST(MeshOptimizer, SphereToCubeWithThePaperFlows) {
  const Reference ref = sphere_to_cube(32);
  MeshOptimizerOptions o;  // N ∘ D ∘ T, T off when E_d stabilises, then N ∘ D
  o.max_iterations = 160;
  o.snapshot_every = 20;
  const MeshOptimizer start(*ref.field, ref.start, o);
  const OptimizedRun r = run(ref, o);
  ASSERT_EQ(r.snapshots.size(), 8u);
  expect_converged(ref, r, start);
  // E_n decreases over the run (not necessarily monotonically): every snapshot after the first is below the start
  // and the last is the lowest.
  double lowest = std::numeric_limits<double>::infinity();
  for (const auto& s : r.snapshots) {
    EXPECT_LT(s.e_n, start.stats().e_n);
    lowest = std::min(lowest, s.e_n);
  }
  EXPECT_EQ(lowest, r.snapshots.back().e_n);
  EXPECT_TRUE(r.snapshots.front().t_flow_on);
  EXPECT_FALSE(r.snapshots.back().t_flow_on);
}

TEST(MeshOptimizer, SphereToCubeModifiedFlowsRecoverSharpEdges) {
  const Reference ref = sphere_to_cube(32);
  MeshOptimizerOptions o;
  o.modified_flows = true;
  o.max_iterations = 120;
  o.snapshot_every = 20;
  const MeshOptimizer start(*ref.field, ref.start, o);
  const OptimizedRun r = run(ref, o);
  expect_converged(ref, r, start);
  const FeatureReport before = measure_features(ref.start, *ref.field, ref.curves, 0.02 * ref.h, 2.0 * ref.h);
  const FeatureReport after = measure_features(r.mesh, *ref.field, ref.curves, 0.02 * ref.h, 2.0 * ref.h);
  EXPECT_LT(before.coverage, 0.05);  // Marching Cubes chamfers every edge
  EXPECT_GE(after.coverage, 0.9) << after.edges << " feature edges";
  EXPECT_LE(after.max_error, 5.0);
}

TEST(MeshOptimizer, CsgBlockFrom64CubedRecoversEdgesHolesAndRims) {
  const Reference ref = csg_block(64);
  MeshOptimizerOptions o;
  o.modified_flows = true;
  o.max_iterations = 80;
  o.snapshot_every = 10;
  const MeshOptimizer start(*ref.field, ref.start, o);
  const OptimizedRun r = run(ref, o);
  expect_converged(ref, r, start);
  const FeatureReport before = measure_features(ref.start, *ref.field, ref.curves, 0.02 * ref.h, 2.0 * ref.h);
  const FeatureReport after = measure_features(r.mesh, *ref.field, ref.curves, 0.02 * ref.h, 2.0 * ref.h);
  EXPECT_LT(before.coverage, 0.25);
  EXPECT_GE(after.coverage, 0.9) << after.edges << " feature edges";
  EXPECT_LE(after.max_error, 5.0);
  // Same genus as the true solid (two through holes): Euler characteristic 2 - 2g = -2.
  EXPECT_EQ(check_mesh(r.mesh).euler_characteristic, -2);
}

// --- Adaptive subdivision ----------------------------------------------------------------------------------------

TEST(MeshOptimizer, AdaptiveSubdivisionRefinesOnlyWhereNormalsDeviate) {
  const Reference ref = csg_block(32);
  MeshOptimizerOptions o;
  o.modified_flows = true;
  o.max_iterations = 40;
  o.subdivision_threshold = 0.002 * ref.h * ref.h;  // refines triangles whose normals are off by more than ~4°
  o.subdivision_interval = 10;
  o.snapshot_every = 5;
  const OptimizedRun r = run(ref, o);
  EXPECT_EQ(r.snapshots_not_watertight, 0);
  EXPECT_EQ(r.snapshots_against_field, 0);
  EXPECT_TRUE(watertight(r.mesh));
  std::int64_t added = 0;
  for (const auto& s : r.snapshots) added += s.triangles_added;
  const auto start_triangles = static_cast<std::int64_t>(ref.start.triangles.size());
  EXPECT_GT(static_cast<std::int64_t>(r.mesh.triangles.size()), start_triangles);
  EXPECT_LT(static_cast<std::int64_t>(r.mesh.triangles.size()), 3 * start_triangles);  // not everywhere

  // Distance to the nearest feature curve, and whether p lies on one of the three cylinder walls (curved: normals
  // vary, so refining there is right).
  auto feature_distance = [&](const Vec3& p) {
    double best = std::numeric_limits<double>::infinity();
    for (const FeatureCurve& c : ref.curves) {
      double d, end;
      Vec3 tangent;
      c.project(p, d, tangent, end);
      best = std::min(best, d);
    }
    return best;
  };
  auto on_cylinder_wall = [&](const Vec3& p) {
    const double boss = std::hypot(p.x() + 0.55, p.y());
    const double cross = std::hypot(p.y(), p.z() - 0.56);
    return std::abs(boss - 0.3) < 0.5 * ref.h || std::abs(boss - 0.15) < 0.5 * ref.h ||
           std::abs(cross - 0.14) < 0.5 * ref.h;
  };
  // Every new vertex sits where the start mesh's normals deviated: near a feature line or on a curved wall.
  int misplaced = 0;
  for (std::size_t v = ref.start.vertices.size(); v < r.mesh.vertices.size(); ++v) {
    const Vec3& p = r.mesh.vertices[v];
    if (feature_distance(p) > 3.0 * ref.h && !on_cylinder_wall(p)) ++misplaced;
  }
  EXPECT_EQ(misplaced, 0) << "of " << r.mesh.vertices.size() - ref.start.vertices.size() << " new vertices";
  // Flat regions keep their triangles: every start triangle well inside a planar face is still there.
  std::set<std::array<std::uint32_t, 3>> final_triangles;
  for (const Triangle& t : r.mesh.triangles) {
    std::array<std::uint32_t, 3> k = t;
    std::rotate(k.begin(), std::min_element(k.begin(), k.end()), k.end());
    final_triangles.insert(k);
  }
  int flat = 0, kept = 0;
  for (const Triangle& t : ref.start.triangles) {
    bool inside_face = true;
    for (std::uint32_t v : t) {
      const Vec3& p = ref.start.vertices[v];
      inside_face = inside_face && feature_distance(p) > 3.0 * ref.h && !on_cylinder_wall(p);
    }
    if (!inside_face) continue;
    ++flat;
    std::array<std::uint32_t, 3> k = t;
    std::rotate(k.begin(), std::min_element(k.begin(), k.end()), k.end());
    kept += final_triangles.count(k) ? 1 : 0;
  }
  EXPECT_GT(flat, 500);
  EXPECT_EQ(kept, flat);

  // Subdivision pays: a clearly lower normal error than the same run without it.
  MeshOptimizerOptions plain = o;
  plain.subdivision_threshold.reset();
  const OptimizedRun p = run(ref, plain);
  EXPECT_LT(r.snapshots.back().e_n, 0.7 * p.snapshots.back().e_n);
}

TEST(MeshOptimizer, TriangleBudgetIsNeverExceeded) {
  const Reference ref = csg_block(24);
  MeshOptimizerOptions o;
  o.max_iterations = 30;
  o.subdivision_threshold = 1e-6 * ref.h * ref.h;  // would refine almost everything
  o.subdivision_interval = 5;
  o.triangle_budget = static_cast<std::int64_t>(ref.start.triangles.size()) + 600;
  o.snapshot_every = 5;
  const OptimizedRun r = run(ref, o);
  std::int64_t added = 0;
  for (const auto& s : r.snapshots) {
    EXPECT_LE(s.triangles, *o.triangle_budget);
    added += s.triangles_added;
  }
  EXPECT_GT(added, 0);
  EXPECT_EQ(r.snapshots_not_watertight, 0);
}

// Red–green refinement on its own: random requests over several rounds keep an icosphere conforming, closed,
// oriented and with the same geometry (new vertices are edge midpoints, so the volume is unchanged), and green
// triangles are never bisected again, so the smallest angle stays bounded.
TEST(RedGreenRefinement, RandomRoundsStayConformingWithBoundedAngles) {
  Mesh mesh = testing::icosphere(1);
  const double volume = check_mesh(mesh).volume;
  const double start_angle = check_mesh(mesh).min_angle_degrees;
  optimizer_detail::RedGreenHierarchy h;
  h.reset(mesh.triangles.size());
  std::mt19937 rng(7);
  for (int round = 0; round < 6; ++round) {
    std::vector<std::uint8_t> request(mesh.triangles.size(), 0);
    std::bernoulli_distribution pick(0.08);
    for (auto& r : request) r = pick(rng) ? 1 : 0;
    const std::size_t before = mesh.triangles.size();
    optimizer_detail::refine_red_green(mesh.vertices, mesh.triangles, h, request, {});
    EXPECT_GT(mesh.triangles.size(), before);
    ASSERT_EQ(h.green_group.size(), mesh.triangles.size());
    const MeshReport rep = check_mesh(mesh);
    EXPECT_TRUE(watertight(mesh)) << "round " << round;
    EXPECT_EQ(rep.euler_characteristic, 2);
    EXPECT_EQ(rep.degenerate_triangles, 0);
    EXPECT_NEAR(rep.volume, volume, 1e-12);
    // Bisecting a red child once more can halve an angle; never twice.
    EXPECT_GT(rep.min_angle_degrees, 0.45 * start_angle) << "round " << round;
  }
}

// --- Determinism, schedule options, cancellation, validation ----------------------------------------------------

TEST(MeshOptimizer, DeterministicAcrossThreadCounts) {
  const Reference ref = csg_block(20);
  MeshOptimizerOptions o;
  o.max_iterations = 12;
  o.subdivision_threshold = 0.02 * ref.h * ref.h;
  o.subdivision_interval = 4;
  o.threads = 1;
  const Mesh one = optimize_mesh(*ref.field, ref.start, o);
  o.threads = 2;
  const Mesh two = optimize_mesh(*ref.field, ref.start, o);
  ASSERT_EQ(one.vertices.size(), two.vertices.size());
  EXPECT_EQ(one.triangles, two.triangles);
  for (std::size_t v = 0; v < one.vertices.size(); ++v) ASSERT_EQ(one.vertices[v], two.vertices[v]) << v;
}

// Checkpoint: an optimizer restored from save_state() continues bit-identically (subdivision and the repair on, so
// the red-green hierarchy and the schedule matter), and a damaged blob is refused cleanly.
TEST(MeshOptimizer, SavedStateContinuesExactlyLikeTheUninterruptedRun) {
  const Reference ref = csg_block(20);
  MeshOptimizerOptions o;
  o.max_iterations = 24;
  o.subdivision_threshold = 0.02 * ref.h * ref.h;
  o.subdivision_interval = 4;
  o.tolerance = 1e-3;
  o.normals = true;
  o.threads = 2;
  MeshOptimizer straight(*ref.field, ref.start, o);
  std::string state;
  std::vector<OptimizerIterationStats> expected;
  std::int64_t added_before = 0;
  while (!straight.done()) {
    straight.step();
    if (straight.stats().iteration <= 9) added_before += straight.stats().triangles_added;
    if (straight.stats().iteration == 9) state = straight.save_state();  // mid T-flow phase, after a subdivision
    if (straight.stats().iteration > 9) expected.push_back(straight.stats());
  }
  ASSERT_FALSE(state.empty());
  EXPECT_GT(added_before, 0) << "the saved state should hold a red-green hierarchy";
  EXPECT_LT(state.size(), 40 * straight.mesh().vertices.size() + 24 * straight.mesh().triangles.size() + 4096);

  MeshOptimizer resumed = MeshOptimizer::from_state(*ref.field, state, o);
  EXPECT_EQ(resumed.stats().iteration, 9);
  EXPECT_EQ(resumed.save_state(), state);  // the whole saved state round-trips
  std::vector<OptimizerIterationStats> got;
  while (!resumed.done()) got.push_back(resumed.step());
  ASSERT_EQ(got.size(), expected.size());
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].iteration, expected[i].iteration);
    EXPECT_EQ(got[i].e_d, expected[i].e_d) << got[i].iteration;
    EXPECT_EQ(got[i].e_n, expected[i].e_n) << got[i].iteration;
    EXPECT_EQ(got[i].t_flow_on, expected[i].t_flow_on) << got[i].iteration;
    EXPECT_EQ(got[i].triangles_added, expected[i].triangles_added) << got[i].iteration;
  }
  const Mesh& a = straight.mesh();
  const Mesh& b = resumed.mesh();
  EXPECT_EQ(a.triangles, b.triangles);
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  for (std::size_t v = 0; v < a.vertices.size(); ++v) ASSERT_EQ(a.vertices[v], b.vertices[v]) << v;
  EXPECT_EQ(a.normals.size(), b.normals.size());

  // Damaged blobs: every truncation and a flipped byte anywhere throw InvalidInput("state"), never crash.
  auto refused = [&](const std::string& blob) {
    try {
      MeshOptimizer::from_state(*ref.field, blob, o);
    } catch (const Error& e) {
      return e.kind() == ErrorKind::kInvalidInput && e.field() == "state";
    }
    return false;
  };
  for (const std::size_t n :
       {std::size_t{0}, std::size_t{3}, std::size_t{8}, std::size_t{20}, state.size() / 2, state.size() - 1}) {
    EXPECT_TRUE(refused(state.substr(0, n))) << n;
  }
  for (const std::size_t at : {std::size_t{5}, std::size_t{12}, state.size() / 3, state.size() - 3}) {
    std::string bad = state;
    bad[at] = static_cast<char>(bad[at] ^ 0x40);
    EXPECT_TRUE(refused(bad)) << at;
  }
  EXPECT_TRUE(refused(state + "x"));
  // Bad options are still reported as options.
  MeshOptimizerOptions bad_options = o;
  bad_options.c_d = 2.0;
  EXPECT_THROW(
      {
        try {
          MeshOptimizer::from_state(*ref.field, state, bad_options);
        } catch (const Error& e) {
          EXPECT_EQ(e.field(), "c_d");
          throw;
        }
      },
      Error);
}

TEST(MeshOptimizer, ExplicitTFlowIterationsAndTolerance) {
  const Reference ref = sphere_to_cube(16);
  MeshOptimizerOptions o;
  o.t_flow_iterations = 7;
  o.max_iterations = 400;
  o.tolerance = 1e-3;
  MeshOptimizer opt(*ref.field, ref.start, o);
  EXPECT_TRUE(opt.t_flow_on());
  std::vector<OptimizerIterationStats> all;
  while (!opt.done()) all.push_back(opt.step());
  ASSERT_GT(all.size(), 7u);
  for (const auto& s : all) EXPECT_EQ(s.t_flow_on, s.iteration <= 7) << s.iteration;
  EXPECT_LT(all.size(), 400u);  // stopped by the tolerance
  // ... because neither figure improved by more than 0.1 % on the best of the 5 iterations before.
  const auto& last = all.back();
  double best_d = last.e_d * 2.0, best_n = last.e_n * 2.0;
  for (std::size_t i = all.size() - 6; i + 1 < all.size(); ++i) {
    best_d = std::min(best_d, all[i].e_d);
    best_n = std::min(best_n, all[i].e_n);
    EXPECT_FALSE(all[i].t_flow_on);
  }
  EXPECT_TRUE(last.e_d >= 0.999 * best_d || last.e_d < 1e-20);
  EXPECT_TRUE(last.e_n >= 0.999 * best_n || last.e_n < 1e-20);
  EXPECT_LT(last.e_n, all.front().e_n / 10.0);
}

TEST(MeshOptimizer, SnapshotsEveryKIterationsAndTheFinalOnce) {
  const Reference ref = sphere_to_cube(12);
  MeshOptimizerOptions o;
  o.max_iterations = 25;
  o.snapshot_every = 10;
  o.normals = true;
  std::vector<int> iterations;
  const Mesh out = optimize_mesh(*ref.field, ref.start, o, [&](const Mesh& m, const OptimizerIterationStats& s) {
    iterations.push_back(s.iteration);
    EXPECT_EQ(m.normals.size(), m.vertices.size());
    EXPECT_EQ(s.triangles, static_cast<std::int64_t>(m.triangles.size()));
  });
  EXPECT_EQ(iterations, (std::vector<int>{10, 20, 25}));
  o.max_iterations = 20;
  iterations.clear();
  optimize_mesh(*ref.field, ref.start, o,
                [&](const Mesh&, const OptimizerIterationStats& s) { iterations.push_back(s.iteration); });
  EXPECT_EQ(iterations, (std::vector<int>{10, 20}));
  for (const Vec3& n : out.normals) EXPECT_NEAR(n.norm(), 1.0, 1e-9);
}

TEST(MeshOptimizer, CancelledStepLeavesTheOptimizerUnchanged) {
  const Reference ref = sphere_to_cube(12);
  MeshOptimizer opt(*ref.field, ref.start, {});
  opt.step();
  const Mesh before = opt.mesh();
  const OptimizerIterationStats stats = opt.stats();
  CancelToken token;
  token.cancel();
  RunControl control;
  control.cancel = &token;
  try {
    opt.step(control);
    FAIL() << "expected Cancelled";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kCancelled);
  }
  EXPECT_EQ(opt.mesh().triangles, before.triangles);
  EXPECT_EQ(opt.mesh().vertices, before.vertices);
  EXPECT_EQ(opt.stats().iteration, stats.iteration);
  EXPECT_EQ(opt.step().iteration, 2);  // and it carries on
}

TEST(MeshOptimizer, CancelMidRunReturnsPromptlyKeepingTheLastSnapshot) {
  const Reference ref = csg_block(64);
  MeshOptimizerOptions o;
  o.max_iterations = 1000000;  // hours uncancelled
  o.snapshot_every = 2;
  o.modified_flows = true;
  CancelToken token;
  RunControl control;
  control.cancel = &token;
  std::mutex mutex;
  Mesh last;
  int last_iteration = 0;
  std::atomic<int> snapshots{0};
  std::chrono::steady_clock::time_point cancelled_at, returned_at;
  bool cancelled = false;
  std::thread worker([&] {
    try {
      optimize_mesh(
          *ref.field, ref.start, o,
          [&](const Mesh& m, const OptimizerIterationStats& s) {
            std::lock_guard lock(mutex);
            last = m;
            last_iteration = s.iteration;
            ++snapshots;
          },
          control);
    } catch (const Error& e) {
      cancelled = e.kind() == ErrorKind::kCancelled;
    }
    returned_at = std::chrono::steady_clock::now();
  });
  while (snapshots.load() < 3) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  std::this_thread::sleep_for(std::chrono::milliseconds(15));  // somewhere inside an iteration
  cancelled_at = std::chrono::steady_clock::now();
  token.cancel();
  worker.join();
  EXPECT_TRUE(cancelled);
  EXPECT_LT(std::chrono::duration<double>(returned_at - cancelled_at).count(), 0.25);
  std::lock_guard lock(mutex);
  EXPECT_GE(last_iteration, 6);
  EXPECT_EQ(last_iteration % 2, 0);
  EXPECT_TRUE(watertight(last));
  EXPECT_EQ(triangles_against_field(last, *ref.field), 0);
}

TEST(MeshOptimizer, InvalidOptionsAndStartMeshes) {
  const testing::SphereField sphere(Vec3::Zero(), 1.0);
  const Mesh good = testing::icosphere(1);
  auto with = [&](const std::function<void(MeshOptimizerOptions&)>& change) {
    MeshOptimizerOptions o;
    change(o);
    return [o, &sphere, &good] { MeshOptimizer(sphere, good, o); };
  };
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.c_d = 0.0; }), "c_d"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.c_n = 1.5; }), "c_n"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.c_t = -0.1; }), "c_t"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.step_bound = std::nan(""); }), "step_bound"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.max_iterations = -1; }), "max_iterations"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.t_flow_iterations = -2; }), "t_flow_iterations"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.tolerance = 0.0; }), "tolerance"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.subdivision_threshold = -1.0; }), "subdivision_threshold"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.subdivision_interval = 0; }), "subdivision_interval"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.triangle_budget = 0; }), "triangle_budget"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.snapshot_every = -1; }), "snapshot_every"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.threads = -1; }), "threads"));
  EXPECT_TRUE(throws_invalid_input(with([](auto& o) { o.d_flow = o.n_flow = o.t_flow = false; }), "d_flow"));

  Mesh empty;
  EXPECT_TRUE(throws_invalid_input([&] { MeshOptimizer(sphere, empty, {}); }, "start"));
  Mesh bad_index = good;
  bad_index.triangles[3][1] = static_cast<std::uint32_t>(good.vertices.size());
  EXPECT_TRUE(throws_invalid_input([&] { MeshOptimizer(sphere, bad_index, {}); }, "start"));
  Mesh repeated = good;
  repeated.triangles[0][1] = repeated.triangles[0][0];
  EXPECT_TRUE(throws_invalid_input([&] { MeshOptimizer(sphere, repeated, {}); }, "start"));
  Mesh not_finite = good;
  not_finite.vertices[2].x() = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(throws_invalid_input([&] { MeshOptimizer(sphere, not_finite, {}); }, "start"));
}

// Without connectivity repair and subdivision the paper's flows only move vertices: the triangles stay as they were.
TEST(MeshOptimizer, FlowsAloneKeepTheConnectivity) {
  const Reference ref = csg_block(20);
  MeshOptimizerOptions o;
  o.repair_connectivity = false;
  o.max_iterations = 30;
  o.modified_flows = true;
  const Mesh out = optimize_mesh(*ref.field, ref.start, o);
  EXPECT_EQ(out.triangles, ref.start.triangles);
  EXPECT_NE(out.vertices, ref.start.vertices);
  EXPECT_EQ(triangles_against_field(out, *ref.field), 0);
}

// A start mesh cut open by the polygonization bounds: the boundary is kept (no T-flow, flips or collapses there) and
// the mesh stays manifold and oriented.
TEST(MeshOptimizer, OpenStartMeshKeepsItsBoundary) {
  const FieldPtr box = make_box(Vec3::Zero(), Vec3(0.8, 0.8, 0.8));
  MarchingCubesOptions mc;
  mc.bounds = Aabb{Vec3(-1.0013, -1.0013, -1.0013), Vec3(0.9987, 0.9987, 0.4987)};  // cuts the top off
  mc.cells = {24, 24, 18};
  const Mesh start = marching_cubes(*box, mc);
  const MeshReport before = check_mesh(start);
  ASSERT_GT(before.boundary_edges, 0);
  MeshOptimizerOptions o;
  o.modified_flows = true;
  o.max_iterations = 40;
  const Mesh out = optimize_mesh(*box, start, o);
  const MeshReport after = check_mesh(out);
  EXPECT_TRUE(mesh_has(after, kOpenManifold));
  EXPECT_EQ(after.boundary_edges, before.boundary_edges);
  EXPECT_EQ(triangles_against_field(out, *box), 0);
}

// A start mesh that is already exact stays put: the icosphere's vertices lie on the sphere, so the D-flow does
// nothing, and only the T-flow slides vertices along the surface (E_d stays at round-off).
TEST(MeshOptimizer, ExactStartStaysOnTheSurface) {
  const testing::SphereField sphere(Vec3::Zero(), 1.0);
  const Mesh start = testing::icosphere(3);
  MeshOptimizerOptions o;
  o.max_iterations = 20;
  const Mesh out = optimize_mesh(sphere, start, o);
  EXPECT_LT(testing::max_distance_to_sphere(out, Vec3::Zero(), 1.0), 1e-3);
  EXPECT_TRUE(watertight(out));
  EXPECT_EQ(out.triangles, start.triangles);
}

}  // namespace
}  // namespace surfacer
