#include "core/polygonize/marching_tiles.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>
#include <numbers>
#include <random>
#include <set>
#include <thread>
#include <vector>

#include "core/mesh/mesh_checks.h"
#include "core/polygonize/a15_table.h"
#include "core/polygonize/marching_cubes.h"
#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "tests/support/error_expectations.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using testing::kClosedManifold;
using testing::kNoDegenerateTriangles;
using testing::kOpenManifold;
using testing::kPositiveVolume;
using testing::mesh_has;
using testing::normals_point_away_from;
using testing::SphereField;
using testing::TorusField;

constexpr double kPi = std::numbers::pi;
// Longest lattice edge (sqrt 6 lattice units) in units of the spacing: ~1.063.
const double kLongestEdge = std::sqrt(6.0) / a15::kMeanEdge;

MarchingTilesOptions tile_options(double half, double spacing, int threads = 1) {
  MarchingTilesOptions o;
  o.bounds = Aabb{Vec3::Constant(-half), Vec3::Constant(half)};
  o.spacing = spacing;
  o.threads = threads;
  return o;
}

// What Marching Tiles promises for a closed surface: a closed, edge- and vertex-manifold, oriented mesh enclosing a
// positive volume, without degenerate triangles, and (with mesh_has's minimum valence) kMinValence.
constexpr unsigned kGoodClosed = kClosedManifold | kNoDegenerateTriangles | kPositiveVolume;
constexpr int kMinValence = 5;

int histogram_peak(const MeshReport& r) {
  int peak = 0;
  for (std::size_t v = 0; v < r.valence_histogram.size(); ++v) {
    if (r.valence_histogram[v] > r.valence_histogram[peak]) peak = static_cast<int>(v);
  }
  return peak;
}

double max_abs_field(const Mesh& mesh, const Field& f) {
  double worst = 0.0;
  for (const Vec3& p : mesh.vertices) worst = std::max(worst, std::abs(f.value(p)));
  return worst;
}

// Counts value() calls; forwards everything (including the Lipschitz bound, unless hidden).
class CountingField final : public Field {
 public:
  CountingField(const Field& inner, bool hide_lipschitz = false) : inner_(inner), hide_(hide_lipschitz) {}
  double value(const Vec3& p) const override {
    calls_.fetch_add(1, std::memory_order_relaxed);
    return inner_.value(p);
  }
  double value_and_gradient(const Vec3& p, Vec3& g) const override { return inner_.value_and_gradient(p, g); }
  std::optional<Aabb> bounds() const override { return inner_.bounds(); }
  std::optional<double> lipschitz_bound() const override { return hide_ ? std::nullopt : inner_.lipschitz_bound(); }
  std::int64_t calls() const { return calls_.load(); }

 private:
  const Field& inner_;
  bool hide_;
  mutable std::atomic<std::int64_t> calls_{0};
};

// Linear interpolation on a lattice edge of length l misplaces the root of a signed distance whose second
// derivative along the edge is at most k by at most k l^2 / 8 (the error of linear interpolation); the clamp of the
// interpolation parameter to [1e-3, 1 - 1e-3] adds at most 1e-3 l. For a sphere of radius r (or a torus tube of
// radius r) the second derivative along any line within l of the surface is at most 1 / (r - l).
double sdf_vertex_bound(double spacing, double radius) {
  const double l = kLongestEdge * spacing;
  return l * l / (8.0 * (radius - l)) + 1e-3 * l;
}

TEST(MarchingTiles, SphereIsClosedWithMinimumValenceFive) {
  const Vec3 c(0.031, -0.017, 0.013);
  const double r = 0.8, h = 0.05;
  const FieldPtr sphere = make_sphere(c, r);
  const Mesh mesh = marching_tiles(*sphere, tile_options(1.0, h));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kGoodClosed, kMinValence));
  EXPECT_EQ(rep.euler_characteristic, 2);
  EXPECT_EQ(rep.components, 1);
  EXPECT_EQ(histogram_peak(rep), 6);
  const double exact = testing::sphere_volume(r);
  EXPECT_NEAR(rep.volume, exact, 0.01 * exact);
  const double bound = sdf_vertex_bound(h, r);
  EXPECT_LT(testing::max_distance_to_sphere(mesh, c, r), bound);
  RecordProperty("max_distance_over_spacing", std::to_string(testing::max_distance_to_sphere(mesh, c, r) / h));
  RecordProperty("min_angle", std::to_string(rep.min_angle_degrees));
  EXPECT_TRUE(mesh.normals.empty());
}

// The same field through Marching Cubes at the same sample spacing has valence-4 vertices; tiles have none.
TEST(MarchingTiles, CubesHaveValenceFourVerticesTilesNone) {
  const Vec3 c(0.031, -0.017, 0.013);
  const double r = 0.8, h = 0.05;
  const FieldPtr sphere = make_sphere(c, r);
  MarchingCubesOptions mc;
  mc.bounds = Aabb{Vec3::Constant(-1.0), Vec3::Constant(1.0)};
  mc.cells = {40, 40, 40};  // cell size 0.05 = h
  const MeshReport cubes = check_mesh(marching_cubes(*sphere, mc));
  const MeshReport tiles = check_mesh(marching_tiles(*sphere, tile_options(1.0, h)));
  ASSERT_GT(cubes.valence_histogram.size(), 4u);
  EXPECT_GT(cubes.valence_histogram[4], 0);
  EXPECT_LE(cubes.min_valence, 4);
  ASSERT_GT(tiles.valence_histogram.size(), 4u);
  EXPECT_EQ(tiles.valence_histogram[3], 0);
  EXPECT_EQ(tiles.valence_histogram[4], 0);
  EXPECT_GE(tiles.min_valence, 5);
  RecordProperty("cubes_valence4", static_cast<int>(cubes.valence_histogram[4]));
  RecordProperty("tiles_min_valence", tiles.min_valence);
}

// A field without a Lipschitz bound takes the sign-scan path; the mesh is the same as with the bound.
TEST(MarchingTiles, SphereWithoutLipschitzBoundMatches) {
  const Vec3 c(0.031, -0.017, 0.013);
  SphereField plain(c, 0.8);
  const FieldPtr sphere = make_sphere(c, 0.8);
  const MarchingTilesOptions o = tile_options(1.0, 0.05, 2);
  const Mesh a = marching_tiles(plain, o);
  const Mesh b = marching_tiles(*sphere, o);
  EXPECT_TRUE(mesh_has(check_mesh(a), kGoodClosed, kMinValence));
  EXPECT_EQ(a.vertices, b.vertices);
  EXPECT_EQ(a.triangles, b.triangles);
}

TEST(MarchingTiles, TorusHasEulerZero) {
  const Vec3 c(0.01, 0.02, -0.015);
  const double big = 0.6, small = 0.25, h = 0.04;
  const FieldPtr torus = make_torus(c, Vec3(0, 0, 1), big, small);
  const Mesh mesh = marching_tiles(*torus, tile_options(1.0, h, 2));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kGoodClosed, kMinValence));
  EXPECT_EQ(rep.euler_characteristic, 0);
  EXPECT_EQ(rep.components, 1);
  const double exact = testing::torus_volume(big, small);
  EXPECT_NEAR(rep.volume, exact, 0.02 * exact);
  EXPECT_LT(testing::max_distance_to_torus(mesh, c, big, small), sdf_vertex_bound(h, small));
}

// Two spheres 0.1 spacing apart: the lattice cannot resolve the gap (the spheres may merge where a lattice edge
// spans it, and outside samples trapped in the gap become small cavities), but whatever it sees must be a closed
// oriented manifold with valence >= 5: Euler characteristic even and at most 2 per component. 3 spacings apart:
// always exactly two spheres.
TEST(MarchingTiles, TwoSpheresAlmostTouching) {
  const double h = 0.04, r0 = 0.4, r1 = 0.35;
  for (double gap : {0.1 * h, 3.0 * h}) {
    SCOPED_TRACE(gap);
    const FieldPtr f = make_csg(CsgOp::kUnion, {make_sphere(Vec3(-0.41, 0.003, 0.001), r0),
                                                make_sphere(Vec3(-0.01 + r1 + gap, 0.003, 0.001), r1)});
    const MeshReport rep = check_mesh(marching_tiles(*f, tile_options(1.0, h, 2)));
    EXPECT_TRUE(mesh_has(rep, kGoodClosed, kMinValence));
    const double exact = testing::sphere_volume(r0) + testing::sphere_volume(r1);
    EXPECT_NEAR(rep.volume, exact, 0.02 * exact);
    if (gap > h) {
      EXPECT_EQ(rep.components, 2);
      EXPECT_EQ(rep.euler_characteristic, 4);
    } else {
      EXPECT_GE(rep.components, 1);
      EXPECT_LE(rep.euler_characteristic, 2 * rep.components);
      EXPECT_EQ(rep.euler_characteristic % 2, 0);
    }
  }
}

// Gyroid sheet clipped by a sphere. The expected Euler characteristic is the one Marching Cubes finds at a 4x finer
// sampling. The clip radius is chosen away from radii where the sphere grazes the sheet: there the solid has knife
// edges thinner than any sampling, and both methods report resolution-dependent slivers and handles (measured:
// radius 0.4-0.43 gives Euler -6, one component, for tiles at spacing 0.04..0.005 and cubes at cell 0.04..0.005;
// radius 0.6-0.7 gives Euler -26..-96 depending on spacing and method).
TEST(MarchingTiles, GyroidClippedBySphere) {
  const FieldPtr f =
      make_csg(CsgOp::kIntersection, {make_gyroid(0.8, 0.16), make_sphere(Vec3(0.013, -0.007, 0.004), 0.41)});
  const double h = 0.02;
  const Mesh mesh = marching_tiles(*f, tile_options(0.5, h, 2));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kGoodClosed, kMinValence));
  MarchingCubesOptions mc;
  mc.bounds = Aabb{Vec3::Constant(-0.5), Vec3::Constant(0.5)};
  mc.cells = {200, 200, 200};  // cell 0.005
  mc.sparse = true;
  mc.threads = 2;
  const MeshReport fine = check_mesh(marching_cubes(*f, mc));
  ASSERT_TRUE(fine.closed);
  EXPECT_EQ(fine.euler_characteristic, -6);  // genus 4
  EXPECT_EQ(rep.euler_characteristic, fine.euler_characteristic);
  EXPECT_EQ(rep.components, fine.components);
  EXPECT_NEAR(rep.volume, fine.volume, 0.03 * fine.volume);
  // Every vertex lies on a crossed lattice edge, so within one edge length of the zero set; the field is
  // sqrt(3)-Lipschitz: |f(v)| <= sqrt(3) * longest edge.
  EXPECT_LT(max_abs_field(mesh, *f), std::sqrt(3.0) * kLongestEdge * h);
  RecordProperty("euler", static_cast<int>(rep.euler_characteristic));
}

// A cube with three orthogonal cylindrical tunnels meeting in the middle: 6 openings, genus 5, Euler -8. Sharp
// edges everywhere; the field is a signed distance bound (1-Lipschitz), so |f(v)| <= longest edge for every vertex
// (a vertex lies on a crossed edge, which holds a zero of f).
TEST(MarchingTiles, CsgBlockWithSharpEdgesAndHoles) {
  const double a = 0.5, r = 0.22, h = 0.03;
  const Vec3 c(0.004, -0.003, 0.002);
  const FieldPtr block = make_csg(
      CsgOp::kDifference, {make_box(c, Vec3::Constant(a)), make_cylinder(c - Vec3(0.8, 0, 0), c + Vec3(0.8, 0, 0), r),
                           make_cylinder(c - Vec3(0, 0.8, 0), c + Vec3(0, 0.8, 0), r),
                           make_cylinder(c - Vec3(0, 0, 0.8), c + Vec3(0, 0, 0.8), r)});
  const Mesh mesh = marching_tiles(*block, tile_options(0.7, h, 2));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kGoodClosed, kMinValence));
  EXPECT_EQ(rep.components, 1);
  EXPECT_EQ(rep.euler_characteristic, -8);
  // Volume by inclusion-exclusion: the cube, minus three cylinders of length 2a, plus the three pairwise
  // (Steinmetz) intersections 16 r^3 / 3, minus the triple one 8 (2 - sqrt 2) r^3. Marching tetrahedra chamfer
  // the sharp edges, so the measured volume is slightly smaller.
  const double exact = 8 * a * a * a - 3 * kPi * r * r * 2 * a + 16 * r * r * r - 8 * (2 - std::sqrt(2.0)) * r * r * r;
  EXPECT_NEAR(rep.volume, exact, 0.01 * exact);
  EXPECT_LT(max_abs_field(mesh, *block), kLongestEdge * h);
}

// A sampled grid (trilinear field of a sphere's distance on 21^3 samples).
TEST(MarchingTiles, SampledGridSphere) {
  SampledGridDesc desc;
  desc.nx = desc.ny = desc.nz = 21;
  desc.origin = Vec3::Constant(-1.0);
  desc.spacing = Vec3::Constant(0.1);
  std::vector<float> values;
  const Vec3 c(0.02, -0.01, 0.03);
  for (int k = 0; k < 21; ++k) {
    for (int j = 0; j < 21; ++j) {
      for (int i = 0; i < 21; ++i) {
        values.push_back(static_cast<float>((desc.origin + 0.1 * Vec3(i, j, k) - c).norm() - 0.7));
      }
    }
  }
  const FieldPtr grid = make_sampled_grid(desc, values);
  ASSERT_TRUE(grid->lipschitz_bound().has_value());
  const Mesh mesh = marching_tiles(*grid, tile_options(1.0, 0.045, 2));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kGoodClosed, kMinValence));
  EXPECT_EQ(rep.euler_characteristic, 2);
  EXPECT_EQ(rep.components, 1);
  // The trilinear interpolant I g of the sphere's distance g differs from g by at most (h^2 / 8)(|g_xx| + |g_yy| +
  // |g_zz|) <= 3 h^2 / (8 rho) (tensor-product linear interpolation error; rho >= 0.7 - sqrt(3) h near the
  // surface); the tiles add their own interpolation error on top (float samples add ~1e-7).
  const double grid_error = 3 * 0.1 * 0.1 / (8 * (0.7 - std::sqrt(3.0) * 0.1));
  EXPECT_LT(testing::max_distance_to_sphere(mesh, c, 0.7), sdf_vertex_bound(0.045, 0.7) + grid_error + 1e-6);
}

TEST(MarchingTiles, DeterministicAcrossThreadCounts) {
  const FieldPtr torus = make_torus(Vec3(0.02, -0.01, 0.03), Vec3(0.2, 0.1, 1.0), 0.55, 0.3);
  TorusField plain(Vec3(0.02, -0.01, 0.03), 0.55, 0.3);  // no Lipschitz bound: sign-scan path
  for (const Field* f : {static_cast<const Field*>(torus.get()), static_cast<const Field*>(&plain)}) {
    MarchingTilesOptions o = tile_options(1.0, 0.037);
    o.bounds.max = Vec3(1.0, 0.93, 1.1);
    o.normals = true;
    o.threads = 1;
    const Mesh one = marching_tiles(*f, o);
    ASSERT_FALSE(one.empty());
    EXPECT_TRUE(mesh_has(check_mesh(one), kGoodClosed, kMinValence));
    for (int threads : {2, 3, 8}) {
      o.threads = threads;
      const Mesh many = marching_tiles(*f, o);
      EXPECT_EQ(many.vertices, one.vertices) << threads;
      EXPECT_EQ(many.normals, one.normals) << threads;
      EXPECT_EQ(many.triangles, one.triangles) << threads;
    }
  }
}

// threads = 2 puts both threads to work on blocks (evaluations come from two distinct threads).
TEST(MarchingTiles, TwoThreadsBothEvaluate) {
  class ThreadRecorder final : public Field {
   public:
    double value(const Vec3& p) const override {
      thread_local std::uint64_t recorded_for = 0;  // the recorder this thread last registered with
      if (recorded_for != serial_) {
        recorded_for = serial_;
        std::lock_guard lock(mutex_);
        ids_.insert(std::this_thread::get_id());
      }
      return p.norm() - 0.8;
    }
    double value_and_gradient(const Vec3& p, Vec3& g) const override {
      g = p.normalized();
      return value(p);
    }
    std::optional<Aabb> bounds() const override { return std::nullopt; }
    std::optional<double> lipschitz_bound() const override { return 1.0; }
    std::size_t threads() const { return ids_.size(); }

   private:
    static std::uint64_t next_serial() {
      static std::atomic<std::uint64_t> next{1};
      return next.fetch_add(1);
    }
    const std::uint64_t serial_ = next_serial();
    mutable std::mutex mutex_;
    mutable std::set<std::thread::id> ids_;
  } field;
  const Mesh mesh = marching_tiles(field, tile_options(1.0, 0.01, 2));
  EXPECT_GT(mesh.triangles.size(), 100000u);
  EXPECT_GE(field.threads(), 2u);
}

TEST(MarchingTiles, NormalsAreUnitAndOutward) {
  const Vec3 c(0.02, 0.01, -0.03);
  const FieldPtr sphere = make_sphere(c, 0.7);
  MarchingTilesOptions o = tile_options(1.0, 0.06, 2);
  o.normals = true;
  const Mesh mesh = marching_tiles(*sphere, o);
  EXPECT_TRUE(normals_point_away_from(mesh, c, 1e-12, 0.9999));
  // Triangle normals agree with the outward direction too.
  for (const Triangle& t : mesh.triangles) {
    const Vec3 n = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    EXPECT_GT(n.dot(mesh.vertices[t[0]] - c), 0.0);
  }
}

// Samples exactly 0 (a box whose faces lie on lattice planes, in dyadic arithmetic) count as outside: no repeated
// or zero-area triangle, still closed and valence >= 5, every vertex within 1e-3 of an edge from the face.
TEST(MarchingTiles, ExactZerosGiveNoDegenerateTriangles) {
  // unit = spacing / kMeanEdge = 2^-5 exactly; lattice coordinates are multiples of 1/32 from bounds.min = -1.
  const double spacing = a15::kMeanEdge / 32.0;
  MarchingTilesOptions o = tile_options(1.0, spacing, 2);
  class DyadicBox final : public Field {
   public:
    double value(const Vec3& p) const override {
      return std::max({std::abs(p.x() - 0.125) - 0.5, std::abs(p.y()) - 0.375, std::abs(p.z() + 0.25) - 0.5});
    }
    double value_and_gradient(const Vec3& p, Vec3& g) const override {
      g = Vec3(1, 0, 0);
      return value(p);
    }
    std::optional<Aabb> bounds() const override { return std::nullopt; }
  } box;
  // Many samples are exactly zero: count them.
  int zeros = 0;
  for (int i = 0; i <= 64; ++i) {
    for (int j = 0; j <= 64; ++j) zeros += box.value(Vec3(-1.0 + i / 32.0, 0.375, -1.0 + j / 32.0)) == 0.0;
  }
  ASSERT_GT(zeros, 100);
  const Mesh mesh = marching_tiles(box, o);
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kGoodClosed, kMinValence));
  EXPECT_EQ(rep.euler_characteristic, 2);
  EXPECT_GT(rep.min_angle_degrees, 0.01);
  EXPECT_LT(max_abs_field(mesh, box), 1e-3 * kLongestEdge * spacing + 1e-12);
  // Faces are exact; the 12 edges (total length 11) are chamfered by cuts through points within one lattice edge
  // l of them, removing at most l^2 / 2 of cross-section each.
  const double l = kLongestEdge * spacing;
  EXPECT_LE(rep.volume, 0.75 + 1e-9);
  EXPECT_GT(rep.volume, 0.75 - 11.0 * l * l / 2.0);
}

TEST(MarchingTiles, SurfaceLeavingBoundsIsOpenButManifold) {
  const FieldPtr sphere = make_sphere(Vec3(0.7, 0.1, -0.2), 0.6);
  const Mesh mesh = marching_tiles(*sphere, tile_options(1.0, 0.05, 2));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kOpenManifold | kNoDegenerateTriangles));
  EXPECT_EQ(rep.components, 1);
  for (const Vec3& p : mesh.vertices) EXPECT_LE(p.x(), 1.0);
}

TEST(MarchingTiles, EmptyWhenNoSurface) {
  EXPECT_TRUE(marching_tiles(*make_sphere(Vec3(5, 5, 5), 0.5), tile_options(1.0, 0.1, 2)).empty());
  SphereField plain(Vec3(5, 5, 5), 0.5);
  EXPECT_TRUE(marching_tiles(plain, tile_options(1.0, 0.1, 2)).empty());
  EXPECT_TRUE(marching_tiles(*make_sphere(Vec3::Zero(), 5.0), tile_options(1.0, 0.1, 2)).empty());  // all inside
}

// Minimum distance to a few points minus r: a particle-like field without a Lipschitz bound, > 0 beyond r of every
// point. With seeds = the points, only blocks near them are visited; the mesh is identical to the full search's.
class PointsField final : public Field {
 public:
  PointsField(std::vector<Vec3> points, double r) : points_(std::move(points)), r_(r) {}
  double value(const Vec3& p) const override {
    double d = HUGE_VAL;
    for (const Vec3& q : points_) d = std::min(d, (p - q).norm());
    return d - r_;
  }
  double value_and_gradient(const Vec3& p, Vec3& g) const override {
    double d = HUGE_VAL;
    for (const Vec3& q : points_) {
      if ((p - q).norm() < d) {
        d = (p - q).norm();
        g = (p - q) / d;
      }
    }
    return d - r_;
  }
  std::optional<Aabb> bounds() const override { return std::nullopt; }

 private:
  std::vector<Vec3> points_;
  double r_;
};

TEST(MarchingTiles, SeedsModeIsClosedAndMatchesFullSearch) {
  const std::vector<Vec3> points = {Vec3(-0.5, -0.4, 0.1), Vec3(0.45, 0.3, -0.2), Vec3(0.1, 0.55, 0.5),
                                    Vec3(0.2, 0.65, 0.55)};
  const double r = 0.2;
  const PointsField field(points, r);
  MarchingTilesOptions o = tile_options(1.0, 0.03, 2);
  CountingField full_count(field);
  const Mesh full = marching_tiles(full_count, o);
  o.seeds = points;
  o.seed_radius = r * 1.01;
  CountingField seeded_count(field);
  const Mesh seeded = marching_tiles(seeded_count, o);
  const MeshReport rep = check_mesh(seeded);
  EXPECT_TRUE(mesh_has(rep, kGoodClosed, kMinValence));
  EXPECT_EQ(rep.components, 3);  // the last two points' balls overlap
  EXPECT_EQ(rep.euler_characteristic, 6);
  EXPECT_EQ(seeded.vertices, full.vertices);
  EXPECT_EQ(seeded.triangles, full.triangles);
  EXPECT_LT(seeded_count.calls(), full_count.calls());
  RecordProperty("seeded_evaluations", std::to_string(seeded_count.calls()));
  RecordProperty("full_evaluations", std::to_string(full_count.calls()));
}

// Balls of radii r_i: min_i |x - p_i| - r_i.
class BallsField final : public Field {
 public:
  BallsField(std::vector<Vec3> centres, std::vector<double> radii) : centres_(std::move(centres)), radii_(radii) {}
  double value(const Vec3& p) const override {
    double f = HUGE_VAL;
    for (std::size_t i = 0; i < centres_.size(); ++i) f = std::min(f, (p - centres_[i]).norm() - radii_[i]);
    return f;
  }
  double value_and_gradient(const Vec3& p, Vec3& g) const override {
    double f = HUGE_VAL;
    for (std::size_t i = 0; i < centres_.size(); ++i) {
      const double d = (p - centres_[i]).norm();
      if (d - radii_[i] < f) {
        f = d - radii_[i];
        g = (p - centres_[i]) / d;
      }
    }
    return f;
  }
  std::optional<Aabb> bounds() const override { return std::nullopt; }

 private:
  std::vector<Vec3> centres_;
  std::vector<double> radii_;
};

// Seeds of their own radii (a large ball among small ones) visit fewer blocks than one radius covering the largest,
// and give the same mesh.
TEST(MarchingTiles, SeedsOfTheirOwnRadiiMatchOneRadiusForAll) {
  std::vector<Vec3> centres;
  std::vector<double> radii;
  for (int i = 0; i < 12; ++i) {
    centres.emplace_back(-0.6 + 0.1 * i, 0.05 * (i % 3), -0.3);
    radii.push_back(0.04 + 0.002 * (i % 4));
  }
  centres.emplace_back(0.3, 0.3, 0.3);
  radii.push_back(0.35);
  const BallsField field(centres, radii);
  MarchingTilesOptions o = tile_options(1.0, 0.02, 2);
  o.seeds = centres;
  o.seed_radius = 0.35 + 0.02;
  CountingField one_count(field);
  const Mesh one = marching_tiles(one_count, o);
  o.seed_radius = 0.02;
  o.seed_radii = radii;
  CountingField own_count(field);
  const Mesh own = marching_tiles(own_count, o);
  EXPECT_TRUE(mesh_has(check_mesh(own), kGoodClosed, kMinValence));
  EXPECT_EQ(own.vertices, one.vertices);
  EXPECT_EQ(own.triangles, one.triangles);
  EXPECT_LT(2 * own_count.calls(), one_count.calls());
}

// A field's inside test lets the polygonizer skip cells whose tetrahedra lie inside; it must not change the mesh.
// Here: balls (no Lipschitz bound given) whose inside test is exact for boxes (a box is inside a ball when its
// farthest corner is), against the same field answering nothing.
class BallsWithInsideTest final : public Field {
 public:
  BallsWithInsideTest(std::vector<Vec3> centres, double r, bool answers)
      : centres_(std::move(centres)), r_(r), answers_(answers) {}
  double value(const Vec3& p) const override {
    calls_.fetch_add(1, std::memory_order_relaxed);
    double d = HUGE_VAL;
    for (const Vec3& c : centres_) d = std::min(d, (p - c).norm());
    return d - r_;
  }
  double value_and_gradient(const Vec3& p, Vec3& g) const override {
    g = Vec3::UnitX();
    return value(p);
  }
  std::optional<Aabb> bounds() const override { return std::nullopt; }
  bool inside_everywhere(const Aabb& box) const override {
    for (const Vec3& c : centres_) {
      const Vec3 far = (box.min - c).cwiseAbs().cwiseMax((box.max - c).cwiseAbs());
      if (far.norm() < r_) return true;
    }
    return false;
  }
  bool answers_inside_boxes() const override { return answers_; }
  std::int64_t calls() const { return calls_.load(); }

 private:
  std::vector<Vec3> centres_;
  double r_;
  bool answers_;
  mutable std::atomic<std::int64_t> calls_{0};
};

TEST(MarchingTiles, CellsInsideTheFieldAreSkippedWithoutChangingTheMesh) {
  const std::vector<Vec3> centres = {Vec3(-0.3, 0.0, 0.1), Vec3(0.35, 0.1, -0.1)};
  for (const double spacing : {0.01, 0.023}) {
    for (const double r : {0.2, 0.45}) {  // apart, then overlapping
      SCOPED_TRACE("spacing " + std::to_string(spacing) + ", r " + std::to_string(r));
      MarchingTilesOptions o = tile_options(1.0, spacing, 2);
      o.seeds = centres;
      o.seed_radius = 1.01 * r;
      const BallsWithInsideTest plain(centres, r, false), culled(centres, r, true);
      const Mesh a = marching_tiles(plain, o);
      const Mesh b = marching_tiles(culled, o);
      EXPECT_TRUE(mesh_has(check_mesh(b), kGoodClosed, kMinValence));
      EXPECT_EQ(b.vertices, a.vertices);
      EXPECT_EQ(b.triangles, a.triangles);
      EXPECT_LT(culled.calls(), plain.calls());
    }
  }
}

// The blocks near the seeds are collected in a bit per block of the lattice when the seeds are many for the lattice,
// in a hash set when they are few: both ways find the same blocks. A few seeds on a fine lattice take the set; the
// same seeds plus many copies of one far seed (its blocks hold no surface) take the bits.
TEST(MarchingTiles, SeedBlocksAreTheSameWhetherKeptAsBitsOrAsASet) {
  const std::vector<Vec3> points = {Vec3(-0.5, -0.4, 0.1), Vec3(0.45, 0.3, -0.2), Vec3(0.1, 0.55, 0.5)};
  const double r = 0.012;
  const PointsField field(points, r);
  for (int threads : {1, 3}) {
    MarchingTilesOptions o = tile_options(1.0, 0.001, threads);  // 250^3 blocks: over 2^20 + 64 bits per seed
    o.seed_radius = r * 1.01;
    o.seeds = points;
    const Mesh few = marching_tiles(field, o);
    std::vector<Vec3> many = points;
    many.resize(points.size() + 300000, Vec3(0.9, 0.9, 0.9));
    o.seeds = many;
    const Mesh with_far = marching_tiles(field, o);
    EXPECT_EQ(check_mesh(few).components, 3);
    EXPECT_EQ(with_far.vertices, few.vertices) << threads << " threads";
    EXPECT_EQ(with_far.triangles, few.triangles) << threads << " threads";
  }
}

// Sparse evaluation: halving the spacing multiplies field evaluations by ~4 (surface area), not ~8 (volume).
TEST(MarchingTiles, EvaluationsScaleWithArea) {
  const FieldPtr sphere = make_sphere(Vec3(0.01, 0.02, 0.03), 0.6);
  std::int64_t calls[2];
  std::size_t tris[2];
  for (int level = 0; level < 2; ++level) {
    CountingField f(*sphere);
    const Mesh m = marching_tiles(f, tile_options(1.0, level == 0 ? 0.01 : 0.005, 2));
    calls[level] = f.calls();
    tris[level] = m.triangles.size();
  }
  const double ratio = static_cast<double>(calls[1]) / static_cast<double>(calls[0]);
  EXPECT_GT(ratio, 3.0);
  EXPECT_LT(ratio, 5.0);
  EXPECT_NEAR(static_cast<double>(tris[1]) / static_cast<double>(tris[0]), 4.0, 0.3);
  // Far fewer than the dense lattice (8 points per cell of edge 4 unit).
  const double unit = 0.005 / a15::kMeanEdge;
  const double dense = 8.0 * std::pow(2.0 / (4.0 * unit), 3.0);
  EXPECT_LT(static_cast<double>(calls[1]), 0.1 * dense);
  RecordProperty("evaluation_ratio", std::to_string(ratio));
}

// A sphere whose value costs ~1 us; optionally with its Lipschitz bound (then the block phase dominates, without it
// the sign scan does).
class SlowSphere final : public Field {
 public:
  explicit SlowSphere(bool lipschitz) : lipschitz_(lipschitz) {}
  double value(const Vec3& p) const override {
    double x = p.norm();
    for (int i = 0; i < 300; ++i) x = std::sqrt(x * x + 1e-300 * i);
    return x - 0.7;
  }
  double value_and_gradient(const Vec3& p, Vec3& g) const override {
    g = p.normalized();
    return value(p);
  }
  std::optional<Aabb> bounds() const override { return std::nullopt; }
  std::optional<double> lipschitz_bound() const override {
    return lipschitz_ ? std::optional<double>(1.0) : std::nullopt;
  }

 private:
  bool lipschitz_;
};

// Cancels once progress passes `at` (or after 30 ms when at < 0); returns the seconds from cancel() to the throw.
double cancel_latency(const Field& field, double spacing, double at) {
  CancelToken token;
  RunControl control;
  control.cancel = &token;
  std::atomic<double> last{-1.0};
  std::atomic<bool> monotone{true};
  control.progress = [&](std::string_view stage, double f) {
    EXPECT_EQ(stage, "polygonize");
    if (f < last.load()) monotone = false;
    last = f;
  };
  std::atomic<std::int64_t> cancelled_at{0};
  std::atomic<bool> done{false};
  const auto now_ns = [] {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
  };
  std::thread canceller([&] {
    if (at < 0.0) {
      std::this_thread::sleep_for(std::chrono::milliseconds(30));
    } else {
      while (last.load() < at && !done.load()) std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    cancelled_at = now_ns();
    token.cancel();
  });
  bool cancelled = false;
  try {
    marching_tiles(field, tile_options(1.0, spacing, 2), control);
  } catch (const Error& e) {
    cancelled = e.kind() == ErrorKind::kCancelled;
  }
  const std::int64_t end = now_ns();
  done = true;
  canceller.join();
  EXPECT_TRUE(cancelled);
  EXPECT_TRUE(monotone.load());
  return static_cast<double>(end - cancelled_at.load()) * 1e-9;
}

// The whole runs take seconds (~1 us per evaluation, millions of evaluations); a cancel must take effect within
// the 50 ms of RunControl's contract (asserted with slack for a loaded machine).
TEST(MarchingTiles, CancelStopsQuickly) {
  const SlowSphere scan(false), blocks(true);
  const double during_scan = cancel_latency(scan, 0.003, -1.0);
  const double during_blocks = cancel_latency(blocks, 0.003, 0.08);
  EXPECT_LT(during_scan, 0.25);
  EXPECT_LT(during_blocks, 0.25);
  RecordProperty("cancel_latency_scan_ms", std::to_string(1e3 * during_scan));
  RecordProperty("cancel_latency_blocks_ms", std::to_string(1e3 * during_blocks));
}

TEST(MarchingTiles, ProgressReachesOne) {
  std::vector<double> seen;
  std::mutex m;
  RunControl control;
  control.progress = [&](std::string_view, double f) {
    std::lock_guard lock(m);
    seen.push_back(f);
  };
  marching_tiles(*make_sphere(Vec3::Zero(), 0.5), tile_options(1.0, 0.05, 2), control);
  ASSERT_FALSE(seen.empty());
  EXPECT_EQ(seen.front(), 0.0);
  EXPECT_EQ(seen.back(), 1.0);
  EXPECT_TRUE(std::is_sorted(seen.begin(), seen.end()));
}

// marching_tiles throws InvalidInput naming `field` in its field and its message.
void expect_invalid(const MarchingTilesOptions& o, const std::string& field) {
  const FieldPtr sphere = make_sphere(Vec3::Zero(), 0.5);
  EXPECT_TRUE(testing::throws_error([&] { marching_tiles(*sphere, o); }, ErrorKind::kInvalidInput, field, field));
}

TEST(MarchingTiles, InvalidOptionsNameTheField) {
  MarchingTilesOptions o = tile_options(1.0, 0.1);
  o.bounds.max.x() = -2.0;
  expect_invalid(o, "bounds");
  o = tile_options(1.0, 0.1);
  o.bounds.min.y() = std::nan("");
  expect_invalid(o, "bounds");
  for (double s : {0.0, -0.1, std::nan(""), HUGE_VAL}) {
    o = tile_options(1.0, s);
    expect_invalid(o, "spacing");
  }
  o = tile_options(1.0, 0.1);
  o.threads = -1;
  expect_invalid(o, "threads");
  const std::vector<Vec3> seeds = {Vec3::Zero(), Vec3(std::nan(""), 0, 0)};
  o = tile_options(1.0, 0.1);
  o.seeds = std::span(seeds).first(1);
  expect_invalid(o, "seed_radius");  // seeds without a radius
  o.seed_radius = -1.0;
  expect_invalid(o, "seed_radius");
  o.seeds = seeds;
  o.seed_radius = 0.5;
  expect_invalid(o, "seeds[1]");
  const std::vector<double> seed_radii = {0.1, -0.1};
  o.seeds = std::span(seeds).first(1);
  o.seed_radii = seed_radii;
  expect_invalid(o, "seed_radii");  // one per seed
  o.seeds = std::span(seeds).first(1);
  o.seed_radii = std::span(seed_radii).first(1);
  EXPECT_NO_THROW(marching_tiles(*make_sphere(Vec3::Zero(), 0.3), o));
  const std::vector<Vec3> two = {Vec3::Zero(), Vec3(0.1, 0, 0)};
  o.seeds = two;
  o.seed_radii = seed_radii;
  expect_invalid(o, "seed_radii[1]");
  // Too fine a lattice is a resource limit, not invalid input.
  o = tile_options(1.0, 1e-12);
  EXPECT_TRUE(testing::throws_error([&] { marching_tiles(*make_sphere(Vec3::Zero(), 0.5), o); },
                                    ErrorKind::kResourceLimit, "spacing"));
}

// The Lipschitz bounds the sparse search relies on hold on random pairs of points for every scene node type.
TEST(MarchingTiles, LipschitzBoundsHold) {
  const std::vector<PointSkeleton> points = {{Vec3(0.1, 0, 0), 0.4, 1.0}, {Vec3(-0.2, 0.1, 0), 0.3, -0.5}};
  const std::vector<SegmentSkeleton> segments = {{Vec3(0, 0, -0.3), Vec3(0, 0.2, 0.3), 0.25, 0.8}};
  BlobOptions blinn;
  blinn.kernel = BlobKernel::kBlinn;
  blinn.blobbiness = 2.0;
  std::vector<PointSkeleton> row;  // spread out: each support box overlaps only its neighbours'
  for (int i = 0; i < 10; ++i) row.push_back({Vec3(-0.9 + 0.2 * i, 0.1, 0), 0.15, 1.0});
  std::vector<PointSkeleton> many;
  for (int i = 0; i < 100; ++i) many.push_back({Vec3(0.01 * i, 0.3 * std::sin(i), 0.2 * std::cos(i)), 0.2, 1.0});
  SampledGridDesc desc;
  desc.nx = desc.ny = desc.nz = 5;
  desc.spacing = Vec3(0.3, 0.2, 0.25);
  desc.origin = Vec3(-0.5, -0.4, -0.5);
  desc.potential = true;
  desc.iso = 0.3;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> uv(-1.0f, 1.0f);
  std::vector<float> gv(125);
  for (float& v : gv) v = uv(rng);
  Eigen::Matrix3d shear;
  shear << 1.0, 0.5, 0.0, 0.0, 0.7, 0.0, 0.1, 0.0, 2.0;
  const std::vector<FieldPtr> fields = {
      make_sphere(Vec3(0.1, 0, 0), 0.5),
      make_box(Vec3::Zero(), Vec3(0.3, 0.2, 0.4)),
      make_rounded_box(Vec3::Zero(), Vec3(0.3, 0.2, 0.4), 0.1),
      make_cylinder(Vec3(0, 0, -0.3), Vec3(0.1, 0.2, 0.3), 0.2),
      make_cone(Vec3(0, 0, -0.3), Vec3(0.1, 0.2, 0.3), 0.3, 0.1),
      make_torus(Vec3::Zero(), Vec3(1, 1, 0), 0.4, 0.1),
      make_plane(Vec3(1, 2, 3), 0.1),
      make_capsule(Vec3(0, 0, -0.3), Vec3(0.1, 0.2, 0.3), 0.2),
      make_gyroid(0.5, 0.1),
      make_blobs(points, segments, BlobOptions{}),
      make_blobs(points, segments, blinn),
      make_blobs(many, {}, BlobOptions{}),
      make_blobs(row, {}, BlobOptions{}),
      make_sampled_grid(desc, gv),
      make_csg(CsgOp::kUnion, {make_sphere(Vec3::Zero(), 0.3), make_gyroid(0.5, 0.1)}),
      make_csg(CsgOp::kDifference, {make_box(Vec3::Zero(), Vec3::Constant(0.3)), make_sphere(Vec3::Zero(), 0.35)},
               CsgOptions{CsgBlend::kRFunction, 0.0}),
      make_csg(CsgOp::kIntersection,
               {make_sphere(Vec3::Zero(), 0.3), make_sphere(Vec3(0.2, 0, 0), 0.3), make_gyroid(0.5, 0.1)},
               CsgOptions{CsgBlend::kRFunction, 0.0}),
      make_csg(CsgOp::kUnion, {make_sphere(Vec3::Zero(), 0.3), make_sphere(Vec3(0.3, 0, 0), 0.2)},
               CsgOptions{CsgBlend::kSmooth, 0.2}),
      make_transform(make_torus(Vec3::Zero(), Vec3(0, 0, 1), 0.4, 0.1), 0.5 * Eigen::Matrix3d::Identity(),
                     Vec3(0.1, 0, 0)),
      make_transform(make_sphere(Vec3::Zero(), 0.3), shear, Vec3(0.1, 0, 0)),
  };
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const std::optional<double> l = fields[i]->lipschitz_bound();
    ASSERT_TRUE(l.has_value()) << i;
    double worst = 0.0;
    for (int trial = 0; trial < 20000; ++trial) {
      const Vec3 p(u(rng), u(rng), u(rng));
      const Vec3 q = p + 0.02 * Vec3(u(rng), u(rng), u(rng));
      const double d = (p - q).norm();
      if (d == 0.0) continue;
      worst = std::max(worst, std::abs(fields[i]->value(p) - fields[i]->value(q)) / d);
    }
    EXPECT_LE(worst, *l * (1.0 + 1e-9)) << "field " << i;
    EXPECT_GT(worst, 0.0) << "field " << i;
  }
}

// Skipping cells by the Lipschitz bound must not change the output: for several node types the mesh equals the one
// from the sign-scan path (bound hidden), where every cell of a visited block is marched.
TEST(MarchingTiles, LipschitzCullingDoesNotChangeTheMesh) {
  const std::vector<PointSkeleton> points = {{Vec3(0.1, 0, 0), 0.5, 1.0}, {Vec3(-0.25, 0.1, 0), 0.4, 1.0}};
  const std::vector<SegmentSkeleton> segments = {{Vec3(0, 0, -0.3), Vec3(0, 0.2, 0.35), 0.3, 0.8}};
  BlobOptions blinn;
  blinn.kernel = BlobKernel::kBlinn;
  blinn.blobbiness = 2.0;
  Eigen::Matrix3d shear;
  shear << 1.0, 0.5, 0.0, 0.0, 0.7, 0.0, 0.1, 0.0, 1.2;
  const std::vector<FieldPtr> fields = {
      make_blobs(points, segments, BlobOptions{}),
      make_blobs(points, segments, blinn),
      make_csg(CsgOp::kUnion, {make_sphere(Vec3(-0.2, 0, 0), 0.3), make_box(Vec3(0.2, 0, 0), Vec3(0.3, 0.2, 0.25))},
               CsgOptions{CsgBlend::kRFunction, 0.0}),
      make_csg(CsgOp::kDifference, {make_box(Vec3::Zero(), Vec3::Constant(0.5)), make_sphere(Vec3::Zero(), 0.6)},
               CsgOptions{CsgBlend::kSmooth, 0.1}),
      make_transform(make_torus(Vec3::Zero(), Vec3(0, 0, 1), 0.5, 0.2), shear, Vec3(0.05, 0, 0)),
  };
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const MarchingTilesOptions o = tile_options(1.0, 0.04, 2);
    CountingField with(*fields[i]), without(*fields[i], /*hide_lipschitz=*/true);
    const Mesh a = marching_tiles(with, o);
    const Mesh b = marching_tiles(without, o);
    ASSERT_FALSE(a.empty()) << i;
    EXPECT_TRUE(mesh_has(check_mesh(a), kGoodClosed, kMinValence));
    EXPECT_EQ(a.vertices, b.vertices) << i;
    EXPECT_EQ(a.triangles, b.triangles) << i;
    // Blob sums (0, 1): the bound adds up every kernel's steepest slope, far above the actual slopes, and at this
    // coarse spacing excludes little: the complete search then costs more than the sign scan (not compared).
    if (i >= 2) {
      EXPECT_LT(with.calls(), without.calls()) << i;
    }
    // Forcing either search gives the same mesh.
    for (TileSearch search : {TileSearch::kLipschitz, TileSearch::kSignScan}) {
      MarchingTilesOptions forced = o;
      forced.search = search;
      EXPECT_EQ(marching_tiles(*fields[i], forced).triangles, a.triangles) << i;
    }
  }
  // kLipschitz needs a bound.
  MarchingTilesOptions o = tile_options(1.0, 0.04, 2);
  o.search = TileSearch::kLipschitz;
  const SphereField plain(Vec3::Zero(), 0.5);
  EXPECT_TRUE(testing::throws_invalid_input([&] { marching_tiles(plain, o); }, "search"));
}

// Marching Cubes' sparse option (no evaluations where the Lipschitz bound rules out a crossing): identical mesh, fewer
// field evaluations.
TEST(MarchingCubesSparse, IdenticalToDenseWithFewerEvaluations) {
  const FieldPtr torus = make_torus(Vec3(0.02, -0.01, 0.03), Vec3(0.2, 0.1, 1.0), 0.55, 0.2);
  MarchingCubesOptions o;
  o.bounds = Aabb{Vec3::Constant(-1.0), Vec3::Constant(1.0)};
  o.cells = {97, 80, 101};
  o.normals = true;
  o.threads = 2;
  CountingField dense_count(*torus);
  const Mesh dense = marching_cubes(dense_count, o);
  o.sparse = true;
  for (int threads : {1, 2, 3}) {
    o.threads = threads;
    CountingField sparse_count(*torus);
    const Mesh sparse = marching_cubes(sparse_count, o);
    EXPECT_EQ(sparse.vertices, dense.vertices);
    EXPECT_EQ(sparse.normals, dense.normals);
    EXPECT_EQ(sparse.triangles, dense.triangles);
    EXPECT_LT(sparse_count.calls() * 3, dense_count.calls());
  }
  // Without a Lipschitz bound the option has no effect.
  TorusField plain(Vec3(0.02, -0.01, 0.03), 0.55, 0.2);
  o.normals = false;
  const Mesh a = marching_cubes(plain, o);
  o.sparse = false;
  EXPECT_EQ(marching_cubes(plain, o).triangles, a.triangles);
}

}  // namespace
}  // namespace surfacer
