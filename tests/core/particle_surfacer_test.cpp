#include "core/particles/particle_surfacer.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <span>
#include <string>

#include "core/mesh/grid_cleanup.h"
#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_repair.h"
#include "core/particles/smoothing.h"
#include "core/util/errors.h"
#include "core/util/triangle_limit.h"
#include "tests/support/error_expectations.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

namespace ps = particle_smoothing;
using testing::kClosed;
using testing::kClosedManifold;
using testing::kEdgeManifold;
using testing::kNoDegenerateTriangles;
using testing::kOriented;
using testing::kPositiveVolume;
using testing::mesh_has;
using testing::nearest_point_distance;
using testing::normals_point_away_from;

// A box of nx x ny x nz particles from `origin` at `spacing`, each moved by up to +-jitter per axis.
std::vector<Vec3> jittered_block(const Vec3& origin, int nx, int ny, int nz, double spacing, double jitter,
                                 std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> offset(-jitter, jitter);
  std::vector<Vec3> p;
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        p.emplace_back(origin.x() + spacing * i + offset(rng), origin.y() + spacing * j + offset(rng),
                       origin.z() + spacing * k + offset(rng));
      }
    }
  }
  return p;
}

// Particles of a jittered cubic lattice (spacing `spacing`, jitter +-spacing/6 per axis) inside a ball: dense enough
// that r_outer = 2 * r_inner >= spacing leaves no interior voids, irregular enough to be a fair test.
std::vector<Vec3> blob(const Vec3& center, double radius, double spacing, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-spacing / 6, spacing / 6);
  std::vector<Vec3> p;
  const int n = static_cast<int>(radius / spacing);
  for (int k = -n; k <= n; ++k) {
    for (int j = -n; j <= n; ++j) {
      for (int i = -n; i <= n; ++i) {
        const Vec3 q = Vec3(i, j, k) * spacing;
        if (q.norm() <= radius) p.push_back(center + q + Vec3(jitter(rng), jitter(rng), jitter(rng)));
      }
    }
  }
  return p;
}

std::vector<Vec3> three_blobs() {
  std::vector<Vec3> p = blob(Vec3(0, 0, 0), 1.5, 0.3, 1);
  for (const Vec3& q : blob(Vec3(6, 0, 0), 1.0, 0.3, 2)) p.push_back(q);
  for (const Vec3& q : blob(Vec3(0, 7, 1), 1.2, 0.3, 3)) p.push_back(q);
  return p;
}

ParticleSurfacingOptions options(double r_inner) {
  ParticleSurfacingOptions o;
  o.r_inner = r_inner;
  return o;
}

// A slab of particle lattice layers, in any orientation: `layers` layers of n x n particles at spacing d, square
// (kind 0), triangular layers stacked straight (1) or face-centred cubic stacked on its (111) face (2), rotated by
// `rotation` about the origin. The top layer is at height `top` in the lattice frame, x and y within [0, width].
struct LatticeSlab {
  std::vector<Vec3> particles;
  Eigen::Matrix3d rotation;
  int kind = 0;
  double d = 0.0, top = 0.0, width_x = 0.0, width_y = 0.0;
  // The highest plane the band admits above the top layer (eq. 3.5 / 3.6): a cusp sits above the circumcentre of a
  // lattice cell, d / sqrt(2) from its particles on a square lattice, d / sqrt(3) on a triangular one.
  double plane(double r_outer) const { return std::sqrt(r_outer * r_outer - d * d / (kind == 0 ? 2.0 : 3.0)); }
};

LatticeSlab lattice_slab(int kind, int n, int layers, double d,
                         const Eigen::Matrix3d& rotation = Eigen::Matrix3d::Identity()) {
  LatticeSlab s;
  s.kind = kind;
  s.d = d;
  s.rotation = rotation;
  const double row = kind == 0 ? d : d * std::sqrt(3.0) / 2.0;
  const double layer = kind == 2 ? d * std::sqrt(2.0 / 3.0) : d;
  for (int k = 0; k < layers; ++k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        Vec3 q(i * d, j * row, k * layer);
        if (kind > 0) q.x() += (j % 2) * d / 2.0;
        if (kind == 2) q += Vec3((k % 3) * d / 2.0, (k % 3) * d * std::sqrt(3.0) / 6.0, 0.0);
        s.top = std::max(s.top, q.z());
        s.width_x = std::max(s.width_x, q.x());
        s.width_y = std::max(s.width_y, q.y());
        s.particles.push_back(rotation * q);
      }
    }
  }
  return s;
}

struct Face {
  int vertices = 0;
  double mean = 0.0, rms = 0.0;  // height above the top layer
};

// The vertices above the top layer, at least `inset` inside the slab's sides.
Face top_face(const Mesh& mesh, const LatticeSlab& slab, double inset) {
  double sum = 0.0, sum2 = 0.0;
  Face f;
  for (const Vec3& world : mesh.vertices) {
    const Vec3 v = slab.rotation.transpose() * world;
    if (v.z() > slab.top && v.x() > inset && v.x() < slab.width_x - inset && v.y() > inset &&
        v.y() < slab.width_y - inset) {
      sum += v.z() - slab.top;
      sum2 += (v.z() - slab.top) * (v.z() - slab.top);
      ++f.vertices;
    }
  }
  if (f.vertices == 0) return f;
  f.mean = sum / f.vertices;
  f.rms = std::sqrt(std::max(0.0, sum2 / f.vertices - f.mean * f.mean));
  return f;
}

Eigen::Matrix3d rotation_xyz(double ax, double ay, double az) {
  const double deg = 3.14159265358979323846 / 180.0;
  return (Eigen::AngleAxisd(az * deg, Vec3::UnitZ()) * Eigen::AngleAxisd(ay * deg, Vec3::UnitY()) *
          Eigen::AngleAxisd(ax * deg, Vec3::UnitX()))
      .toRotationMatrix();
}

// A thin sheet: `layers` layers of particles (spacing d, jitter d/8) on the wavy surface z = a sin(x/3) cos(y/4).
std::vector<Vec3> wavy_sheet(int n, int layers, double d, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-d / 8, d / 8);
  std::vector<Vec3> p;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const double x = i * d, y = j * d, z = 2.0 * d * std::sin(x / (3 * d)) * std::cos(y / (4 * d));
      for (int k = 0; k < layers; ++k) p.emplace_back(x + jitter(rng), y + jitter(rng), z + k * d + jitter(rng));
    }
  }
  return p;
}

// Droplets of radius 1..3 d and single particles scattered in a box, none touching.
std::vector<Vec3> droplets(double d, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Vec3> p;
  for (int k = 0; k < 24; ++k) {
    const Vec3 c = Vec3(k % 4, (k / 4) % 3, k / 12) * 9.0 * d + Vec3(u(rng), u(rng), u(rng)) * d;
    const double radius = k % 6 == 5 ? 0.0 : d * (1.0 + 2.0 * u(rng));  // every sixth a single particle
    for (const Vec3& q : blob(c, radius, d, seed + k)) p.push_back(q);
  }
  return p;
}

struct Scene {
  std::string name;
  std::vector<Vec3> particles;
  double r_inner;
};
std::vector<Scene> varied_scenes() {
  std::vector<Scene> scenes;
  for (const std::uint32_t seed : {1u, 2u}) {
    scenes.push_back({"one-layer sheet " + std::to_string(seed), wavy_sheet(20, 1, 1.0, seed), 0.5 + 0.1 * seed});
    scenes.push_back({"droplets " + std::to_string(seed), droplets(1.0, seed), 0.5 + 0.1 * seed});
  }
  scenes.push_back({"two-layer sheet", wavy_sheet(18, 2, 1.0, 3), 0.55});
  scenes.push_back({"blobs", three_blobs(), 0.25});
  return scenes;
}

// --- Checkable facts (docs/ALGORITHMS.md §1) ------------------------------------------------------------------------

TEST(ParticleSurfacer, EveryVertexFaithfulAfterTheConstrainedSweeps) {
  const std::vector<Vec3> particles = three_blobs();
  ParticleSurfacingOptions o = options(0.25);
  o.polish_sweeps = 0;  // the output is then the mesh right after step 5
  ParticleSurfacingStats stats;
  const Mesh mesh = surface_particles(particles, {}, o, {}, &stats);
  ASSERT_GT(mesh.vertices.size(), 1000u);
  // Tolerance: 1e-9 relative (projection lands exactly on the sphere up to rounding).
  const double tol = 1e-9 * 0.5;
  for (const Vec3& v : mesh.vertices) {
    const double d = nearest_point_distance(particles, v);
    ASSERT_GE(d, 0.25 - tol);
    ASSERT_LE(d, 0.5 + tol);
  }
  EXPECT_EQ(stats.faithful_after_constrained, 1.0);
  EXPECT_LE(stats.max_violation_after_constrained, tol);
  EXPECT_EQ(stats.r_outer, 0.5);
  EXPECT_EQ(stats.vertices, mesh.vertices.size());

  // With the default polish, the reported fraction matches a brute-force count of the output.
  o.polish_sweeps = 5;
  const Mesh polished = surface_particles(particles, {}, o, {}, &stats);
  std::size_t faithful = 0;
  double worst = 0.0;
  for (const Vec3& v : polished.vertices) {
    const double d = nearest_point_distance(particles, v);
    const double violation = std::max({0.25 - d, d - 0.5, 0.0});
    faithful += violation <= tol;
    worst = std::max(worst, violation);
  }
  EXPECT_DOUBLE_EQ(stats.faithful_after_polish, static_cast<double>(faithful) / polished.vertices.size());
  EXPECT_NEAR(stats.max_violation_after_polish, worst, 1e-12);
  EXPECT_GT(stats.max_polish_displacement, 0.0);
  EXPECT_LT(stats.max_polish_displacement, 0.25);  // polish does not move the surface far (thesis §3.8)
}

TEST(ParticleSurfacer, SquareLatticeWithOuterRadiusPerEquation35GivesAPlanarTopFace) {
  // Lattice spacing d = 1, r_inner = d (the thesis' "average inter-particle spacing" choice). Eq. 3.5 asks
  // r_outer^2 >= r_inner^2 + d^2/2 = 1.5; the default r_outer = 2 r_inner satisfies it with room. r_outer = 1.05
  // violates it: no plane fits between the spheres, the surface must follow them.
  const LatticeSlab slab = lattice_slab(0, 14, 3, 1.0);
  const auto rms = [&](const ParticleSurfacingOptions& o) {
    const Face face = top_face(surface_particles(slab.particles, {}, o), slab, 2.5);
    EXPECT_GT(face.vertices, 100);
    return face.rms;
  };
  ParticleSurfacingOptions o = options(1.0);
  o.polish_sweeps = 0;
  const double flat = rms(o);
  o.r_outer = 1.05;
  const double bumpy = rms(o);
  EXPECT_LT(flat, 0.005 * 1.0);  // < 0.5% of r_inner
  EXPECT_GT(bumpy, 0.015);
  // The default polish keeps it planar.
  o.r_outer.reset();
  o.polish_sweeps = 5;
  EXPECT_LT(rms(o), 0.005);
}

// Where eq. 3.5 holds, across r_inner / d and with r_outer = 2 d or the default 2 r_inner, the top face of a square
// lattice is a plane (RMS < 0.5 % of r_inner), at or below the highest plane the band admits (it rests on the cusps),
// and every final vertex is faithful (docs/ALGORITHMS.md §1, "Flat surfaces").
TEST(ParticleSurfacer, SquareLatticesAcrossSpacingsGiveFlatTopFaces) {
  for (const double r_inner : {0.45, 0.6, 0.7, 0.85, 1.0}) {
    for (const bool default_outer : {false, true}) {
      SCOPED_TRACE(::testing::Message() << "r_inner " << r_inner << (default_outer ? ", r_outer 2 r_inner" : ", 2 d"));
      const double r_outer = default_outer ? 2.0 * r_inner : 2.0;
      const LatticeSlab slab = lattice_slab(0, 14, 3, 1.0);
      ParticleSurfacingOptions o = options(r_inner);
      if (!default_outer) o.r_outer = r_outer;
      ParticleSurfacingStats stats;
      const Face face = top_face(surface_particles(slab.particles, {}, o, {}, &stats), slab, 2.5);
      ASSERT_GT(face.vertices, 50);
      EXPECT_LT(face.rms, 0.005 * r_inner);
      // The vertices between the held ones may stand a little above the plane (2e-5 d measured).
      EXPECT_LE(face.mean, slab.plane(r_outer) + 1e-3 * r_inner);
      EXPECT_GE(face.mean, slab.plane(r_outer) - 0.02 * r_inner);
      EXPECT_EQ(stats.faithful_after_polish, 1.0);
      EXPECT_GT(stats.cusp_vertices, 0u);
    }
  }
}

// r_inner a few spacings wide (a kernel radius taken for r_inner): dozens of outer spheres pass near each vertex, and
// the top face still rests on the cusps as a plane, every vertex faithful (docs/ALGORITHMS.md §1, CHOICE "cusps
// held"). The search itself is held against every triple in cusp_search_test.cpp.
TEST(ParticleSurfacer, WideRadiiOnLatticesStillGiveFlatTopFaces) {
  for (const int kind : {0, 1}) {
    for (const double r_inner : {1.5, 2.0, 3.0}) {
      SCOPED_TRACE(::testing::Message() << "kind " << kind << ", r_inner " << r_inner << " d");
      const LatticeSlab slab = lattice_slab(kind, 26, 3, 1.0);
      ParticleSurfacingStats stats;
      const Face face =
          top_face(surface_particles(slab.particles, {}, options(r_inner), {}, &stats), slab, 2.0 * r_inner + 2.0);
      ASSERT_GT(face.vertices, 20);
      EXPECT_LT(face.rms, 0.005 * r_inner);
      EXPECT_LE(face.mean, slab.plane(2.0 * r_inner) + 1e-3 * r_inner);
      EXPECT_GE(face.mean, slab.plane(2.0 * r_inner) - 0.02 * r_inner);
      EXPECT_EQ(stats.faithful_after_polish, 1.0);
      EXPECT_GT(stats.cusp_vertices, 0u);
    }
  }
}

// Lattices the tests of the method were not built on: square, triangular (eq. 3.6) and face-centred cubic slabs,
// turned to arbitrary orientations, at spacings and radii where the equations hold.
TEST(ParticleSurfacer, LatticesInAnyOrientationGiveFlatFaces) {
  struct Case {
    int kind;
    double r_inner, r_outer;
    Eigen::Matrix3d rotation;
  };
  const std::vector<Case> cases = {
      {0, 0.6, 1.2, rotation_xyz(20, 35, 10)},  {0, 0.8, 1.6, rotation_xyz(33, 0, 0)},
      {1, 0.6, 1.2, rotation_xyz(17, -25, 40)}, {1, 0.45, 0.9, rotation_xyz(0, 0, 0)},
      {2, 0.5, 1.0, rotation_xyz(40, 10, 70)},  {2, 0.7, 1.3, rotation_xyz(-10, 20, 30)},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(::testing::Message() << "kind " << c.kind << ", r_inner " << c.r_inner << ", r_outer " << c.r_outer);
    const LatticeSlab slab = lattice_slab(c.kind, 16, 3, 1.0, c.rotation);
    ParticleSurfacingOptions o = options(c.r_inner);
    o.r_outer = c.r_outer;
    ParticleSurfacingStats stats;
    const Mesh mesh = surface_particles(slab.particles, {}, o, {}, &stats);
    const Face face = top_face(mesh, slab, 2.5);
    ASSERT_GT(face.vertices, 50);
    EXPECT_LT(face.rms, 0.005 * c.r_inner);
    EXPECT_NEAR(face.mean, slab.plane(c.r_outer), 0.02 * c.r_inner);
    EXPECT_EQ(stats.faithful_after_polish, 1.0);
    EXPECT_TRUE(mesh_has(check_mesh(mesh), kClosedManifold | kNoDegenerateTriangles | kPositiveVolume));
  }
}

// vertex_only_band keeps the thesis' band at the vertices: the face floats above every plane the band admits, held
// where a vertex happens to lie near a cusp; the default holds every cusp and lays the face on them.
TEST(ParticleSurfacer, VertexOnlyBandLeavesTheFaceAboveTheCusps) {
  const LatticeSlab slab = lattice_slab(0, 14, 3, 1.0);
  ParticleSurfacingOptions o = options(0.6);
  ParticleSurfacingStats held, free;
  const Face on_cusps = top_face(surface_particles(slab.particles, {}, o, {}, &held), slab, 2.5);
  o.vertex_only_band = true;
  const Face thesis = top_face(surface_particles(slab.particles, {}, o, {}, &free), slab, 2.5);
  EXPECT_GT(thesis.mean, slab.plane(1.2) + 0.02);
  EXPECT_GT(thesis.rms, 0.005 * 0.6);
  EXPECT_LE(on_cusps.mean, slab.plane(1.2) + 1e-3 * 0.6);
  EXPECT_EQ(free.cusp_vertices, 0u);
  EXPECT_GT(held.cusp_vertices, 0u);
  EXPECT_EQ(held.faithful_after_polish, 1.0);
  EXPECT_EQ(free.faithful_after_polish, 1.0);
}

// Holding the cusps moves a curved fluid's surface in, toward the particles' own volume (N d^3 for particles on a
// lattice of spacing d), which the band's r_outer start overstates: droplets of every size end closer to it, and
// still within the band.
TEST(ParticleSurfacer, HeldCuspsBringDropletVolumesCloserToTheParticles) {
  for (const double radius : {2.0, 3.5, 6.0}) {
    SCOPED_TRACE(radius);
    const std::vector<Vec3> particles = blob(Vec3(0.3, -0.2, 0.1), radius, 1.0, 11);
    const double particle_volume = static_cast<double>(particles.size());
    ParticleSurfacingOptions o = options(0.6);
    ParticleSurfacingStats stats;
    const MeshReport held = check_mesh(surface_particles(particles, {}, o, {}, &stats));
    o.vertex_only_band = true;
    const MeshReport thesis = check_mesh(surface_particles(particles, {}, o));
    EXPECT_GT(held.volume, particle_volume);  // r_inner = 0.6 d > d / 2: any faithful surface holds more
    EXPECT_LT(held.volume, thesis.volume);
    EXPECT_EQ(stats.faithful_after_polish, 1.0);
    EXPECT_TRUE(mesh_has(held, kClosedManifold | kNoDegenerateTriangles | kPositiveVolume));
    EXPECT_EQ(held.components, 1);
  }
}

TEST(ParticleSurfacer, FreeFloatingBlobsGiveClosedOrientedManifolds) {
  ParticleSurfacingStats stats;
  const Mesh mesh = surface_particles(three_blobs(), {}, options(0.25), {}, &stats);
  const MeshReport r = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(r, kClosedManifold | kNoDegenerateTriangles | kPositiveVolume));
  EXPECT_EQ(r.components, 3);
  EXPECT_EQ(r.euler_characteristic, 6);  // three spheres
  EXPECT_EQ(stats.triangles, mesh.triangles.size());
}

TEST(ParticleSurfacer, IsolatedParticleGivesASmallClosedSphere) {
  const Vec3 c(1, -2, 3);
  const std::vector<Vec3> particles{c};
  ParticleSurfacingOptions o = options(1.0);
  o.polish_sweeps = 0;
  const Mesh mesh = surface_particles(particles, {}, o);
  const MeshReport r = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(r, kClosedManifold));
  EXPECT_EQ(r.components, 1);
  EXPECT_EQ(r.euler_characteristic, 2);
  double lo = 1e9, hi = 0.0;
  for (const Vec3& v : mesh.vertices) {
    lo = std::min(lo, (v - c).norm());
    hi = std::max(hi, (v - c).norm());
  }
  EXPECT_GE(lo, 1.0 - 1e-9);
  EXPECT_LE(hi, 2.0 + 1e-9);
  EXPECT_LT(hi - lo, 0.1);  // round: every vertex within 10% of r_inner of one radius
  // Volume of a sphere of that radius, within the faceting error.
  const double radius = 0.5 * (lo + hi);
  EXPECT_NEAR(r.volume, testing::sphere_volume(radius), 0.03 * r.volume);
}

// Dense particles (where the polygonizer reads most signs from a precomputed inside mask) across r_outer / r_inner,
// including ratios whose mask is coarser than r_inner / 2: the initial vertices lie on the r_outer iso-surface up to
// half a lattice edge, so no sample outside the r_outer balls was taken for inside.
TEST(ParticleSurfacer, InitialSurfaceLiesOnTheOuterIsoSurfaceAcrossRadiusRatios) {
  const std::vector<Vec3> particles = jittered_block(Vec3::Zero(), 12, 12, 12, 0.1, 0.02, 9);
  const double r_inner = 0.08, h = 0.8 * r_inner;  // the default spacing factor
  for (double ratio : {1.3, 2.0, 5.0, 12.0}) {
    ParticleSurfacingOptions o = options(r_inner);
    o.r_outer = ratio * r_inner;
    const Mesh initial = initial_particle_surface(particles, {}, o, {});
    ASSERT_GT(initial.vertices.size(), 100u) << ratio;
    EXPECT_TRUE(mesh_has(check_mesh(initial), kClosed | kOriented, 5)) << ratio;  // no cell skipped that held surface
    double worst = 0.0;
    for (const Vec3& v : initial.vertices) {
      worst = std::max(worst, std::abs(nearest_point_distance(particles, v) - *o.r_outer));
    }
    EXPECT_LE(worst, 0.5 * h) << "r_outer = " << ratio << " r_inner";
  }
}

// The same with per-particle radii, narrow and wide spreads: the initial vertices lie on the iso-surface of
// min_i (|x - p_i| - r_outer_i), which the polygonizer's sign test and its inside mask (built for the smallest
// ball) must both respect.
TEST(ParticleSurfacer, InitialSurfaceLiesOnTheWeightedOuterIsoSurface) {
  const std::vector<Vec3> particles = jittered_block(Vec3::Zero(), 12, 12, 12, 0.1, 0.02, 11);
  const double r_inner = 0.08, h = 0.8 * r_inner;
  for (const double spread : {0.1, 0.5}) {
    std::vector<double> radii(particles.size());
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> factor(1.0 - spread, 1.0 + spread);
    for (double& r : radii) r = r_inner * factor(rng);
    for (const double ratio : {2.0, 5.0}) {
      ParticleSurfacingOptions o = options(r_inner);
      o.r_outer = ratio * r_inner;
      const Mesh initial = initial_particle_surface(particles, radii, o, {});
      ASSERT_GT(initial.vertices.size(), 100u);
      EXPECT_TRUE(mesh_has(check_mesh(initial), kClosed | kOriented, 5));
      double worst = 0.0;
      for (const Vec3& v : initial.vertices) {
        double f = std::numeric_limits<double>::infinity();
        for (std::size_t i = 0; i < particles.size(); ++i)
          f = std::min(f, (v - particles[i]).norm() - ratio * radii[i]);
        worst = std::max(worst, std::abs(f));
      }
      EXPECT_LE(worst, 0.5 * h) << "radii spread " << spread << ", r_outer = " << ratio << " r_inner";
    }
  }
}

TEST(ParticleSurfacer, InitialMarchingTilesMeshHasMinimumValenceFive) {
  ParticleSurfacingStats stats;
  const Mesh initial = initial_particle_surface(three_blobs(), {}, options(0.25), {}, &stats);
  const MeshReport r = check_mesh(initial);
  EXPECT_TRUE(mesh_has(r, kClosed | kOriented, 5));
  EXPECT_EQ(stats.initial_min_valence, r.min_valence);
  EXPECT_EQ(r.components, 3);
  // ... and its vertices lie on the r_outer iso-surface up to the linear interpolation error, at most half a lattice
  // edge where the distance field has a crease between two particles (h = 0.8 r_inner = 0.2).
  const std::vector<Vec3> particles = three_blobs();
  for (const Vec3& v : initial.vertices) ASSERT_NEAR(nearest_point_distance(particles, v), 0.5, 0.5 * 0.2);
  // The full pipeline reports the same initial mesh.
  ParticleSurfacingStats full;
  (void)surface_particles(particles, {}, options(0.25), {}, &full);
  EXPECT_EQ(full.initial_vertices, initial.vertices.size());
  EXPECT_EQ(full.initial_min_valence, r.min_valence);
}

TEST(ParticleSurfacer, ContainerBoxKeepsEveryVertexInside) {
  // Fluid resting in the corner of a tank: particles reach the walls, so the r_outer surface pokes through them.
  const std::vector<Vec3> particles = jittered_block(Vec3::Constant(0.1), 8, 8, 4, 0.3, 0.05, 5);
  ParticleSurfacingOptions o = options(0.25);
  o.container_box = Aabb{Vec3(0, 0, 0), Vec3(2, 2, 2)};
  o.erosion = 0.2;  // erosion moves vertices too; the container still wins
  const Mesh mesh = surface_particles(particles, {}, o);
  int on_floor = 0;
  for (const Vec3& v : mesh.vertices) {
    ASSERT_TRUE(o.container_box->contains(v)) << v.transpose();
    on_floor += v.z() == 0.0;
  }
  EXPECT_GT(on_floor, 50);  // the fluid lies flat on the floor
  EXPECT_TRUE(mesh_has(check_mesh(mesh), kClosed | kEdgeManifold | kOriented));
}

TEST(ParticleSurfacer, ContainerSolidSnapsVerticesInside) {
  const std::vector<Vec3> particles = blob(Vec3(0, 0, 0), 1.5, 0.3, 9);
  ParticleSurfacingOptions o = options(0.25);
  const auto solid = std::make_shared<testing::SphereField>(Vec3(0.8, 0, 0), 1.6);  // cuts off the +x side
  o.container_solid = solid;
  const Mesh mesh = surface_particles(particles, {}, o);
  int on_wall = 0;
  for (const Vec3& v : mesh.vertices) {
    const double f = solid->value(v);
    ASSERT_LE(f, 1e-12) << v.transpose();
    on_wall += f > -1e-6;
  }
  EXPECT_GT(on_wall, 20);
}

// --- Solver ---------------------------------------------------------------------------------------------------------

Mesh noisy_sphere(int subdivisions, double noise, std::uint32_t seed) {
  Mesh m = testing::icosphere(subdivisions, 1.0);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-noise, noise);
  for (Vec3& v : m.vertices) v *= 1.0 + u(rng);
  return m;
}

// The 1-ring against a set-based reference, on a closed mesh large enough to be cut into several vertex ranges and on
// a soup with repeated and degenerate triangles, for several thread counts.
TEST(ParticleSmoothing, OneRingIsTheSetOfEdgeNeighboursWhateverTheThreads) {
  Mesh soup;
  std::mt19937 rng(5);
  std::uniform_int_distribution<std::uint32_t> pick(0, 149999);
  for (int t = 0; t < 300000; ++t) soup.triangles.push_back({pick(rng), pick(rng), t % 7 == 0 ? 17u : pick(rng)});
  for (const Mesh& m : {testing::icosphere(7, 1.0), soup}) {
    const std::size_t n = m.triangles.size() == 300000 ? 150000 : m.vertices.size();
    ASSERT_GT(n, 2u * 65536u);
    std::vector<std::set<std::uint32_t>> reference(n);
    for (const Triangle& t : m.triangles) {
      for (int c = 0; c < 3; ++c) {
        const std::uint32_t a = t[c], b = t[(c + 1) % 3];
        if (a == b) continue;
        reference[a].insert(b);
        reference[b].insert(a);
      }
    }
    for (const int threads : {1, 2, 3, 8}) {
      SCOPED_TRACE(threads);
      const ps::Graph ring = ps::one_ring(n, m.triangles, threads);
      ASSERT_EQ(ring.rows(), n);
      for (std::size_t i = 0; i < n; ++i) {
        const std::vector<std::uint32_t> row(ring.cols.begin() + ring.offsets[i],
                                             ring.cols.begin() + ring.offsets[i + 1]);
        ASSERT_EQ(row, std::vector<std::uint32_t>(reference[i].begin(), reference[i].end())) << "vertex " << i;
      }
    }
  }
}

// Normals and the two-ring sweep plan are built in parallel pieces: the same bits and lists whatever the threads.
TEST(ParticleSmoothing, NormalsAndSweepPlanAreTheSameWhateverTheThreads) {
  const Mesh m = noisy_sphere(7, 0.02, 3);
  ASSERT_GT(m.vertices.size(), 2u * 65536u);
  const ps::Graph ring = ps::one_ring(m.vertices.size(), m.triangles, 2);
  const std::vector<Vec3> normals = ps::vertex_normals(m.vertices, m.triangles, 1);
  const ps::SweepPlan plan = ps::plan_two_ring_sweeps(ring, 8, 1);
  EXPECT_EQ(plan.interior.size() + plan.seams.size(), m.vertices.size());
  for (const Vec3& n : normals) ASSERT_NEAR(n.norm(), 1.0, 1e-12);
  for (const int threads : {2, 3, 8}) {
    SCOPED_TRACE(threads);
    EXPECT_EQ(ps::vertex_normals(m.vertices, m.triangles, threads), normals);
    const ps::SweepPlan p = ps::plan_two_ring_sweeps(ring, 8, threads);
    EXPECT_EQ(p.interior, plan.interior);
    EXPECT_EQ(p.seams, plan.seams);
    EXPECT_EQ(p.block_begin, plan.block_begin);
  }
}

TEST(ParticleSmoothing, BilaplacianIsSymmetricPositiveSemidefiniteWithTwoRingSupport) {
  const Mesh m = noisy_sphere(3, 0.05, 1);
  const ps::Graph ring = ps::one_ring(m.vertices.size(), m.triangles);
  const ps::SparseMatrix b = ps::bilaplacian(m.vertices, m.triangles, ring, 2);
  const std::size_t n = m.vertices.size();
  // Dense copy for the checks.
  std::vector<std::vector<double>> dense(n, std::vector<double>(n, 0.0));
  for (std::size_t i = 0; i < n; ++i) {
    dense[i][i] = b.diagonal[i];
    for (std::uint32_t e = b.graph.offsets[i]; e < b.graph.offsets[i + 1]; ++e) dense[i][b.graph.cols[e]] = b.values[e];
  }
  double scale = 0.0;
  for (std::size_t i = 0; i < n; ++i) scale = std::max(scale, b.diagonal[i]);
  for (std::size_t i = 0; i < n; ++i) {
    double row_sum = 0.0;
    for (std::size_t j = 0; j < n; ++j) {
      EXPECT_NEAR(dense[i][j], dense[j][i], 1e-6 * scale);
      row_sum += dense[i][j];
    }
    EXPECT_NEAR(row_sum, 0.0, 1e-5 * scale);  // W 1 = 0, so B 1 = 0
    // Support: within two rings of i.
    std::set<std::uint32_t> two;
    for (std::uint32_t e = ring.offsets[i]; e < ring.offsets[i + 1]; ++e) {
      const std::uint32_t k = ring.cols[e];
      two.insert(k);
      for (std::uint32_t f = ring.offsets[k]; f < ring.offsets[k + 1]; ++f) two.insert(ring.cols[f]);
    }
    for (std::uint32_t e = b.graph.offsets[i]; e < b.graph.offsets[i + 1]; ++e) EXPECT_TRUE(two.count(b.graph.cols[e]));
  }
  std::mt19937 rng(3);
  std::normal_distribution<double> g;
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<Vec3> x(n);
    for (Vec3& v : x) v = Vec3(g(rng), g(rng), g(rng));
    EXPECT_GE(ps::energy(b, x), -1e-6 * scale);
  }
  EXPECT_EQ(b.nonzeros(), b.values.size() + n);
}

TEST(ParticleSmoothing, DegenerateTrianglesKeepTheMatrixFinite) {
  Mesh m = testing::icosphere(2, 1.0);
  // Collapse one triangle onto a line and another onto a point.
  const Triangle t = m.triangles[0];
  m.vertices[t[2]] = 0.5 * (m.vertices[t[0]] + m.vertices[t[1]]);
  const Triangle u = m.triangles[100];
  m.vertices[u[1]] = m.vertices[u[0]];
  m.vertices[u[2]] = m.vertices[u[0]];
  const ps::Graph ring = ps::one_ring(m.vertices.size(), m.triangles);
  const ps::SparseMatrix b = ps::bilaplacian(m.vertices, m.triangles, ring, 1);
  for (const double d : b.diagonal) EXPECT_TRUE(std::isfinite(d));
  for (const float v : b.values) EXPECT_TRUE(std::isfinite(v));
  const std::vector<Vec3> normals = ps::vertex_normals(m.vertices, m.triangles);
  ps::OffsetSmoothing smoothing(ring, ps::cotangent_laplacian(m.vertices, m.triangles, ring, 1), m.vertices, normals,
                                1);
  for (int s = 0; s < 5; ++s) smoothing.sweep({}, {}, 1.4, 1);
  for (const double v : smoothing.offsets()) EXPECT_TRUE(std::isfinite(v));
}

// The matrix-free sweeps minimize the Bilaplacian energy of the explicit B, and the parallel order (block interiors
// first, then seams) converges like plain Gauss-Seidel in index order.
TEST(ParticleSmoothing, BlockOrderedGaussSeidelConvergesLikeSequential) {
  const Mesh m = noisy_sphere(4, 0.1, 2);
  const std::size_t n = m.vertices.size();
  const ps::Graph ring = ps::one_ring(n, m.triangles);
  const ps::SparseMatrix b = ps::bilaplacian(m.vertices, m.triangles, ring, 2);
  const ps::Cotangent cot = ps::cotangent_laplacian(m.vertices, m.triangles, ring, 2);
  const std::vector<Vec3> normals = ps::vertex_normals(m.vertices, m.triangles);
  const ps::SweepPlan sequential_plan = ps::plan_two_ring_sweeps(ring, 1),
                      blocked_plan = ps::plan_two_ring_sweeps(ring, 8);
  ASSERT_TRUE(sequential_plan.seams.empty());
  ASSERT_FALSE(blocked_plan.seams.empty());
  EXPECT_EQ(blocked_plan.interior.size() + blocked_plan.seams.size(), n);
  const ps::OffsetSmoothing probe_energy(ring, cot, m.vertices, normals, 1);
  // The energy through W equals x^T B x with the explicit B.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-0.05, 0.05);
  std::vector<double> probe(n);
  for (double& v : probe) v = u(rng);
  std::vector<Vec3> x(n);
  for (std::size_t i = 0; i < n; ++i) x[i] = m.vertices[i] + probe[i] * normals[i];
  EXPECT_NEAR(probe_energy.energy(probe), ps::energy(b, x), 1e-5 * ps::energy(b, x));
  // Offsets clamped to a band of +-0.05 around the start; the energy is compared with its minimum estimated from many
  // sequential sweeps.
  const std::vector<double> lo(n, -0.05), hi(n, 0.05);
  for (const double omega : {1.0, 1.4}) {
    ps::OffsetSmoothing sequential(ring, cot, m.vertices, normals, 1), blocked(ring, cot, m.vertices, normals, 8),
        converged(ring, cot, m.vertices, normals, 1);
    for (int s = 0; s < 400; ++s) converged.sweep(lo, hi, omega, 1);
    const double emin = converged.energy();
    double es = sequential.energy(), eb = es;
    const double e0 = es;
    for (int s = 0; s < 10; ++s) {
      sequential.sweep(lo, hi, omega, 1);
      blocked.sweep(lo, hi, omega, 2);
      const double es_next = sequential.energy(), eb_next = blocked.energy();
      // Projected SOR with 0 < omega < 2 never increases a convex quadratic over a box.
      EXPECT_LE(es_next, es * (1 + 1e-9)) << omega;
      EXPECT_LE(eb_next, eb * (1 + 1e-9)) << omega;
      es = es_next;
      eb = eb_next;
    }
    EXPECT_LT(es - emin, 0.2 * (e0 - emin)) << omega;
    EXPECT_LT(eb - emin, 0.2 * (e0 - emin)) << omega;
    EXPECT_NEAR((eb - emin) / (es - emin), 1.0, 0.3) << omega;
    // The parallel order gives the same bits on one thread as on two.
    ps::OffsetSmoothing one_thread(ring, cot, m.vertices, normals, 8);
    for (int s = 0; s < 10; ++s) one_thread.sweep(lo, hi, omega, 1);
    EXPECT_TRUE(std::ranges::equal(one_thread.offsets(), blocked.offsets())) << omega;
  }
  // The same holds for the uniform Laplacian sweeps.
  const ps::SweepPlan ring_blocked = ps::plan_sweeps(ring, 8);
  std::vector<Vec3> ls = m.vertices, lb = m.vertices;
  for (int s = 0; s < 5; ++s) {
    ps::laplacian_sweep(ls, ring, 0.6, ps::plan_sweeps(ring, 1), 1);
    ps::laplacian_sweep(lb, ring, 0.6, ring_blocked, 2);
  }
  double diff = 0.0;
  for (std::size_t i = 0; i < ls.size(); ++i) diff = std::max(diff, (ls[i] - lb[i]).norm());
  EXPECT_LT(diff, 0.05);
}

TEST(ParticleSurfacer, ResultIsIdenticalForAnyThreadCount) {
  for (const auto& [particles, r_inner] :
       {std::pair{three_blobs(), 0.25}, std::pair{wavy_sheet(16, 1, 1.0, 3), 0.6}, std::pair{droplets(1.0, 3), 0.6}}) {
    ParticleSurfacingOptions o = options(r_inner);
    o.threads = 1;
    const Mesh one = surface_particles(particles, {}, o);
    for (const int threads : {2, 3}) {
      o.threads = threads;
      const Mesh other = surface_particles(particles, {}, o);
      EXPECT_EQ(other.triangles, one.triangles);
      EXPECT_EQ(other.vertices, one.vertices);
    }
  }
}

// --- Promises on varied inputs: faithful vertices, no slivers ----------------------------------------------------

// Thesis §3.8 lets the polish leave the band; by default the final projection brings every vertex back: each lies
// between r_inner and r_outer of its nearest particle (1e-3 r_inner is the promise; rounding is far below it).
TEST(ParticleSurfacer, EveryFinalVertexIsFaithfulByDefault) {
  for (const Scene& scene : varied_scenes()) {
    SCOPED_TRACE(scene.name);
    ParticleSurfacingOptions o = options(scene.r_inner);
    ParticleSurfacingStats stats;
    const Mesh mesh = surface_particles(scene.particles, {}, o, {}, &stats);
    ASSERT_GT(mesh.vertices.size(), 500u);
    const double tol = 1e-3 * scene.r_inner;
    std::size_t outside = 0;
    double worst = 0.0;
    for (const Vec3& v : mesh.vertices) {
      const double d = nearest_point_distance(scene.particles, v);
      const double violation = std::max({scene.r_inner - d, d - 2 * scene.r_inner, 0.0});
      outside += violation > tol;
      worst = std::max(worst, violation);
    }
    EXPECT_EQ(outside, 0u) << "worst " << worst / scene.r_inner << " r_inner";
    EXPECT_EQ(stats.faithful_after_polish, 1.0);
    EXPECT_GT(stats.max_polish_displacement, 0.0);  // the polish did move vertices
  }
}

// The thesis' unconstrained polish, kept as an option, does leave vertices outside the band (what the default fixes).
TEST(ParticleSurfacer, UnconstrainedPolishMayLeaveTheBand) {
  double lowest = 1.0;
  for (const Scene& scene : varied_scenes()) {
    ParticleSurfacingOptions o = options(scene.r_inner);
    o.unconstrained_polish = true;
    ParticleSurfacingStats stats;
    (void)surface_particles(scene.particles, {}, o, {}, &stats);
    EXPECT_EQ(stats.max_final_projection, 0.0);
    lowest = std::min(lowest, stats.faithful_after_polish);
  }
  EXPECT_LT(lowest, 0.999);
}

// The repair's promise, on the mesh as a reader of the frame sees it (quantized on `grid`): a closed manifold with
// valence >= 5, no triangle collinear there, slivers_left counting exactly its triangles below the repair's threshold
// (the default, 10 degrees), at most `max_left` of them, and none below 1 degree.
void expect_no_sliver(const Mesh& mesh, const QuantizationGrid& grid, const ParticleSurfacingStats& stats,
                      std::int64_t max_left = 0) {
  const MeshReport r = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(r, kClosedManifold | kNoDegenerateTriangles | kPositiveVolume, 5));
  Mesh decoded = mesh;
  snap_to_grid(decoded.vertices, grid);
  EXPECT_GE(check_mesh(decoded).min_angle_degrees, 1.0);
  std::int64_t below = 0;
  for (const Triangle& t : decoded.triangles) {
    below += min_angle_degrees(decoded.vertices[t[0]], decoded.vertices[t[1]], decoded.vertices[t[2]]) <
             ParticleSurfacingOptions{}.min_angle_degrees;
  }
  EXPECT_EQ(stats.slivers_left, below);
  EXPECT_LE(stats.slivers_left, max_left);
  for (const Triangle& t : mesh.triangles) {
    std::array<Eigen::Matrix<std::int64_t, 3, 1>, 3> q;
    for (int k = 0; k < 3; ++k) {
      const auto g = grid.quantize(mesh.vertices[t[k]]);
      q[k] = Eigen::Matrix<std::int64_t, 3, 1>(g[0], g[1], g[2]);
    }
    ASSERT_FALSE((q[1] - q[0]).cross(q[2] - q[0]).isZero()) << "a triangle collinear on the output grid";
  }
}

TEST(ParticleSurfacer, NoSliversOnSheetsAndDroplets) {
  for (const Scene& scene : varied_scenes()) {
    SCOPED_TRACE(scene.name);
    ParticleSurfacingOptions o = options(scene.r_inner);
    Aabb box;
    for (const Vec3& p : scene.particles) box.merge(p);
    box = box.padded(3 * scene.r_inner);
    o.output_grid = QuantizationGrid::of(box, 11);  // a step of about 0.03 r_inner: coarse, as a stress
    ParticleSurfacingStats stats;
    const Mesh mesh = surface_particles(scene.particles, {}, o, {}, &stats);
    expect_no_sliver(mesh, *o.output_grid, stats);
  }
}

// The velocity of Enright's test (period 3), which stretches a ball into thin sheets.
Vec3 enright_velocity(const Vec3& p, double t) {
  const double pi = 3.14159265358979323846, s = std::cos(pi * t / 3.0);
  const double sx = std::sin(pi * p.x()), sy = std::sin(pi * p.y()), sz = std::sin(pi * p.z());
  const double s2x = std::sin(2 * pi * p.x()), s2y = std::sin(2 * pi * p.y()), s2z = std::sin(2 * pi * p.z());
  return Vec3(2 * sx * sx * s2y * s2z, -s2x * sy * sy * s2z, -s2x * s2y * sz * sz) * s;
}

// A lattice ball (radius 0.15 at (0.35, 0.35, 0.35), spacing d) carried by the Enright field to time `t` (RK4).
std::vector<Vec3> enright_sheet(double d, double t_end) {
  std::vector<Vec3> p;
  const int n = static_cast<int>(std::ceil(0.15 / d));
  for (int k = -n; k <= n; ++k) {
    for (int j = -n; j <= n; ++j) {
      for (int i = -n; i <= n; ++i) {
        const Vec3 q = Vec3(i, j, k) * d;
        if (q.norm() <= 0.15) p.push_back(q + Vec3(0.35, 0.35, 0.35));
      }
    }
  }
  const double dt = 0.01;
  for (double t = 0.0; t < t_end - 1e-9; t += dt) {
    for (Vec3& x : p) {
      const Vec3 k1 = enright_velocity(x, t), k2 = enright_velocity(x + 0.5 * dt * k1, t + 0.5 * dt);
      const Vec3 k3 = enright_velocity(x + 0.5 * dt * k2, t + 0.5 * dt), k4 = enright_velocity(x + dt * k3, t + dt);
      x += dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
    }
  }
  return p;
}

// Thin sheets the tests of the method were not built on, quantized on a job's 14-bit grid: no sliver and no
// triangle collinear on the grid (the repair has work to do: sub-particle bubbles, slivers), every vertex faithful.
TEST(ParticleSurfacer, EnrightSheetsEndWithoutSliversOnTheOutputGrid) {
  const double d = 0.01;
  const std::vector<Vec3> particles = enright_sheet(d, 2.0);
  for (const bool vertex_only_band : {false, true}) {
    SCOPED_TRACE(vertex_only_band);
    ParticleSurfacingOptions o = options(0.6 * d);
    o.vertex_only_band = vertex_only_band;
    o.output_grid = QuantizationGrid::of(
        particle_sequence_box(Aabb::of(particles), 0.0, o.r_inner, o.r_outer, {}, std::nullopt), 14);
    ParticleSurfacingStats stats;
    const Mesh mesh = surface_particles(particles, {}, o, {}, &stats);
    // A few stay below the default 10 degrees, in valence-5 knots of the sheets' rims where no flip, collapse or move
    // within the band makes them better (4 of the 194 found on our band, 52 of 563 on the thesis').
    expect_no_sliver(mesh, *o.output_grid, stats, stats.slivers_found / 8);
    EXPECT_GT(stats.slivers_found, 0);
    EXPECT_GT(stats.bubbles_dropped, 0u);
    EXPECT_EQ(stats.faithful_after_polish, 1.0);
  }
}

// Voids among the outer balls smaller than a particle are dropped, larger ones kept: a lattice block at spacing 1
// with r_outer = 0.9 covers every cell; one particle missing leaves a void too small to hold one, a missing 3 x 3 x 3
// block a bubble larger than a particle. With r_outer = 0.8 every lattice cell leaves a void at its centre.
TEST(ParticleSurfacer, BubblesSmallerThanAParticleAreDropped) {
  struct Case {
    int hole;  // particles missing along each axis, about the centre
    double r_inner;
    int components;
    bool dropped;
  };
  for (const Case& c :
       {Case{0, 0.45, 1, false}, Case{1, 0.45, 1, true}, Case{3, 0.45, 2, false}, Case{0, 0.4, 1, true}}) {
    SCOPED_TRACE(::testing::Message() << "hole " << c.hole << ", r_inner " << c.r_inner);
    std::vector<Vec3> particles;
    for (int k = 0; k < 9; ++k) {
      for (int j = 0; j < 9; ++j) {
        for (int i = 0; i < 9; ++i) {
          const bool missing =
              2 * std::abs(i - 4) < c.hole && 2 * std::abs(j - 4) < c.hole && 2 * std::abs(k - 4) < c.hole;
          if (!missing) particles.emplace_back(i, j, k);
        }
      }
    }
    ParticleSurfacingStats stats;
    const Mesh mesh = surface_particles(particles, {}, options(c.r_inner), {}, &stats);
    const MeshReport r = check_mesh(mesh);
    EXPECT_EQ(r.components, c.components);
    EXPECT_EQ(stats.bubbles_dropped > 0, c.dropped);
    EXPECT_TRUE(mesh_has(r, kClosedManifold | kNoDegenerateTriangles | kPositiveVolume, 5));
    EXPECT_EQ(stats.faithful_after_polish, 1.0);
  }
}

// Sparse random particles with a small r_inner make many tiny, tight components, where smoothing does leave slivers:
// the repair removes most of them, the smallest angle only grows, slivers_left counts exactly what stays below the
// threshold, and the mesh stays closed and manifold with valence >= 5. At 1 degree what it leaves sits among vertices
// at the valence floor; at the default 10 also where no flip, collapse or move in the band makes a triangle better.
TEST(ParticleSurfacer, SliverRepairOnSparseRandomParticles) {
  for (const std::uint32_t seed : {1u, 2u}) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 10.0);
    std::vector<Vec3> particles(1200);
    for (Vec3& p : particles) p = Vec3(u(rng), u(rng), u(rng));
    ParticleSurfacingOptions o = options(0.45);
    o.min_angle_degrees = 0.0;
    const MeshReport raw = check_mesh(surface_particles(particles, {}, o));
    EXPECT_LT(raw.min_angle_degrees, 1.0);
    double smallest_at_one = 0.0;
    for (const double threshold : {1.0, ParticleSurfacingOptions{}.min_angle_degrees}) {
      SCOPED_TRACE(::testing::Message() << "seed " << seed << " threshold " << threshold);
      o.min_angle_degrees = threshold;
      ParticleSurfacingStats stats;
      const Mesh mesh = surface_particles(particles, {}, o, {}, &stats);
      const MeshReport repaired = check_mesh(mesh);
      EXPECT_GT(stats.slivers_found, 0);
      EXPECT_LE(stats.slivers_left, stats.slivers_found / 8);
      EXPECT_GE(repaired.min_angle_degrees, raw.min_angle_degrees);
      EXPECT_GE(repaired.min_angle_degrees, smallest_at_one);  // a higher threshold never leaves a smaller angle
      smallest_at_one = repaired.min_angle_degrees;
      std::vector<std::set<std::uint32_t>> neighbours(mesh.vertices.size());
      for (const Triangle& t : mesh.triangles) {
        for (int c = 0; c < 3; ++c) {
          neighbours[t[c]].insert(t[(c + 1) % 3]);
          neighbours[t[c]].insert(t[(c + 2) % 3]);
        }
      }
      std::int64_t left = 0;
      for (const Triangle& t : mesh.triangles) {
        if (min_angle_degrees(mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]]) >= threshold) continue;
        ++left;
        if (threshold == 1.0) {
          EXPECT_TRUE(neighbours[t[0]].size() == 5 || neighbours[t[1]].size() == 5 || neighbours[t[2]].size() == 5);
        }
      }
      EXPECT_EQ(left, stats.slivers_left);
      EXPECT_TRUE(mesh_has(repaired, kClosedManifold | kNoDegenerateTriangles | kPositiveVolume, 5));
      EXPECT_EQ(repaired.components, raw.components);
    }
  }
}

// --- Options and inputs ----------------------------------------------------------------------------------------------

// The largest distance of a vertex outside the band of per-particle radii (r_inner_i = radii[i], r_outer_i = 2
// radii[i]), by brute force.
double weighted_violation(const Mesh& mesh, std::span<const Vec3> particles, std::span<const double> radii) {
  double worst = 0.0;
  for (const Vec3& v : mesh.vertices) {
    double inner = 1e9, outer = 1e9;
    for (std::size_t i = 0; i < particles.size(); ++i) {
      const double d = (particles[i] - v).norm();
      inner = std::min(inner, d - radii[i]);
      outer = std::min(outer, d - 2 * radii[i]);
    }
    worst = std::max({worst, -inner, outer});
  }
  return worst;
}

TEST(ParticleSurfacer, PerParticleRadiiScaleTheBand) {
  std::vector<Vec3> particles = blob(Vec3(0, 0, 0), 1.0, 0.3, 4);
  std::vector<double> radii(particles.size(), 0.2);
  for (const Vec3& q : blob(Vec3(5, 0, 0), 1.5, 0.6, 5)) {
    particles.push_back(q);
    radii.push_back(0.4);
  }
  ParticleSurfacingOptions o;  // r_inner from the radii (median); r_outer = 2 r_inner -> ratio 2
  o.polish_sweeps = 0;
  const Mesh mesh = surface_particles(particles, radii, o);
  EXPECT_EQ(check_mesh(mesh).components, 2);
  EXPECT_LE(weighted_violation(mesh, particles, radii), 1e-9);
  // Equal radii reproduce the uniform-radius surface.
  const std::vector<Vec3> blobs = three_blobs();
  ParticleSurfacingOptions u = options(0.25);
  const Mesh uniform = surface_particles(blobs, {}, u);
  u.r_inner.reset();
  const Mesh weighted = surface_particles(blobs, std::vector<double>(blobs.size(), 0.25), u);
  ASSERT_EQ(weighted.triangles, uniform.triangles);
  double diff = 0.0;
  for (std::size_t i = 0; i < uniform.vertices.size(); ++i)
    diff = std::max(diff, (uniform.vertices[i] - weighted.vertices[i]).norm());
  EXPECT_LT(diff, 1e-9);
}

// Particles far larger than the rest (a pscale left at its default among simulation particles) are searched in tiers
// of their own (docs/ALGORITHMS.md §1, CHOICE "radius tiers"): every vertex stays faithful to the balls of its own
// radii, on the large balls as on the small ones, and a small particle touching a large one is one component with it.
TEST(ParticleSurfacer, LargeParticlesAmongSmallOnesKeepEveryVertexFaithful) {
  std::vector<Vec3> particles = blob(Vec3(0, 0, 0), 0.6, 0.1, 11);
  std::vector<double> radii(particles.size(), 0.05);
  const auto add = [&](const Vec3& p, double r) {
    particles.push_back(p);
    radii.push_back(r);
  };
  add(Vec3(0.7, 0.0, 0.0), 0.4);  // overlapping the blob's side
  add(Vec3(0.0, 0.0, 0.2), 1.5);  // inside the blob, wider than it: every small ball lies in its outer ball
  add(Vec3(6.0, 0.0, 0.0), 0.8);  // apart, with one small particle touching it
  add(Vec3(6.0, 0.85, 0.0), 0.05);
  add(Vec3(-6.0, 0.0, 0.0), 0.05);  // a lone small particle
  for (const double big : {0.9, 0.0}) {
    std::vector<Vec3> p = particles;
    std::vector<double> r = radii;
    if (big == 0.0) {  // without the widest one: the blob and the ball at its side
      p.erase(p.begin() + static_cast<std::ptrdiff_t>(p.size()) - 4);
      r.erase(r.begin() + static_cast<std::ptrdiff_t>(r.size()) - 4);
    }
    ParticleSurfacingOptions o;
    o.r_inner = 0.05;
    o.spacing_factor = 2.5;  // the large spheres' area would take most of the time
    o.min_particles_per_component = 2;
    ParticleSurfacingStats stats;
    const Mesh mesh = surface_particles(p, r, o, {}, &stats);
    const MeshReport report = check_mesh(mesh);
    EXPECT_TRUE(report.closed && report.edge_manifold && report.vertex_manifold) << big;
    EXPECT_EQ(report.components, 2) << big;  // the blob with its large ball(s); the pair
    EXPECT_EQ(stats.components_dropped, 1u) << big;
    EXPECT_EQ(stats.faithful_after_polish, 1.0) << big;
    EXPECT_LE(weighted_violation(mesh, p, r), 1e-9) << big;
  }
}

// A radius whose sphere alone would need more triangles than the limit allows is refused before Marching Tiles lists a
// block (listing the blocks of a ball of radius 2e6 at spacing 0.04 would not end), naming the limit and the particle;
// a large radius within the limit is surfaced. The spacing follows the median radius, which the outlier leaves alone
// (the mean would be 1e6 / 124).
TEST(ParticleSurfacer, ARadiusWhoseSphereAloneIsOverTheTriangleLimitIsRefusedAtOnce) {
  std::vector<Vec3> particles = blob(Vec3(0, 0, 0), 0.3, 0.1, 5);
  std::vector<double> radii(particles.size(), 0.05);
  particles.emplace_back(0.25, 0.5, 0.75);
  radii.push_back(1e6);
  ParticleSurfacingOptions o;  // r_inner: the median radius, 0.05
  TriangleLimit limit;
  limit.max_triangles = 1'000'000;
  limit.name = "--max-triangles";
  RunControl control;
  control.triangles = &limit;
  try {
    (void)surface_particles(particles, radii, o, control);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit) << e.what();
    EXPECT_EQ(e.field(), "--max-triangles");
    const std::string message = e.what();
    EXPECT_NE(message.find("(0.25, 0.5, 0.75) has r_outer 2e+06"), std::string::npos) << message;
    EXPECT_NE(message.find("at spacing 0.04"), std::string::npos) << message;  // 0.8 x 0.05
    EXPECT_NE(message.find("raise --max-triangles"), std::string::npos) << message;
  }
  radii.back() = 0.5;
  const Mesh mesh = surface_particles(particles, radii, o, control);
  EXPECT_TRUE(check_mesh(mesh).closed);
  EXPECT_LT(mesh.triangles.size(), 1'000'000u);
}

TEST(ParticleSurfacer, DropsSmallComponentsWhenAsked) {
  std::vector<Vec3> particles = blob(Vec3(0, 0, 0), 1.5, 0.3, 6);
  const std::size_t in_blob = particles.size();
  for (int i = 0; i < 5; ++i) particles.emplace_back(5.0 + 3.0 * i, 4.0, 0.0);  // spray, far apart
  particles.emplace_back(5.0, 4.0, 0.4);                                        // a pair: its r_outer balls overlap
  ParticleSurfacingOptions o = options(0.25);
  ParticleSurfacingStats stats;
  EXPECT_EQ(check_mesh(surface_particles(particles, {}, o, {}, &stats)).components, 6);
  EXPECT_EQ(stats.components_dropped, 0u);
  o.min_particles_per_component = 3;
  const Mesh kept = surface_particles(particles, {}, o, {}, &stats);
  EXPECT_EQ(check_mesh(kept).components, 1);
  EXPECT_EQ(stats.components_dropped, 5u);  // four singles and the pair
  EXPECT_EQ(stats.particles_used, in_blob);
  o.min_particles_per_component = 2;
  (void)surface_particles(particles, {}, o, {}, &stats);
  EXPECT_EQ(stats.components_dropped, 4u);
}

TEST(ParticleSurfacer, DerivesInnerRadiusFromNearestNeighbourSpacing) {
  std::vector<Vec3> particles = lattice_slab(0, 8, 4, 0.7).particles;
  for (int i = 0; i < 5; ++i) particles.emplace_back(100.0 + 50.0 * i, 0, 0);  // stray spray is left out of the mean
  ParticleSurfacingOptions o;
  o.derive_r_inner = true;
  o.bilaplacian_sweeps = 2;
  ParticleSurfacingStats stats;
  (void)surface_particles(particles, {}, o, {}, &stats);
  EXPECT_NEAR(stats.r_inner, 0.7, 1e-12);
  EXPECT_NEAR(stats.r_outer, 1.4, 1e-12);
  EXPECT_NEAR(stats.spacing, 0.8 * 0.7, 1e-12);
}

TEST(ParticleSurfacer, ErosionMovesTheSurfaceInward) {
  const std::vector<Vec3> particles = blob(Vec3(0, 0, 0), 1.5, 0.3, 7);
  ParticleSurfacingOptions o = options(0.25);
  o.min_angle_degrees = 0.0;  // vertex for vertex: no repair that the eroded surface would make otherwise
  const Mesh plain = surface_particles(particles, {}, o);
  o.erosion = 0.4;
  ParticleSurfacingStats stats;
  const Mesh eroded = surface_particles(particles, {}, o, {}, &stats);
  ASSERT_EQ(eroded.triangles, plain.triangles);
  double mean_shift = 0.0;
  for (std::size_t i = 0; i < plain.vertices.size(); ++i) mean_shift += (plain.vertices[i] - eroded.vertices[i]).norm();
  mean_shift /= static_cast<double>(plain.vertices.size());
  EXPECT_NEAR(mean_shift, 0.4 * 0.25, 1e-9);  // every vertex moves epsilon * r_inner
  EXPECT_LT(check_mesh(eroded).volume, check_mesh(plain).volume);
  EXPECT_GE(stats.max_polish_displacement, 0.1);
}

TEST(ParticleSurfacer, NormalsOnRequest) {
  ParticleSurfacingOptions o = options(0.25);
  o.normals = true;
  const Vec3 c(0, 0, 0);
  const Mesh mesh = surface_particles(std::vector<Vec3>{c}, {}, o);
  EXPECT_TRUE(normals_point_away_from(mesh, c, 1e-12, 0.99));  // unit and outward
}

TEST(ParticleSurfacer, StatefulSurfacerMatchesOneShotAcrossFrames) {
  ParticleSurfacer surfacer(options(0.25));
  const std::vector<Vec3> a = three_blobs();
  const std::vector<Vec3> b = blob(Vec3(1, 1, 1), 1.0, 0.3, 8);
  (void)surfacer.surface(a);
  const Mesh second = surfacer.surface(b);
  const Mesh fresh = surface_particles(b, {}, options(0.25));
  EXPECT_EQ(second.vertices, fresh.vertices);
  EXPECT_EQ(second.triangles, fresh.triangles);
  EXPECT_EQ(surfacer.options().r_inner, 0.25);
}

TEST(ParticleSurfacer, EmptyInputGivesEmptyMesh) {
  ParticleSurfacingStats stats;
  EXPECT_TRUE(surface_particles({}, {}, options(1.0), {}, &stats).empty());
  EXPECT_EQ(stats.particles, 0u);
}

void expect_invalid(const ParticleSurfacingOptions& o, const std::string& field, std::span<const Vec3> particles = {},
                    std::span<const double> radii = {}) {
  const std::vector<Vec3> two{Vec3::Zero(), Vec3::Ones()};
  EXPECT_TRUE(testing::throws_invalid_input(
      [&] { (void)surface_particles(particles.empty() ? std::span<const Vec3>(two) : particles, radii, o); }, field));
}

TEST(ParticleSurfacer, RejectsBadOptionsAndInputsWithTheFieldName) {
  ParticleSurfacingOptions o;
  expect_invalid(o, "r_inner");  // neither r_inner, derive_r_inner nor radii
  o = options(-1.0);
  expect_invalid(o, "r_inner");
  o = options(1.0);
  o.r_outer = 0.5;
  try {
    (void)ParticleSurfacer(o);
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_EQ(e.field(), "r_outer");
    EXPECT_NE(std::string(e.what()).find("must exceed r_inner"), std::string::npos) << e.what();
  }
  // Below the floor the initial tiling's work per particle has no bound known before it starts (1e-6 spun for
  // minutes in the seeding, past cancel).
  for (double factor : {0.0, 1e-6, 0.099, 10.5}) {
    o = options(1.0);
    o.spacing_factor = factor;
    expect_invalid(o, "spacing_factor");
  }
  o = options(1.0);
  o.spacing_factor = ParticleSurfacingOptions::kMinSpacingFactor;
  EXPECT_NO_THROW(validate(o));
  o.r_inner = 1.0;
  o.derive_r_inner = true;
  expect_invalid(o, "derive_r_inner");
  o = options(1.0);
  o.bilaplacian_sweeps = -1;
  expect_invalid(o, "bilaplacian_sweeps");
  o = options(1.0);
  o.relaxation = 1.5;
  expect_invalid(o, "relaxation");
  for (const double angle : {-1.0, 31.0, std::nan("")}) {
    o = options(1.0);
    o.min_angle_degrees = angle;
    expect_invalid(o, "min_angle_degrees");
  }
  o = options(1.0);
  o.output_grid = QuantizationGrid::of(Aabb{Vec3::Zero(), Vec3::Ones()}, 31);
  expect_invalid(o, "output_grid.bits");
  o.output_grid = QuantizationGrid::of(Aabb{Vec3::Ones(), Vec3::Zero()}, 14);
  expect_invalid(o, "output_grid.box");
  o = options(1.0);
  o.erosion = -0.1;
  expect_invalid(o, "erosion");
  o = options(1.0);
  o.container_box = Aabb{Vec3(1, 1, 1), Vec3(0, 2, 2)};
  expect_invalid(o, "container_box");
  o = options(1.0);
  o.threads = -2;
  expect_invalid(o, "threads");
  o = options(1.0);
  const std::vector<Vec3> bad{Vec3(0, std::nan(""), 0)};
  expect_invalid(o, "particles", bad);
  const std::vector<Vec3> two{Vec3::Zero(), Vec3::Ones()};
  const std::vector<double> one_radius{1.0};
  expect_invalid(o, "radii", two, one_radius);
  const std::vector<double> negative{1.0, -1.0};
  expect_invalid(o, "radii", two, negative);
  ParticleSurfacingOptions derive;
  derive.derive_r_inner = true;
  const std::vector<Vec3> single{Vec3::Zero()};
  expect_invalid(derive, "r_inner", single);
}

// --- Coincident particles -----------------------------------------------------------------------------------------

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// n particles at one point used to cost every vertex O(n) to O(n^3) in step 4 (20,000 ran for minutes): exact
// duplicates are merged and give the surface of one particle, byte for byte, and count in the components.
TEST(ParticleSurfacer, IdenticalParticlesGiveTheSurfaceOfOne) {
  const Vec3 centre(0.5, 0.25, -1.0);
  ParticleSurfacingOptions o = options(0.01);
  ParticleSurfacingStats one_stats;
  const Mesh one = surface_particles(std::vector<Vec3>{centre}, {}, o, {}, &one_stats);
  ASSERT_FALSE(one.triangles.empty());
  for (const std::size_t n : {2000u, 20000u}) {
    const auto t0 = std::chrono::steady_clock::now();
    ParticleSurfacingStats stats;
    const Mesh many = surface_particles(std::vector<Vec3>(n, centre), {}, o, {}, &stats);
    EXPECT_LT(seconds_since(t0), 2.0) << n;
    EXPECT_EQ(many.vertices, one.vertices) << n;
    EXPECT_EQ(many.triangles, one.triangles) << n;
    EXPECT_EQ(stats.particles, n);
    EXPECT_EQ(stats.particles_used, n);
    EXPECT_EQ(stats.seeds, 1u);
  }
  // Ten copies form a component of ten: kept by min_particles_per_component 5.
  o.min_particles_per_component = 5;
  EXPECT_EQ(surface_particles(std::vector<Vec3>(10, centre), {}, o).triangles, one.triangles);
  // Per-particle radii: smaller copies at the same point change nothing; the largest radius is the one kept.
  ParticleSurfacingOptions weighted = options(0.01);
  std::vector<Vec3> at_centre(501, centre);
  std::vector<double> radii(501, 0.005);
  radii[250] = 0.01;
  EXPECT_EQ(surface_particles(at_centre, radii, weighted).vertices,
            surface_particles(std::vector<Vec3>{centre}, std::vector<double>{0.01}, weighted).vertices);
}

// Near-coincident particles (within 1e-9 of each other, 1e-7 r_inner) are merged too: as fast as one particle, and
// every vertex is within the band of the cloud (up to the merge tolerance).
TEST(ParticleSurfacer, NearCoincidentParticlesCostWhatOneCosts) {
  const Vec3 centre(0.5, 0.5, 0.5);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> jitter(-5e-10, 5e-10);
  std::vector<Vec3> cloud(20000);
  for (Vec3& p : cloud) p = centre + Vec3(jitter(rng), jitter(rng), jitter(rng));
  const ParticleSurfacingOptions o = options(0.01);
  const auto t0 = std::chrono::steady_clock::now();
  ParticleSurfacingStats stats;
  const Mesh mesh = surface_particles(cloud, {}, o, {}, &stats);
  EXPECT_LT(seconds_since(t0), 2.0);
  EXPECT_TRUE(mesh_has(check_mesh(mesh), kClosedManifold));
  EXPECT_EQ(stats.particles_used, cloud.size());
  EXPECT_LE(stats.seeds, 8u);
  for (const Vec3& v : mesh.vertices) {
    const double d = (v - centre).norm();
    EXPECT_GE(d, 0.01 - 1e-8);
    EXPECT_LE(d, 0.02 + 1e-8);
  }
}

// A cluster too wide to merge (5,000 particles within 1e-4 r_inner, mostly farther apart than the merge tolerance) but
// far denser than any fluid: no vertex searches the cusps of more than kMaxCuspSpheres spheres (this ran for more
// than ten minutes).
TEST(ParticleSurfacer, DenseClusterBeyondTheMergeToleranceStaysFast) {
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> offset(0.0, 1e-6);
  std::vector<Vec3> cloud(5000);
  for (Vec3& p : cloud) p = Vec3(0.5 + offset(rng), 0.5 + offset(rng), 0.5 + offset(rng));
  const auto t0 = std::chrono::steady_clock::now();
  ParticleSurfacingStats stats;
  const Mesh mesh = surface_particles(cloud, {}, options(0.01), {}, &stats);
  EXPECT_LT(seconds_since(t0), 5.0);
  EXPECT_GT(stats.seeds, 1000u);  // mostly not merged
  EXPECT_TRUE(mesh_has(check_mesh(mesh), kClosedManifold));
  EXPECT_EQ(stats.faithful_after_polish, 1.0);
}

// --- Cancellation and progress ------------------------------------------------------------------------------------

TEST(ParticleSurfacer, ReportsEveryStageInOrder) {
  std::vector<std::string> stages;
  RunControl control;
  control.progress = [&](std::string_view stage, double) {
    if (stages.empty() || stages.back() != stage) stages.emplace_back(stage);
  };
  ParticleSurfacingOptions o = options(0.25);
  o.erosion = 0.1;
  o.threads = 1;
  (void)surface_particles(three_blobs(), {}, o, control);
  const std::vector<std::string> expected{"distance_field", "polygonize", "laplacian", "build_b",
                                          "bilaplacian",    "polish",     "erosion",   "cleanup"};
  EXPECT_EQ(stages, expected);
}

// Cancels `particles` as each stage in `stages` reports progress; the run must end with kCancelled within `seconds`.
void expect_prompt_cancel(const std::vector<Vec3>& particles, const ParticleSurfacingOptions& o,
                          std::initializer_list<const char*> stages, double seconds) {
  for (const std::string when : stages) {
    CancelToken token;
    RunControl control;
    control.cancel = &token;
    std::chrono::steady_clock::time_point cancelled_at;
    control.progress = [&](std::string_view stage, double) {
      if (stage == when && !token.cancelled()) {
        cancelled_at = std::chrono::steady_clock::now();
        token.cancel();
      }
    };
    try {
      (void)surface_particles(particles, {}, o, control);
      ADD_FAILURE() << "not cancelled at " << when;
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kCancelled) << when;
      EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - cancelled_at).count(), seconds)
          << when;
    }
  }
}

TEST(ParticleSurfacer, CancelTakesEffectWithinASweep) {
  const std::vector<Vec3> particles = blob(Vec3(0, 0, 0), 3.0, 0.3, 10);
  expect_prompt_cancel(particles, options(0.25), {"polygonize", "laplacian", "bilaplacian", "polish"}, 0.2);
  CancelToken token;
  token.cancel();
  RunControl control;
  control.cancel = &token;
  EXPECT_THROW((void)surface_particles(particles, {}, options(0.25), control), Error);
}

// Cancel takes effect within a sweep with thousands of particles at one point, in every stage.
TEST(ParticleSurfacer, CancelIsPromptWithCoincidentParticles) {
  expect_prompt_cancel(std::vector<Vec3>(8000, Vec3(0.1, 0.2, 0.3)), options(0.01),
                       {"distance_field", "polygonize", "laplacian", "build_b", "bilaplacian", "polish"}, 0.5);
}

}  // namespace
}  // namespace surfacer
