// Dynamic mesh optimization (core/optimize/mesh_optimizer.h; Ohtake, Belyaev, Pasko 2002; docs/ALGORITHMS.md §3).
//
// Layout: every sweep is a Jacobi pass (reads `from`, writes `to`) over fixed chunks of kChunk vertices or triangles
// handed to parallel_for, so results do not depend on the thread count; reductions sum per-chunk partials in chunk
// order. An iteration works on scratch arrays and only commits them at its end (strong guarantee on cancel).
#include "core/optimize/mesh_optimizer.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>

#include "core/mesh/mesh_edit.h"
#include "core/optimize/cleanup.h"
#include "core/optimize/refine.h"
#include "core/scene/scene.h"
#include "core/util/checks.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"
#include "core/util/state_blob.h"
#include "core/util/triangle_limit.h"

namespace surfacer {
namespace {

constexpr int kChunk = 4096;
constexpr double kGradientEpsilon = 1e-12;  // ε of the Newton projection F_D
constexpr double kMinCos = 0.02;            // flip guard: n_T·m_T must stay >= this (or not get worse)
constexpr double kDegenerateArea = 1e-12;   // times L²: below this a triangle has no normal
constexpr int kGuardHalvings = 3;           // then the move is dropped
constexpr int kModifiedSteps = 5;           // gradient steps of the modified N-flow (paper §3.1)
constexpr int kBacktrackHalvings = 12;      // step halvings before a modified-flow gradient step is given up
// Automatic T-flow switch-off: E_d decreased by less than kStableDrop over kStableWindow iterations.
constexpr int kMinTIterations = 10;
constexpr int kStableWindow = 5;
constexpr double kStableDrop = 0.05;
constexpr double kPi = 3.14159265358979323846;

// --- Checkpoint blobs ---------------------------------------------------------------------------------------------
constexpr char kStateMagic[4] = {'S', 'O', 'P', 'T'};
constexpr std::uint32_t kStateVersion = 1;

struct GreenChild {  // a checkpoint's entry of RedGreenHierarchy::green_group
  std::uint32_t triangle;
  std::int32_t group;
};

[[noreturn]] void bad_state(const std::string& why) {
  throw InvalidInput("state", "optimizer checkpoint is not valid (" + why + "); start the optimization over");
}

int chunks_of(std::size_t n) { return static_cast<int>((n + kChunk - 1) / kChunk); }

// Runs body(begin, end) over [0, n) in chunks of kChunk, checking for cancel before each chunk.
template <class Body>
void for_chunks(std::size_t n, int threads, const RunControl& control, Body&& body) {
  parallel_for(chunks_of(n), threads, [&](int c) {
    control.check();
    const std::size_t begin = static_cast<std::size_t>(c) * kChunk;
    body(begin, std::min(n, begin + kChunk));
  });
}

// Vertex adjacency in compressed rows.
struct Topology {
  VertexTriangles faces;                     // vertex -> incident triangles
  std::vector<std::uint32_t> vv_offset, vv;  // vertex -> distinct neighbours
  std::vector<std::uint8_t> interior;        // every edge at the vertex has exactly two triangles

  std::size_t degree(std::size_t v) const { return vv_offset[v + 1] - vv_offset[v]; }

  void build(std::size_t vertex_count, const std::vector<Triangle>& tris, int threads, const RunControl& control) {
    faces = vertex_triangles(vertex_count, tris);
    const std::vector<std::uint32_t>& vt_offset = faces.offsets;
    const std::vector<std::uint32_t>& vt = faces.triangles;
    // Neighbours: the other two corners of each incident triangle, sorted; an edge shared by exactly two incident
    // triangles appears twice.
    std::vector<std::uint32_t> counts(vertex_count, 0);
    interior.assign(vertex_count, 0);
    auto neighbours = [&](std::size_t v, std::vector<std::uint32_t>& out) {
      out.clear();
      for (std::uint32_t i = vt_offset[v]; i < vt_offset[v + 1]; ++i) {
        const Triangle& t = tris[vt[i]];
        for (std::uint32_t w : t) {
          if (w != v) out.push_back(w);
        }
      }
      std::sort(out.begin(), out.end());
    };
    for_chunks(vertex_count, threads, control, [&](std::size_t begin, std::size_t end) {
      std::vector<std::uint32_t> local;
      for (std::size_t v = begin; v < end; ++v) {
        neighbours(v, local);
        std::uint32_t distinct = 0;
        bool ok = !local.empty();
        for (std::size_t i = 0; i < local.size();) {
          std::size_t j = i;
          while (j < local.size() && local[j] == local[i]) ++j;
          ok = ok && (j - i == 2);
          ++distinct;
          i = j;
        }
        counts[v] = distinct;
        interior[v] = ok ? 1 : 0;
      }
    });
    vv_offset.assign(vertex_count + 1, 0);
    for (std::size_t v = 0; v < vertex_count; ++v) vv_offset[v + 1] = vv_offset[v] + counts[v];
    vv.resize(vv_offset.back());
    for_chunks(vertex_count, threads, control, [&](std::size_t begin, std::size_t end) {
      std::vector<std::uint32_t> local;
      for (std::size_t v = begin; v < end; ++v) {
        neighbours(v, local);
        local.erase(std::unique(local.begin(), local.end()), local.end());
        std::copy(local.begin(), local.end(), vv.begin() + vv_offset[v]);
      }
    });
  }
};

// The two other corners of triangle t seen from v, counter-clockwise: (v, q1, q2) is t rotated.
std::pair<std::uint32_t, std::uint32_t> others(const Triangle& t, std::uint32_t v) {
  if (t[0] == v) return {t[1], t[2]};
  if (t[1] == v) return {t[2], t[0]};
  return {t[0], t[1]};
}

Vec3 cross_of(const std::vector<Vec3>& p, const Triangle& t) { return (p[t[1]] - p[t[0]]).cross(p[t[2]] - p[t[0]]); }
Vec3 centroid_of(const std::vector<Vec3>& p, const Triangle& t) { return (p[t[0]] + p[t[1]] + p[t[2]]) / 3.0; }

Vec3 unit_gradient(const Field& field, const Vec3& x) {
  Vec3 g;
  field.value_and_gradient(x, g);
  const double len = g.norm();
  return len > 0.0 && std::isfinite(len) ? Vec3(g / len) : Vec3::Zero();
}

// Smallest angle of a non-degenerate triangle in degrees: the one opposite the shortest edge. `cross` = |(b-a)x(c-a)|.
double min_angle_of(const Vec3& a, const Vec3& b, const Vec3& c, double cross) {
  const std::array<Vec3, 3> p{a, b, c};
  std::array<double, 3> opposite;  // squared length of the edge opposite corner k
  for (int k = 0; k < 3; ++k) opposite[k] = (p[(k + 2) % 3] - p[(k + 1) % 3]).squaredNorm();
  const int k = static_cast<int>(std::min_element(opposite.begin(), opposite.end()) - opposite.begin());
  const double dot = (p[(k + 1) % 3] - p[k]).dot(p[(k + 2) % 3] - p[k]);
  return std::atan2(cross, dot) * 180.0 / kPi;
}

}  // namespace

void validate(const MeshOptimizerOptions& o) {
  const MeshOptimizerOptions defaults;
  require_range_open_low("c_d", o.c_d, 0.0, 1.0,
                         "the default " + format_number(defaults.c_d) + " takes the full Newton step onto f = 0");
  require_range_open_low(
      "c_n", o.c_n, 0.0, 1.0,
      "the default " + format_number(defaults.c_n) + " takes the full projection onto the centroid tangent planes");
  require_range_open_low("c_t", o.c_t, 0.0, 1.0, "the paper uses 0.1; the default is " + format_number(defaults.c_t));
  require_range_open_low("step_bound", o.step_bound, 0.0, 1.0,
                         "the paper uses 0.1..0.25; the default is " + format_number(defaults.step_bound));
  require_count("max_iterations", o.max_iterations, 0, kMaxIterations,
                "the default is " + std::to_string(defaults.max_iterations));
  if (o.t_flow_iterations && *o.t_flow_iterations < 0) {
    throw InvalidInput("t_flow_iterations", "t_flow_iterations (" + std::to_string(*o.t_flow_iterations) +
                                                ") must be >= 0; leave it unset to switch the T-flow off when E_d "
                                                "stabilises");
  }
  if (o.t_flow_iterations && !o.t_flow) {
    throw InvalidInput("t_flow_iterations",
                       "t_flow_iterations sets how long the T-flow runs, but t_flow is off: turn t_flow on or leave "
                       "t_flow_iterations unset");
  }
  if (o.tolerance && !(*o.tolerance > 0.0 && *o.tolerance < 1.0)) {
    throw InvalidInput("tolerance", "tolerance (" + format_number(*o.tolerance) +
                                        ") must be in (0, 1): a relative change of E_d and E_n, e.g. 1e-3");
  }
  if (o.subdivision_threshold && !(*o.subdivision_threshold > 0.0 && std::isfinite(*o.subdivision_threshold))) {
    throw InvalidInput("subdivision_threshold",
                       "subdivision_threshold (" + format_number(*o.subdivision_threshold) +
                           ") must be a finite number > 0 (scene units², e.g. 0.004 h² for grid spacing h)");
  }
  if (o.subdivision_interval < 1) {
    throw InvalidInput("subdivision_interval", "subdivision_interval (" + std::to_string(o.subdivision_interval) +
                                                   ") must be >= 1; the default is " +
                                                   std::to_string(defaults.subdivision_interval));
  }
  if (o.triangle_budget && *o.triangle_budget <= 0) {
    throw InvalidInput("triangle_budget", "triangle_budget (" + std::to_string(*o.triangle_budget) +
                                              ") must be > 0; leave it unset for no limit");
  }
  if (o.snapshot_every < 0) {
    throw InvalidInput("snapshot_every", "snapshot_every (" + std::to_string(o.snapshot_every) +
                                             ") must be >= 0 (0: only the final mesh)");
  }
  if (o.threads < 0) {
    throw InvalidInput("threads", "threads (" + std::to_string(o.threads) + ") must be >= 0 (0: hardware threads)");
  }
  if (!o.d_flow && !o.n_flow && !o.t_flow && !o.subdivision_threshold) {
    throw InvalidInput("d_flow",
                       "every flow is off and subdivision is off, so nothing would change; enable d_flow "
                       "and n_flow (the defaults)");
  }
}

void validate_start_mesh(const Mesh& start) {
  if (start.triangles.empty()) {
    throw InvalidInput("start", "start mesh has no triangles; polygonize the field first (Marching Cubes or Tiles)");
  }
  if (start.vertices.size() >= std::numeric_limits<std::uint32_t>::max() / 2) {
    throw ResourceLimit(
        "start", "start mesh has " + std::to_string(start.vertices.size()) + " vertices; at most 2^31 are supported");
  }
  for (std::size_t t = 0; t < start.triangles.size(); ++t) {
    const Triangle& tri = start.triangles[t];
    for (std::uint32_t v : tri) {
      if (v >= start.vertices.size()) {
        throw InvalidInput("start", "start triangle " + std::to_string(t) + " uses vertex " + std::to_string(v) +
                                        " but the mesh has " + std::to_string(start.vertices.size()) + " vertices");
      }
    }
    if (tri[0] == tri[1] || tri[1] == tri[2] || tri[2] == tri[0]) {
      throw InvalidInput(
          "start", "start triangle " + std::to_string(t) + " repeats a vertex; remove degenerate triangles first");
    }
  }
  for (std::size_t v = 0; v < start.vertices.size(); ++v) {
    if (!start.vertices[v].allFinite()) {
      throw InvalidInput("start", "start vertex " + std::to_string(v) + " is not finite");
    }
  }
}

struct MeshOptimizer::State {
  const Field& field;
  MeshOptimizerOptions options;
  int threads;
  double length_scale = 1.0;  // L: bounding-box diagonal of the start mesh's used vertices

  // Committed state (the result of the last complete iteration).
  Mesh mesh;
  Topology topo;
  optimizer_detail::RedGreenHierarchy hierarchy;
  OptimizerIterationStats stats;
  std::vector<double> vertex_f;     // f at the committed vertices
  std::vector<Vec3> vertex_g;       // ∇f at the committed vertices
  std::vector<Vec3> triangle_m;     // m(C_T) at the committed centroids
  std::vector<double> e_d_history;  // [k] after iteration k
  std::vector<double> e_n_history;
  int last_disruption = 0;  // the last iteration with the T-flow or a subdivision
  bool t_active = false;
  int t_done = 0;
  bool converged = false;
  // Triangles control.triangles' hook has covered for the refinement (the caller's reservation only grows).
  mutable std::int64_t reserved_triangles = 0;

  State(const Field& f, Mesh start, const MeshOptimizerOptions& o)
      : field(f), options(o), threads(resolve_threads(o.threads)), mesh(std::move(start)) {}

  double degenerate_cross() const { return 2.0 * kDegenerateArea * length_scale * length_scale; }

  // --- Figures -------------------------------------------------------------------------------------------------
  // Evaluates f, ∇f at the vertices and m at the centroids of (positions, tris) and the figures of §2.4.
  struct Evaluated {
    OptimizerIterationStats stats;
    std::vector<double> f;
    std::vector<Vec3> g, m;
  };
  // `known_m`: the field normals at the centroids of (p, tris), if already evaluated.
  Evaluated evaluate(const std::vector<Vec3>& p, const std::vector<Triangle>& tris, const Topology& topology,
                     const std::vector<Vec3>* known_m, const RunControl& control) const {
    Evaluated out;
    const std::size_t nv = p.size(), nt = tris.size();
    out.f.assign(nv, 0.0);
    out.g.assign(nv, Vec3::Zero());
    out.m.assign(nt, Vec3::Zero());
    std::vector<double> area(nt, 0.0);
    // Triangles: m(C_T), E_n, min angle.
    struct TriPartial {
      double en = 0.0, area = 0.0, min_angle = 180.0;
    };
    std::vector<TriPartial> tp(chunks_of(nt));
    for_chunks(nt, threads, control, [&](std::size_t begin, std::size_t end) {
      TriPartial acc;
      for (std::size_t t = begin; t < end; ++t) {
        const Triangle& tri = tris[t];
        const Vec3 n = cross_of(p, tri);
        const double len = n.norm();
        out.m[t] = known_m != nullptr ? (*known_m)[t] : unit_gradient(field, centroid_of(p, tri));
        area[t] = 0.5 * len;
        if (len <= degenerate_cross()) continue;
        acc.en += area[t] * (n / len - out.m[t]).squaredNorm();
        acc.area += area[t];
        acc.min_angle = std::min(acc.min_angle, min_angle_of(p[tri[0]], p[tri[1]], p[tri[2]], len));
      }
      tp[begin / kChunk] = acc;
    });
    // Vertices: f, ∇f, E_d, distances.
    struct VertPartial {
      double ed = 0.0, area = 0.0, max_d = 0.0, sum_d2 = 0.0;
      std::int64_t used = 0;
    };
    std::vector<VertPartial> vp(chunks_of(nv));
    for_chunks(nv, threads, control, [&](std::size_t begin, std::size_t end) {
      VertPartial acc;
      for (std::size_t v = begin; v < end; ++v) {
        if (topology.faces.offsets[v] == topology.faces.offsets[v + 1]) continue;
        out.f[v] = field.value_and_gradient(p[v], out.g[v]);
        const double g2 = out.g[v].squaredNorm();
        const double d2 = g2 > 0.0 ? out.f[v] * out.f[v] / g2 : out.f[v] * out.f[v];
        double ap = 0.0;
        for (std::uint32_t i = topology.faces.offsets[v]; i < topology.faces.offsets[v + 1]; ++i)
          ap += area[topology.faces.triangles[i]];
        acc.ed += ap * d2;
        acc.area += ap;
        acc.max_d = std::max(acc.max_d, std::sqrt(d2));
        acc.sum_d2 += d2;
        ++acc.used;
      }
      vp[begin / kChunk] = acc;
    });
    TriPartial ts;
    for (const TriPartial& x : tp) {
      ts.en += x.en;
      ts.area += x.area;
      ts.min_angle = std::min(ts.min_angle, x.min_angle);
    }
    VertPartial vs;
    for (const VertPartial& x : vp) {
      vs.ed += x.ed;
      vs.area += x.area;
      vs.max_d = std::max(vs.max_d, x.max_d);
      vs.sum_d2 += x.sum_d2;
      vs.used += x.used;
    }
    OptimizerIterationStats& s = out.stats;
    s.e_d = vs.area > 0.0 ? vs.ed / vs.area : 0.0;
    s.e_n = ts.area > 0.0 ? ts.en / ts.area : 0.0;
    s.max_distance = vs.max_d;
    s.rms_distance = vs.used > 0 ? std::sqrt(vs.sum_d2 / static_cast<double>(vs.used)) : 0.0;
    s.min_angle_degrees = ts.area > 0.0 ? ts.min_angle : 0.0;
    s.triangles = static_cast<std::int64_t>(nt);
    s.vertices = vs.used;
    return out;
  }

  void commit_evaluation(Evaluated&& e) {
    vertex_f = std::move(e.f);
    vertex_g = std::move(e.g);
    triangle_m = std::move(e.m);
    if (options.normals) {
      mesh.normals.resize(mesh.vertices.size());
      for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
        const double len = vertex_g[v].norm();
        mesh.normals[v] = len > 0.0 ? Vec3(vertex_g[v] / len) : Vec3::UnitZ();
      }
    } else {
      mesh.normals.clear();
    }
  }

  // --- Flip guard ----------------------------------------------------------------------------------------------
  // `to` holds the proposed positions; on return the accepted ones. A triangle's score is n_T·m_T (-2 when
  // degenerate); the move is accepted when score(to) >= min(kMinCos, score(from)), with m_from for both sides, or,
  // when `m_to` is given, with m_to refreshed at the triangle's new centroid (exact: used at the end of an iteration,
  // where m_from must be the field normals at the centroids of `from`). Otherwise the moves of the triangle's
  // vertices are halved (kGuardHalvings times, then dropped) and the check repeats. Returns the number of limited
  // vertices.
  std::int64_t guard(const std::vector<Vec3>& from, std::vector<Vec3>& to, const std::vector<Triangle>& tris,
                     const std::vector<Vec3>& m_from, std::vector<Vec3>* m_to, const RunControl& control) const {
    const std::size_t nt = tris.size(), nv = from.size();
    auto score = [&](const std::vector<Vec3>& p, std::size_t t, const Vec3& m) {
      const Vec3 n = cross_of(p, tris[t]);
      const double len = n.norm();
      return len <= degenerate_cross() ? -2.0 : n.dot(m) / len;
    };
    const std::vector<Vec3>& m_new = m_to != nullptr ? *m_to : m_from;
    // floor(t) = min(kMinCos, score before); computed only for triangles that score below kMinCos after the move.
    constexpr double kUnset = 3.0;
    std::vector<double> floor_score(nt, kUnset);
    auto floor_of = [&](std::size_t t) {
      if (floor_score[t] == kUnset) floor_score[t] = std::min(kMinCos, score(from, t, m_from[t]));
      return floor_score[t];
    };
    const std::vector<Vec3> proposed = to;
    std::vector<std::uint8_t> halvings(nv, 0);
    std::vector<std::vector<std::uint32_t>> bad(chunks_of(nt));
    std::vector<std::uint8_t> bumped(nv, 0);
    for (;;) {
      for_chunks(nt, threads, control, [&](std::size_t b, std::size_t e) {
        auto& list = bad[b / kChunk];
        list.clear();
        for (std::size_t t = b; t < e; ++t) {
          const double now = score(to, t, m_new[t]);
          if (now < kMinCos && now < floor_of(t)) list.push_back(static_cast<std::uint32_t>(t));
        }
      });
      std::vector<std::uint32_t> moved;
      std::fill(bumped.begin(), bumped.end(), 0);
      for (const auto& list : bad) {
        for (std::uint32_t t : list) {
          for (std::uint32_t v : tris[t]) {
            if (bumped[v] || halvings[v] > kGuardHalvings) continue;
            bumped[v] = 1;
            moved.push_back(v);
            ++halvings[v];
            const double scale = halvings[v] > kGuardHalvings ? 0.0 : std::ldexp(1.0, -halvings[v]);
            to[v] = scale == 0.0 ? from[v] : Vec3(from[v] + scale * (proposed[v] - from[v]));
          }
        }
      }
      if (moved.empty()) break;
      if (m_to != nullptr) {
        for (std::uint32_t v : moved) {
          for (std::uint32_t i = topo.faces.offsets[v]; i < topo.faces.offsets[v + 1]; ++i) {
            const std::uint32_t t = topo.faces.triangles[i];
            (*m_to)[t] = unit_gradient(field, centroid_of(to, tris[t]));
          }
        }
      }
    }
    return std::count_if(halvings.begin(), halvings.end(), [](std::uint8_t h) { return h > 0; });
  }

  // --- Flows (each a Jacobi sweep from `p` to `q`) ---------------------------------------------------------------
  // T-flow, paper eq. 6: q = p + c_t [U - (U·n) n] at interior vertices.
  void t_sweep(const std::vector<Vec3>& p, std::vector<Vec3>& q, const std::vector<Triangle>& tris,
               const RunControl& control) const {
    q = p;
    for_chunks(p.size(), threads, control, [&](std::size_t b, std::size_t e) {
      for (std::size_t v = b; v < e; ++v) {
        if (!topo.interior[v]) continue;
        const std::size_t k = topo.degree(v);
        Vec3 u = Vec3::Zero();
        for (std::uint32_t i = topo.vv_offset[v]; i < topo.vv_offset[v + 1]; ++i) u += p[topo.vv[i]];
        u = u / static_cast<double>(k) - p[v];
        Vec3 n = Vec3::Zero();
        for (std::uint32_t i = topo.faces.offsets[v]; i < topo.faces.offsets[v + 1]; ++i)
          n += cross_of(p, tris[topo.faces.triangles[i]]);
        const double len = n.norm();
        if (!(len > 0.0)) continue;
        n /= len;
        q[v] = p[v] + options.c_t * (u - u.dot(n) * n);
      }
    });
  }

  // D-flow, paper eq. 3 and 5: q = p + c_d F_D clamped to step_bound sqrt(A(P)). `cached` f/∇f at p, if valid.
  void d_sweep(const std::vector<Vec3>& p, std::vector<Vec3>& q, const std::vector<Triangle>& tris, bool cached,
               const RunControl& control) const {
    q = p;
    std::vector<double> area(tris.size());
    for_chunks(tris.size(), threads, control, [&](std::size_t b, std::size_t e) {
      for (std::size_t t = b; t < e; ++t) area[t] = 0.5 * cross_of(p, tris[t]).norm();
    });
    for_chunks(p.size(), threads, control, [&](std::size_t b, std::size_t e) {
      for (std::size_t v = b; v < e; ++v) {
        if (topo.faces.offsets[v] == topo.faces.offsets[v + 1]) continue;
        double f;
        Vec3 g;
        if (cached) {
          f = vertex_f[v];
          g = vertex_g[v];
        } else {
          f = field.value_and_gradient(p[v], g);
        }
        Vec3 step = -options.c_d * f * g / (g.squaredNorm() + kGradientEpsilon);
        double ap = 0.0;
        for (std::uint32_t i = topo.faces.offsets[v]; i < topo.faces.offsets[v + 1]; ++i)
          ap += area[topo.faces.triangles[i]];
        const double bound = options.step_bound * std::sqrt(ap);
        const double len = step.norm();
        if (!std::isfinite(len)) continue;
        if (len > bound) step *= bound / len;
        q[v] = p[v] + step;
      }
    });
  }

  // m(C_T) at the centroids of p.
  std::vector<Vec3> centroid_normals(const std::vector<Vec3>& p, const std::vector<Triangle>& tris,
                                     const RunControl& control) const {
    std::vector<Vec3> m(tris.size());
    for_chunks(tris.size(), threads, control, [&](std::size_t b, std::size_t e) {
      for (std::size_t t = b; t < e; ++t) m[t] = unit_gradient(field, centroid_of(p, tris[t]));
    });
    return m;
  }

  // N-flow (§2.2): q = p + c_n Σ A(T) ((C_T - P)·m_T) m_T / Σ A(T).
  void n_sweep(const std::vector<Vec3>& p, std::vector<Vec3>& q, const std::vector<Triangle>& tris,
               const std::vector<Vec3>& m, const RunControl& control) const {
    q = p;
    for_chunks(p.size(), threads, control, [&](std::size_t b, std::size_t e) {
      for (std::size_t v = b; v < e; ++v) {
        Vec3 sum = Vec3::Zero();
        double weight = 0.0;
        for (std::uint32_t i = topo.faces.offsets[v]; i < topo.faces.offsets[v + 1]; ++i) {
          const Triangle& tri = tris[topo.faces.triangles[i]];
          const double a = 0.5 * cross_of(p, tri).norm();
          const Vec3& mt = m[topo.faces.triangles[i]];
          sum += a * (centroid_of(p, tri) - p[v]).dot(mt) * mt;
          weight += a;
        }
        if (weight > 0.0) q[v] = p[v] + options.c_n * sum / weight;
      }
    });
  }

  // Modified N-flow (§3.1): five steps P -= (1/deg) ∇E(P), ∇φ(T) = ½ (n_T - m_T) × (Q2 - Q1), m frozen, each step
  // clamped to c_n step_bound sqrt(A(P)) / deg; the neighbours stay at p (Jacobi).
  void modified_n_sweep(const std::vector<Vec3>& p, std::vector<Vec3>& q, const std::vector<Triangle>& tris,
                        const std::vector<Vec3>& m, const RunControl& control) const {
    q = p;
    const double tiny = degenerate_cross();
    for_chunks(p.size(), threads, control, [&](std::size_t b, std::size_t e) {
      for (std::size_t v = b; v < e; ++v) {
        const std::size_t deg = topo.degree(v);
        if (deg == 0) continue;
        double ap = 0.0;
        for (std::uint32_t i = topo.faces.offsets[v]; i < topo.faces.offsets[v + 1]; ++i) {
          ap += 0.5 * cross_of(p, tris[topo.faces.triangles[i]]).norm();
        }
        const double inv_deg = 1.0 / static_cast<double>(deg);
        const double bound = options.c_n * options.step_bound * std::sqrt(ap) * inv_deg;
        // E(x) and its gradient with the neighbours at p and m frozen.
        auto energy = [&](const Vec3& x, Vec3* grad) {
          double sum = 0.0;
          for (std::uint32_t i = topo.faces.offsets[v]; i < topo.faces.offsets[v + 1]; ++i) {
            const auto [a, c] = others(tris[topo.faces.triangles[i]], static_cast<std::uint32_t>(v));
            const Vec3 n = (p[a] - x).cross(p[c] - x);
            const double len = n.norm();
            const Vec3& mt = m[topo.faces.triangles[i]];
            sum += 0.5 * (len - n.dot(mt));
            if (grad != nullptr && len > tiny) *grad += 0.5 * (n / len - mt).cross(p[c] - p[a]);
          }
          return sum;
        };
        Vec3 x = p[v];
        for (int s = 0; s < kModifiedSteps; ++s) {
          Vec3 grad = Vec3::Zero();
          const double e0 = energy(x, &grad);
          Vec3 step = -options.c_n * inv_deg * grad;
          const double len = step.norm();
          if (!(len > 0.0)) break;
          if (len > bound) step *= bound / len;
          // Backtracking: φ is only piecewise smooth (|n - m| has a kink where a strip of triangles collapses onto
          // a feature line), so a fixed step would oscillate across the minimum; halve until E decreases.
          int halvings = 0;
          while (energy(x + step, nullptr) >= e0 && halvings < kBacktrackHalvings) {
            step *= 0.5;
            ++halvings;
          }
          if (halvings == kBacktrackHalvings) break;
          x += step;
        }
        q[v] = x;
      }
    });
  }

  // --- Adaptive subdivision (§3.2) -----------------------------------------------------------------------------
  // δ(T) = (A(T)/4) Σ_k |n_T - m(C_k)|² over the four sub-triangles' centroids; C_4 = C_T (m given).
  std::vector<double> deviations(const std::vector<Vec3>& p, const std::vector<Triangle>& tris,
                                 const std::vector<Vec3>& m, const RunControl& control) const {
    std::vector<double> delta(tris.size(), 0.0);
    for_chunks(tris.size(), threads, control, [&](std::size_t b, std::size_t e) {
      for (std::size_t t = b; t < e; ++t) {
        const Triangle& tri = tris[t];
        const Vec3 cr = cross_of(p, tri);
        const double len = cr.norm();
        if (len <= degenerate_cross()) continue;
        const Vec3 n = cr / len;
        const Vec3 &a = p[tri[0]], &bb = p[tri[1]], &c = p[tri[2]];
        double sum = (n - m[t]).squaredNorm();
        sum += (n - unit_gradient(field, (4.0 * a + bb + c) / 6.0)).squaredNorm();
        sum += (n - unit_gradient(field, (a + 4.0 * bb + c) / 6.0)).squaredNorm();
        sum += (n - unit_gradient(field, (a + bb + 4.0 * c) / 6.0)).squaredNorm();
        delta[t] = 0.125 * len * sum;  // A/4 = |cross| / 8
      }
    });
    return delta;
  }

  // One subdivision round on (p, tris, h); returns the number of triangles added (0: nothing to do or no room).
  std::int64_t subdivide(std::vector<Vec3>& p, std::vector<Triangle>& tris, optimizer_detail::RedGreenHierarchy& h,
                         const std::vector<Vec3>& m, const RunControl& control) const {
    const std::vector<double> delta = deviations(p, tris, m, control);
    std::vector<std::uint32_t> order;
    for (std::size_t t = 0; t < tris.size(); ++t) {
      if (delta[t] > *options.subdivision_threshold) order.push_back(static_cast<std::uint32_t>(t));
    }
    if (order.empty()) return 0;
    std::size_t comparisons = 0;  // a sort of millions: it checks for cancel too
    std::stable_sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
      if ((++comparisons & ((std::size_t{1} << 20) - 1)) == 0) control.check();
      return delta[a] > delta[b];
    });
    // The option's budget and the caller's limit (control.triangles: a server's --max-triangles), whichever is less.
    const auto budget =
        std::min(options.triangle_budget.value_or(std::numeric_limits<std::int64_t>::max()), max_triangles(control));
    // Request the worst `count` triangles; halve the request until the closed result fits the budget. A trial stops
    // at the first pass whose result would not fit, before building it.
    for (std::size_t count = order.size(); count > 0; count /= 2) {
      std::vector<std::uint8_t> request(tris.size(), 0);
      for (std::size_t i = 0; i < count; ++i) request[order[i]] = 1;
      std::vector<Vec3> trial_p = p;
      std::vector<Triangle> trial_t = tris;
      optimizer_detail::RedGreenHierarchy trial_h;
      trial_h.assign(h, control);
      if (optimizer_detail::refine_red_green(trial_p, trial_t, trial_h, request, control, budget,
                                             &reserved_triangles)) {
        const auto added = static_cast<std::int64_t>(trial_t.size()) - static_cast<std::int64_t>(tris.size());
        p = std::move(trial_p);
        tris = std::move(trial_t);
        h = std::move(trial_h);
        return added;
      }
    }
    return 0;
  }

  // --- Schedule ------------------------------------------------------------------------------------------------
  void update_schedule(const OptimizerIterationStats& s) {
    const int k = s.iteration;
    if (s.t_flow_on) {
      ++t_done;
      if (options.t_flow_iterations) {
        t_active = t_done < *options.t_flow_iterations;
      } else {
        const bool tiny = s.e_d <= 1e-20 * length_scale * length_scale;
        const bool flat = t_done >= kMinTIterations && k >= kStableWindow &&
                          s.e_d > (1.0 - kStableDrop) * e_d_history[k - kStableWindow];
        const bool half = 2 * k >= options.max_iterations;
        if (tiny || flat || half) t_active = false;
      }
    }
    if (s.t_flow_on || s.triangles_added > 0) last_disruption = k;
    if (options.tolerance && k - last_disruption > kStableWindow) {
      // Neither figure improved by more than `tolerance` on the best of the previous kStableWindow iterations
      // (E_n need not fall monotonically, so one iteration is not enough), or both are at round-off level.
      auto stalled = [&](const std::vector<double>& history, double now, double floor) {
        double best = history[k - 1];
        for (int j = k - kStableWindow; j < k; ++j) best = std::min(best, history[j]);
        return now >= (1.0 - *options.tolerance) * best || now <= floor;
      };
      converged =
          stalled(e_d_history, s.e_d, 1e-24 * length_scale * length_scale) && stalled(e_n_history, s.e_n, 1e-24);
    }
  }

  OptimizerIterationStats step(const RunControl& control) {
    control.check();
    const int k = stats.iteration + 1;
    std::vector<Vec3> p = mesh.vertices, q;
    std::vector<Triangle> tris = mesh.triangles;
    std::int64_t limited = 0;
    const bool t_on = t_active && options.t_flow;
    if (t_on) {
      t_sweep(p, q, tris, control);
      limited += guard(p, q, tris, triangle_m, nullptr, control);
      p.swap(q);
    }
    if (options.d_flow) {
      d_sweep(p, q, tris, !t_on, control);
      limited += guard(p, q, tris, triangle_m, nullptr, control);
      p.swap(q);
    }
    if (options.n_flow) {
      const std::vector<Vec3> m = centroid_normals(p, tris, control);
      if (options.modified_flows && !t_on) {
        modified_n_sweep(p, q, tris, m, control);
      } else {
        n_sweep(p, q, tris, m, control);
      }
      limited += guard(p, q, tris, m, nullptr, control);
      p.swap(q);
    }
    // The sweeps' guards used the field normals from before each sweep; the iteration's result is checked once more
    // with the exact normals at its centroids (which the figures reuse), so no committed triangle faces against ∇f.
    std::vector<Vec3> m_final = centroid_normals(p, tris, control);
    limited += guard(mesh.vertices, p, tris, triangle_m, &m_final, control);
    // A round on the last iteration would hand back unconverged midpoints, so none is done there.
    const bool subdivision_due =
        options.subdivision_threshold && k % options.subdivision_interval == 0 && k < options.max_iterations;
    optimizer_detail::RedGreenHierarchy new_h;
    if (options.repair_connectivity || subdivision_due) new_h.assign(hierarchy, control);
    optimizer_detail::CleanupCounts cleanup;
    if (options.repair_connectivity) {
      optimizer_detail::CleanupOptions co;
      co.min_cos = kMinCos;
      co.degenerate_cross = degenerate_cross();
      cleanup = optimizer_detail::repair_connectivity(p, tris, new_h, m_final, topo.faces, field, co, control);
    }
    const bool reconnected = cleanup.flips + cleanup.collapses > 0;
    Topology new_topo;
    if (reconnected) new_topo.build(p.size(), tris, threads, control);
    Evaluated e = evaluate(p, tris, reconnected ? new_topo : topo, &m_final, control);
    std::int64_t added = 0;
    if (subdivision_due) {
      added = subdivide(p, tris, new_h, e.m, control);
      if (added > 0) {
        new_topo.build(p.size(), tris, threads, control);
        e = evaluate(p, tris, new_topo, nullptr, control);
      }
    }
    // Commit (nothing below throws Cancelled).
    mesh.vertices = std::move(p);
    mesh.triangles = std::move(tris);
    if (reconnected || added > 0) topo = std::move(new_topo);
    if (options.repair_connectivity || subdivision_due) hierarchy = std::move(new_h);
    stats = e.stats;
    stats.iteration = k;
    stats.t_flow_on = t_on;
    stats.limited_moves = limited;
    stats.triangles_added = added;
    stats.flips = cleanup.flips;
    stats.collapses = cleanup.collapses;
    commit_evaluation(std::move(e));
    e_d_history.push_back(stats.e_d);
    e_n_history.push_back(stats.e_n);
    update_schedule(stats);
    return stats;
  }
};

MeshOptimizer::MeshOptimizer(const Field& field, Mesh start, const MeshOptimizerOptions& options) {
  validate(options);
  validate_start_mesh(start);
  state_ = std::make_unique<State>(field, std::move(start), options);
  State& s = *state_;
  s.topo.build(s.mesh.vertices.size(), s.mesh.triangles, s.threads, {});
  Aabb box = Aabb::empty();
  for (const Triangle& t : s.mesh.triangles) {
    for (std::uint32_t v : t) box.merge(s.mesh.vertices[v]);
  }
  s.length_scale = std::max(box.size().norm(), std::numeric_limits<double>::min());
  s.hierarchy.reset(s.mesh.triangles.size());
  State::Evaluated e = s.evaluate(s.mesh.vertices, s.mesh.triangles, s.topo, nullptr, {});
  s.stats = e.stats;
  s.commit_evaluation(std::move(e));
  s.e_d_history.push_back(s.stats.e_d);
  s.e_n_history.push_back(s.stats.e_n);
  s.t_active = options.t_flow && (!options.t_flow_iterations || *options.t_flow_iterations > 0);
  s.stats.t_flow_on = false;
}

MeshOptimizer::MeshOptimizer(std::unique_ptr<State> state) : state_(std::move(state)) {}

std::string MeshOptimizer::save_state() const {
  const State& s = *state_;
  state_blob::Writer w(kStateMagic, kStateVersion);
  w.put_array(s.mesh.vertices);
  w.put_array(s.mesh.triangles);
  w.put(s.length_scale);
  const OptimizerIterationStats& st = s.stats;
  w.put<std::int32_t>(st.iteration);
  for (const double v : {st.e_d, st.e_n, st.max_distance, st.rms_distance, st.min_angle_degrees}) w.put(v);
  for (const std::int64_t v :
       {st.triangles, st.vertices, st.limited_moves, st.triangles_added, st.flips, st.collapses}) {
    w.put(v);
  }
  w.put<std::uint8_t>(st.t_flow_on ? 1 : 0);
  w.put_array(s.e_d_history);
  w.put_array(s.e_n_history);
  w.put<std::int32_t>(s.last_disruption);
  w.put<std::uint8_t>(s.t_active ? 1 : 0);
  w.put<std::int32_t>(s.t_done);
  w.put<std::uint8_t>(s.converged ? 1 : 0);
  // Green children only (most triangles are not): (triangle, group) pairs.
  std::vector<GreenChild> green;
  for (std::size_t t = 0; t < s.hierarchy.green_group.size(); ++t) {
    if (s.hierarchy.green_group[t] >= 0) green.push_back({static_cast<std::uint32_t>(t), s.hierarchy.green_group[t]});
  }
  w.put_array(green);
  w.put_array(s.hierarchy.green_parents);
  // The midpoint map in key order, so equal states give equal blobs.
  std::vector<std::pair<std::uint64_t, std::uint32_t>> midpoints(s.hierarchy.midpoints.begin(),
                                                                 s.hierarchy.midpoints.end());
  std::sort(midpoints.begin(), midpoints.end());
  w.put<std::uint64_t>(midpoints.size());
  for (const auto& [key, v] : midpoints) {
    w.put(key);
    w.put(v);
  }
  return w.finish();
}

MeshOptimizer MeshOptimizer::from_state(const Field& field, std::string_view state,
                                        const MeshOptimizerOptions& options) {
  state_blob::Reader r(state, kStateMagic, "not an optimizer checkpoint", bad_state);
  if (const auto version = r.version(); version != kStateVersion) {
    bad_state("version " + std::to_string(version) + ", this server reads version " + std::to_string(kStateVersion));
  }
  Mesh mesh;
  mesh.vertices = r.get_array<Vec3>();
  mesh.triangles = r.get_array<Triangle>();
  try {
    validate(options);
    validate_start_mesh(mesh);  // indices, finite positions
  } catch (const Error& e) {
    if (e.field() == "start") bad_state(e.what());
    throw;
  }
  auto st = std::make_unique<State>(field, std::move(mesh), options);
  State& s = *st;
  s.length_scale = r.get<double>();
  if (!(s.length_scale > 0.0) || !std::isfinite(s.length_scale)) bad_state("length scale");
  OptimizerIterationStats& stats = s.stats;
  stats.iteration = r.get<std::int32_t>();
  for (double* v : {&stats.e_d, &stats.e_n, &stats.max_distance, &stats.rms_distance, &stats.min_angle_degrees}) {
    *v = r.get<double>();
  }
  for (std::int64_t* v : {&stats.triangles, &stats.vertices, &stats.limited_moves, &stats.triangles_added, &stats.flips,
                          &stats.collapses}) {
    *v = r.get<std::int64_t>();
  }
  stats.t_flow_on = r.get<std::uint8_t>() != 0;
  s.e_d_history = r.get_array<double>();
  s.e_n_history = r.get_array<double>();
  if (stats.iteration < 0 || s.e_d_history.size() != static_cast<std::size_t>(stats.iteration) + 1 ||
      s.e_n_history.size() != s.e_d_history.size()) {
    bad_state("the error history does not match the iteration count");
  }
  s.last_disruption = r.get<std::int32_t>();
  s.t_active = r.get<std::uint8_t>() != 0;
  s.t_done = r.get<std::int32_t>();
  s.converged = r.get<std::uint8_t>() != 0;
  if (s.last_disruption < 0 || s.last_disruption > stats.iteration || s.t_done < 0 || s.t_done > stats.iteration) {
    bad_state("schedule counters out of range");
  }
  optimizer_detail::RedGreenHierarchy& h = s.hierarchy;
  const auto green = r.get_array<GreenChild>();
  h.green_parents = r.get_array<Triangle>();
  const std::size_t nv = s.mesh.vertices.size();
  h.green_group.assign(s.mesh.triangles.size(), -1);
  for (const GreenChild& c : green) {
    if (c.triangle >= h.green_group.size() || c.group < 0 ||
        c.group >= static_cast<std::int64_t>(h.green_parents.size())) {
      bad_state("green child out of range");
    }
    h.green_group[c.triangle] = c.group;
  }
  for (const Triangle& t : h.green_parents) {
    for (const std::uint32_t v : t) {
      if (v >= nv) bad_state("green parent vertex out of range");
    }
  }
  const auto midpoints = r.get<std::uint64_t>();
  if (midpoints > r.remaining() / (sizeof(std::uint64_t) + sizeof(std::uint32_t))) bad_state("midpoints");
  for (std::uint64_t i = 0; i < midpoints; ++i) {
    const auto key = r.get<std::uint64_t>();
    const auto v = r.get<std::uint32_t>();
    if (v >= nv) bad_state("midpoint vertex out of range");
    h.midpoints.emplace(key, v);
  }
  if (r.remaining() != 0) bad_state(std::to_string(r.remaining()) + " trailing bytes");
  s.topo.build(nv, s.mesh.triangles, s.threads, {});
  // f, grad f and the centroid normals: the same evaluations the saved step committed.
  State::Evaluated e = s.evaluate(s.mesh.vertices, s.mesh.triangles, s.topo, nullptr, {});
  s.commit_evaluation(std::move(e));
  return MeshOptimizer(std::move(st));
}

MeshOptimizer::~MeshOptimizer() = default;
MeshOptimizer::MeshOptimizer(MeshOptimizer&&) noexcept = default;
MeshOptimizer& MeshOptimizer::operator=(MeshOptimizer&&) noexcept = default;

OptimizerIterationStats MeshOptimizer::step(const RunControl& control) { return state_->step(control); }
const Mesh& MeshOptimizer::mesh() const { return state_->mesh; }
const OptimizerIterationStats& MeshOptimizer::stats() const { return state_->stats; }
bool MeshOptimizer::done() const {
  return state_->stats.iteration >= state_->options.max_iterations || state_->converged;
}
bool MeshOptimizer::t_flow_on() const { return state_->t_active && state_->options.t_flow; }

Mesh optimize_mesh(const Field& field, Mesh start, const MeshOptimizerOptions& options,
                   const OptimizerSnapshotFn& on_snapshot, const RunControl& control) {
  MeshOptimizer optimizer(field, std::move(start), options);
  while (!optimizer.done()) {
    const OptimizerIterationStats s = optimizer.step(control);
    control.report("optimize", options.max_iterations > 0
                                   ? std::min(1.0, static_cast<double>(s.iteration) / options.max_iterations)
                                   : 1.0);
    if (on_snapshot && options.snapshot_every > 0 && s.iteration % options.snapshot_every == 0 && !optimizer.done()) {
      on_snapshot(optimizer.mesh(), s);
    }
  }
  if (on_snapshot) on_snapshot(optimizer.mesh(), optimizer.stats());
  return optimizer.mesh();
}

}  // namespace surfacer
