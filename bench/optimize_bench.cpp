// Mesh optimizer (core/optimize/mesh_optimizer.h): cost per iteration, iterations to converge, and how much grid
// resolution the optimizer is worth against plain Marching Cubes. Prints tables (no Google Benchmark registration).
//   build-opt/bench/optimize_bench            all three sections (about a minute on 2 cores)
//   build-opt/bench/optimize_bench --quick    skips the 256^3 Marching Cubes rows
//
// Errors are in % of the true solid's bounding-box diagonal (the Extended Marching Cubes anchor: < 0.25 % on the
// fandisk from a 65^3 grid, Kobbelt et al. 2001):
//   vertex max / RMS: |f| / |∇f| at the vertices (the optimizer's own figure),
//   face max / RMS:   |f| / |∇f| at 7 points per triangle (centroid, edge midpoints, 3 inner points) — this is where
//                     Marching Cubes loses: its vertices lie near the surface but its chamfers cut every edge,
//   E_n:              Σ A |n_T - m(C_T)|² / Σ A,
//   dihedral:         mesh edges within 0.02 h of a true feature line (h: the 64^3 spacing), along it, with their two
//                     triangles on different faces; coverage = their length / the lines' length (2 h kept off every
//                     corner); error = |angle between the triangle normals - true 90°|.
#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "bench/bench_args.h"
#include "core/optimize/mesh_optimizer.h"
#include "core/polygonize/marching_cubes.h"
#include "core/scene/scene.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

constexpr double kPi = 3.14159265358979323846;

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// --- Reference shapes with their feature lines -------------------------------------------------------------------

struct Curve {
  bool circle = false;
  Vec3 a, b;  // segment ends; or circle centre and unit axis
  double radius = 0.0;
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
    distance = std::hypot(r - radius, axial);
    tangent = b.cross(r > 0.0 ? Vec3(radial / r) : Vec3(b.unitOrthogonal()));
    from_end = 1e300;
  }
  double length() const { return circle ? 2.0 * kPi * radius : (b - a).norm(); }
};

struct Shape {
  std::string name;
  FieldPtr field;
  std::vector<Curve> curves;
  Aabb solid;            // bounding box of the true solid
  Aabb grid;             // cubic region polygonized (grid planes kept off the faces)
  FieldPtr start_field;  // the field polygonized for the start mesh (sphere-to-cube: the sphere)
  double diagonal() const { return solid.size().norm(); }
  double h(int cells) const { return grid.size().x() / cells; }
};

Curve segment(const Vec3& a, const Vec3& b) {
  Curve c;
  c.a = a;
  c.b = b;
  return c;
}
Curve circle(const Vec3& centre, const Vec3& axis, double r) {
  Curve c;
  c.circle = true;
  c.a = centre;
  c.b = axis.normalized();
  c.radius = r;
  return c;
}

std::vector<Curve> box_edges(const Vec3& half, const Eigen::Matrix3d& rotation) {
  std::vector<Curve> out;
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (int su = -1; su <= 1; su += 2) {
      for (int sv = -1; sv <= 1; sv += 2) {
        Vec3 a = Vec3::Zero(), b = Vec3::Zero();
        a[axis] = -half[axis];
        b[axis] = half[axis];
        a[u] = b[u] = su * half[u];
        a[v] = b[v] = sv * half[v];
        out.push_back(segment(rotation * a, rotation * b));
      }
    }
  }
  return out;
}

// The CSG block of tests/core/mesh_optimizer_test.cpp: slab + box + cylindrical boss, minus two holes.
Shape csg_block() {
  Shape s;
  s.name = "CSG block";
  const FieldPtr slab = make_box(Vec3(0, 0, 0), Vec3(1.0, 0.7, 0.35));
  const FieldPtr top = make_box(Vec3(0.3, 0, 0.5), Vec3(0.45, 0.45, 0.35));
  const FieldPtr boss = make_cylinder(Vec3(-0.55, 0, 0), Vec3(-0.55, 0, 0.6), 0.3);
  const FieldPtr hole = make_cylinder(Vec3(-0.55, 0, -0.5), Vec3(-0.55, 0, 0.8), 0.15);
  const FieldPtr cross_hole = make_cylinder(Vec3(-0.2, 0, 0.56), Vec3(0.9, 0, 0.56), 0.14);
  s.field = make_csg(CsgOp::kDifference, {make_csg(CsgOp::kUnion, {slab, top, boss}), hole, cross_hole});
  s.start_field = s.field;
  s.solid = Aabb{Vec3(-1.0, -0.7, -0.35), Vec3(1.0, 0.7, 0.85)};
  s.grid = Aabb{Vec3::Constant(-1.1013), Vec3::Constant(1.0987)};
  s.curves = box_edges(Vec3(1.0, 0.7, 0.35), Eigen::Matrix3d::Identity());
  const double x0 = -0.15, x1 = 0.75, y0 = -0.45, y1 = 0.45;
  for (double z : {0.85, 0.35}) {
    s.curves.push_back(segment({x0, y0, z}, {x1, y0, z}));
    s.curves.push_back(segment({x0, y1, z}, {x1, y1, z}));
    s.curves.push_back(segment({x0, y0, z}, {x0, y1, z}));
    s.curves.push_back(segment({x1, y0, z}, {x1, y1, z}));
  }
  for (double x : {x0, x1}) {
    for (double y : {y0, y1}) s.curves.push_back(segment({x, y, 0.35}, {x, y, 0.85}));
  }
  s.curves.push_back(circle({x0, 0, 0.56}, Vec3::UnitX(), 0.14));
  s.curves.push_back(circle({x1, 0, 0.56}, Vec3::UnitX(), 0.14));
  s.curves.push_back(circle({-0.55, 0, 0.6}, Vec3::UnitZ(), 0.3));
  s.curves.push_back(circle({-0.55, 0, 0.6}, Vec3::UnitZ(), 0.15));
  s.curves.push_back(circle({-0.55, 0, 0.35}, Vec3::UnitZ(), 0.3));
  s.curves.push_back(circle({-0.55, 0, -0.35}, Vec3::UnitZ(), 0.15));
  return s;
}

// A box rotated off the grid axes (Marching Cubes is at its worst on edges that are not grid-aligned).
Shape rotated_box() {
  Shape s;
  s.name = "rotated box";
  const Vec3 half(0.8, 0.6, 0.5);
  const Eigen::Matrix3d r = Eigen::AngleAxisd(0.5, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  s.field = make_transform(make_box(Vec3::Zero(), half), r, Vec3::Zero());
  s.start_field = s.field;
  s.solid = Aabb::empty();
  for (int c = 0; c < 8; ++c) {
    s.solid.merge(
        Vec3(r * Vec3((c & 1) ? half.x() : -half.x(), (c & 2) ? half.y() : -half.y(), (c & 4) ? half.z() : -half.z())));
  }
  const double extent = s.solid.size().maxCoeff() * 0.55;
  s.grid = Aabb{Vec3::Constant(-extent - 0.0013), Vec3::Constant(extent - 0.0013)};
  s.curves = box_edges(half, r);
  return s;
}

// The paper's sphere-to-cube: a sphere of radius 1.2 polygonized, then evolved toward the cube |x|,|y|,|z| <= 1.
Shape sphere_to_cube() {
  Shape s;
  s.name = "sphere-to-cube";
  s.field = make_box(Vec3::Zero(), Vec3::Ones());
  s.start_field = make_sphere(Vec3::Zero(), 1.2);
  s.solid = Aabb{-Vec3::Ones(), Vec3::Ones()};
  s.grid = Aabb{Vec3::Constant(-1.5013), Vec3::Constant(1.4987)};
  s.curves = box_edges(Vec3::Ones(), Eigen::Matrix3d::Identity());
  return s;
}

Mesh polygonize(const Shape& s, int cells, bool start = true) {
  MarchingCubesOptions o;
  o.bounds = s.grid;
  o.cells = {cells, cells, cells};
  return marching_cubes(start ? *s.start_field : *s.field, o);
}

// --- Error figures -------------------------------------------------------------------------------------------------

struct Errors {
  std::int64_t triangles = 0;
  double vertex_max = 0, vertex_rms = 0, face_max = 0, face_rms = 0, e_n = 0;
  double coverage = 0, dihedral_max = 0, dihedral_mean = 0;
  int feature_edges = 0;
};

double distance_estimate(const Field& f, const Vec3& p) {
  Vec3 g;
  const double v = f.value_and_gradient(p, g);
  const double len = g.norm();
  return len > 0.0 ? std::abs(v) / len : std::abs(v);
}

Errors measure(const Shape& s, const Mesh& mesh, double h64) {
  Errors e;
  const Field& f = *s.field;
  e.triangles = static_cast<std::int64_t>(mesh.triangles.size());
  const std::size_t nt = mesh.triangles.size();
  const int chunks = static_cast<int>((nt + 4095) / 4096);
  struct Partial {
    double vmax = 0, vsum = 0, fmax = 0, fsum = 0, en = 0, area = 0;
    std::int64_t vcount = 0, fcount = 0;
  };
  std::vector<Partial> parts(chunks);
  std::vector<std::uint8_t> seen(mesh.vertices.size(), 0);
  for (const Triangle& t : mesh.triangles) {
    for (std::uint32_t v : t) seen[v] = 1;
  }
  parallel_for(chunks, 0, [&](int c) {
    Partial& acc = parts[c];
    const std::size_t begin = static_cast<std::size_t>(c) * 4096, end = std::min(nt, begin + 4096);
    for (std::size_t t = begin; t < end; ++t) {
      const Vec3 &a = mesh.vertices[mesh.triangles[t][0]], &b = mesh.vertices[mesh.triangles[t][1]],
                 &cc = mesh.vertices[mesh.triangles[t][2]];
      const Vec3 n = (b - a).cross(cc - a);
      const double area = 0.5 * n.norm();
      if (area > 0.0) {
        Vec3 g;
        f.value_and_gradient((a + b + cc) / 3.0, g);
        acc.en += area * (n.normalized() - g.normalized()).squaredNorm();
        acc.area += area;
      }
      for (const Vec3& p : {Vec3((a + b + cc) / 3.0), Vec3(0.5 * (a + b)), Vec3(0.5 * (b + cc)), Vec3(0.5 * (cc + a)),
                            Vec3((4 * a + b + cc) / 6.0), Vec3((a + 4 * b + cc) / 6.0), Vec3((a + b + 4 * cc) / 6.0)}) {
        const double d = distance_estimate(f, p);
        acc.fmax = std::max(acc.fmax, d);
        acc.fsum += d * d;
        ++acc.fcount;
      }
    }
  });
  Partial total;
  for (const Partial& p : parts) {
    total.fmax = std::max(total.fmax, p.fmax);
    total.fsum += p.fsum;
    total.fcount += p.fcount;
    total.en += p.en;
    total.area += p.area;
  }
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    if (!seen[v]) continue;
    const double d = distance_estimate(f, mesh.vertices[v]);
    total.vmax = std::max(total.vmax, d);
    total.vsum += d * d;
    ++total.vcount;
  }
  const double diag = s.diagonal() / 100.0;  // -> percent
  e.vertex_max = total.vmax / diag;
  e.vertex_rms = std::sqrt(total.vsum / std::max<std::int64_t>(1, total.vcount)) / diag;
  e.face_max = total.fmax / diag;
  e.face_rms = std::sqrt(total.fsum / std::max<std::int64_t>(1, total.fcount)) / diag;
  e.e_n = total.area > 0 ? total.en / total.area : 0.0;

  // Feature edges: sort (edge, triangle) pairs; manifold edges only.
  std::vector<std::pair<std::uint64_t, std::uint32_t>> corners;
  corners.reserve(3 * nt);
  for (std::size_t t = 0; t < nt; ++t) {
    for (int k = 0; k < 3; ++k) {
      std::uint32_t a = mesh.triangles[t][k], b = mesh.triangles[t][(k + 1) % 3];
      if (a > b) std::swap(a, b);
      corners.push_back({(static_cast<std::uint64_t>(a) << 32) | b, static_cast<std::uint32_t>(t)});
    }
  }
  std::sort(corners.begin(), corners.end());
  const double tol = 0.02 * h64, exclude = 2.0 * h64;
  double length = 0.0;
  for (const Curve& c : s.curves) length += c.circle ? c.length() : std::max(0.0, c.length() - 2 * exclude);
  double covered = 0.0, sum = 0.0;
  auto normal = [&](std::uint32_t t) {
    const Triangle& tri = mesh.triangles[t];
    return Vec3((mesh.vertices[tri[1]] - mesh.vertices[tri[0]])
                    .cross(mesh.vertices[tri[2]] - mesh.vertices[tri[0]])
                    .normalized());
  };
  for (std::size_t i = 0; i + 1 < corners.size(); ++i) {
    if (corners[i].first != corners[i + 1].first ||
        (i + 2 < corners.size() && corners[i + 2].first == corners[i].first) ||
        (i > 0 && corners[i - 1].first == corners[i].first)) {
      continue;
    }
    const auto a = static_cast<std::uint32_t>(corners[i].first >> 32);
    const auto b = static_cast<std::uint32_t>(corners[i].first & 0xffffffffu);
    const Vec3 p = mesh.vertices[a], q = mesh.vertices[b];
    for (const Curve& c : s.curves) {
      double dp, dq, dm, end;
      Vec3 tangent;
      c.project(p, dp, tangent, end);
      if (dp > tol) continue;
      c.project(q, dq, tangent, end);
      if (dq > tol) continue;
      c.project(0.5 * (p + q), dm, tangent, end);
      const double sagitta = c.circle ? (q - p).squaredNorm() / (8 * c.radius) : 0.0;
      if (dm > tol + sagitta || end < exclude ||
          std::abs((q - p).normalized().dot(tangent)) < std::cos(25 * kPi / 180)) {
        continue;
      }
      const std::uint32_t t0 = corners[i].second, t1 = corners[i + 1].second;
      auto centroid = [&](std::uint32_t t) {
        const Triangle& tri = mesh.triangles[t];
        return Vec3((mesh.vertices[tri[0]] + mesh.vertices[tri[1]] + mesh.vertices[tri[2]]) / 3.0);
      };
      Vec3 g0, g1;
      f.value_and_gradient(centroid(t0), g0);
      f.value_and_gradient(centroid(t1), g1);
      if (g0.normalized().dot(g1.normalized()) > std::cos(30 * kPi / 180)) continue;
      const double angle = std::acos(std::clamp(normal(t0).dot(normal(t1)), -1.0, 1.0)) * 180 / kPi;
      const double err = std::abs(angle - 90.0);
      e.dihedral_max = std::max(e.dihedral_max, err);
      sum += err;
      covered += (q - p).norm();
      ++e.feature_edges;
      break;
    }
  }
  e.coverage = length > 0 ? covered / length : 0.0;
  e.dihedral_mean = e.feature_edges > 0 ? sum / e.feature_edges : 0.0;
  return e;
}

void print_errors_header() {
  std::printf("  %-28s %10s %9s %9s %9s %9s %10s %8s %8s %8s\n", "mesh", "triangles", "vtx max%", "vtx rms%",
              "face max%", "face rms%", "E_n", "feat cov", "dih max", "dih mean");
}
void print_errors(const std::string& label, const Errors& e) {
  std::printf("  %-28s %10lld %9.4f %9.4f %9.4f %9.4f %10.2e %8.2f", label.c_str(), static_cast<long long>(e.triangles),
              e.vertex_max, e.vertex_rms, e.face_max, e.face_rms, e.e_n, e.coverage);
  if (e.feature_edges > 0) {
    std::printf(" %8.2f %8.2f\n", e.dihedral_max, e.dihedral_mean);
  } else {
    std::printf(" %8s %8s\n", "-", "-");
  }
}

// --- Sections -----------------------------------------------------------------------------------------------------

// Milliseconds per iteration per 100 k vertices of each flow configuration (each iteration also evaluates E_d, E_n
// and the distances and runs the final flip guard and the connectivity repair).
void time_flows() {
  const Shape s = csg_block();
  const Mesh start = polygonize(s, 180);  // ~100 k vertices
  std::printf("\n== Cost per iteration: CSG block, Marching Cubes 180^3 start, %zu vertices, %zu triangles ==\n",
              start.vertices.size(), start.triangles.size());
  std::printf("  %-40s %8s %14s %14s %8s\n", "flows", "threads", "ms/iteration", "ms/it/100k V", "speedup");
  struct Config {
    const char* name;
    bool t, d, n, modified;
  };
  const Config configs[] = {
      {"T only", true, false, false, false},
      {"D only", false, true, false, false},
      {"N only", false, false, true, false},
      {"modified N only", false, false, true, true},
      {"N o D o T (phase 1)", true, true, true, false},
      {"N o D (phase 2)", false, true, true, false},
      {"modified N o D (phase 2)", false, true, true, true},
  };
  const double per_100k = 1e5 / static_cast<double>(start.vertices.size());
  for (const Config& c : configs) {
    double one = 0.0;
    for (int threads : {1, 2}) {
      MeshOptimizerOptions o;
      o.t_flow = c.t;
      o.d_flow = c.d;
      o.n_flow = c.n;
      o.modified_flows = c.modified;
      if (c.t) o.t_flow_iterations = 1000;
      o.threads = threads;
      MeshOptimizer opt(*s.field, start, o);
      opt.step();  // warm-up (the first iteration moves the most)
      const int iterations = 4;
      const auto t0 = std::chrono::steady_clock::now();
      for (int i = 0; i < iterations; ++i) opt.step();
      const double ms = 1e3 * seconds_since(t0) / iterations;
      if (threads == 1) one = ms;
      std::printf("  %-40s %8d %14.1f %14.1f %8.2f\n", c.name, threads, ms, ms * per_100k, one / ms);
    }
  }
}

// Iterations until the tolerance criterion stops the run (tolerance 1e-3, at most 400).
void convergence() {
  std::printf("\n== Iterations to converge (tolerance 1e-3, T-flow off automatically, at most 400; 2 threads) ==\n");
  std::printf("  %-34s %9s %10s %10s %10s %10s %11s %8s\n", "shape / flows", "iters", "E_d start", "E_d end",
              "E_n start", "E_n end", "T-flow its", "seconds");
  struct Case {
    Shape shape;
    int cells;
  };
  const Case cases[] = {{sphere_to_cube(), 32}, {csg_block(), 64}, {rotated_box(), 64}};
  for (const Case& c : cases) {
    const Mesh start = polygonize(c.shape, c.cells);
    for (bool modified : {false, true}) {
      MeshOptimizerOptions o;
      o.modified_flows = modified;
      o.tolerance = 1e-3;
      o.max_iterations = 400;
      o.threads = 2;
      MeshOptimizer opt(*c.shape.field, start, o);
      const OptimizerIterationStats s0 = opt.stats();
      int t_iterations = 0;
      const auto t0 = std::chrono::steady_clock::now();
      while (!opt.done()) t_iterations += opt.step().t_flow_on ? 1 : 0;
      const double sec = seconds_since(t0);
      const OptimizerIterationStats& s1 = opt.stats();
      const std::string label =
          c.shape.name + " " + std::to_string(c.cells) + "^3 " + (modified ? "modified" : "paper N");
      std::printf("  %-34s %9d %10.2e %10.2e %10.2e %10.2e %11d %8.2f\n", label.c_str(), s1.iteration, s0.e_d, s1.e_d,
                  s0.e_n, s1.e_n, t_iterations, sec);
    }
  }
}

// The optimized 64^3 mesh against plain Marching Cubes at 64^3, 128^3 and 256^3.
void resolution_worth(bool quick) {
  for (const Shape& s : {csg_block(), rotated_box()}) {
    const double h64 = s.h(64);
    std::printf("\n== %s: optimized 64^3 vs Marching Cubes (h64 = %.4f, diagonal %.3f) ==\n", s.name.c_str(), h64,
                s.diagonal());
    print_errors_header();
    std::vector<std::pair<std::string, Errors>> rows;
    for (int cells : {64, 128, 256}) {
      if (quick && cells == 256) continue;
      const auto t0 = std::chrono::steady_clock::now();
      const Mesh mc = polygonize(s, cells, false);
      const double sec = seconds_since(t0);
      rows.emplace_back("MC " + std::to_string(cells) + "^3", measure(s, mc, h64));
      print_errors(rows.back().first + " (" + std::to_string(static_cast<int>(sec * 1000)) + " ms)",
                   rows.back().second);
    }
    const Mesh start = polygonize(s, 64, false);
    for (int variant = 0; variant < 3; ++variant) {
      MeshOptimizerOptions o;
      o.modified_flows = variant != 0;
      o.max_iterations = 150;
      o.threads = 2;
      if (variant == 2) o.subdivision_threshold = 0.004 * h64 * h64;
      const auto t0 = std::chrono::steady_clock::now();
      const Mesh out = optimize_mesh(*s.field, start, o);
      const double sec = seconds_since(t0);
      const char* name = variant == 0 ? "opt 64^3 paper N" : variant == 1 ? "opt 64^3 modified" : "opt 64^3 mod+subdiv";
      rows.emplace_back(name, measure(s, out, h64));
      print_errors(std::string(name) + " (" + std::to_string(static_cast<int>(sec)) + " s)", rows.back().second);
    }
    const Errors& opt = rows[rows.size() - 2].second;
    // How many times lower the optimized figure is (">10^4x" when it is at round-off level).
    auto lower = [](double mc, double optimized) {
      char buf[32];
      if (optimized <= 1e-4 * mc) return std::string(" >10^4x");
      std::snprintf(buf, sizeof buf, "%7.1fx", mc / optimized);
      return std::string(buf);
    };
    for (const auto& [label, e] : rows) {
      if (label.rfind("MC", 0) != 0) continue;
      std::printf("  opt 64^3 modified vs %-9s lower by: face max %s, face rms %s, E_n %s; %5.2fx the triangles\n",
                  label.c_str(), lower(e.face_max, opt.face_max).c_str(), lower(e.face_rms, opt.face_rms).c_str(),
                  lower(e.e_n, opt.e_n).c_str(), static_cast<double>(opt.triangles) / static_cast<double>(e.triangles));
    }
  }
}

constexpr const char* kUsage = "usage: optimize_bench [--quick]\n";

}  // namespace
}  // namespace surfacer

int main(int argc, char** argv) {
  bool quick = false;
  surfacer::bench::Args args(argc, argv, "optimize_bench", surfacer::kUsage);
  while (args.next()) {
    if (args.flag() == "--quick") {
      quick = true;
    } else {
      args.unknown();
    }
  }
  std::printf("optimize_bench: hardware threads %d\n", surfacer::resolve_threads(0));
  surfacer::time_flows();
  surfacer::convergence();
  surfacer::resolution_worth(quick);
  std::printf("\nAnchor: Extended Marching Cubes reaches < 0.25 %% of the diagonal on the fandisk from a 65^3 grid.\n");
  return 0;
}
