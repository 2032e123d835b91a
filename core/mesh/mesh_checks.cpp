// check_mesh works from one vertex -> corner table (counting sort of the 3F corners by vertex, O(V + F), no maps):
// for every vertex v the corners of its triangles give its link edges (a, b) (triangle (v, a, b) counter-clockwise),
// i.e. directed mesh edges v->a and b->v. Sorting those few (neighbour, direction) pairs per vertex yields, for each
// edge (v, w) counted at its smaller end, its number of triangles and how often each direction is used; the link
// graph's connectivity (a small union-find per vertex) decides whether the triangles around v form one fan.
#include "core/mesh/mesh_checks.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <string>

#include "core/util/errors.h"

namespace surfacer {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct UnionFind {
  std::vector<std::uint32_t> parent;
  explicit UnionFind(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0u); }
  std::uint32_t find(std::uint32_t x) {
    while (parent[x] != x) {
      parent[x] = parent[parent[x]];  // path halving
      x = parent[x];
    }
    return x;
  }
  void unite(std::uint32_t a, std::uint32_t b) {
    a = find(a);
    b = find(b);
    if (a == b) return;
    if (a < b) std::swap(a, b);
    parent[a] = b;  // smaller id becomes the root: deterministic and keeps trees shallow enough here
  }
};

bool repeated(const Triangle& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }

}  // namespace

MeshReport check_mesh(const Mesh& mesh) {
  MeshReport report;
  const std::size_t nv = mesh.vertices.size();
  const std::size_t nf = mesh.triangles.size();
  if (nf > (std::numeric_limits<std::uint32_t>::max() - 2) / 3) {
    throw ResourceLimit("triangles", "check_mesh supports at most 1431655764 triangles");
  }
  for (std::size_t t = 0; t < nf; ++t) {
    for (std::uint32_t v : mesh.triangles[t]) {
      if (v >= nv) {
        throw InvalidInput("triangles", "triangle " + std::to_string(t) + " uses vertex " + std::to_string(v) +
                                            " but the mesh has " + std::to_string(nv) + " vertices");
      }
    }
  }

  // --- Geometry per triangle -----------------------------------------------------------------------------------
  const double diag2 = nv > 0 ? Aabb::of(mesh.vertices).size().squaredNorm() : 0.0;
  const double min_area = 1e-14 * diag2;
  double max_cos = -2.0, min_cos = 2.0;  // of all angles: smallest angle <-> largest cosine
  double area = 0.0, volume = 0.0;
  std::int64_t valid_faces = 0;
  for (const Triangle& t : mesh.triangles) {
    if (repeated(t)) {
      ++report.degenerate_triangles;
      continue;
    }
    ++valid_faces;
    const Vec3& a = mesh.vertices[t[0]];
    const Vec3& b = mesh.vertices[t[1]];
    const Vec3& c = mesh.vertices[t[2]];
    const Vec3 n = (b - a).cross(c - a);
    const double tri_area = 0.5 * n.norm();
    area += tri_area;
    volume += a.dot(b.cross(c)) / 6.0;
    if (!(tri_area >= min_area) || tri_area == 0.0) {
      ++report.degenerate_triangles;
      continue;
    }
    const Vec3* p[3] = {&a, &b, &c};
    for (int i = 0; i < 3; ++i) {
      const Vec3 u = *p[(i + 1) % 3] - *p[i];
      const Vec3 v = *p[(i + 2) % 3] - *p[i];
      const double cosine = u.dot(v) / std::sqrt(u.squaredNorm() * v.squaredNorm());
      max_cos = std::max(max_cos, cosine);
      min_cos = std::min(min_cos, cosine);
    }
  }
  report.area = area;
  report.volume = volume;
  if (max_cos >= -1.5) {
    report.min_angle_degrees = std::acos(std::clamp(max_cos, -1.0, 1.0)) * 180.0 / kPi;
    report.max_angle_degrees = std::acos(std::clamp(min_cos, -1.0, 1.0)) * 180.0 / kPi;
  }

  // --- Vertex -> corner table (triangles with a repeated index are left out of the topology) ------------------
  std::vector<std::uint32_t> start(nv + 1, 0);
  for (const Triangle& t : mesh.triangles) {
    if (repeated(t)) continue;
    for (std::uint32_t v : t) ++start[v + 1];
  }
  for (std::size_t v = 0; v < nv; ++v) start[v + 1] += start[v];
  std::vector<std::uint32_t> corners(start[nv]);
  {
    std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
    for (std::size_t t = 0; t < nf; ++t) {
      const Triangle& tri = mesh.triangles[t];
      if (repeated(tri)) continue;
      for (std::uint32_t c = 0; c < 3; ++c) corners[fill[tri[c]]++] = static_cast<std::uint32_t>(3 * t + c);
    }
  }

  // --- Per vertex: edges, orientation, valence, fans --------------------------------------------------------------
  struct Incidence {
    std::uint32_t other;
    int direction;  // +1: v -> other, -1: other -> v
    bool operator<(const Incidence& o) const { return other < o.other; }
  };
  std::vector<Incidence> incidences;
  std::vector<std::uint32_t> distinct;
  std::vector<std::uint32_t> link_parent;
  auto link_find = [&](std::uint32_t x) {
    while (link_parent[x] != x) x = link_parent[x] = link_parent[link_parent[x]];
    return x;
  };
  std::int64_t edges = 0, referenced = 0;
  bool oriented = true, vertex_manifold = true;
  int min_valence = std::numeric_limits<int>::max(), max_valence = 0;
  std::vector<std::int64_t> histogram;
  UnionFind components(nv);

  for (std::size_t v = 0; v < nv; ++v) {
    const std::uint32_t begin = start[v], end = start[v + 1];
    if (begin == end) continue;
    ++referenced;
    incidences.clear();
    for (std::uint32_t k = begin; k < end; ++k) {
      const std::uint32_t t = corners[k] / 3, c = corners[k] % 3;
      const Triangle& tri = mesh.triangles[t];
      incidences.push_back({tri[(c + 1) % 3], +1});
      incidences.push_back({tri[(c + 2) % 3], -1});
    }
    std::sort(incidences.begin(), incidences.end());
    distinct.clear();
    bool fan_ok = true;
    for (std::size_t r = 0; r < incidences.size();) {
      std::size_t s = r;
      int out = 0;
      while (s < incidences.size() && incidences[s].other == incidences[r].other) {
        out += incidences[s].direction > 0 ? 1 : 0;
        ++s;
      }
      const auto multiplicity = static_cast<std::int64_t>(s - r);
      const std::uint32_t w = incidences[r].other;
      distinct.push_back(w);
      if (multiplicity > 2) fan_ok = false;
      if (w > v) {
        ++edges;
        components.unite(static_cast<std::uint32_t>(v), w);
        if (multiplicity == 1) ++report.boundary_edges;
        if (multiplicity > 2) ++report.non_manifold_edges;
        if (multiplicity > 2 || (multiplicity == 2 && out != 1)) oriented = false;
      }
      r = s;
    }
    const int valence = static_cast<int>(distinct.size());
    min_valence = std::min(min_valence, valence);
    max_valence = std::max(max_valence, valence);
    if (histogram.size() <= static_cast<std::size_t>(valence)) histogram.resize(valence + 1, 0);
    ++histogram[valence];

    // The link of v: its distinct neighbours joined by one edge per triangle. One fan <=> connected link with every
    // neighbour in at most two triangles (a path: half-disk; a cycle: disk).
    if (fan_ok) {
      link_parent.resize(distinct.size());
      std::iota(link_parent.begin(), link_parent.end(), 0u);
      std::size_t parts = distinct.size();
      for (std::uint32_t k = begin; k < end; ++k) {
        const std::uint32_t t = corners[k] / 3, c = corners[k] % 3;
        const Triangle& tri = mesh.triangles[t];
        const auto ia = static_cast<std::uint32_t>(
            std::lower_bound(distinct.begin(), distinct.end(), tri[(c + 1) % 3]) - distinct.begin());
        const auto ib = static_cast<std::uint32_t>(
            std::lower_bound(distinct.begin(), distinct.end(), tri[(c + 2) % 3]) - distinct.begin());
        const std::uint32_t ra = link_find(ia), rb = link_find(ib);
        if (ra != rb) {
          link_parent[ra] = rb;
          --parts;
        }
      }
      fan_ok = parts == 1;
    }
    vertex_manifold = vertex_manifold && fan_ok;
  }

  report.closed = report.boundary_edges == 0;
  report.edge_manifold = report.non_manifold_edges == 0;
  report.vertex_manifold = vertex_manifold && report.edge_manifold;
  report.oriented = oriented;
  report.euler_characteristic = referenced - edges + valid_faces;
  for (std::size_t v = 0; v < nv; ++v) {
    if (start[v] != start[v + 1] && components.find(static_cast<std::uint32_t>(v)) == v) ++report.components;
  }
  report.valence_histogram = std::move(histogram);
  if (referenced > 0) {
    report.min_valence = min_valence;
    report.max_valence = max_valence;
  }
  return report;
}

}  // namespace surfacer
