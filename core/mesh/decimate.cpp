// Decimation (core/mesh/decimate.h, docs/ALGORITHMS.md §5 CHOICE "Decimation").
//
// The loop is our own on an OpenMesh TriMesh (its collapse; the link condition as its is_collapse_ok): a heap of
// vertices keyed by the quadric cost of their cheapest collapse, whose expensive checks (fan geometry, the Hausdorff
// samples, the engine's rule) run only when a vertex reaches the top of the heap (lazy evaluation: the key is a lower
// bound of the cost of its cheapest legal collapse, made exact at the top and pushed back when another vertex is then
// cheaper). A large mesh is cut into regions (cells of a grid, each triangle in the cell of its centroid) decimated
// in parallel with the vertices they share frozen, twice (the second grid shifted by half a cell), then one pass over
// the merged mesh starting from the last seams.
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
// A region's triangles, about (the grid's cells are sized for it from the mean triangle area); meshes with fewer
// than two regions' worth are decimated in one pass.


// The smallest angle of triangle (a, b, c), as its cosine's largest value (cosines decrease with the angle).
double max_cosine(const Vec3& a, const Vec3& b, const Vec3& c) {
  const auto cosine = [](const Vec3& apex, const Vec3& p, const Vec3& q) {
    const Vec3 u = p - apex, v = q - apex;
    const double norms = u.norm() * v.norm();
    return norms > 0.0 ? u.dot(v) / norms : 1.0;
  };
  return std::max({cosine(a, b, c), cosine(b, c, a), cosine(c, a, b)});
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
    return m[0] * x * x + 2.0 * m[1] * x * y + 2.0 * m[2] * x * z + 2.0 * m[3] * x + m[4] * y * y +
           2.0 * m[5] * y * z + 2.0 * m[6] * y + m[7] * z * z + 2.0 * m[8] * z + m[9];
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
  double max_cos_angle = 1.0;   // of the smallest angle allowed
  double min_cos_normal = 0.0;  // of the largest normal turn allowed
  const RunControl& control;
  // Whether this is the first pass (each patch sums its vertices' quadrics from its own triangles) or a later one
  // (quadrics reads them).
  bool initial = true;
  std::vector<Quadric> quadrics{};     // per input vertex after the first of several passes, else empty
  std::vector<std::uint8_t> frozen{};  // per input vertex: shared by regions (neither end of a collapse), or empty
  std::vector<std::uint8_t> seed{};    // per input vertex: a first candidate of the pass, or empty (all are)
  std::vector<std::uint8_t> removed{};  // per input vertex
  std::atomic<std::size_t> collapses{0};
};

// A binary min-heap of vertices by key (ties: the smaller vertex first) that knows where each vertex sits, so a key
// changes in place.
class VertexHeap {
 public:
  explicit VertexHeap(std::size_t vertices) : key_(vertices, 0.0), position_(vertices, kNone) {}
  bool empty() const { return heap_.empty(); }
  bool contains(std::uint32_t v) const { return position_[v] != kNone; }
  double key(std::uint32_t v) const { return key_[v]; }
  double top_key() const { return key_[heap_.front()]; }
  // Inserts v or changes its key.
  void set(std::uint32_t v, double key) {
    if (position_[v] == kNone) {
      position_[v] = static_cast<std::uint32_t>(heap_.size());
      heap_.push_back(v);
      key_[v] = key;
      up(position_[v]);
      return;
    }
    const double old = key_[v];
    key_[v] = key;
    if (key < old) {
      up(position_[v]);
    } else {
      down(position_[v]);
    }
  }
  std::uint32_t pop() {
    const std::uint32_t v = heap_.front();
    position_[v] = kNone;
    const std::uint32_t last = heap_.back();
    heap_.pop_back();
    if (!heap_.empty()) {
      heap_.front() = last;
      position_[last] = 0;
      down(0);
    }
    return v;
  }

 private:
  bool before(std::uint32_t a, std::uint32_t b) const {
    return key_[a] < key_[b] || (key_[a] == key_[b] && a < b);
  }
  void place(std::uint32_t i, std::uint32_t v) {
    heap_[i] = v;
    position_[v] = i;
  }
  void up(std::uint32_t i) {
    const std::uint32_t v = heap_[i];
    while (i > 0) {
      const std::uint32_t parent = (i - 1) / 2;
      if (!before(v, heap_[parent])) break;
      place(i, heap_[parent]);
      i = parent;
    }
    place(i, v);
  }
  void down(std::uint32_t i) {
    const std::uint32_t v = heap_[i];
    const auto n = static_cast<std::uint32_t>(heap_.size());
    while (true) {
      std::uint32_t child = 2 * i + 1;
      if (child >= n) break;
      if (child + 1 < n && before(heap_[child + 1], heap_[child])) ++child;
      if (!before(heap_[child], v)) break;
      place(i, heap_[child]);
      i = child;
    }
    place(i, v);
  }

  std::vector<double> key_;
  std::vector<std::uint32_t> position_;
  std::vector<std::uint32_t> heap_;
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
  const Quadric& quadric(VertexHandle v) const { return quadrics_[v.idx()]; }

  void build() {
    const Mesh& mesh = shared_.mesh;
    // Local vertices in increasing input order; corner_[3 t + k] is corner k of triangle t in local numbering.
    const std::size_t n = patch_.triangles.size();
    std::vector<std::uint64_t> corners(3 * n);
    for (std::size_t t = 0; t < n; ++t) {
      for (int k = 0; k < 3; ++k) {
        corners[3 * t + k] = (static_cast<std::uint64_t>(patch_.triangles[t][k]) << 32) | (3 * t + k);
      }
    }
    std::sort(corners.begin(), corners.end());
    corner_.resize(3 * n);
    for (const std::uint64_t c : corners) {
      const auto v = static_cast<std::uint32_t>(c >> 32);
      if (global_.empty() || global_.back() != v) global_.push_back(v);
      corner_[static_cast<std::uint32_t>(c)] = static_cast<std::uint32_t>(global_.size() - 1);
    }
    // Positions and quadrics in local order: a region's are then near in memory.
    positions_.reserve(global_.size());
    for (const std::uint32_t v : global_) positions_.push_back(mesh.vertices[v]);
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
  // when the patch is a manifold: no triangle repeats a vertex, every directed edge is in one triangle at most, and
  // every vertex's triangles form one fan, closed or with one gap. Returns false otherwise (the caller then clears
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
    om_.reserve(vertices, 3 * n / 2 + 16, n);
    for (std::size_t v = 0; v < vertices; ++v) om_.add_vertex(TriMesh::Point(0.0, 0.0, 0.0));
    std::vector<HalfedgeHandle> half(3 * n);
    std::vector<HalfedgeHandle> boundary_out(vertices);  // the outgoing boundary halfedge of each vertex
    std::vector<std::uint8_t> boundary_in(vertices, 0);
    for (std::uint32_t h = 0; h < 3 * n; ++h) {
      if (half[h].is_valid()) continue;  // made with its opposite
      const std::uint32_t from = corner_[h], to = to_of(h);
      if (find(from, to) != h) return false;
      const HalfedgeHandle made =
          om_.new_edge(VertexHandle(static_cast<int>(from)), VertexHandle(static_cast<int>(to)));
      half[h] = made;
      const std::uint32_t opposite = find(to, from);
      if (opposite == kNone - 1) return false;
      if (opposite != kNone) {
        half[opposite] = om_.opposite_halfedge_handle(made);
      } else {
        // The boundary halfedge to -> from.
        if (boundary_out[to].is_valid() || boundary_in[from]) return false;  // two gaps in one fan
        boundary_out[to] = om_.opposite_halfedge_handle(made);
        boundary_in[from] = 1;
      }
    }
    for (std::size_t t = 0; t < n; ++t) {
      const FaceHandle f = om_.new_face();
      om_.set_halfedge_handle(f, half[3 * t + 2]);  // as add_face: the face lists its corners in input order
      for (int k = 0; k < 3; ++k) {
        om_.set_face_handle(half[3 * t + k], f);
        om_.set_next_halfedge_handle(half[3 * t + k], half[3 * t + (k + 1) % 3]);
        const VertexHandle from(static_cast<int>(corner_[3 * t + k]));
        if (!om_.halfedge_handle(from).is_valid()) om_.set_halfedge_handle(from, half[3 * t + k]);
      }
    }
    // Boundary halfedges: each continues with the outgoing one of the vertex it ends at; a boundary vertex starts
    // its rotation there (OpenMesh's invariant).
    for (std::size_t v = 0; v < vertices; ++v) {
      const HalfedgeHandle out = boundary_out[v];
      if (!out.is_valid()) continue;
      om_.set_face_handle(out, FaceHandle());
      const VertexHandle to = om_.to_vertex_handle(out);
      if (!boundary_out[to.idx()].is_valid() || !boundary_in[to.idx()]) return false;
      om_.set_next_halfedge_handle(out, boundary_out[to.idx()]);
      om_.set_halfedge_handle(VertexHandle(static_cast<int>(v)), out);
    }
    // One fan per vertex: the rotation from its halfedge meets every triangle at it.
    std::vector<std::uint32_t> triangles_at(vertices, 0);
    for (const std::uint32_t c : corner_) ++triangles_at[c];
    for (std::size_t v = 0; v < vertices; ++v) {
      const VertexHandle vh(static_cast<int>(v));
      const HalfedgeHandle start = om_.halfedge_handle(vh);
      if (boundary_out[v].is_valid() != static_cast<bool>(boundary_in[v])) return false;
      std::uint32_t seen = 0, steps = 0;
      HalfedgeHandle h = start;
      do {
        if (!om_.is_boundary(h)) ++seen;
        if (seen > triangles_at[v] || ++steps > triangles_at[v] + 1) return false;
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
      if (shared_.seed.empty() || shared_.seed[global_[v.idx()]]) push(v);
    }
  }

  // Whether collapsing v0 into v1 along h keeps every guarantee; when it does, fan_ holds the faces left at v1 that
  // were v0's and gathered_ / assigned_ the samples to move and the fan_ face each goes to.
  bool legal(HalfedgeHandle h) {
    const VertexHandle v0 = om_.from_vertex_handle(h), v1 = om_.to_vertex_handle(h);
    if (lock_[v0.idx()] != kFree || lock_[v1.idx()] == kFrozen) return false;
    const HalfedgeHandle o = om_.opposite_halfedge_handle(h);
    const FaceHandle fl = om_.face_handle(h), fr = om_.face_handle(o);

    // The faces that stay, with v0 moved to p1: their angles and normal turns (cheap, most refusals) first.
    const Vec3& p0 = position(v0);
    const Vec3& p1 = position(v1);
    fan_.clear();
    for (const HalfedgeHandle out : om_.voh_range(v0)) {
      const FaceHandle f = om_.face_handle(out);
      if (!f.is_valid() || f == fl || f == fr) continue;
      const Vec3& a = position(om_.to_vertex_handle(out));
      const Vec3& b = position(om_.to_vertex_handle(om_.next_halfedge_handle(out)));
      const Fan face{f, {p1, a, b}};
      if (max_cosine(p1, a, b) > shared_.max_cos_angle) return false;
      const Vec3 n_old = (a - p0).cross(b - p0);
      const Vec3 n_new = (a - p1).cross(b - p1);
      if (n_old.dot(n_new) < shared_.min_cos_normal * n_old.norm() * n_new.norm()) return false;
      fan_.push_back(face);
    }
    if (fan_.empty()) return false;

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
    if (om_.valence(vl) == 3 && om_.valence(vr) == 3 && om_.find_halfedge(vl, vr).is_valid()) {
      return false;
    }

    // The Hausdorff samples of v0's faces and v0 itself, each within the tolerance of a face of the new fan.
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
      return squared_distance_to_triangle(q, c[0], c[1], c[2]) <= shared_.tolerance2;
    };
    if (first >= 0 && near(first)) return first;
    for (int i = 0; i < static_cast<int>(fan_.size()); ++i) {
      if (i != first && near(i)) return i;
    }
    return -1;
  }

  // Collapses along h, which legal(h) just accepted (fan_, gathered_, assigned_ and v0_face_ are its).
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
    om_.collapse(h);
    ++collapses_;
    // The fans of v0's neighbours changed: what they found illegal may not be now. A queued neighbour's key stays a
    // lower bound of its collapses' costs (quadrics only grow) but for its new neighbour v1.
    for (const VertexHandle w : support_) {
      const auto i = static_cast<std::uint32_t>(w.idx());
      floor_[i] = -std::numeric_limits<double>::infinity();
      if (w != v1 && heap_.contains(i)) {
        if (lock_[v1.idx()] != kFrozen) heap_.set(i, std::min(heap_.key(i), cost(w, v1)));
      } else {
        push(w);
      }
    }
  }

  // Pops the cheapest vertex, makes its key exact (the cheapest candidate not known illegal) and collapses it when
  // that candidate is legal and still no other vertex is cheaper; a candidate found illegal stays skipped (floor_)
  // until the vertex's fan changes.
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
        if (!heap_.empty() && c > heap_.top_key()) {
          floor_[v] = c;
          heap_.set(v, c);
          break;
        }
        if (legal(h)) {
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

  Shared& shared_;
  const Patch& patch_;
  TriMesh om_;
  std::vector<std::uint32_t> global_;      // local vertex -> input vertex
  std::vector<std::uint32_t> corner_;      // 3 t + k: the local vertex at corner k of patch triangle t
  std::vector<std::uint8_t> added_;        // per patch triangle when built by add_faces(): whether it was added
  std::vector<Vec3> positions_;            // per local vertex
  std::vector<Quadric> quadrics_;          // per local vertex
  std::vector<std::uint8_t> lock_;         // per local vertex
  std::vector<double> floor_;              // per local vertex: its collapses cheaper than this were found illegal
  std::vector<std::uint32_t> refused_;     // patch triangles OpenMesh refused
  std::vector<std::int32_t> head_;         // per face: its first sample node, or -1
  std::vector<Vec3> node_point_;            // per sample node: the removed input vertex's position
  std::vector<std::int32_t> node_next_;     // per sample node: the next of its face's list, or -1
  VertexHeap heap_{0};
  std::size_t collapses_ = 0;
  // Scratch of legal() and collapse().
  std::vector<Fan> fan_;
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

std::pair<std::vector<std::uint32_t>, std::uint32_t> assign_regions(const Mesh& mesh,
                                                                    const std::vector<Triangle>& triangles,
                                                                    const Grid& grid, double shift);

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
// in the order of their first triangles; and how many regions there are.
std::pair<std::vector<std::uint32_t>, std::uint32_t> assign_regions(const Mesh& mesh,
                                                                    const std::vector<Triangle>& triangles,
                                                                    const Grid& grid, double shift) {
  std::vector<std::uint32_t> region(triangles.size());
  std::vector<std::uint32_t> number(static_cast<std::size_t>(grid.dims[0] * grid.dims[1] * grid.dims[2]), kNone);
  std::uint32_t count = 0;
  for (std::size_t i = 0; i < triangles.size(); ++i) {
    const Triangle& t = triangles[i];
    const Vec3 centroid = (mesh.vertices[t[0]] + mesh.vertices[t[1]] + mesh.vertices[t[2]]) / 3.0;
    double index = 0.0;
    for (int a = 2; a >= 0; --a) {
      const double u = std::floor((centroid[a] - grid.origin[a]) / grid.edge + shift);
      index = index * grid.dims[a] + std::clamp(u, 0.0, grid.dims[a] - 1.0);
    }
    std::uint32_t& r = number[static_cast<std::size_t>(index)];
    if (r == kNone) r = count++;
    region[i] = r;
  }
  return {std::move(region), count};
}

// One pass over the regions of `input` (region[t], `count` of them) on `threads`, each decimated with the vertices it
// shares with another frozen; the decimated regions merged in region order. Afterwards shared.seed holds the frozen
// vertices and their neighbours, where the next pass starts.
Patch region_pass(Shared& shared, const Patch& input, const std::vector<std::uint32_t>& region, std::uint32_t count,
                  int threads) {
  const std::size_t vertices = shared.mesh.vertices.size();
  std::vector<std::uint32_t> region_of(vertices, kNone);
  shared.frozen.assign(vertices, 0);
  std::vector<std::uint32_t> offsets(count + 1, 0);
  for (std::size_t t = 0; t < input.triangles.size(); ++t) {
    ++offsets[region[t] + 1];
    for (const std::uint32_t v : input.triangles[t]) {
      if (region_of[v] == kNone) region_of[v] = region[t];
      if (region_of[v] != region[t]) shared.frozen[v] = 1;
    }
  }
  for (std::uint32_t r = 0; r < count; ++r) offsets[r + 1] += offsets[r];
  std::vector<std::uint32_t> order(input.triangles.size());
  std::vector<std::uint32_t> fill(offsets.begin(), offsets.end() - 1);
  for (std::uint32_t t = 0; t < input.triangles.size(); ++t) order[fill[region[t]]++] = t;

  std::vector<Patch> parts(count);
  std::vector<std::vector<std::pair<std::uint32_t, Quadric>>> partial(count);
  parallel_for(static_cast<int>(count), threads, [&](int r) {
    Patch patch;
    patch.triangles.reserve(offsets[r + 1] - offsets[r]);
    for (std::uint32_t i = offsets[r]; i < offsets[r + 1]; ++i) {
      const std::uint32_t t = order[i];
      patch.triangles.push_back(input.triangles[t]);
      patch.points.insert(patch.points.end(), input.points.begin() + input.first[t],
                          input.points.begin() + input.first[t + 1]);
      patch.first.push_back(static_cast<std::uint32_t>(patch.points.size()));
    }
    PatchDecimator decimator(shared, patch);
    parts[r] = decimator.run();
    partial[r] = decimator.frozen_quadrics();
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
  shared.seed.assign(vertices, 0);
  for (const Triangle& t : merged.triangles) {
    if (shared.frozen[t[0]] || shared.frozen[t[1]] || shared.frozen[t[2]]) {
      for (const std::uint32_t v : t) shared.seed[v] = 1;
    }
  }
  shared.frozen.clear();
  return merged;
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
                  .control = control};
    shared.removed.assign(mesh.vertices.size(), 0);
    Patch whole;
    whole.triangles = mesh.triangles;
    whole.first.assign(mesh.triangles.size() + 1, 0);
    if (const std::optional<Grid> grid = region_grid(mesh)) {
      // Two passes over regions, the second's cells shifted by half a cell so that the first's seams lie inside
      // them; then one pass over the merged mesh from the second's seams.
      const int threads = resolve_threads(options.threads);
      shared.quadrics.resize(mesh.vertices.size());
      for (const double shift : {0.0, 0.5}) {
        const auto [region, count] = assign_regions(mesh, whole.triangles, *grid, shift);
        if (shift == 0.0) s.regions = count;
        whole = region_pass(shared, whole, region, count, threads);
        control.report("decimate", shift == 0.0 ? 0.7 : 0.9);
      }
    }
    if (s.regions == 0) s.regions = 1;
    const Patch last = PatchDecimator(shared, whole).run();
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
    // Two searches that stop at the first particle found: one in the outer ball (most often in x's own cell), none in
    // the inner one.
    return [hash, inner, outer](const Vec3& x) { return hash->any_within(x, outer) && !hash->any_within(x, inner); };
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
