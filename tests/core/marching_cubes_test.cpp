#include "core/polygonize/marching_cubes.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <mutex>
#include <random>
#include <thread>

#include "core/mesh/mesh_checks.h"
#include "core/util/errors.h"
#include "tests/support/error_expectations.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using testing::BoxField;
using testing::kClosedManifold;
using testing::kNoDegenerateTriangles;
using testing::kOpenManifold;
using testing::kPositiveVolume;
using testing::mesh_has;
using testing::normals_point_away_from;
using testing::PlaneField;
using testing::SphereField;
using testing::throws_invalid_input;
using testing::TorusField;
using testing::TwoSpheresField;

MarchingCubesOptions cube_options(double half, int cells, int threads = 1) {
  MarchingCubesOptions o;
  o.bounds = Aabb{Vec3::Constant(-half), Vec3::Constant(half)};
  o.cells = {cells, cells, cells};
  o.threads = threads;
  return o;
}

// Samples of a field on the grid of `options` (x fastest).
std::vector<float> sample(const Field& f, const MarchingCubesOptions& o) {
  std::vector<float> s;
  const Vec3 size = o.bounds.size();
  for (int k = 0; k <= o.cells[2]; ++k) {
    for (int j = 0; j <= o.cells[1]; ++j) {
      for (int i = 0; i <= o.cells[0]; ++i) {
        const Vec3 p =
            o.bounds.min + Vec3(size.x() * i / o.cells[0], size.y() * j / o.cells[1], size.z() * k / o.cells[2]);
        s.push_back(static_cast<float>(f.value(p)));
      }
    }
  }
  return s;
}

TEST(MarchingCubes, SphereIsClosedManifoldAndAccurate) {
  const Vec3 c(0.031, -0.017, 0.013);
  const double r = 0.8;
  SphereField sphere(c, r);
  const MarchingCubesOptions o = cube_options(1.0, 40);
  const double h = 2.0 / 40;
  const Mesh mesh = marching_cubes(sphere, o);
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kClosedManifold | kNoDegenerateTriangles | kPositiveVolume));
  EXPECT_EQ(rep.euler_characteristic, 2);
  EXPECT_EQ(rep.components, 1);
  const double exact = testing::sphere_volume(r);
  EXPECT_NEAR(rep.volume, exact, 0.01 * exact);
  // Linear interpolation of an exact SDF along a grid edge misplaces the root by about max|f''| h^2 / 8 with
  // |f''| <= 1 / r near the surface (measured: 0.0078 h here); allow twice that.
  const double dist = testing::max_distance_to_sphere(mesh, c, r);
  EXPECT_LT(dist, h * h / (4.0 * r));
  // A cubic lattice produces valence-4 vertices (Marching Tiles will not; ALGORITHMS.md section 2).
  ASSERT_GT(rep.valence_histogram.size(), 4u);
  EXPECT_GT(rep.valence_histogram[4], 0);
  EXPECT_GE(rep.min_valence, 3);
  EXPECT_TRUE(mesh.normals.empty());
  RecordProperty("valence4_vertices", static_cast<int>(rep.valence_histogram[4]));
  RecordProperty("vertices", static_cast<int>(mesh.vertices.size()));
}

TEST(MarchingCubes, TorusHasEulerZero) {
  const Vec3 c(0.01, 0.02, -0.015);
  TorusField torus(c, 0.6, 0.25);
  const Mesh mesh = marching_cubes(torus, cube_options(1.0, 48, 2));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kClosedManifold));
  EXPECT_EQ(rep.euler_characteristic, 0);
  EXPECT_EQ(rep.components, 1);
  const double exact = testing::torus_volume(0.6, 0.25);
  EXPECT_NEAR(rep.volume, exact, 0.02 * exact);
  const double h = 2.0 / 48;
  EXPECT_LT(testing::max_distance_to_torus(mesh, c, 0.6, 0.25), h * h / (4.0 * 0.25));  // as for the sphere
}

TEST(MarchingCubes, TwoSpheresGiveTwoComponents) {
  TwoSpheresField f(Vec3(-0.5, 0, 0), 0.35, Vec3(0.5, 0.05, 0), 0.3);
  const Mesh mesh = marching_cubes(f, cube_options(1.0, 36, 2));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kClosedManifold));
  EXPECT_EQ(rep.components, 2);
  EXPECT_EQ(rep.euler_characteristic, 4);
  const double exact = testing::sphere_volume(0.35) + testing::sphere_volume(0.3);
  EXPECT_NEAR(rep.volume, exact, 0.02 * exact);
}

TEST(MarchingCubes, GridAlignedBoxWithExactZerosHasNoDegenerateTriangles) {
  // Faces of the box lie on grid planes: those samples are exactly 0 and count as outside.
  BoxField box(Vec3::Zero(), Vec3(0.5, 0.5, 0.5));
  const Mesh mesh = marching_cubes(box, cube_options(1.0, 16));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kClosedManifold | kNoDegenerateTriangles));
  EXPECT_EQ(rep.euler_characteristic, 2);
  // Every vertex sits on the box surface (at a zero sample).
  for (const Vec3& p : mesh.vertices) EXPECT_NEAR(p.cwiseAbs().maxCoeff(), 0.5, 1e-12);
  EXPECT_GT(rep.min_angle_degrees, 1.0);
}

TEST(MarchingCubes, PlaneThroughGridPointsIsOpenButManifold) {
  PlaneField plane(Vec3(0, 0, 1), 0.25);  // z = 0.25 is a grid plane for 8 cells on [-1, 1]
  const Mesh mesh = marching_cubes(plane, cube_options(1.0, 8));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kOpenManifold | kNoDegenerateTriangles));
  EXPECT_EQ(rep.components, 1);
  EXPECT_EQ(rep.euler_characteristic, 1);  // a disk
  EXPECT_NEAR(rep.area, 4.0, 1e-9);
  for (const Vec3& p : mesh.vertices) EXPECT_NEAR(p.z(), 0.25, 1e-12);
  for (const Triangle& t : mesh.triangles) {  // outward: +z
    const Vec3 n = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    EXPECT_GT(n.z(), 0.0);
  }
}

TEST(MarchingCubes, SurfaceLeavingBoundsIsOpenButManifold) {
  SphereField sphere(Vec3(0.7, 0.1, -0.2), 0.6);
  const Mesh mesh = marching_cubes(sphere, cube_options(1.0, 30, 2));
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kOpenManifold));
  EXPECT_EQ(rep.euler_characteristic, 1);
  for (const Vec3& p : mesh.vertices) EXPECT_LE(p.x(), 1.0);
}

TEST(MarchingCubes, DeterministicAcrossThreadCounts) {
  TorusField torus(Vec3(0.02, -0.01, 0.03), 0.55, 0.3);
  MarchingCubesOptions o = cube_options(1.0, 37);
  o.cells = {37, 29, 41};
  o.normals = true;
  o.threads = 1;
  const Mesh one = marching_cubes(torus, o);
  ASSERT_FALSE(one.empty());
  for (int threads : {2, 3, 8}) {
    o.threads = threads;
    const Mesh many = marching_cubes(torus, o);
    EXPECT_EQ(many.vertices, one.vertices) << threads;
    EXPECT_EQ(many.normals, one.normals) << threads;
    EXPECT_EQ(many.triangles, one.triangles) << threads;
  }
  // The same for pre-sampled input.
  o.threads = 1;
  const std::vector<float> s = sample(torus, o);
  const Mesh one_s = marching_cubes_samples(s, o);
  o.threads = 2;
  const Mesh two_s = marching_cubes_samples(s, o);
  EXPECT_EQ(two_s.vertices, one_s.vertices);
  EXPECT_EQ(two_s.normals, one_s.normals);
  EXPECT_EQ(two_s.triangles, one_s.triangles);
  EXPECT_TRUE(mesh_has(check_mesh(two_s), kClosedManifold));
}

TEST(MarchingCubes, FieldNormalsAreUnitAndOutward) {
  const Vec3 c(0.02, 0.01, -0.03);
  SphereField sphere(c, 0.7);
  MarchingCubesOptions o = cube_options(1.0, 24, 2);
  o.normals = true;
  const Mesh mesh = marching_cubes(sphere, o);
  EXPECT_TRUE(normals_point_away_from(mesh, c, 1e-12, 0.9999));
}

TEST(MarchingCubes, SampleNormalsFromCentralDifferences) {
  const Vec3 c(0.02, 0.01, -0.03);
  SphereField sphere(c, 0.7);
  MarchingCubesOptions o = cube_options(1.0, 32, 2);
  o.normals = true;
  const std::vector<float> s = sample(sphere, o);
  const Mesh mesh = marching_cubes_samples(s, o);
  const MeshReport rep = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(rep, kClosedManifold));
  EXPECT_EQ(rep.euler_characteristic, 2);
  EXPECT_TRUE(normals_point_away_from(mesh, c, 1e-9, 0.99));
}

// Random inside/outside patterns exercise every cube case, ambiguous faces included; padding with outside samples
// closes the surface. The table must give closed, oriented 2-manifolds every time.
TEST(MarchingCubes, RandomSignsGiveClosedOrientedManifolds) {
  std::mt19937 rng(12345);
  for (int trial = 0; trial < 40; ++trial) {
    const int n = 6 + trial % 5;
    MarchingCubesOptions o = cube_options(1.0, n);
    o.cells = {n, n + 1, n - 1};
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    std::vector<float> s;
    for (int k = 0; k <= o.cells[2]; ++k) {
      for (int j = 0; j <= o.cells[1]; ++j) {
        for (int i = 0; i <= o.cells[0]; ++i) {
          const bool border = i == 0 || j == 0 || k == 0 || i == o.cells[0] || j == o.cells[1] || k == o.cells[2];
          float v = border ? 1.0f : u(rng) + (trial % 3 == 0 ? 0.3f : 0.0f);
          if (!border && trial % 4 == 1 && (i + j + k) % 7 == 0) v = 0.0f;  // exact zeros too
          s.push_back(v);
        }
      }
    }
    o.threads = 1 + trial % 3;
    const Mesh mesh = marching_cubes_samples(s, o);
    const MeshReport rep = check_mesh(mesh);
    SCOPED_TRACE(trial);
    EXPECT_TRUE(mesh_has(rep, kClosedManifold | kPositiveVolume));
    EXPECT_EQ(rep.euler_characteristic % 2, 0);
  }
}

// Every sign pattern of two face-adjacent cubes (all three axes), and every 5th of four cubes around a z-edge,
// padded by outside samples: closed, manifold and oriented. (core/polygonize/mc_tables.py checks the face-sharing
// property the manifoldness rests on for all case pairs; this checks the compiled table and the marcher.)
TEST(MarchingCubes, ExhaustiveSmallConfigurations) {
  struct Shape {
    int nx, ny, nz;  // configuration points per axis
  };
  for (Shape shape : {Shape{3, 2, 2}, Shape{2, 3, 2}, Shape{2, 2, 3}, Shape{3, 3, 2}}) {
    const int points = shape.nx * shape.ny * shape.nz;
    MarchingCubesOptions o;
    o.cells = {shape.nx + 1, shape.ny + 1, shape.nz + 1};
    o.bounds = Aabb{Vec3::Zero(), Vec3(o.cells[0], o.cells[1], o.cells[2])};
    o.threads = 1;
    std::vector<float> s(static_cast<std::size_t>(o.cells[0] + 1) * (o.cells[1] + 1) * (o.cells[2] + 1));
    int failures = 0;
    const int stride = points > 12 ? 5 : 1;
    for (int pattern = 1; pattern < (1 << points) && failures < 5; pattern += stride) {
      std::fill(s.begin(), s.end(), 1.0f);
      for (int p = 0; p < points; ++p) {
        const int i = 1 + p % shape.nx, j = 1 + (p / shape.nx) % shape.ny, k = 1 + p / (shape.nx * shape.ny);
        // Values differ per point so interpolated positions are generic.
        const float magnitude = 0.3f + 0.1f * static_cast<float>((p * 7 + pattern) % 5);
        s[(static_cast<std::size_t>(k) * (o.cells[1] + 1) + j) * (o.cells[0] + 1) + i] =
            (pattern >> p) & 1 ? -magnitude : magnitude;
      }
      const ::testing::AssertionResult good =
          mesh_has(check_mesh(marching_cubes_samples(s, o)), kClosedManifold | kPositiveVolume);
      if (!good) {
        ADD_FAILURE() << "shape " << shape.nx << shape.ny << shape.nz << " pattern " << pattern << ": "
                      << good.message();
        ++failures;
      }
    }
  }
}

TEST(MarchingCubes, EmptyWhenNoCrossing) {
  SphereField sphere(Vec3(5, 5, 5), 0.5);
  const Mesh mesh = marching_cubes(sphere, cube_options(1.0, 8, 2));
  EXPECT_TRUE(mesh.empty());
  EXPECT_TRUE(mesh.vertices.empty());
}

TEST(MarchingCubes, ReportsProgress) {
  SphereField sphere(Vec3::Zero(), 0.5);
  std::mutex m;
  std::vector<double> fractions;
  RunControl control;
  control.progress = [&](std::string_view stage, double f) {
    std::lock_guard lock(m);
    EXPECT_EQ(stage, "polygonize");
    fractions.push_back(f);
  };
  marching_cubes(sphere, cube_options(1.0, 16, 2), control);
  ASSERT_FALSE(fractions.empty());
  EXPECT_DOUBLE_EQ(*std::max_element(fractions.begin(), fractions.end()), 1.0);
  EXPECT_GE(fractions.size(), 16u);
}

TEST(MarchingCubes, AlreadyCancelledThrows) {
  SphereField sphere(Vec3::Zero(), 0.5);
  CancelToken token;
  token.cancel();
  RunControl control;
  control.cancel = &token;
  try {
    marching_cubes(sphere, cube_options(1.0, 16, 2), control);
    FAIL() << "expected Cancelled";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kCancelled);
  }
  std::vector<float> s(17 * 17 * 17, 1.0f);
  EXPECT_THROW(marching_cubes_samples(s, cube_options(1.0, 16, 1), control), Error);
}

TEST(MarchingCubes, CancelTakesEffectQuickly) {
  TorusField torus(Vec3::Zero(), 0.6, 0.3);
  CancelToken token;
  RunControl control;
  control.cancel = &token;
  const auto start = std::chrono::steady_clock::now();
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    token.cancel();
  });
  bool cancelled = false;
  std::chrono::steady_clock::time_point end;
  try {
    marching_cubes(torus, cube_options(1.0, 600, 2), control);  // ~2e8 field samples: many seconds uncancelled
  } catch (const Error& e) {
    end = std::chrono::steady_clock::now();
    cancelled = e.kind() == ErrorKind::kCancelled;
  }
  canceller.join();
  EXPECT_TRUE(cancelled);
  EXPECT_LT(std::chrono::duration<double>(end - start).count(), 0.5);
}

TEST(MarchingCubes, InvalidOptions) {
  SphereField sphere(Vec3::Zero(), 0.5);
  MarchingCubesOptions o = cube_options(1.0, 8);
  o.bounds.max.y() = o.bounds.min.y();
  EXPECT_TRUE(throws_invalid_input([&] { marching_cubes(sphere, o); }, "bounds"));
  o = cube_options(1.0, 8);
  o.bounds.max.x() = std::nan("");
  EXPECT_TRUE(throws_invalid_input([&] { marching_cubes(sphere, o); }, "bounds"));
  o = cube_options(1.0, 8);
  o.cells[2] = 0;
  EXPECT_TRUE(throws_invalid_input([&] { marching_cubes(sphere, o); }, "cells"));
  o = cube_options(1.0, 8);
  o.threads = -1;
  EXPECT_TRUE(throws_invalid_input([&] { marching_cubes(sphere, o); }, "threads"));
  o = cube_options(1.0, 8);
  std::vector<float> s(9 * 9 * 8, 1.0f);
  EXPECT_TRUE(throws_invalid_input([&] { marching_cubes_samples(s, o); }, "samples"));
}

TEST(MarchingCubes, SingleCellGrid) {
  MarchingCubesOptions o = cube_options(1.0, 1);
  std::vector<float> s = {-1, 1, 1, 1, 1, 1, 1, 1};
  const Mesh mesh = marching_cubes_samples(s, o);
  ASSERT_EQ(mesh.triangles.size(), 1u);
  ASSERT_EQ(mesh.vertices.size(), 3u);
  for (const Vec3& p : mesh.vertices) EXPECT_NEAR(p.sum(), -2.0, 1e-12);  // midpoints of the edges at (-1,-1,-1)
}

}  // namespace
}  // namespace surfacer
