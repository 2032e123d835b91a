#include "core/mesh/grid_cleanup.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <limits>
#include <optional>
#include <unordered_map>
#include <utility>

#include "core/mesh/mesh_edit.h"
#include "core/mesh/mesh_repair.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

using GridPoint = std::array<std::uint32_t, 3>;

// One 64-bit key per grid point: exact up to 21 bits, a mix of the three coordinates above (equal keys are then
// compared coordinate by coordinate).
std::uint64_t key_of(const GridPoint& g, int bits) {
  if (bits <= 21) return (std::uint64_t{g[0]} << 42) | (std::uint64_t{g[1]} << 21) | g[2];
  std::uint64_t h = g[0];
  h = h * 0x9E3779B97F4A7C15ull ^ g[1];
  h = h * 0x9E3779B97F4A7C15ull ^ g[2];
  return h * 0xBF58476D1CE4E5B9ull;
}

// What one scan of the mesh finds on the grid.
struct Findings {
  std::vector<GridPoint> points;                 // every vertex's grid point
  std::vector<std::uint32_t> degenerate;         // triangles collinear on the grid
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keys;  // (key, vertex) of referenced vertices, sorted
  std::vector<std::uint32_t> coincident;         // referenced vertices on the grid point of a lower-keyed other
};

bool inside(const Vec3& p, const Aabb& box) {
  return (p.array() >= box.min.array()).all() && (p.array() <= box.max.array()).all();
}

Findings scan(const Mesh& mesh, const QuantizationGrid& grid, int threads) {
  Findings f;
  const std::size_t nv = mesh.vertices.size(), nt = mesh.triangles.size();
  f.points.resize(nv);
  for_chunks(nv, threads, [&](std::size_t begin, std::size_t end) {
    for (std::size_t v = begin; v < end; ++v) f.points[v] = grid.frame_point(mesh.vertices[v]);
  });
  std::vector<char> used(nv, 0);
  {
    const int chunks = static_cast<int>(std::min<std::size_t>(64, nt / 16384 + 1));
    std::vector<std::vector<std::uint32_t>> found(static_cast<std::size_t>(chunks));
    parallel_for(chunks, threads, [&](int c) {
      const auto [begin, end] = chunk_range(nt, chunks, c);
      for (std::size_t t = begin; t < end; ++t) {
        const Triangle& tri = mesh.triangles[t];
        if (collinear_on_grid(f.points[tri[0]], f.points[tri[1]], f.points[tri[2]])) {
          found[static_cast<std::size_t>(c)].push_back(static_cast<std::uint32_t>(t));
        }
      }
    });
    for (const auto& list : found) f.degenerate.insert(f.degenerate.end(), list.begin(), list.end());
  }
  for (const Triangle& t : mesh.triangles) used[t[0]] = used[t[1]] = used[t[2]] = 1;
  f.keys.reserve(nv);
  for (std::size_t v = 0; v < nv; ++v) {
    if (used[v]) f.keys.emplace_back(key_of(f.points[v], grid.bits), static_cast<std::uint32_t>(v));
  }
  std::sort(f.keys.begin(), f.keys.end());
  for (std::size_t i = 0; i < f.keys.size();) {
    std::size_t j = i + 1;
    while (j < f.keys.size() && f.keys[j].first == f.keys[i].first) ++j;
    for (std::size_t a = i + 1; a < j; ++a) {  // equal keys: the same point unless mixed above 21 bits
      for (std::size_t b = i; b < a; ++b) {
        if (f.points[f.keys[a].second] == f.points[f.keys[b].second]) {
          f.coincident.push_back(f.keys[a].second);
          break;
        }
      }
    }
    i = j;
  }
  return f;
}

// Moves vertices of degenerate triangles and vertices on shared grid points to free neighbouring grid points.
class Nudger {
 public:
  Nudger(Mesh& mesh, const QuantizationGrid& grid, Findings& findings)
      : mesh_(mesh),
        grid_(grid),
        findings_(findings),
        adjacency_(vertex_triangles(mesh.vertices.size(), mesh.triangles)) {}

  // Nudges one vertex of triangle t (the one that moves least), unless t is no longer degenerate.
  bool fix_triangle(std::uint32_t t) {
    const Triangle& tri = mesh_.triangles[t];
    if (!collinear_on_grid(point(tri[0]), point(tri[1]), point(tri[2]))) return false;
    std::optional<std::pair<double, GridPoint>> best;
    std::uint32_t best_vertex = MeshEditor::kNone;
    for (const std::uint32_t v : tri) {
      if (const auto m = best_move(v); m && (!best || m->first < best->first)) {
        best = m;
        best_vertex = v;
      }
    }
    if (!best) return false;
    move(best_vertex, best->second);
    return true;
  }

  // Nudges v when another vertex shares its grid point.
  bool fix_vertex(std::uint32_t v) {
    if (occupancy(point(v)) < 2) return false;
    const auto m = best_move(v);
    if (!m) return false;
    move(v, m->second);
    return true;
  }

  std::int64_t nudges = 0;

 private:
  const GridPoint& point(std::uint32_t v) const { return findings_.points[v]; }

  // Vertices on grid point g: those the scan found there, plus the moves since.
  int occupancy(const GridPoint& g) const {
    const std::uint64_t key = key_of(g, grid_.bits);
    int count = 0;
    auto it =
        std::lower_bound(findings_.keys.begin(), findings_.keys.end(), std::pair<std::uint64_t, std::uint32_t>(key, 0));
    for (; it != findings_.keys.end() && it->first == key; ++it)
      count += moved_.count(it->second) == 0 && point(it->second) == g;
    for (const auto& [v, from] : moved_) count += point(v) == g;
    return count;
  }

  Vec3 position(std::uint32_t v, std::uint32_t moving, const GridPoint& to) const {
    return grid_.dequantize(v == moving ? to : point(v));
  }

  // The free neighbouring grid point of v nearest to v's position that leaves none of v's triangles degenerate on
  // the grid or turned against its normal before the move, with its squared distance.
  std::optional<std::pair<double, GridPoint>> best_move(std::uint32_t v) const {
    const Vec3& here = mesh_.vertices[v];
    if (!inside(here, grid_.box)) return std::nullopt;
    const std::span<const std::uint32_t> fan = adjacency_.of(v);
    std::optional<std::pair<double, GridPoint>> best;
    const GridPoint from = point(v);
    for (int dx = -1; dx <= 1; ++dx) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dz = -1; dz <= 1; ++dz) {
          if (dx == 0 && dy == 0 && dz == 0) continue;
          GridPoint to = from;
          const std::array<int, 3> step{dx, dy, dz};
          bool valid = true;
          for (int c = 0; c < 3; ++c) {
            const std::int64_t value = std::int64_t{from[c]} + step[c];
            valid = valid && value >= 0 && value <= std::int64_t{grid_.max_value()};
            to[c] = static_cast<std::uint32_t>(std::max<std::int64_t>(0, value));
          }
          if (!valid) continue;
          const double distance = (grid_.dequantize(to) - here).squaredNorm();
          if (best && distance >= best->first) continue;
          if (!acceptable(v, to, fan)) continue;
          best = std::pair(distance, to);
        }
      }
    }
    return best;
  }

  bool acceptable(std::uint32_t v, const GridPoint& to, std::span<const std::uint32_t> fan) const {
    if (occupancy(to) > 0) return false;
    for (const std::uint32_t t : fan) {
      const Triangle& tri = mesh_.triangles[t];
      std::array<GridPoint, 3> g;
      for (int k = 0; k < 3; ++k) g[k] = tri[k] == v ? to : point(tri[k]);
      if (collinear_on_grid(g[0], g[1], g[2])) return false;
      const Vec3 a = position(tri[0], v, to), b = position(tri[1], v, to), c = position(tri[2], v, to);
      const Vec3& a0 = mesh_.vertices[tri[0]];
      const Vec3 before = (mesh_.vertices[tri[1]] - a0).cross(mesh_.vertices[tri[2]] - a0);
      if (!((b - a).cross(c - a).dot(before) > 0.0)) return false;
    }
    return true;
  }

  void move(std::uint32_t v, const GridPoint& to) {
    moved_.emplace(v, point(v));
    findings_.points[v] = to;
    mesh_.vertices[v] = grid_.dequantize(to);
    ++nudges;
  }

  Mesh& mesh_;
  const QuantizationGrid& grid_;
  Findings& findings_;
  VertexTriangles adjacency_;
  std::unordered_map<std::uint32_t, GridPoint> moved_;  // vertex -> the grid point it left
};

// Collapses every edge whose two ends share a grid point (docs/ALGORITHMS.md §5 "Clean on the grid"): merging them
// moves nothing a decoder sees, so no triangle can fold or turn degenerate by it; only the topology can forbid it
// (OpenMesh's is_collapse_ok through MeshEditor). The degenerate triangles of the scan are the only places such an
// edge can be, and the grid points do not change, so passes over them reach a fixed point: a pass that collapses
// nothing ends the loop. Removed vertices and triangles are compacted away; normals and attributes follow their
// vertices. Returns the number of collapses.
std::int64_t collapse_coincident_edges(Mesh& mesh, Findings& f, int max_passes, int min_valence,
                                       const RunControl& control) {
  const std::size_t nv = mesh.vertices.size();
  const VertexTriangles adjacency = vertex_triangles(nv, mesh.triangles);
  std::vector<char> gone(nv, 0);
  std::int64_t collapses = 0;
  {
    MeshEditor editor(mesh.triangles, adjacency, nv);
    const auto floor = static_cast<std::size_t>(min_valence);
    // The valence floor of the sliver repair: a vertex at or above it does not go below it.
    auto may_lose = [&](std::uint32_t v) {
      const std::size_t valence = editor.neighbours(v).size();
      return valence < floor || valence - 1 >= floor;
    };
    std::vector<std::uint32_t> work = f.degenerate;
    for (int pass = 0; pass < max_passes && !work.empty(); ++pass) {
      control.check();
      std::vector<std::uint32_t> left;
      for (const std::uint32_t t : work) {
        if (editor.removed(t)) continue;
        bool done = false;
        for (int k = 0; k < 3 && !done; ++k) {
          const std::uint32_t a = mesh.triangles[t][static_cast<std::size_t>(k)];
          const std::uint32_t b = mesh.triangles[t][static_cast<std::size_t>((k + 1) % 3)];
          if (f.points[a] != f.points[b]) continue;
          for (const auto& [keep, lost] : {std::pair(a, b), std::pair(b, a)}) {
            const auto site = editor.collapse_site(t, keep, lost);
            if (!site) continue;
            const Triangle& tri = mesh.triangles[t];
            const std::uint32_t third = tri[0] != a && tri[0] != b   ? tri[0]
                                        : tri[1] != a && tri[1] != b ? tri[1]
                                                                     : tri[2];
            const std::size_t kept_valence = editor.neighbours(keep).size();
            const std::size_t merged = kept_valence + editor.neighbours(lost).size() - 4;
            if (!may_lose(third) || !may_lose(site->vertex) || (merged < floor && kept_valence >= floor)) continue;
            editor.collapse(t, keep, lost);
            gone[lost] = 1;
            ++collapses;
            done = true;
            break;
          }
        }
        if (!done) left.push_back(t);
      }
      if (left.size() == work.size()) break;
      work.swap(left);
    }
  }
  if (collapses == 0) return 0;
  std::vector<std::uint32_t> remap(nv, MeshEditor::kNone);
  std::uint32_t next = 0;
  for (std::size_t v = 0; v < nv; ++v) {
    if (gone[v]) continue;
    mesh.vertices[next] = mesh.vertices[v];
    f.points[next] = f.points[v];
    if (!mesh.normals.empty()) mesh.normals[next] = mesh.normals[v];
    for (Attribute& attribute : mesh.attributes) {
      const auto c = static_cast<std::size_t>(attribute.components);
      std::copy_n(attribute.values.begin() + static_cast<std::ptrdiff_t>(v * c), c,
                  attribute.values.begin() + static_cast<std::ptrdiff_t>(next * c));
    }
    remap[v] = next++;
  }
  mesh.vertices.resize(next);
  f.points.resize(next);
  if (!mesh.normals.empty()) mesh.normals.resize(next);
  for (Attribute& attribute : mesh.attributes)
    attribute.values.resize(next * static_cast<std::size_t>(attribute.components));
  std::size_t kept = 0;
  for (const Triangle& t : mesh.triangles) {
    if (t[0] == MeshEditor::kNone) continue;
    mesh.triangles[kept++] = Triangle{remap[t[0]], remap[t[1]], remap[t[2]]};
  }
  mesh.triangles.resize(kept);
  return collapses;
}

}  // namespace

GridCleanupReport clean_on_grid(Mesh& mesh, const QuantizationGrid& grid, const GridCleanupOptions& options,
                                const RunControl& control) {
  if (options.min_valence < 3 || options.min_valence > 6) {
    throw InvalidInput("min_valence", "min_valence (" + std::to_string(options.min_valence) + ") must be in [3, 6]");
  }
  if (options.max_rounds < 1) {
    throw InvalidInput("max_rounds", "max_rounds (" + std::to_string(options.max_rounds) + ") must be at least 1");
  }
  const int threads = resolve_threads(options.threads);
  GridCleanupReport report;
  Findings f = scan(mesh, grid, threads);
  report.degenerate_found = static_cast<std::int64_t>(f.degenerate.size());
  report.coincident_found = static_cast<std::int64_t>(f.coincident.size());
  if (!f.degenerate.empty()) {
    report.collapses += collapse_coincident_edges(mesh, f, options.max_rounds, options.min_valence, control);
    f = scan(mesh, grid, threads);
  }
  for (int round = 0; round < options.max_rounds && !(f.degenerate.empty() && f.coincident.empty()); ++round) {
    control.check();
    if (!f.degenerate.empty()) {
      SliverOptions slivers;
      slivers.min_angle_degrees = 0.0;  // only what the grid makes degenerate
      slivers.grid = grid;
      slivers.min_valence = options.min_valence;
      slivers.threads = threads;
      const SliverReport r = repair_slivers(mesh, slivers, control);
      report.flips += r.flips;
      report.collapses += r.collapses;
      f = scan(mesh, grid, threads);
    }
    if (f.degenerate.empty() && f.coincident.empty()) break;
    control.check();
    Nudger nudger(mesh, grid, f);
    for (const std::uint32_t t : f.degenerate) nudger.fix_triangle(t);
    for (const std::uint32_t v : f.coincident) nudger.fix_vertex(v);
    report.nudges += nudger.nudges;
    f = scan(mesh, grid, threads);
  }
  report.degenerate_left = static_cast<std::int64_t>(f.degenerate.size());
  report.coincident_left = static_cast<std::int64_t>(f.coincident.size());
  return report;
}

void snap_to_grid(std::vector<Vec3>& vertices, const QuantizationGrid& grid, int threads) {
  for_chunks(vertices.size(), resolve_threads(threads), [&](std::size_t begin, std::size_t end) {
    for (std::size_t v = begin; v < end; ++v) vertices[v] = grid.dequantize(grid.frame_point(vertices[v]));
  });
}

}  // namespace surfacer
