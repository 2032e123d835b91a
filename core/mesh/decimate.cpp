// Decimation (core/mesh/decimate.h, docs/ALGORITHMS.md §5 CHOICE "Decimation").
//
// The loop is our own on an OpenMesh TriMesh (its collapse written out; the link condition as its is_collapse_ok): a
// heap of vertices keyed by the quadric cost of their cheapest collapse, whose checks run only when a vertex reaches
// the top of the heap (lazy evaluation: the key is a lower bound of the cost of its cheapest legal collapse, made
// exact at the top and pushed back when another vertex is then cheaper). The cheap checks (fan geometry, link
// condition) also skip the candidates they refuse while the vertex is at the top; the expensive ones (the Hausdorff
// samples, the engine's rule) wait until its candidate is the cheapest collapse of all.
//
// A large mesh is cut into regions (cells of a grid, each triangle in the cell of its centroid) decimated in parallel
// with the vertices they share (or share with triangles left out) frozen. A vertex is dirty while some collapse of
// it has not been tried since its fan last changed: a frozen one and its neighbours stay dirty. After the first pass
// over all triangles, each pass takes only the triangles within kRings edges of a dirty vertex: over the cells
// shifted by half a cell (the first pass's seams inside them), by a quarter (the crossings of both seams inside), then
// over the connected parts of what is left near dirty vertices, until none is (at most kSeamPasses).
//
// Hausdorff samples: every removed vertex is a point held by one face of the current mesh, within the tolerance of
// it; a collapse gathers the points of the faces at v0 (and v0 itself) and is legal only when each lies within the
// tolerance of one of the faces the collapse leaves at v1, which then holds it (as OpenMesh's ModHausdorffT, with
// the points as singly linked lists of positions).
#include "core/mesh/decimate.h"

#include <Eigen/Geometry>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <optional>

#include "core/particles/spatial_hash.h"
#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

struct Traits : OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3d;  // unused: positions are read from the input by global vertex id
};
using TriMesh = OpenMesh::TriMesh_ArrayKernelT<Traits>;
using VertexHandle = TriMesh::VertexHandle;
using HalfedgeHandle = TriMesh::HalfedgeHandle;
using FaceHandle = TriMesh::FaceHandle;

constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
// Triangles per region, about: a region's TriMesh, positions and quadrics (~1 MB) stay in a core's cache, which
// measured 1.9x faster per collapse than one TriMesh of 300 k triangles. Meshes with fewer than two regions' worth
// are decimated in one pass.
constexpr double kRegionTriangles = 8192.0;
constexpr double kMaxCells = 64.0;  // per axis
// Passes after the first decimate only the triangles within kRings edges of a dirty vertex; after the three over grid
// cells, at most kSeamPasses over connected parts (each leaves fewer dirty vertices; the gyroid and the particle
// block need one to three).
constexpr int kRings = 2;
constexpr int kSeamPasses = 4;
// A region's triangles, about (the grid's cells are sized for it from the mean triangle area); meshes with fewer
// than two regions' worth are decimated in one pass.

// Whether an angle of triangle (a, b, c) has a cosine above max_cos (in [0, 1]): an angle below the smallest allowed.
// Without roots: at an acute corner, u.v > m |u| |v| <=> (u.v)^2 > m^2 |u|^2 |v|^2. A corner with an edge of length
// 0 counts as a cosine of 1.
bool has_small_angle(const Vec3& a, const Vec3& b, const Vec3& c, double max_cos) {
  const double m2 = max_cos * max_cos;
  const auto small = [&](const Vec3& apex, const Vec3& p, const Vec3& q) {
    const Vec3 u = p - apex, v = q - apex;
    const double uu = u.squaredNorm(), vv = v.squaredNorm();
    if (!(uu > 0.0) || !(vv > 0.0)) return 1.0 > max_cos;
    const double d = u.dot(v);
    return d > 0.0 && d * d > m2 * uu * vv;
  };
  return small(a, b, c) || small(b, c, a) || small(c, a, b);
}

// Whether normals n and m (not normalized) turn by more than the angle whose cosine is min_cos (in [0, 1]); without
// roots, as has_small_angle.
bool turns_beyond(const Vec3& n, const Vec3& m, double min_cos) {
  const double d = n.dot(m);
  return d < 0.0 || d * d < min_cos * min_cos * n.squaredNorm() * m.squaredNorm();
}

// Squared distance from p to triangle (a, b, c) (Ericson, Real-Time Collision Detection §5.1.5).
double squared_distance_to_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return ap.squaredNorm();
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return bp.squaredNorm();
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return (ap - ab * (d1 / (d1 - d3))).squaredNorm();
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return cp.squaredNorm();
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return (ap - ac * (d2 / (d2 - d6))).squaredNorm();
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    return (bp - (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))).squaredNorm();
  }
  const double denom = 1.0 / (va + vb + vc);
  return (ap - ab * (vb * denom) - ac * (vc * denom)).squaredNorm();
}

// Garland-Heckbert plane quadric, area-weighted as OpenMesh's ModQuadricT: the symmetric 4x4 matrix's upper triangle.
struct Quadric {
  std::array<double, 10> m{};

  static Quadric plane(const Vec3& n, double d, double weight) {
    const double a = n.x(), b = n.y(), c = n.z();
    return {{weight * a * a, weight * a * b, weight * a * c, weight * a * d, weight * b * b, weight * b * c,
             weight * b * d, weight * c * c, weight * c * d, weight * d * d}};
  }
  Quadric& operator+=(const Quadric& o) {
    for (int i = 0; i < 10; ++i) m[i] += o.m[i];
    return *this;
  }
  double operator()(const Vec3& p) const {
    const double x = p.x(), y = p.y(), z = p.z();
    return m[0] * x * x + 2.0 * m[1] * x * y + 2.0 * m[2] * x * z + 2.0 * m[3] * x + m[4] * y * y + 2.0 * m[5] * y * z +
           2.0 * m[6] * y + m[7] * z * z + 2.0 * m[8] * z + m[9];
  }
};

// Triangles (input vertex ids), each with the positions of the removed input vertices it holds (Hausdorff samples).
struct Patch {
  std::vector<Triangle> triangles;
  std::vector<std::uint32_t> first{0};  // triangles.size() + 1 offsets into points
  std::vector<Vec3> points;
};

// What every pass reads, and the per-vertex state passes share: a region writes only its own (unfrozen) vertices.
struct Shared {
  const Mesh& mesh;
  const SurfacePointRule* rule;  // null: no rule
  double tolerance2 = 0.0;
  double max_cos_angle = 1.0;            // of the smallest angle allowed
  double min_cos_normal = 0.0;           // of the largest normal turn allowed
  std::optional<QuantizationGrid> grid;  // the angles' (DecimateOptions::grid)
  const RunControl& control;
  // Whether this is the first pass (each patch sums its vertices' quadrics from its own triangles) or a later one
  // (quadrics reads them).
  bool initial = true;
  std::vector<Quadric> quadrics{};     // per input vertex after the first of several passes, else empty
  std::vector<std::uint8_t> frozen{};  // per input vertex: shared by regions (neither end of a collapse), or empty
  // Per input vertex: whether it may have a legal collapse not tried since its fan last changed (a pass starts from
  // these); empty: all may.
  std::vector<std::uint8_t> dirty{};
  std::vector<std::uint8_t> removed{};  // per input vertex
  std::atomic<std::size_t> collapses{0};
};

// A binary min-heap of vertices by key (ties: the smaller vertex first) that knows where each vertex sits, so a key
// changes in place. Entries hold their keys: a comparison reads no other array.
class VertexHeap {
 public:
  explicit VertexHeap(std::size_t vertices) : position_(vertices, kNone) {}
  bool empty() const { return heap_.empty(); }
  bool contains(std::uint32_t v) const { return position_[v] != kNone; }
  // The key of a vertex the heap contains.
  double key(std::uint32_t v) const { return heap_[position_[v]].key; }
  double top_key() const { return heap_.front().key; }
  // Inserts v or changes its key.
  void set(std::uint32_t v, double key) {
    if (position_[v] == kNone) {
      heap_.push_back({key, v});
      up(static_cast<std::uint32_t>(heap_.size() - 1), heap_.back());
      return;
    }
    const std::uint32_t i = position_[v];
    const Entry entry{key, v};
    if (key < heap_[i].key) {
      up(i, entry);
    } else {
      down(i, entry);
    }
  }
  std::uint32_t pop() {
    const std::uint32_t v = heap_.front().vertex;
    position_[v] = kNone;
    const Entry last = heap_.back();
    heap_.pop_back();
    if (!heap_.empty()) down(0, last);
    return v;
  }

 private:
  struct Entry {
    double key;
    std::uint32_t vertex;
  };
  static bool before(const Entry& a, const Entry& b) {
    return a.key < b.key || (a.key == b.key && a.vertex < b.vertex);
  }
  void place(std::uint32_t i, const Entry& e) {
    heap_[i] = e;
    position_[e.vertex] = i;
  }
  // Moves `e` from slot i towards the root to its place.
  void up(std::uint32_t i, Entry e) {
    while (i > 0) {
      const std::uint32_t parent = (i - 1) / 2;
      if (!before(e, heap_[parent])) break;
      place(i, heap_[parent]);
      i = parent;
    }
    place(i, e);
  }
  // Moves `e` from slot i towards the leaves to its place.
  void down(std::uint32_t i, Entry e) {
    const auto n = static_cast<std::uint32_t>(heap_.size());
    while (true) {
      std::uint32_t child = 2 * i + 1;
      if (child >= n) break;
      if (child + 1 < n && before(heap_[child + 1], heap_[child])) ++child;
      if (!before(heap_[child], e)) break;
      place(i, heap_[child]);
      i = child;
    }
    place(i, e);
  }

  std::vector<std::uint32_t> position_;
  std::vector<Entry> heap_;
};

// One pass over a patch: its own TriMesh, heap and sample lists.
class PatchDecimator {
 public:
  PatchDecimator(Shared& shared, const Patch& patch) : shared_(shared), patch_(patch) {}

  Patch run() {
    build();
    fill_heap();
    collapse_all();
    return result();
  }

  // After run(): the frozen vertices (input ids) that stay dirty: they were, or their fan or a neighbour's changed in
  // this run. (The run cleared its other vertices' flags: their collapses were all tried.)
  std::vector<std::uint32_t> dirty_frozen() const {
    std::vector<std::uint32_t> out;
    for (const VertexHandle v : om_.vertices()) {
      if (lock_[v.idx()] != kFrozen) continue;
      bool dirty = changed_[v.idx()] || shared_.dirty.empty() || shared_.dirty[global_[v.idx()]];
      for (auto w = om_.cvv_begin(v); !dirty && w.is_valid(); ++w) dirty = changed_[w->idx()];
      if (dirty) out.push_back(global_[v.idx()]);
    }
    return out;
  }

  // After run() in the first pass: the frozen vertices' quadrics from this patch's triangles alone.
  std::vector<std::pair<std::uint32_t, Quadric>> frozen_quadrics() const {
    std::vector<std::pair<std::uint32_t, Quadric>> out;
    if (shared_.initial) {
      for (std::size_t v = 0; v < global_.size(); ++v) {
        if (lock_[v] == kFrozen) out.emplace_back(global_[v], quadrics_[v]);
      }
    }
    return out;
  }

 private:
  enum Lock : std::uint8_t { kFree = 0, kKeep = 1, kFrozen = 2 };  // kKeep: never v0; kFrozen: never v0 or v1

  const Vec3& position(VertexHandle v) const { return positions_[v.idx()]; }
  // Where a decoder of the frame reads it (DecimateOptions::grid), for the angles.
  const Vec3& shown(VertexHandle v) const { return shown_.empty() ? positions_[v.idx()] : shown_[v.idx()]; }
  const Quadric& quadric(VertexHandle v) const { return quadrics_[v.idx()]; }

  void build() {
    const Mesh& mesh = shared_.mesh;
    // Local vertices in increasing input order; corner_[3 t + k] is corner k of triangle t in local numbering.
    // The corners sorted by input vertex, stably (a radix sort of 11-bit digits of the vertex's offset from the
    // smallest; the corners come in corner order).
    const std::size_t n = patch_.triangles.size();
    std::uint32_t lowest = std::numeric_limits<std::uint32_t>::max(), highest = 0;
    for (const Triangle& t : patch_.triangles) {
      for (const std::uint32_t v : t) {
        lowest = std::min(lowest, v);
        highest = std::max(highest, v);
      }
    }
    std::vector<std::uint64_t> corners(3 * n), sorted(3 * n);
    for (std::size_t t = 0; t < n; ++t) {
      for (int k = 0; k < 3; ++k) {
        corners[3 * t + k] = (static_cast<std::uint64_t>(patch_.triangles[t][k] - lowest) << 32) | (3 * t + k);
      }
    }
    constexpr int kDigit = 11;
    const std::uint64_t range = n > 0 ? highest - lowest : 0;
    for (int shift = 0; shift == 0 || (range >> shift) > 0; shift += kDigit) {
      std::array<std::uint32_t, (1u << kDigit) + 1> start{};
      const auto digit = [&](std::uint64_t c) {
        return static_cast<std::uint32_t>(c >> (32 + shift)) & ((1u << kDigit) - 1);
      };
      for (const std::uint64_t c : corners) ++start[digit(c) + 1];
      for (std::size_t d = 0; d < (1u << kDigit); ++d) start[d + 1] += start[d];
      for (const std::uint64_t c : corners) sorted[start[digit(c)]++] = c;
      corners.swap(sorted);
    }
    corner_.resize(3 * n);
    for (const std::uint64_t c : corners) {
      const auto v = static_cast<std::uint32_t>(c >> 32) + lowest;
      if (global_.empty() || global_.back() != v) global_.push_back(v);
      corner_[static_cast<std::uint32_t>(c)] = static_cast<std::uint32_t>(global_.size() - 1);
    }
    // Positions and quadrics in local order: a region's are then near in memory.
    positions_.reserve(global_.size());
    for (const std::uint32_t v : global_) positions_.push_back(mesh.vertices[v]);
    if (shared_.grid) {
      shown_.reserve(global_.size());
      for (const std::uint32_t v : global_)
        shown_.push_back(shared_.grid->dequantize(shared_.grid->frame_point(mesh.vertices[v])));
    }
    if (shared_.initial) {
      quadrics_.resize(global_.size());
      for (std::size_t t = 0; t < n; ++t) {
        const std::uint32_t* c = &corner_[3 * t];
        const Vec3 &a = positions_[c[0]], &b = positions_[c[1]], &d = positions_[c[2]];
        Vec3 normal = (b - a).cross(d - a);
        double area = normal.norm();
        if (area > std::numeric_limits<float>::min()) {  // as ModQuadricT
          normal /= area;
          area *= 0.5;
        }
        const Quadric q = Quadric::plane(normal, -a.dot(normal), area);
        for (int k = 0; k < 3; ++k) quadrics_[c[k]] += q;
      }
    } else {
      quadrics_.reserve(global_.size());
      for (const std::uint32_t v : global_) quadrics_.push_back(shared_.quadrics[v]);
    }
    om_.request_vertex_status();
    om_.request_edge_status();
    om_.request_face_status();
    lock_.assign(global_.size(), kFree);
    head_.reserve(n);
    node_point_.reserve(patch_.points.size() + global_.size());  // each collapse adds one
    node_next_.reserve(patch_.points.size() + global_.size());
    if (!connect()) {
      om_.clean();
      add_faces();
    }
    for (std::size_t t = 0; t < n; ++t) {
      if (!added_.empty() && !added_[t]) {
        refused_.push_back(static_cast<std::uint32_t>(t));
        continue;
      }
      std::int32_t head = -1;
      for (std::uint32_t i = patch_.first[t + 1]; i-- > patch_.first[t];) {
        node_point_.push_back(patch_.points[i]);
        node_next_.push_back(head);
        head = static_cast<std::int32_t>(node_point_.size() - 1);
      }
      head_.push_back(head);
    }
    // Boundary vertices stay: locking them keeps every boundary (and any face OpenMesh refused) exactly as it was.
    for (const VertexHandle v : om_.vertices()) {
      if (om_.is_boundary(v) || om_.is_isolated(v)) lock_[v.idx()] = std::max<std::uint8_t>(lock_[v.idx()], kKeep);
      if (!shared_.frozen.empty() && shared_.frozen[global_[v.idx()]]) lock_[v.idx()] = kFrozen;
    }
    floor_.assign(global_.size(), -std::numeric_limits<double>::infinity());
    changed_.assign(global_.size(), 0);
    shaped_.assign(global_.size(), kNone);
    heap_ = VertexHeap(global_.size());
  }

  // The faces one by one through OpenMesh's add_face; a face it refuses (at a non-manifold edge or vertex) stays as
  // it is (added_[t] false), and so do its vertices.
  void add_faces() {
    om_.reserve(global_.size(), 3 * patch_.triangles.size() / 2 + 16, patch_.triangles.size());
    for (std::size_t v = 0; v < global_.size(); ++v) om_.add_vertex(TriMesh::Point(0.0, 0.0, 0.0));
    added_.assign(patch_.triangles.size(), 1);
    for (std::size_t t = 0; t < patch_.triangles.size(); ++t) {
      if ((t & 4095) == 4095) shared_.control.check();
      const VertexHandle a(static_cast<int>(corner_[3 * t])), b(static_cast<int>(corner_[3 * t + 1])),
          c(static_cast<int>(corner_[3 * t + 2]));
      if (!om_.add_face(a, b, c).is_valid()) {
        added_[t] = 0;
        for (const VertexHandle v : {a, b, c}) lock_[v.idx()] = std::max<std::uint8_t>(lock_[v.idx()], kKeep);
      }
    }
  }

  // The TriMesh's halfedges linked directly (what add_face does one face at a time, at ~2.5 k instructions a face)
  // when the patch is edge-manifold: no triangle repeats a vertex, every directed edge is in one triangle at most, and
  // every vertex's triangles form fans (one closed fan, or open fans). Returns false otherwise (the caller then clears
  // the TriMesh and uses add_faces()). Halfedge 3 t + k of the patch runs from corner k of triangle t to corner k + 1.
  bool connect() {
    const std::size_t n = patch_.triangles.size(), vertices = global_.size();
    // The halfedges grouped by their first vertex (a counting sort): an edge's opposite is found among the
    // halfedges leaving its second vertex.
    const auto to_of = [&](std::uint32_t h) { return corner_[h - h % 3 + (h % 3 + 1) % 3]; };
    std::vector<std::uint32_t> first(vertices + 1, 0);
    for (std::size_t h = 0; h < 3 * n; ++h) {
      if (corner_[h] == to_of(static_cast<std::uint32_t>(h))) return false;
      ++first[corner_[h] + 1];
    }
    for (std::size_t v = 0; v < vertices; ++v) first[v + 1] += first[v];
    std::vector<std::uint32_t> leaving(3 * n);
    {
      std::vector<std::uint32_t> fill(first.begin(), first.end() - 1);
      for (std::uint32_t h = 0; h < 3 * n; ++h) leaving[fill[corner_[h]]++] = h;
    }
    const auto find = [&](std::uint32_t from, std::uint32_t to) {
      std::uint32_t found = kNone;
      for (std::uint32_t i = first[from]; i < first[from + 1]; ++i) {
        if (to_of(leaving[i]) != to) continue;
        if (found != kNone) return kNone - 1;  // a directed edge in two triangles
        found = leaving[i];
      }
      return found;
    };
    // Edge e for the first patch halfedge h of its two: TriMesh halfedge 2 e runs as h, 2 e + 1 back (the opposite
    // patch halfedge, or a boundary halfedge), as OpenMesh's new_edge makes them.
    struct Boundary {
      HalfedgeHandle halfedge;
      std::uint32_t from, to;
    };
    std::vector<std::uint32_t> half(3 * n, kNone);
    std::vector<Boundary> boundary;
    std::uint32_t edges = 0;
    for (std::uint32_t h = 0; h < 3 * n; ++h) {
      if (half[h] != kNone) continue;  // made with its opposite
      const std::uint32_t from = corner_[h], to = to_of(h);
      if (find(from, to) != h) return false;
      half[h] = 2 * edges;
      const std::uint32_t opposite = find(to, from);
      if (opposite == kNone - 1) return false;
      if (opposite != kNone) {
        half[opposite] = 2 * edges + 1;
      } else {
        boundary.push_back({HalfedgeHandle(static_cast<int>(2 * edges + 1)), to, from});
      }
      ++edges;
    }
    om_.resize(vertices, edges, n);
    const auto handle = [&](std::uint32_t h) { return HalfedgeHandle(static_cast<int>(half[h])); };
    for (std::uint32_t h = 0; h < 3 * n; ++h) {
      om_.set_vertex_handle(handle(h), VertexHandle(static_cast<int>(to_of(h))));
    }
    for (const Boundary& b : boundary) om_.set_vertex_handle(b.halfedge, VertexHandle(static_cast<int>(b.to)));
    for (std::uint32_t t = 0; t < n; ++t) {
      const FaceHandle f(static_cast<int>(t));
      om_.set_halfedge_handle(f, handle(3 * t + 2));  // as add_face: the face lists its corners in input order
      for (std::uint32_t k = 0; k < 3; ++k) {
        om_.set_face_handle(handle(3 * t + k), f);
        om_.set_next_halfedge_handle(handle(3 * t + k), handle(3 * t + (k + 1) % 3));
        const VertexHandle from(static_cast<int>(corner_[3 * t + k]));
        if (!om_.halfedge_handle(from).is_valid()) om_.set_halfedge_handle(from, handle(3 * t + k));
      }
    }
    // Boundary halfedges: one arriving at a vertex with one gap continues with the one leaving it. At a vertex with
    // several (open fans that meet there), each fan's arriving one continues with the next fan's leaving one (fans in
    // the order of their leaving halfedges), so that the rotation about the vertex meets every fan. A boundary
    // vertex starts its rotation at a boundary halfedge (OpenMesh's invariant).
    std::vector<std::uint32_t> triangles_at(vertices, 0);
    for (const std::uint32_t c : corner_) ++triangles_at[c];
    std::vector<std::uint32_t> gaps(vertices, 0), arriving(vertices, 0);
    std::vector<HalfedgeHandle> boundary_out(vertices);
    for (const Boundary& b : boundary) {
      ++gaps[b.from];
      ++arriving[b.to];
      if (!boundary_out[b.from].is_valid()) boundary_out[b.from] = b.halfedge;
    }
    std::vector<Boundary> shared_vertex;  // leaving a vertex with several gaps
    for (const Boundary& b : boundary) {
      if (gaps[b.from] != arriving[b.from] || gaps[b.to] != arriving[b.to]) return false;
      if (gaps[b.to] == 1) om_.set_next_halfedge_handle(b.halfedge, boundary_out[b.to]);
      if (gaps[b.from] > 1) shared_vertex.push_back(b);
    }
    std::sort(shared_vertex.begin(), shared_vertex.end(), [](const Boundary& a, const Boundary& b) {
      return a.from != b.from ? a.from < b.from : a.halfedge.idx() < b.halfedge.idx();
    });
    for (std::size_t i = 0; i < shared_vertex.size();) {
      const std::uint32_t v = shared_vertex[i].from, k = gaps[v];
      std::vector<HalfedgeHandle> in(k);
      for (std::uint32_t j = 0; j < k; ++j) {
        // The fan from its leaving boundary halfedge to the triangle halfedge whose opposite is boundary.
        HalfedgeHandle h = shared_vertex[i + j].halfedge;
        std::uint32_t steps = 0;
        do {
          h = om_.next_halfedge_handle(om_.opposite_halfedge_handle(h));
          if (++steps > triangles_at[v]) return false;
        } while (!om_.is_boundary(om_.opposite_halfedge_handle(h)));
        in[j] = om_.opposite_halfedge_handle(h);
      }
      for (std::uint32_t j = 0; j < k; ++j) {
        om_.set_next_halfedge_handle(in[j], shared_vertex[i + (j + 1) % k].halfedge);
      }
      i += k;
    }
    for (std::size_t v = 0; v < vertices; ++v) {
      if (boundary_out[v].is_valid()) om_.set_halfedge_handle(VertexHandle(static_cast<int>(v)), boundary_out[v]);
    }
    // The rotation from each vertex's halfedge meets every triangle at it.
    for (std::size_t v = 0; v < vertices; ++v) {
      const HalfedgeHandle start = om_.halfedge_handle(VertexHandle(static_cast<int>(v)));
      std::uint32_t seen = 0, steps = 0;
      HalfedgeHandle h = start;
      do {
        if (!om_.is_boundary(h)) ++seen;
        if (seen > triangles_at[v] || ++steps > triangles_at[v] + gaps[v]) return false;
        h = om_.next_halfedge_handle(om_.opposite_halfedge_handle(h));
      } while (h != start);
      if (seen != triangles_at[v]) return false;
    }
    return true;
  }

  double cost(VertexHandle v0, VertexHandle v1) const {
    const Vec3& p1 = position(v1);
    return quadric(v0)(p1) + quadric(v1)(p1);
  }

  // Queues v at the cost of its cheapest collapse the locks allow (or not at all when none is).
  void push(VertexHandle v) {
    if (lock_[v.idx()] != kFree) return;
    double best = std::numeric_limits<double>::infinity();
    for (const VertexHandle w : om_.vv_range(v)) {
      if (lock_[w.idx()] != kFrozen) best = std::min(best, cost(v, w));
    }
    if (best < std::numeric_limits<double>::infinity()) heap_.set(static_cast<std::uint32_t>(v.idx()), best);
  }

  void fill_heap() {
    for (const VertexHandle v : om_.vertices()) {
      if (lock_[v.idx()] == kFree && (shared_.dirty.empty() || shared_.dirty[global_[v.idx()]])) push(v);
    }
  }

  // Whether collapsing v0 into v1 along h keeps the mesh's shape: the locks, the angles and normal turns of the faces
  // that stay, the link condition. When it does, fan_ holds the faces left at v1 that were v0's.
  bool shape_legal(HalfedgeHandle h) {
    const VertexHandle v0 = om_.from_vertex_handle(h), v1 = om_.to_vertex_handle(h);
    if (lock_[v0.idx()] != kFree || lock_[v1.idx()] == kFrozen) return false;
    const HalfedgeHandle o = om_.opposite_halfedge_handle(h);
    const FaceHandle fl = om_.face_handle(h), fr = om_.face_handle(o);

    // The faces that stay, with v0 moved to p1: their angles and normal turns (cheap, most refusals) first.
    // They depend on v0's fan and p1 only: a collapse that passed them and waits in the heap (collapse_all) is not
    // measured again until v0's fan changes.
    const Vec3& p0 = position(v0);
    const Vec3& p1 = position(v1);
    const bool measured = shaped_[v0.idx()] == static_cast<std::uint32_t>(v1.idx());
    fan_.clear();
    for (const HalfedgeHandle out : om_.voh_range(v0)) {
      const FaceHandle f = om_.face_handle(out);
      if (!f.is_valid() || f == fl || f == fr) continue;
      const VertexHandle va = om_.to_vertex_handle(out), vb = om_.to_vertex_handle(om_.next_halfedge_handle(out));
      const Vec3& a = position(va);
      const Vec3& b = position(vb);
      fan_.push_back({f, {p1, a, b}});
      if (measured) continue;
      if (has_small_angle(shown(v1), shown(va), shown(vb), shared_.max_cos_angle)) return false;
      if (turns_beyond((a - p0).cross(b - p0), (a - p1).cross(b - p1), shared_.min_cos_normal)) return false;
    }
    if (fan_.empty()) return false;
    shaped_[v0.idx()] = static_cast<std::uint32_t>(v1.idx());

    // OpenMesh's is_collapse_ok for an interior v0 (v0 is never on a boundary here), whose own version allocates on
    // every call (a fifth of the instructions of a run): vl and vr differ, and v0 and v1 share no neighbour but them
    // (the link condition), so the mesh stays manifold.
    const VertexHandle vl = om_.to_vertex_handle(om_.next_halfedge_handle(h));
    const VertexHandle vr = om_.to_vertex_handle(om_.next_halfedge_handle(o));
    if (vl == vr) return false;
    ring_.clear();
    for (const VertexHandle w : om_.vv_range(v1)) ring_.push_back(w);
    for (const VertexHandle w : om_.vv_range(v0)) {
      if (w != v1 && w != vl && w != vr && std::find(ring_.begin(), ring_.end(), w) != ring_.end()) return false;
    }
    // As OpenMesh's Decimater: not a tetrahedron's last collapse (v0 has at least three neighbours: fan_ is not
    // empty).
    const auto valence_is_3 = [&](VertexHandle v) {
      int valence = 0;
      for (auto w = om_.cvv_begin(v); w.is_valid() && valence <= 3; ++w) ++valence;
      return valence == 3;
    };
    if (valence_is_3(vl) && valence_is_3(vr)) {
      for (const VertexHandle w : om_.vv_range(vl)) {
        if (w == vr) return false;
      }
    }
    return true;
  }

  // After shape_legal(h) accepted h: whether the collapse keeps the Hausdorff samples of v0's faces and v0 itself
  // within the tolerance of the new fan, and the engine's rule at the new faces; when it does, gathered_ / assigned_
  // hold the samples to move and the fan_ face each goes to.
  bool faithful(HalfedgeHandle h) {
    const VertexHandle v0 = om_.from_vertex_handle(h), v1 = om_.to_vertex_handle(h);
    const HalfedgeHandle o = om_.opposite_halfedge_handle(h);
    const FaceHandle fl = om_.face_handle(h), fr = om_.face_handle(o);
    const VertexHandle vl = om_.to_vertex_handle(om_.next_halfedge_handle(h));
    const VertexHandle vr = om_.to_vertex_handle(om_.next_halfedge_handle(o));
    const Vec3& p0 = position(v0);
    const Vec3& p1 = position(v1);
    // The Hausdorff samples of v0's faces and v0 itself, each within the tolerance of a face of the new fan.
    planes_.clear();
    for (const Fan& face : fan_) planes_.push_back(Plane::of(face.corner));
    gathered_.clear();
    assigned_.clear();
    const auto gather = [&](FaceHandle f, int fan_index) {
      for (std::int32_t n = head_[f.idx()]; n >= 0; n = node_next_[n]) {
        const int to = place(node_point_[n], fan_index);
        if (to < 0) return false;
        gathered_.push_back(n);
        assigned_.push_back(to);
      }
      return true;
    };
    for (std::size_t i = 0; i < fan_.size(); ++i) {
      if (!gather(fan_[i].face, static_cast<int>(i))) return false;
    }
    if ((fl.is_valid() && !gather(fl, -1)) || (fr.is_valid() && !gather(fr, -1))) return false;
    v0_face_ = place(p0, -1);
    if (v0_face_ < 0) return false;

    // The engine's rule at the new triangles' centroids and the midpoints of the new edges (v1, w), w a neighbour of
    // v0 but not of v1.
    if (shared_.rule != nullptr) {
      const SurfacePointRule& rule = *shared_.rule;
      for (const Fan& face : fan_) {
        if (!rule((face.corner[0] + face.corner[1] + face.corner[2]) / 3.0)) return false;
      }
      for (const VertexHandle w : om_.vv_range(v0)) {
        if (w == v1 || w == vl || w == vr) continue;
        if (!rule(0.5 * (p1 + position(w)))) return false;
      }
    }
    return true;
  }

  // The index in fan_ of a face within the tolerance of q, trying `first` (or -1) first; -1 when none.
  int place(const Vec3& q, int first) const {
    const auto near = [&](int i) {
      const auto& c = fan_[i].corner;
      const Plane& plane = planes_[i];
      // Farther from the face's plane than the tolerance: not near. Nearest to a point inside the face: its
      // distance to the plane decides. Else the exact distance.
      const Vec3 ap = q - c[0];
      const double s = ap.dot(plane.normal);
      if (plane.normal2 > 0.0) {
        const double limit = shared_.tolerance2 * plane.normal2;
        if (s * s > limit) return false;
        const double d20 = ap.dot(plane.ab), d21 = ap.dot(plane.ac);
        const double v = (plane.d11 * d20 - plane.d01 * d21) * plane.inverse;
        const double w = (plane.d00 * d21 - plane.d01 * d20) * plane.inverse;
        if (v >= 0.0 && w >= 0.0 && v + w <= 1.0) return true;
      }
      return squared_distance_to_triangle(q, c[0], c[1], c[2]) <= shared_.tolerance2;
    };
    if (first >= 0 && near(first)) return first;
    for (int i = 0; i < static_cast<int>(fan_.size()); ++i) {
      if (i != first && near(i)) return i;
    }
    return -1;
  }

  // Collapses along h, which shape_legal(h) and faithful(h) just accepted (fan_, gathered_, assigned_ and v0_face_ are
  // theirs).
  void collapse(HalfedgeHandle h) {
    const VertexHandle v0 = om_.from_vertex_handle(h), v1 = om_.to_vertex_handle(h);
    for (const FaceHandle f : om_.vf_range(v0)) head_[f.idx()] = -1;
    for (std::size_t i = 0; i < gathered_.size(); ++i) {
      std::int32_t& head = head_[fan_[assigned_[i]].face.idx()];
      node_next_[gathered_[i]] = head;
      head = gathered_[i];
    }
    node_point_.push_back(position(v0));
    std::int32_t& head = head_[fan_[v0_face_].face.idx()];
    node_next_.push_back(head);
    head = static_cast<std::int32_t>(node_point_.size() - 1);

    quadrics_[v1.idx()] += quadrics_[v0.idx()];
    shared_.removed[global_[v0.idx()]] = 1;
    support_.clear();
    for (const VertexHandle w : om_.vv_range(v0)) support_.push_back(w);
    collapse_halfedge(h);
    ++collapses_;
    // The fans of v0's neighbours changed: what they found illegal may not be now. A queued neighbour's key stays a
    // lower bound of its collapses' costs (quadrics only grow) but for its new neighbour v1.
    changed_[v1.idx()] = 1;
    shaped_[v1.idx()] = kNone;
    for (const VertexHandle w : support_) {
      const auto i = static_cast<std::uint32_t>(w.idx());
      changed_[i] = 1;
      shaped_[i] = kNone;
      floor_[i] = -std::numeric_limits<double>::infinity();
      if (w != v1 && heap_.contains(i)) {
        if (lock_[v1.idx()] != kFrozen) heap_.set(i, std::min(heap_.key(i), cost(w, v1)));
      } else {
        push(w);
      }
    }
  }

  // OpenMesh's PolyConnectivity::collapse (its collapse_edge, then collapse_loop for each of the two faces left as
  // loops of two halfedges) written out on the kernel's accessors: the same links and the same outgoing halfedges,
  // without the library's out-of-line calls and assertions (two thirds of a collapse's instructions).
  void collapse_halfedge(HalfedgeHandle h0) {
    const HalfedgeHandle h1 = om_.next_halfedge_handle(h0);
    const HalfedgeHandle o1 = om_.next_halfedge_handle(om_.opposite_halfedge_handle(h0));
    collapse_edge(h0);
    if (om_.next_halfedge_handle(om_.next_halfedge_handle(h1)) == h1) collapse_loop(om_.next_halfedge_handle(h1));
    if (om_.next_halfedge_handle(om_.next_halfedge_handle(o1)) == o1) collapse_loop(o1);
  }

  void collapse_edge(HalfedgeHandle h) {
    const HalfedgeHandle hn = om_.next_halfedge_handle(h), hp = om_.prev_halfedge_handle(h);
    const HalfedgeHandle o = om_.opposite_halfedge_handle(h);
    const HalfedgeHandle on = om_.next_halfedge_handle(o), op = om_.prev_halfedge_handle(o);
    const FaceHandle fh = om_.face_handle(h), fo = om_.face_handle(o);
    const VertexHandle vh = om_.to_vertex_handle(h), vo = om_.to_vertex_handle(o);
    for (const HalfedgeHandle in : om_.vih_range(vo)) om_.set_vertex_handle(in, vh);
    om_.set_next_halfedge_handle(hp, hn);
    om_.set_next_halfedge_handle(op, on);
    if (fh.is_valid()) om_.set_halfedge_handle(fh, hn);
    if (fo.is_valid()) om_.set_halfedge_handle(fo, on);
    if (om_.halfedge_handle(vh) == o) om_.set_halfedge_handle(vh, hn);
    adjust_outgoing_halfedge(vh);
    om_.set_isolated(vo);
    om_.status(om_.edge_handle(h)).set_deleted(true);
    om_.status(vo).set_deleted(true);
  }

  void collapse_loop(HalfedgeHandle h0) {
    const HalfedgeHandle h1 = om_.next_halfedge_handle(h0);
    const HalfedgeHandle o0 = om_.opposite_halfedge_handle(h0), o1 = om_.opposite_halfedge_handle(h1);
    const VertexHandle v0 = om_.to_vertex_handle(h0), v1 = om_.to_vertex_handle(h1);
    const FaceHandle fh = om_.face_handle(h0), fo = om_.face_handle(o0);
    om_.set_next_halfedge_handle(h1, om_.next_halfedge_handle(o0));
    om_.set_next_halfedge_handle(om_.prev_halfedge_handle(o0), h1);
    om_.set_face_handle(h1, fo);
    om_.set_halfedge_handle(v0, h1);
    adjust_outgoing_halfedge(v0);
    om_.set_halfedge_handle(v1, o1);
    adjust_outgoing_halfedge(v1);
    if (fo.is_valid() && om_.halfedge_handle(fo) == o0) om_.set_halfedge_handle(fo, h1);
    if (fh.is_valid()) {
      om_.set_halfedge_handle(fh, HalfedgeHandle());
      om_.status(fh).set_deleted(true);
    }
    om_.status(om_.edge_handle(h0)).set_deleted(true);
  }

  // A boundary vertex's outgoing halfedge is a boundary one (OpenMesh's invariant).
  void adjust_outgoing_halfedge(VertexHandle v) {
    for (const HalfedgeHandle h : om_.voh_range(v)) {
      if (om_.is_boundary(h)) {
        om_.set_halfedge_handle(v, h);
        return;
      }
    }
  }

  // Pops the cheapest vertex, makes its key exact (the cheapest candidate of a legal shape not known illegal) and
  // collapses it when that candidate is faithful and still no other vertex is cheaper; a candidate found illegal stays
  // skipped (floor_) until the vertex's fan changes.
  void collapse_all() {
    std::vector<std::pair<double, HalfedgeHandle>> candidates;
    std::size_t pops = 0;
    while (!heap_.empty()) {
      if ((++pops & 1023) == 0) shared_.control.check();
      const std::uint32_t v = heap_.pop();
      const VertexHandle v0(static_cast<int>(v));
      candidates.clear();
      for (const HalfedgeHandle h : om_.voh_range(v0)) {
        const VertexHandle v1 = om_.to_vertex_handle(h);
        if (lock_[v1.idx()] == kFrozen) continue;
        const double c = cost(v0, v1);
        if (c >= floor_[v]) candidates.emplace_back(c, h);
      }
      std::sort(candidates.begin(), candidates.end(), [&](const auto& a, const auto& b) {
        return a.first != b.first ? a.first < b.first
                                  : om_.to_vertex_handle(a.second).idx() < om_.to_vertex_handle(b.second).idx();
      });
      for (const auto& [c, h] : candidates) {
        if (!shape_legal(h)) continue;
        if (!heap_.empty() && c > heap_.top_key()) {
          floor_[v] = c;
          heap_.set(v, c);
          break;
        }
        if (faithful(h)) {
          collapse(h);
          break;
        }
      }
    }
    shared_.collapses += collapses_;
    // The quadrics of this pass's own vertices for the next pass (frozen ones are other regions' too).
    if (!shared_.quadrics.empty()) {
      for (std::size_t v = 0; v < global_.size(); ++v) {
        if (lock_[v] != kFrozen) shared_.quadrics[global_[v]] = quadrics_[v];
      }
    }
    if (!shared_.dirty.empty()) {
      for (std::size_t v = 0; v < global_.size(); ++v) {
        if (lock_[v] != kFrozen) shared_.dirty[global_[v]] = 0;
      }
    }
  }

  // The surviving faces in face order, each from its first halfedge on (orientation kept), with their samples; then
  // the refused ones as they came.
  Patch result() const {
    Patch out;
    out.triangles.reserve(om_.n_faces() - 2 * collapses_ + refused_.size());
    out.first.reserve(out.triangles.capacity() + 1);
    for (const FaceHandle f : om_.faces()) {
      if (om_.status(f).deleted()) continue;
      Triangle tri;
      int k = 0;
      for (const VertexHandle v : om_.fv_range(f)) tri[k++] = global_[v.idx()];
      out.triangles.push_back(tri);
      for (std::int32_t n = head_[f.idx()]; n >= 0; n = node_next_[n]) out.points.push_back(node_point_[n]);
      out.first.push_back(static_cast<std::uint32_t>(out.points.size()));
    }
    for (const std::uint32_t t : refused_) {
      out.triangles.push_back(patch_.triangles[t]);
      out.points.insert(out.points.end(), patch_.points.begin() + patch_.first[t],
                        patch_.points.begin() + patch_.first[t + 1]);
      out.first.push_back(static_cast<std::uint32_t>(out.points.size()));
    }
    return out;
  }

  struct Fan {
    FaceHandle face;
    std::array<Vec3, 3> corner;  // with v0 at p1
  };
  // A fan face's edges from its first corner, their dot products and its (unnormalized) normal: what place() needs
  // for a point's distance to the plane and its barycentric coordinates.
  struct Plane {
    Vec3 ab, ac, normal;
    double normal2 = 0.0, d00 = 0.0, d01 = 0.0, d11 = 0.0, inverse = 0.0;
    static Plane of(const std::array<Vec3, 3>& c) {
      Plane p;
      p.ab = c[1] - c[0];
      p.ac = c[2] - c[0];
      p.normal = p.ab.cross(p.ac);
      p.normal2 = p.normal.squaredNorm();
      p.d00 = p.ab.dot(p.ab);
      p.d01 = p.ab.dot(p.ac);
      p.d11 = p.ac.dot(p.ac);
      const double denominator = p.d00 * p.d11 - p.d01 * p.d01;
      if (!(denominator > 0.0) || !std::isfinite(1.0 / denominator)) {
        p.normal2 = 0.0;  // degenerate: exact path
      } else {
        p.inverse = 1.0 / denominator;
      }
      return p;
    }
  };

  Shared& shared_;
  const Patch& patch_;
  TriMesh om_;
  std::vector<std::uint32_t> global_;    // local vertex -> input vertex
  std::vector<std::uint32_t> corner_;    // 3 t + k: the local vertex at corner k of patch triangle t
  std::vector<std::uint8_t> added_;      // per patch triangle when built by add_faces(): whether it was added
  std::vector<Vec3> positions_;          // per local vertex
  std::vector<Vec3> shown_;              // per local vertex, on the grid (empty without one)
  std::vector<Quadric> quadrics_;        // per local vertex
  std::vector<std::uint8_t> lock_;       // per local vertex
  std::vector<double> floor_;            // per local vertex: its collapses cheaper than this were found illegal
  std::vector<std::uint8_t> changed_;    // per local vertex: whether its fan changed in this run
  std::vector<std::uint32_t> shaped_;    // per local vertex: the v1 whose fan geometry shape_legal() last passed
                                         // since the vertex's fan changed, or kNone
  std::vector<std::uint32_t> refused_;   // patch triangles OpenMesh refused
  std::vector<std::int32_t> head_;       // per face: its first sample node, or -1
  std::vector<Vec3> node_point_;         // per sample node: the removed input vertex's position
  std::vector<std::int32_t> node_next_;  // per sample node: the next of its face's list, or -1
  VertexHeap heap_{0};
  std::size_t collapses_ = 0;
  // Scratch of shape_legal(), faithful() and collapse().
  std::vector<Fan> fan_;
  std::vector<Plane> planes_;  // per fan_ face, made by faithful()
  std::vector<std::int32_t> gathered_;
  std::vector<int> assigned_;
  int v0_face_ = -1;
  std::vector<VertexHandle> support_;
  std::vector<VertexHandle> ring_;
};

// Cubic cells of edge `edge` from `origin`, `dims` per axis: the regions of a large mesh.
struct Grid {
  Eigen::Array3d origin;
  double edge = 0.0;
  std::array<double, 3> dims{};
};

// Regions numbered in the order of their first triangles, a region per key: key(t) (below `keys`) for each of the
// `triangles` that `active` marks (every one when it is empty), the others getting the count. Returns the region of
// each triangle and the count.
template <class Key>
std::pair<std::vector<std::uint32_t>, std::uint32_t> number_regions(std::size_t triangles,
                                                                    const std::vector<std::uint8_t>& active,
                                                                    std::size_t keys, Key&& key) {
  std::vector<std::uint32_t> region(triangles);
  std::vector<std::uint32_t> number(keys, kNone);
  std::uint32_t count = 0;
  for (std::size_t t = 0; t < triangles; ++t) {
    if (!active.empty() && !active[t]) continue;
    std::uint32_t& r = number[key(t)];
    if (r == kNone) r = count++;
    region[t] = r;
  }
  if (!active.empty()) {
    for (std::size_t t = 0; t < triangles; ++t) {
      if (!active[t]) region[t] = count;
    }
  }
  return {std::move(region), count};
}

std::pair<std::vector<std::uint32_t>, std::uint32_t> assign_regions(const Mesh& mesh,
                                                                    const std::vector<Triangle>& triangles,
                                                                    const Grid& grid, double shift,
                                                                    const std::vector<std::uint8_t>& active = {});

// The grid whose cells hold about kRegionTriangles triangles each, at most kMaxCells per axis, or nullopt when the
// mesh holds fewer than two regions' worth. The first guess assumes one sheet of surface per cell (a surface
// crossing a cell of edge L has about L^2 of area in it); while the occupied cells then hold more than 1.5 times
// the target on average (a surface folded into several sheets per cell, as a gyroid), the edge shrinks by the square
// root of the excess (docs/ALGORITHMS.md §5 CHOICE "Decimation": regions larger than a core's cache are slower per
// collapse).
std::optional<Grid> region_grid(const Mesh& mesh) {
  const std::size_t n = mesh.triangles.size();
  if (static_cast<double>(n) < 2.0 * kRegionTriangles) return std::nullopt;
  Eigen::Array3d lo = Eigen::Array3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const Vec3& p : mesh.vertices) {
    lo = lo.min(p.array());
    hi = hi.max(p.array());
  }
  double area = 0.0;
  for (const Triangle& t : mesh.triangles) {
    const Vec3 &a = mesh.vertices[t[0]], &b = mesh.vertices[t[1]], &c = mesh.vertices[t[2]];
    area += 0.5 * (b - a).cross(c - a).norm();
  }
  const double smallest = (hi - lo).maxCoeff() / kMaxCells;
  Grid grid{lo, std::max(std::sqrt(kRegionTriangles * area / static_cast<double>(n)), smallest), {}};
  if (!(grid.edge > 0.0) || !std::isfinite(grid.edge)) return std::nullopt;
  const auto size = [&] {
    for (int a = 0; a < 3; ++a) grid.dims[a] = std::floor((hi[a] - lo[a]) / grid.edge) + 2.0;  // room for the shift
  };
  size();
  for (int refine = 0; refine < 3 && grid.edge > smallest; ++refine) {
    const double mean = static_cast<double>(n) / assign_regions(mesh, mesh.triangles, grid, 0.0).second;
    if (mean <= 1.5 * kRegionTriangles) break;
    grid.edge = std::max(grid.edge * std::sqrt(kRegionTriangles / mean), smallest);
    size();
  }
  return grid;
}

// The region of each triangle: the cell of its centroid in `grid` shifted by `shift` cells along every axis, numbered
// in the order of their first triangles; and how many regions there are. With `active` not empty, only the triangles
// it marks get a cell, the others the count.
std::pair<std::vector<std::uint32_t>, std::uint32_t> assign_regions(const Mesh& mesh,
                                                                    const std::vector<Triangle>& triangles,
                                                                    const Grid& grid, double shift,
                                                                    const std::vector<std::uint8_t>& active) {
  const auto cells = static_cast<std::size_t>(grid.dims[0] * grid.dims[1] * grid.dims[2]);
  return number_regions(triangles.size(), active, cells, [&](std::size_t i) {
    const Triangle& t = triangles[i];
    const Vec3 centroid = (mesh.vertices[t[0]] + mesh.vertices[t[1]] + mesh.vertices[t[2]]) / 3.0;
    double index = 0.0;
    for (int a = 2; a >= 0; --a) {
      const double u = std::floor((centroid[a] - grid.origin[a]) / grid.edge + shift);
      index = index * grid.dims[a] + std::clamp(u, 0.0, grid.dims[a] - 1.0);
    }
    return static_cast<std::size_t>(index);
  });
}

// One pass over the regions of `input` (region[t] < count; region[t] == count: left as it is) on `threads`, each
// decimated with the vertices it shares with another region or with the triangles left frozen; the decimated regions
// merged in region order, then the triangles left. Afterwards shared.dirty holds the frozen vertices that may have
// untried collapses (docs/ALGORITHMS.md §5 CHOICE "Decimation") and their neighbours.
Patch region_pass(Shared& shared, const Patch& input, const std::vector<std::uint32_t>& region, std::uint32_t count,
                  int threads) {
  const std::size_t vertices = shared.mesh.vertices.size();
  std::vector<std::uint32_t> region_of(vertices, kNone);
  shared.frozen.assign(vertices, 0);
  std::vector<std::uint32_t> offsets(count + 2, 0);
  for (std::size_t t = 0; t < input.triangles.size(); ++t) {
    ++offsets[region[t] + 1];
    for (const std::uint32_t v : input.triangles[t]) {
      if (region_of[v] == kNone) region_of[v] = region[t];
      if (region_of[v] != region[t]) shared.frozen[v] = 1;
    }
  }
  for (std::uint32_t r = 0; r <= count; ++r) offsets[r + 1] += offsets[r];
  std::vector<std::uint32_t> order(input.triangles.size());
  std::vector<std::uint32_t> fill(offsets.begin(), offsets.end() - 1);
  for (std::uint32_t t = 0; t < input.triangles.size(); ++t) order[fill[region[t]]++] = t;
  const auto copy = [&](Patch& patch, std::uint32_t begin, std::uint32_t end) {
    for (std::uint32_t i = begin; i < end; ++i) {
      const std::uint32_t t = order[i];
      patch.triangles.push_back(input.triangles[t]);
      patch.points.insert(patch.points.end(), input.points.begin() + input.first[t],
                          input.points.begin() + input.first[t + 1]);
      patch.first.push_back(static_cast<std::uint32_t>(patch.points.size()));
    }
  };

  std::vector<Patch> parts(count);
  std::vector<std::vector<std::pair<std::uint32_t, Quadric>>> partial(count);
  std::vector<std::vector<std::uint32_t>> dirty(count);
  parallel_for(static_cast<int>(count), threads, [&](int r) {
    Patch patch;
    patch.triangles.reserve(offsets[r + 1] - offsets[r]);
    copy(patch, offsets[r], offsets[r + 1]);
    PatchDecimator decimator(shared, patch);
    parts[r] = decimator.run();
    partial[r] = decimator.frozen_quadrics();
    dirty[r] = decimator.dirty_frozen();
  });
  // The first pass's frozen vertices get their whole quadrics here, summed in region order.
  for (const auto& list : partial) {
    for (const auto& [v, q] : list) shared.quadrics[v] += q;
  }
  shared.initial = false;

  Patch merged;
  for (const Patch& part : parts) {
    const auto base = static_cast<std::uint32_t>(merged.points.size());
    merged.triangles.insert(merged.triangles.end(), part.triangles.begin(), part.triangles.end());
    merged.points.insert(merged.points.end(), part.points.begin(), part.points.end());
    for (std::size_t i = 1; i < part.first.size(); ++i) merged.first.push_back(base + part.first[i]);
  }
  copy(merged, offsets[count], offsets[count + 1]);
  // Frozen vertices are clean unless a region found them dirty; a dirty one's neighbours are dirty too (their collapse
  // into it was not tried).
  for (std::size_t v = 0; v < vertices; ++v) {
    if (shared.frozen[v]) shared.dirty[v] = 0;
  }
  for (const auto& list : dirty) {
    for (const std::uint32_t v : list) shared.dirty[v] = 2;
  }
  for (const Triangle& t : merged.triangles) {
    if (shared.dirty[t[0]] == 2 || shared.dirty[t[1]] == 2 || shared.dirty[t[2]] == 2) {
      for (const std::uint32_t v : t) shared.dirty[v] = std::max<std::uint8_t>(shared.dirty[v], 1);
    }
  }
  for (std::uint8_t& d : shared.dirty) d = d != 0;
  shared.frozen.clear();
  return merged;
}

// The triangles of `triangles` (per triangle: 1) within `rings` rings of a dirty vertex: those with a vertex reached
// from a dirty one by at most `rings` edges.
std::vector<std::uint8_t> near_dirty(const Shared& shared, const std::vector<Triangle>& triangles, int rings) {
  std::vector<std::uint8_t> reached = shared.dirty;
  std::vector<std::uint8_t> next;
  for (int ring = 0; ring < rings; ++ring) {
    next = reached;
    for (const Triangle& t : triangles) {
      if (reached[t[0]] || reached[t[1]] || reached[t[2]]) next[t[0]] = next[t[1]] = next[t[2]] = 1;
    }
    reached.swap(next);
  }
  std::vector<std::uint8_t> active(triangles.size(), 0);
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    const Triangle& tri = triangles[t];
    active[t] = reached[tri[0]] | reached[tri[1]] | reached[tri[2]];
  }
  return active;
}

// Regions of the active triangles: their connected components (through shared vertices), numbered in the order of
// their first triangles; inactive triangles get the count.
std::pair<std::vector<std::uint32_t>, std::uint32_t> components(const std::vector<Triangle>& triangles,
                                                                const std::vector<std::uint8_t>& active,
                                                                std::size_t vertices) {
  // Union-find over vertices: the vertices of an active triangle are one set.
  std::vector<std::uint32_t> parent(vertices, kNone);
  const auto find = [&](std::uint32_t v) {
    while (parent[v] != v) {
      parent[v] = parent[parent[v]];
      v = parent[v];
    }
    return v;
  };
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    if (!active[t]) continue;
    for (const std::uint32_t v : triangles[t]) {
      if (parent[v] == kNone) parent[v] = v;
    }
    std::uint32_t a = find(triangles[t][0]);
    for (int k = 1; k < 3; ++k) {
      const std::uint32_t b = find(triangles[t][k]);
      if (a != b) parent[std::max(a, b)] = std::min(a, b);
      a = std::min(a, b);
    }
  }
  return number_regions(triangles.size(), active, vertices, [&](std::size_t t) { return find(triangles[t][0]); });
}

Mesh assemble(const Mesh& mesh, const Shared& shared, const std::vector<Triangle>& triangles) {
  Mesh out;
  std::vector<std::uint32_t> new_index(mesh.vertices.size(), kNone);
  std::vector<std::uint32_t> kept;
  kept.reserve(mesh.vertices.size());
  for (std::uint32_t v = 0; v < mesh.vertices.size(); ++v) {
    if (shared.removed[v]) continue;
    new_index[v] = static_cast<std::uint32_t>(kept.size());
    kept.push_back(v);
  }
  out.vertices.reserve(kept.size());
  for (std::uint32_t v : kept) out.vertices.push_back(mesh.vertices[v]);
  if (!mesh.normals.empty()) {
    out.normals.reserve(kept.size());
    for (std::uint32_t v : kept) out.normals.push_back(mesh.normals[v]);
  }
  for (const Attribute& a : mesh.attributes) {
    Attribute& b = out.attributes.emplace_back();
    b.name = a.name;
    b.components = a.components;
    b.values.reserve(kept.size() * static_cast<std::size_t>(a.components));
    for (std::uint32_t v : kept) {
      const auto first = a.values.begin() + static_cast<std::ptrdiff_t>(v) * a.components;
      b.values.insert(b.values.end(), first, first + a.components);
    }
  }
  out.triangles.reserve(triangles.size());
  for (const Triangle& t : triangles) out.triangles.push_back({new_index[t[0]], new_index[t[1]], new_index[t[2]]});
  return out;
}

}  // namespace

Mesh decimate(const Mesh& mesh, const DecimateOptions& options, const SurfacePointRule& acceptable,
              const RunControl& control, DecimateStats* stats) {
  validate(options);
  const auto start = std::chrono::steady_clock::now();
  DecimateStats local;
  DecimateStats& s = stats ? *stats : local;
  s = {};
  s.vertices_before = mesh.vertices.size();
  s.triangles_before = mesh.triangles.size();
  Mesh out;
  if (options.tolerance == 0.0 || mesh.triangles.empty()) {
    out = mesh;
  } else {
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      for (std::uint32_t v : mesh.triangles[t]) {
        if (v >= mesh.vertices.size()) {
          throw InvalidInput("triangles", "triangle " + std::to_string(t) + " names vertex " + std::to_string(v) +
                                              " of " + std::to_string(mesh.vertices.size()));
        }
      }
    }
    control.report("decimate", 0.0);
    Shared shared{.mesh = mesh,
                  .rule = acceptable ? &acceptable : nullptr,
                  .tolerance2 = options.tolerance * options.tolerance,
                  .max_cos_angle = std::cos(options.min_angle_degrees * std::numbers::pi / 180.0),
                  .min_cos_normal = std::cos(DecimateOptions::kMaxNormalDeviationDegrees * std::numbers::pi / 180.0),
                  .grid = options.grid,
                  .control = control};
    shared.removed.assign(mesh.vertices.size(), 0);
    Patch whole;
    whole.triangles = mesh.triangles;
    whole.first.assign(mesh.triangles.size() + 1, 0);
    Patch last;
    if (const std::optional<Grid> grid = region_grid(mesh)) {
      // A pass over the grid's cells; one over the cells shifted by half a cell, near the first's seams (which then
      // lie inside them); one over the cells shifted by a quarter, near what is still dirty (the crossings of the two
      // seams lie inside them); then passes over the connected parts of what is near dirty vertices.
      const int threads = resolve_threads(options.threads);
      shared.quadrics.resize(mesh.vertices.size());
      shared.dirty.assign(mesh.vertices.size(), 1);
      constexpr double kShift[] = {0.0, 0.5, 0.25};  // of the grid passes, in cells along every axis
      for (int pass = 0; pass < 3 + kSeamPasses; ++pass) {
        if (pass > 0 && std::find(shared.dirty.begin(), shared.dirty.end(), 1) == shared.dirty.end()) break;
        std::vector<std::uint8_t> active;
        if (pass > 0) active = near_dirty(shared, whole.triangles, kRings);
        const auto [region, count] = pass < 3 ? assign_regions(mesh, whole.triangles, *grid, kShift[pass], active)
                                              : components(whole.triangles, active, mesh.vertices.size());
        if (pass == 0) s.regions = count;
        whole = region_pass(shared, whole, region, count, threads);
        control.report("decimate", pass == 0 ? 0.7 : 0.9);
      }
      last = std::move(whole);
    } else {
      s.regions = 1;
      last = PatchDecimator(shared, whole).run();
    }
    control.check();
    s.collapses = shared.collapses;
    out = assemble(mesh, shared, last.triangles);
  }
  s.vertices_after = out.vertices.size();
  s.triangles_after = out.triangles.size();
  s.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

SurfacePointRule particle_band_rule(std::span<const Vec3> particles, std::span<const double> radii, double r_inner,
                                    double r_outer) {
  if (particles.empty()) return [](const Vec3&) { return false; };
  const double ratio = r_outer / r_inner;
  double largest_outer = r_outer;
  if (!radii.empty()) {
    largest_outer = 0.0;
    for (double r : radii) largest_outer = std::max(largest_outer, r * ratio);
  }
  auto hash = std::make_shared<SpatialHash>(particles, largest_outer);
  constexpr double kRelative = 1e-9;  // as the surfacer's faithful fraction
  if (radii.empty()) {
    const double inner = r_inner * (1.0 - kRelative), outer = r_outer * (1.0 + kRelative);
    // One walk over the cells of a box that holds the inner ball finds any particle inside it and most often one
    // inside the outer ball too (the box's half-width is r_outer / sqrt(3) when that exceeds r_inner: its particles
    // all lie in the outer ball); a search of the outer ball only when it finds none.
    const double half_width = std::max(inner, outer / std::sqrt(3.0));
    return [hash, inner, outer, half_width](const Vec3& x) {
      const double inner2 = inner * inner, outer2 = outer * outer;
      const double qx = x.x(), qy = x.y(), qz = x.z();
      const std::span<const Vec3> points = hash->sorted_points();
      bool near = false;
      const bool clear =
          hash->for_each_range(x.array() - half_width, x.array() + half_width, [&](std::uint32_t b, std::uint32_t e) {
            for (std::uint32_t s = b; s < e; ++s) {
              const double dx = points[s].x() - qx, dy = points[s].y() - qy, dz = points[s].z() - qz;
              const double d2 = dx * dx + dy * dy + dz * dz;
              if (d2 < inner2) return false;
              near = near || d2 < outer2;
            }
            return true;
          });
      return clear && (near || hash->any_within(x, outer));
    };
  }
  return [hash, radii, ratio, largest_outer](const Vec3& x) {
    bool inside_outer = false, outside_inner = true;
    hash->for_each_within(x, largest_outer * (1.0 + kRelative), [&](std::uint32_t i, const Vec3&, double d2) {
      const double d = std::sqrt(d2);
      if (d < radii[i] * (1.0 - kRelative)) outside_inner = false;
      if (d <= radii[i] * ratio * (1.0 + kRelative)) inside_outer = true;
    });
    return inside_outer && outside_inner;
  };
}

SurfacePointRule zero_set_rule(const Field& field, double tolerance) {
  return [&field, tolerance](const Vec3& x) {
    Vec3 gradient;
    const double f = std::abs(field.value_and_gradient(x, gradient));
    return f <= tolerance * gradient.norm();
  };
}

}  // namespace surfacer
