// Active implicit surfaces (core/active/active_surface.h): the Enright deformation test and coating a particle
// sequence.
//
//   active_bench                 Enright at 100^3 and the 200-frame coating sequence
//   active_bench --full          Enright also at 128^3 and 200^3
//   active_bench --enright N     Enright at N^3 only (N >= 8: coarser grids barely hold the sphere; repeatable)
//   active_bench --coat-only     only the coating sequence
//   active_bench --general-only  Enright with the general velocity only (VelocityFn called per node and stage, as
//                                OpenVDB's field functor is); by default the separable (cached u(x)) form runs too,
//                                then again with volume control (delta) on top, and a table puts them side by side
//   active_bench --delta D       the volume control of those runs (repeatable; default 1; 0: none)
//   active_bench --compensate    the Enright runs with error compensation (BFECC on every sub-step)
//   active_bench --cfl C         the Enright runs' CFL number (default the engine's, 0.5)
//   options: --threads T (default 2), --particles N (default 10000), --frames F (>= 2, default 200),
//            --alpha A (tracking alpha = A * kernel radius, > 0, default 0.3), --beta B (tension beta = B * radius^2,
//            default 0.02), --dropout D (fraction of the particles absent from each frame, below 1, default 0.1)
//   A flag the others make useless is refused like a bad value (exit 2): --coat-only with --enright, --full,
//   --general-only, --delta, --compensate or --cfl; --full with --enright; --delta with --general-only; a coating flag
//   (--particles,
//   --frames, --alpha, --beta, --dropout) with --enright.
//
// Enright (Enright, Fedkiw, Ferziger & Mitchell 2002, §5.3): sphere r = 0.15 at (0.35, 0.35, 0.35) in the unit cube,
// period T = 3, without and with volume control (docs/ALGORITHMS.md §4, "Control terms on top of advection").
// Reported: volume change at T/2 and T (Marching Cubes volume of the potential on its grid, against the initial one),
// wall and CPU seconds, and cost per active node per sub-step (wall and CPU, over the sum of active nodes of every
// sub-step, reinitializations and polygonizations included); for the side-by-side table also the largest volume
// change over the frames and the mean distance of the surface at T to the exact solution (the initial sphere).
// Anchor on this machine: OpenVDB LevelSetAdvection (HJ-WENO5, TVD-RK2, no volume control) -36.1% at 100^3 (-25.3%
// at 128^3, -7.35% at 200^3), ~0.5 us per active voxel per step.
//
// Coating: a generated sequence of particles (a ball that stretches into two lobes and turns, with per-frame jitter
// of 0.15 spacing like a simulation's noise, and a changing particle set: 10% absent from each frame) coated with the
// Wyvill kernel field, one skin per frame (coat_particles), against polygonizing each frame's target directly with
// Marching Tiles (the popping baseline). Reported: ms per frame; flicker = mean distance of each frame's vertices to
// the previous frame's surface over the particles' mean displacement (the brief's measure), and the same motion over
// that of the clean sequence's surface (no jitter, no dropout: 1 means no flicker); the skin's distance to its
// frame's target and to the clean surface.
#include <sys/resource.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "bench/bench_args.h"
#include "core/active/active_surface.h"
#include "core/particles/spatial_hash.h"
#include "core/polygonize/marching_tiles.h"

namespace {

using namespace surfacer;

// Volume control of the Enright runs with delta (see print_delta_table).
constexpr double kDefaultDelta = 1.0;

double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}
double wall_seconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

class Sphere final : public Field {
 public:
  Sphere(const Vec3& c, double r) : c_(c), r_(r) {}
  double value(const Vec3& p) const override { return (p - c_).norm() - r_; }
  double value_and_gradient(const Vec3& p, Vec3& g) const override {
    const Vec3 d = p - c_;
    const double n = d.norm();
    g = n > 0.0 ? Vec3(d / n) : Vec3(1, 0, 0);
    return n - r_;
  }
  std::optional<Aabb> bounds() const override { return Aabb{c_.array() - r_, c_.array() + r_}; }

 private:
  Vec3 c_;
  double r_;
};

// How the Enright runs step: error compensation and the CFL number (nullopt: the engine's default).
struct EnrightScheme {
  bool compensate = false;
  std::optional<double> cfl;
};

struct EnrightResult {
  double delta = 0.0;
  double dv_half = 0.0, dv_end = 0.0;  // volume change at T/2 and T, %
  double max_abs_dv = 0.0;             // largest |volume change| over the frames, %
  double shape_error = 0.0;            // mean distance of the surface at T to the initial sphere, in h
  int steps = 0;
  double wall = 0.0;
};

EnrightResult enright(int n, int threads, const EnrightScheme& scheme, bool separable, double delta = 0.0) {
  const double period = 3.0;
  ActiveSurfaceOptions o;
  o.h = 1.0 / n;
  o.domain = Aabb{Vec3::Zero(), Vec3::Ones()};
  o.threads = threads;
  o.delta = delta;
  o.error_compensation = scheme.compensate;
  if (scheme.cfl) o.cfl = scheme.cfl;
  const Sphere sphere(Vec3(0.35, 0.35, 0.35), 0.15);
  const double w0 = wall_seconds(), c0 = cpu_seconds();
  ActiveSurface surface(sphere, o);
  if (separable) {
    surface.set_velocity(enright_separable_velocity(period));  // u(x) cached per node, cos(pi t / T) per stage
  } else {
    surface.set_velocity([period](const Vec3& p, double t) { return enright_velocity(p, t, period); });
  }
  const ActiveFrameStats s0 = surface.stats();
  const double exact = 4.0 / 3.0 * 3.14159265358979323846 * 0.15 * 0.15 * 0.15;
  std::printf(
      "\nEnright %d^3, %s velocity (h = %.5f, band_width %.0f, reinit every %d, cfl %g%s, %d threads, delta %g): "
      "V0 %.6f (exact %.6f), %lld active nodes\n",
      n, separable ? "separable (cached)" : "general (per node and stage)", o.h, o.band_width,
      o.reinitialization_interval(), *o.cfl, o.error_compensation ? ", error compensation" : "", threads, delta,
      s0.volume, exact, static_cast<long long>(s0.active_nodes));
  std::printf("  %6s %9s %6s %10s %10s %6s %5s %9s %9s %10s %10s\n", "t", "dV", "steps", "active", "peak act.",
              "reinit", "comp", "wall s", "cpu s", "us/n-s wall", "us/n-s cpu");
  const int frames = 8;
  double node_steps = 0.0, peak = 0.0;
  int steps = 0;
  double dv_half = 0.0, dv_end = 0.0, max_abs_dv = 0.0;
  for (int f = 1; f <= frames; ++f) {
    const ActiveFrameStats s = surface.advance(period / frames);
    node_steps += static_cast<double>(s.active_node_steps);
    steps += s.substeps;
    peak = std::max(peak, static_cast<double>(s.active_nodes));
    const double dv = 100.0 * (s.volume - s0.volume) / s0.volume;
    if (f == frames / 2) dv_half = dv;
    if (f == frames) dv_end = dv;
    max_abs_dv = std::max(max_abs_dv, std::abs(dv));
    const double w = wall_seconds() - w0, c = cpu_seconds() - c0;
    std::printf("  %6.3f %8.2f%% %6d %10lld %10.0f %6d %5d %9.2f %9.2f %10.3f %10.3f\n", s.time, dv, s.substeps,
                static_cast<long long>(s.active_nodes), peak, s.reinitializations, s.components, w, c,
                1e6 * w / node_steps, 1e6 * c / node_steps);
    std::fflush(stdout);
  }
  const double w = wall_seconds() - w0, c = cpu_seconds() - c0;
  // The exact solution at T is the initial sphere: how far the surface ended from it (outside the timings).
  double shape_error = 0.0;
  const Mesh end = surface.polygonize(Polygonizer::kCubes);
  for (const Vec3& p : end.vertices) shape_error += std::abs((p - Vec3(0.35, 0.35, 0.35)).norm() - 0.15);
  shape_error /= std::max<std::size_t>(1, end.vertices.size()) * o.h;
  std::printf(
      "  => %d^3 %s: dV(T/2) %.2f%%  dV(T) %.2f%%  %d steps  %.1f s wall (%.1f s cpu)  %.3f us per active "
      "node-step wall (%.3f cpu, %.3f cpu per thread)\n",
      n, separable ? "separable" : "general", dv_half, dv_end, steps, w, c, 1e6 * w / node_steps, 1e6 * c / node_steps,
      1e6 * c / node_steps / threads);
  return {delta, dv_half, dv_end, max_abs_dv, shape_error, steps, w};
}

// Volume-controlled advection side by side: the separable Enright run without delta (the last entry of `runs`) and
// with each delta.
void print_delta_table(int n, const std::vector<EnrightResult>& runs) {
  std::printf("\nEnright %d^3, volume control on top of the advection (normal speed delta (V0 - V) / V0):\n", n);
  std::printf("  %8s %10s %10s %12s %16s %16s %7s %8s\n", "delta", "dV(T/2)", "dV(T)", "max |dV|", "sphere dist (h)",
              "(% of r)", "steps", "wall s");
  const double radius_in_h = 0.15 * n;  // the sphere's r in grid spacings
  for (const EnrightResult& r : runs) {
    std::printf("  %8g %9.2f%% %9.2f%% %11.2f%% %16.2f %15.2f%% %7d %8.1f\n", r.delta, r.dv_half, r.dv_end,
                r.max_abs_dv, r.shape_error, 100.0 * r.shape_error / radius_in_h, r.steps, r.wall);
  }
}

// --- Coating ---------------------------------------------------------------------------------------------------------

struct Sequence {
  std::vector<std::vector<Vec3>> frames;
  std::vector<std::vector<std::uint32_t>> ids;  // particle id of every frame entry
  double spacing = 0.0;                         // mean particle spacing
};

// A ball of particles that turns about z while stretching into two lobes along its (turning) x axis; every frame
// adds fresh jitter of 0.15 spacing, as a simulation's particle noise would, and omits a random `dropout` fraction of
// the particles (the particle set changes from frame to frame, as with emission, deletion or level-of-detail).
Sequence make_sequence(int particles, int frames, double dropout, double jitter_spacings) {
  Sequence seq;
  std::mt19937_64 rng(12345);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  const double radius = 0.3;
  std::vector<Vec3> base;
  while (static_cast<int>(base.size()) < particles) {
    const Vec3 p(uni(rng), uni(rng), uni(rng));
    if (p.squaredNorm() <= 1.0) base.push_back(radius * p);
  }
  seq.spacing = std::cbrt(4.0 / 3.0 * 3.14159265358979323846 * radius * radius * radius / particles);
  const double jitter = jitter_spacings * seq.spacing;
  seq.frames.resize(frames);
  seq.ids.resize(frames);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int k = 0; k < frames; ++k) {
    const double t = static_cast<double>(k) / std::max(1, frames - 1);
    const double split = 0.35 * (0.5 - 0.5 * std::cos(3.14159265358979323846 * t));  // 0 -> 0.35
    const Eigen::Matrix3d rot = Eigen::AngleAxisd(1.5 * t, Vec3::UnitZ()).toRotationMatrix();
    auto& out = seq.frames[k];
    out.reserve(particles);
    for (std::uint32_t i = 0; i < base.size(); ++i) {
      const Vec3& b = base[i];
      const Vec3 noise(gauss(rng), gauss(rng), gauss(rng));
      if (unit(rng) < dropout) continue;
      seq.ids[k].push_back(i);
      Vec3 q = b;
      q.x() += (b.x() >= 0.0 ? split : -split);  // two lobes drifting apart
      q.y() *= 1.0 - 0.3 * split;
      out.push_back(rot * q + jitter * noise);
    }
  }
  return seq;
}

// Mean distance from the vertices of `mesh` to the triangles of `prev` (exact point-triangle distances over the
// triangles near each vertex).
double mean_distance_to_mesh(const Mesh& mesh, const Mesh& prev, double reach) {
  if (mesh.vertices.empty() || prev.triangles.empty()) return 0.0;
  std::vector<Vec3> centroids;
  centroids.reserve(prev.triangles.size());
  double max_edge = 0.0;
  for (const Triangle& t : prev.triangles) {
    const Vec3 &a = prev.vertices[t[0]], &b = prev.vertices[t[1]], &c = prev.vertices[t[2]];
    centroids.push_back((a + b + c) / 3.0);
    max_edge = std::max({max_edge, (a - b).norm(), (b - c).norm(), (c - a).norm()});
  }
  const SpatialHash hash(centroids, reach);
  auto point_triangle = [](const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    // Ericson, Real-Time Collision Detection §5.1.5.
    const Vec3 ab = b - a, ac = c - a, ap = p - a;
    const double d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0 && d2 <= 0) return (p - a).norm();
    const Vec3 bp = p - b;
    const double d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0 && d4 <= d3) return (p - b).norm();
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + d1 / (d1 - d3) * ab)).norm();
    const Vec3 cp = p - c;
    const double d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0 && d5 <= d6) return (p - c).norm();
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + d2 / (d2 - d6) * ac)).norm();
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
      return (p - (b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b))).norm();
    }
    const double denom = 1.0 / (va + vb + vc);
    return (p - (a + ab * (vb * denom) + ac * (vc * denom))).norm();
  };
  double sum = 0.0;
  for (const Vec3& p : mesh.vertices) {
    double best = std::numeric_limits<double>::infinity();
    hash.for_each_within(p, reach + max_edge, [&](std::uint32_t i, const Vec3&, double) {
      const Triangle& t = prev.triangles[i];
      best = std::min(best, point_triangle(p, prev.vertices[t[0]], prev.vertices[t[1]], prev.vertices[t[2]]));
    });
    if (!std::isfinite(best)) best = hash.nearest(p)->distance;
    sum += best;
  }
  return sum / static_cast<double>(mesh.vertices.size());
}

void coat(int particles, int frames, int threads, double alpha_scale, double beta_scale, double dropout) {
  const Sequence seq = make_sequence(particles, frames, dropout, 0.15);
  const Sequence clean = make_sequence(particles, frames, 0.0, 0.0);  // the motion without noise: the reference
  ParticleTargetOptions kernel;
  kernel.radius = 2.5 * seq.spacing;
  kernel.iso = 0.5;
  CoatOptions coat;
  coat.kernel = kernel;
  coat.frame_duration = 1.0;
  ActiveSurfaceOptions o;
  o.h = kernel.radius / 3.0;
  o.threads = threads;
  // Tracking: g = iso - sum K has |grad g| of a few / R at the skin, so alpha = alpha_scale R relaxes a gap at a rate
  // of about 3 alpha_scale per frame: 0.3 follows the motion within a fraction of h while filtering the frame-to-frame
  // noise (1 tracks tighter and flickers more); a little tension (features of radius R are smoothed by about
  // beta / (alpha |grad g| R)).
  o.alpha = alpha_scale * kernel.radius;
  o.beta = beta_scale * kernel.radius * kernel.radius;
  // Mean displacement between consecutive frames of the particles present in both.
  double mean_particle_motion = 0.0;
  for (int k = 1; k < frames; ++k) {
    double s = 0.0;
    int n = 0;
    std::size_t j = 0;
    for (std::size_t i = 0; i < seq.ids[k].size(); ++i) {
      while (j < seq.ids[k - 1].size() && seq.ids[k - 1][j] < seq.ids[k][i]) ++j;
      if (j < seq.ids[k - 1].size() && seq.ids[k - 1][j] == seq.ids[k][i]) {
        s += (seq.frames[k][i] - seq.frames[k - 1][j]).norm();
        ++n;
      }
    }
    mean_particle_motion += s / std::max(1, n);
  }
  mean_particle_motion /= std::max(1, frames - 1);
  std::printf(
      "\nCoating %d frames of %d particles, %.0f%% absent per frame (spacing %.4f, R %.4f, h %.4f, alpha %.4g, "
      "beta %.3g, %d threads); mean particle motion per frame %.5f\n",
      frames, particles, 100.0 * dropout, seq.spacing, kernel.radius, o.h, o.alpha, o.beta, threads,
      mean_particle_motion);

  // Active skin.
  Mesh prev;
  double skin_motion = 0.0, skin_lag = 0.0;
  int skin_pairs = 0, frame_index = 0;
  std::vector<std::vector<Vec3>> skin_vertices(frames);
  std::int64_t node_steps = 0, vertices = 0;
  int substeps = 0;
  double measure_wall = 0.0, measure_cpu = 0.0;  // the flicker measure inside the sink, not part of the skin's cost
  double w0 = wall_seconds(), c0 = cpu_seconds();
  coat_particles(seq.frames, coat, o, [&](ActiveFrame&& f) {
    const double mw = wall_seconds(), mc = cpu_seconds();
    if (!prev.vertices.empty()) {
      skin_motion += mean_distance_to_mesh(f.mesh, prev, 3.0 * o.h);
      ++skin_pairs;
    }
    skin_vertices[frame_index++] = f.mesh.vertices;  // for the tracking lag, measured against the direct surface
    measure_wall += wall_seconds() - mw;
    measure_cpu += cpu_seconds() - mc;
    node_steps += f.stats.active_node_steps;
    substeps += f.stats.substeps;
    vertices += static_cast<std::int64_t>(f.mesh.vertices.size());
    prev = std::move(f.mesh);
  });
  const double skin_wall = wall_seconds() - w0 - measure_wall, skin_cpu = cpu_seconds() - c0 - measure_cpu;
  // Direct polygonization of each frame's target (Marching Tiles at the same spacing), and of the clean sequence.
  auto tiles = [&](const std::vector<Vec3>& points) {
    const FieldPtr target = make_particle_target(points, kernel);
    MarchingTilesOptions mt;
    mt.bounds = *target->bounds();
    mt.spacing = o.h;
    mt.threads = threads;
    mt.seeds = points;
    mt.seed_radius = kernel.radius;
    return marching_tiles(*target, mt);
  };
  prev = Mesh{};
  Mesh prev_clean;
  double direct_motion = 0.0, clean_motion = 0.0, skin_to_clean = 0.0;
  int direct_pairs = 0;
  double direct_time_wall = 0.0, direct_time_cpu = 0.0;
  for (int k = 0; k < frames; ++k) {
    const double a = wall_seconds(), ac = cpu_seconds();
    Mesh mesh = tiles(seq.frames[k]);
    direct_time_wall += wall_seconds() - a;
    direct_time_cpu += cpu_seconds() - ac;
    Mesh clean_mesh = tiles(clean.frames[k]);
    if (!prev.vertices.empty()) {
      direct_motion += mean_distance_to_mesh(mesh, prev, 3.0 * o.h);
      clean_motion += mean_distance_to_mesh(clean_mesh, prev_clean, 3.0 * o.h);
      ++direct_pairs;
    }
    Mesh skin;
    skin.vertices = std::move(skin_vertices[k]);
    skin_lag += mean_distance_to_mesh(skin, mesh, 3.0 * o.h);
    skin_to_clean += mean_distance_to_mesh(skin, clean_mesh, 3.0 * o.h);
    prev = std::move(mesh);
    prev_clean = std::move(clean_mesh);
  }
  const double pairs = std::max(1, direct_pairs);
  const double skin_flicker = skin_motion / std::max(1, skin_pairs) / mean_particle_motion;
  const double direct_flicker = direct_motion / pairs / mean_particle_motion;
  const double clean_per_frame = clean_motion / pairs;
  std::printf(
      "  active skin : %7.1f ms/frame wall (%.1f cpu), %.1f sub-steps/frame, %.0f active nodes/sub-step, "
      "%.0f vertices/frame\n",
      1e3 * skin_wall / frames, 1e3 * skin_cpu / frames, static_cast<double>(substeps) / frames,
      static_cast<double>(node_steps) / std::max(1, substeps), static_cast<double>(vertices) / frames);
  std::printf("  direct tiles: %7.1f ms/frame wall (%.1f cpu)\n", 1e3 * direct_time_wall / frames,
              1e3 * direct_time_cpu / frames);
  std::printf(
      "  flicker = mean vertex motion to the previous frame's surface / mean particle motion (%.5f):\n"
      "    active skin %.3f, direct tiles %.3f, clean sequence (no jitter, no dropout) %.3f\n",
      mean_particle_motion, skin_flicker, direct_flicker, clean_per_frame / mean_particle_motion);
  std::printf("  motion per frame over the clean surface's: active skin %.2f, direct tiles %.2f (1 = no flicker)\n",
              skin_motion / std::max(1, skin_pairs) / clean_per_frame, direct_motion / pairs / clean_per_frame);
  std::printf("  mean distance of the skin to the frame's own target surface %.2f h, to the clean surface %.2f h\n",
              skin_lag / frames / o.h, skin_to_clean / frames / o.h);
}

constexpr const char* kUsage =
    "usage: active_bench [--full] [--enright N]... [--coat-only] [--general-only] [--delta D]... [--compensate]\n"
    "                    [--cfl C] [--threads T] [--particles N] [--frames F] [--alpha A] [--beta B] [--dropout D]\n";

}  // namespace

int main(int argc, char** argv) {
  int threads = 2, particles = 10000, frames = 200;
  double alpha_scale = 0.3, beta_scale = 0.02, dropout = 0.1;
  bool full = false, coat_only = false, general_only = false;
  std::vector<int> sizes;
  std::vector<double> deltas;
  bool deltas_given = false;
  EnrightScheme scheme;
  // The last flag given that only the Enright runs use, and the last that only the coating sequence uses.
  std::string enright_flag, coating_flag;
  bench::Args args(argc, argv, "active_bench", kUsage);
  while (args.next()) {
    const std::string& a = args.flag();
    if (a == "--full" || a == "--general-only" || a == "--enright" || a == "--delta" || a == "--compensate" ||
        a == "--cfl") {
      enright_flag = a;
      if (a == "--full") {
        full = true;
      } else if (a == "--compensate") {
        scheme.compensate = true;
      } else if (a == "--cfl") {
        scheme.cfl = args.number({.min = 0.0, .max = 1.0, .min_open = true});
      } else if (a == "--general-only") {
        general_only = true;
      } else if (a == "--enright") {
        sizes.push_back(args.integer(8));
      } else {
        deltas_given = true;
        if (const double d = args.number({.min = 0.0}); d > 0.0) deltas.push_back(d);
      }
    } else if (a == "--coat-only") {
      coat_only = true;
    } else if (a == "--threads") {
      threads = args.integer(1);
    } else if (a == "--particles" || a == "--frames" || a == "--alpha" || a == "--beta" || a == "--dropout") {
      coating_flag = a;
      if (a == "--particles") {
        particles = args.integer(1);
      } else if (a == "--frames") {
        frames = args.integer(2);  // the flicker is measured between consecutive frames
      } else if (a == "--alpha") {
        alpha_scale = args.number({.min = 0.0, .min_open = true});  // coat_particles tracks with alpha > 0
      } else if (a == "--beta") {
        beta_scale = args.number({.min = 0.0});
      } else {
        dropout = args.number({.min = 0.0, .max = 1.0, .max_open = true});  // coat_particles needs no frame empty
      }
    } else {
      args.unknown();
    }
  }
  // Combinations in which a flag would change nothing.
  if (coat_only && !enright_flag.empty()) {
    args.error(enright_flag + " configures the Enright runs, which --coat-only skips");
  }
  if (full && !sizes.empty()) {
    args.error("--full adds 128^3 and 200^3 to the default 100^3; with --enright, give every size as --enright N");
  }
  if (general_only && deltas_given) {
    args.error("--delta is the volume control of the separable runs, which --general-only skips");
  }
  if (!sizes.empty() && !coating_flag.empty()) {
    args.error(coating_flag + " configures the coating sequence, which --enright skips (Enright only)");
  }
  if (!deltas_given) deltas = {kDefaultDelta};
  const bool enright_only = !sizes.empty();
  if (sizes.empty() && !coat_only) {
    sizes.push_back(100);
    if (full) {
      sizes.push_back(128);
      sizes.push_back(200);
    }
  }
  std::printf(
      "Anchor (OpenVDB LevelSetAdvection, HJ-WENO5 + TVD-RK2, this machine): dV(T) -36.1%% at 100^3, -25.3%% at "
      "128^3, -7.35%% at 200^3; ~0.5 us per active voxel per step\n");
  for (const int n : sizes) {
    enright(n, threads, scheme, false);
    if (general_only) continue;
    std::vector<EnrightResult> runs = {enright(n, threads, scheme, true)};
    for (const double delta : deltas) runs.push_back(enright(n, threads, scheme, true, delta));
    if (!deltas.empty()) print_delta_table(n, runs);
  }
  if (!enright_only) coat(particles, frames, threads, alpha_scale, beta_scale, dropout);
  return 0;
}
