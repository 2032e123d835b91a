// check_mesh works from one vertex -> corner table (a counting sort of the 3F corners by vertex, O(V + F), no maps)
// and then makes one pass over the vertices. For every vertex v the corners of its triangles give its link edges
// a -> b (triangle (v, a, b) counter-clockwise), i.e. directed mesh edges v -> a and b -> v.
//
// Fast path (nearly every vertex of a closed, oriented surface): when every b is the a of exactly one other corner,
// the link edges chain into a permutation of the corners; one cycle through all of them is one closed, oriented
// disk of triangles around v, whose valence is the number of corners and whose edges each have two triangles, one
// in each direction. Checking that takes a few compares per corner, no sort.
// General path (boundary, non-manifold or misoriented vertices): sorting the (neighbour, direction) pairs yields,
// for each edge (v, w) counted at its smaller end, its number of triangles and how often each direction is used; the
// link graph's connectivity (a small union-find) decides whether the triangles around v form one fan.
//
// Parallel and deterministic: triangles and vertices are cut into blocks of fixed size, each block's sums are kept
// apart and added in block order, so the report's bits do not depend on the threads. The table is built without
// atomics (RowBuckets, core/util/parallel.h): the triangles are cut into a few contiguous parts (one per thread, at
// most kMaxParts), each of which counts its corners per vertex while the triangle pass reads it anyway, then writes
// them at its cursors. Every triangle is read twice by one thread, and a vertex's corners come in triangle order
// whatever the threads. Components come from a union-find whose links always point to the smaller index: each block of
// vertices links the edges inside it without atomics (its finds never leave it), then the edges between blocks are
// linked in parallel with atomic compare-and-swap; the number of components is the referenced vertices minus the
// successful links, whichever thread made them. Large arrays are allocated uninitialized and first written by the
// parallel passes, so their pages are faulted in by every thread rather than by one.
#include "core/mesh/mesh_checks.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>
#include <string>
#include <utility>

#include "core/util/errors.h"
#include "core/util/parallel.h"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace surfacer {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr std::size_t kTriangleBlock = std::size_t{1} << 16;
constexpr std::size_t kVertexBlock = std::size_t{1} << 15;
constexpr int kMaxFastCorners = 32;  // corners of one vertex the fast path handles (a bit mask each)
constexpr int kMaxParts = 8;         // triangle parts: each costs 4 bytes per vertex
// The corner after / before corner c of a triangle (no branch, no division: corners are stored as 4 t + c).
constexpr std::uint32_t kNext[4] = {1, 2, 0, 0};
constexpr std::uint32_t kPrev[4] = {2, 0, 1, 0};

bool repeated(const Triangle& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }

// Bit j set where a[j] == x, for j < k; `a` holds k values padded to a multiple of four with values other than x.
std::uint32_t match_mask(const std::uint32_t* a, int k, std::uint32_t x) {
  std::uint32_t mask = 0;
#if defined(__SSE2__)
  const __m128i key = _mm_set1_epi32(static_cast<int>(x));
  for (int j = 0; j < k; j += 4) {
    const __m128i values = _mm_load_si128(reinterpret_cast<const __m128i*>(a + j));
    mask |= static_cast<std::uint32_t>(_mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(values, key)))) << j;
  }
#else
  for (int j = 0; j < k; ++j) mask |= static_cast<std::uint32_t>(a[j] == x) << j;
#endif
  return mask;
}

int block_count(std::size_t n, std::size_t block) { return static_cast<int>((n + block - 1) / block); }

// Union-find: links point from the larger root to the smaller, so no cycle can form and concurrent unite() calls
// agree; path halving only ever shortens a path to a vertex's own root. The *_alone calls skip the atomics.
class UnionFind {
 public:
  // Allocated, not initialized: reset() every vertex first (in parallel, so that the pages are first touched by the
  // threads that use them rather than by one).
  explicit UnionFind(std::size_t n) : parent_(std::make_unique_for_overwrite<std::uint32_t[]>(n)) {}
  void reset(std::size_t begin, std::size_t end) const {
    for (std::size_t i = begin; i < end; ++i) parent_[i] = static_cast<std::uint32_t>(i);
  }
  std::uint32_t find(std::uint32_t x) const {
    for (;;) {
      const std::uint32_t p = at(x).load(std::memory_order_relaxed);
      if (p == x) return x;
      const std::uint32_t g = at(p).load(std::memory_order_relaxed);
      if (g != p) at(x).store(g, std::memory_order_relaxed);  // x is no root: only compressions write it
      x = g;
    }
  }
  // Joins w's component to the one whose root was `root` (updated to the joined root); true when this call joined
  // two components. Cheaper than unite() when one vertex is joined to many neighbours in a row.
  bool join(std::uint32_t& root, std::uint32_t w) const {
    std::uint32_t rw = find(w);
    if (rw == root) return false;
    std::uint32_t big = std::max(root, rw), small = std::min(root, rw);
    if (at(big).compare_exchange_strong(big, small, std::memory_order_relaxed)) {
      root = small;
      return true;
    }
    // Another thread moved one of the roots meanwhile.
    const bool joined = unite(root, w);
    root = find(root);
    return joined;
  }
  // The same without atomics, for one thread alone on a set of vertices whose paths stay inside it.
  std::uint32_t find_alone(std::uint32_t x) const {
    while (parent_[x] != x) x = parent_[x] = parent_[parent_[x]];
    return x;
  }
  bool join_alone(std::uint32_t& root, std::uint32_t w) const {
    const std::uint32_t rw = find_alone(w);
    if (rw == root) return false;
    if (rw < root) {
      parent_[root] = rw;
      root = rw;
    } else {
      parent_[rw] = root;
    }
    return true;
  }
  // True when this call joined two components.
  bool unite(std::uint32_t a, std::uint32_t b) const {
    for (;;) {
      a = find(a);
      b = find(b);
      if (a == b) return false;
      if (a < b) std::swap(a, b);
      std::uint32_t expected = a;
      if (at(a).compare_exchange_strong(expected, b, std::memory_order_relaxed)) return true;
    }
  }

 private:
  std::atomic_ref<std::uint32_t> at(std::uint32_t x) const { return std::atomic_ref<std::uint32_t>(parent_[x]); }
  std::unique_ptr<std::uint32_t[]> parent_;
};

// Sums of one block of triangles.
struct TriangleSums {
  std::int64_t degenerate = 0;
  std::int64_t valid = 0;
  double area = 0.0;    // twice the area
  double volume = 0.0;  // six times the signed volume
  // Of all angles, as signed squared cosines cos * |cos| (monotonic in the cosine; no square root per angle).
  double max_cos = -2.0;
  double min_cos = 2.0;
  std::int64_t below_angle = 0;

  void add(const TriangleSums& b) {
    degenerate += b.degenerate;
    valid += b.valid;
    area += b.area;
    volume += b.volume;
    max_cos = std::max(max_cos, b.max_cos);
    min_cos = std::min(min_cos, b.min_cos);
    below_angle += b.below_angle;
  }
};

// Sums of one block of vertices.
struct VertexSums {
  std::int64_t referenced = 0;
  std::int64_t edges = 0;
  std::int64_t boundary_edges = 0;
  std::int64_t non_manifold_edges = 0;
  std::int64_t links = 0;  // successful union-find links
  bool oriented = true;
  bool vertex_manifold = true;
  int min_valence = std::numeric_limits<int>::max();
  int max_valence = 0;
  std::vector<std::int64_t> histogram;

  void add(const VertexSums& b) {
    referenced += b.referenced;
    edges += b.edges;
    boundary_edges += b.boundary_edges;
    non_manifold_edges += b.non_manifold_edges;
    links += b.links;
    oriented = oriented && b.oriented;
    vertex_manifold = vertex_manifold && b.vertex_manifold;
    min_valence = std::min(min_valence, b.min_valence);
    max_valence = std::max(max_valence, b.max_valence);
    if (histogram.size() < b.histogram.size()) histogram.resize(b.histogram.size(), 0);
    for (std::size_t i = 0; i < b.histogram.size(); ++i) histogram[i] += b.histogram[i];
  }

  void add_valence(int valence) {
    min_valence = std::min(min_valence, valence);
    max_valence = std::max(max_valence, valence);
    if (histogram.size() <= static_cast<std::size_t>(valence)) histogram.resize(valence + 1, 0);
    ++histogram[valence];
  }
};

class Checker {
 public:
  Checker(const Mesh& mesh, int threads, const RunControl& control, double below_degrees)
      : mesh_(mesh),
        threads_(threads),
        control_(control),
        count_below_(below_degrees > 0.0),
        below_cos_(std::cos(below_degrees * kPi / 180.0) * std::abs(std::cos(below_degrees * kPi / 180.0))),
        nv_(mesh.vertices.size()),
        nf_(mesh.triangles.size()),
        components_(nv_) {}

  MeshReport run() {
    if (nf_ >= std::size_t{1} << 30) throw ResourceLimit("triangles", "check_mesh supports at most 2^30 - 1 triangles");
    prepare_vertices();
    triangle_pass();
    build_offsets();
    fill_corners();
    vertex_pass();
    return report();
  }

 private:
  // The bounding box (for the zero-area threshold); resets the union-find and zeroes the parts' corner counts, one
  // block of vertices per item, so that their pages are first touched by every thread.
  void prepare_vertices() {
    const int vertex_blocks = block_count(nv_, kVertexBlock);
    const int triangle_blocks = block_count(nf_, kTriangleBlock);
    parts_ = std::clamp(threads_, 1, std::clamp(triangle_blocks, 1, kMaxParts));
    part_begin_.resize(parts_ + 1);
    for (int p = 0; p <= parts_; ++p) part_begin_[p] = static_cast<std::size_t>(triangle_blocks) * p / parts_;
    buckets_.emplace(nv_, parts_);
    std::vector<Aabb> boxes(vertex_blocks, Aabb::empty());
    parallel_for(vertex_blocks, threads_, [&](int b) {
      control_.check();
      const std::size_t begin = b * kVertexBlock, end = std::min(nv_, (b + 1) * kVertexBlock);
      components_.reset(begin, end);
      buckets_->clear(begin, end);
      Aabb box = Aabb::empty();
      for (std::size_t v = begin; v < end; ++v) box.merge(mesh_.vertices[v]);
      boxes[b] = box;
    });
    Aabb box = Aabb::empty();
    for (const Aabb& b : boxes) box.merge(b);
    diag2_ = nv_ > 0 ? box.size().squaredNorm() : 0.0;
  }

  // Area, volume, angles and degenerate triangles, per block of triangles, and the corners per vertex, per part.
  // Throws InvalidInput for the first triangle (lowest index) that uses a vertex out of range: a part stops at its
  // first, and the parts are in triangle order.
  void triangle_pass() {
    triangle_sums_.assign(block_count(nf_, kTriangleBlock), TriangleSums{});
    std::vector<std::size_t> first_bad(parts_, nf_);
    const double min_area = 1e-14 * diag2_;
    parallel_for(parts_, threads_, [&](int part) {
      std::uint32_t* count = buckets_->count(part);
      for (std::size_t block = part_begin_[part]; block < part_begin_[part + 1]; ++block) {
        control_.check();
        TriangleSums s;
        const std::size_t end = std::min(nf_, (block + 1) * kTriangleBlock);
        for (std::size_t t = block * kTriangleBlock; t < end; ++t) {
          const Triangle& tri = mesh_.triangles[t];
          if (tri[0] >= nv_ || tri[1] >= nv_ || tri[2] >= nv_) {
            first_bad[part] = t;
            return;
          }
          if (repeated(tri)) {
            ++s.degenerate;
            continue;
          }
          ++s.valid;
          for (std::uint32_t v : tri) ++count[v];
          const Vec3& a = mesh_.vertices[tri[0]];
          const Vec3& b = mesh_.vertices[tri[1]];
          const Vec3& c = mesh_.vertices[tri[2]];
          const Vec3 ab = b - a, ac = c - a, bc = c - b;
          const double twice_area = ab.cross(ac).norm();
          s.area += twice_area;           // halved once, in report()
          s.volume += a.dot(b.cross(c));  // divided by 6 once, in report()
          if (!(twice_area >= 2.0 * min_area) || twice_area == 0.0) {
            ++s.degenerate;
            if (count_below_) ++s.below_angle;
            continue;
          }
          const double ab2 = ab.squaredNorm(), ac2 = ac.squaredNorm(), bc2 = bc.squaredNorm();
          // The angles at a, b and c: cos = dot / (|u| |v|), compared as dot |dot| / (|u|^2 |v|^2), with one division.
          const double da = ab.dot(ac), db = -ab.dot(bc), dc = ac.dot(bc);
          const double r = 1.0 / (ab2 * ac2 * bc2);
          const double sa = da * std::abs(da) * bc2 * r;
          const double sb = db * std::abs(db) * ac2 * r;
          const double sc = dc * std::abs(dc) * ab2 * r;
          const double largest = std::max({sa, sb, sc});  // of the smallest angle
          s.max_cos = std::max(s.max_cos, largest);
          s.min_cos = std::min({s.min_cos, sa, sb, sc});
          if (count_below_ && largest > below_cos_) ++s.below_angle;
        }
        triangle_sums_[block] = s;
      }
    });
    for (std::size_t t : first_bad) {
      if (t == nf_) continue;
      for (std::uint32_t v : mesh_.triangles[t]) {
        if (v >= nv_) {
          throw InvalidInput("triangles", "triangle " + std::to_string(t) + " uses vertex " + std::to_string(v) +
                                              " but the mesh has " + std::to_string(nv_) + " vertices");
        }
      }
    }
  }

  // start_[v]: v's first corner, the vertices in order; within v, part 0's corners come first, and so on. The parts'
  // counts become their write cursors.
  void build_offsets() {
    start_.resize(nv_ + 1);
    const std::uint32_t corners = buckets_->place(start_.data(), [&](int blocks, auto&& body) {
      parallel_for(blocks, threads_, [&](int b) {
        control_.check();
        body(b);
      });
    });
    corners_.resize(corners);  // each slot filled once, by fill_corners
  }

  // corners_[start_[v] ..  start_[v + 1]): the corners (4 t + c) at vertex v, in triangle order; triangles with a
  // repeated index are left out of the topology.
  void fill_corners() {
    parallel_for(parts_, threads_, [&](int part) {
      control_.check();
      std::uint32_t* next = buckets_->cursor(part);
      const std::size_t end = std::min(nf_, part_begin_[part + 1] * kTriangleBlock);
      for (std::size_t t = part_begin_[part] * kTriangleBlock; t < end; ++t) {
        const Triangle& tri = mesh_.triangles[t];
        if (repeated(tri)) continue;
        for (std::uint32_t c = 0; c < 3; ++c) corners_[next[tri[c]]++] = static_cast<std::uint32_t>(t << 2 | c);
      }
    });
  }

  // The component links of one block of vertices, which ends at `end`: an edge to a vertex of the same block is linked
  // at once, without atomics (a find from a vertex of the block then stays in the block: links point to smaller
  // indices), one to a later block is kept for the second phase.
  struct Links {
    std::uint32_t end;
    std::vector<std::array<std::uint32_t, 2>> later;
  };

  void vertex_pass() {
    const int blocks = block_count(nv_, kVertexBlock);
    vertex_sums_.assign(blocks, VertexSums{});
    std::vector<std::vector<std::array<std::uint32_t, 2>>> later(blocks);
    parallel_for(blocks, threads_, [&](int block) {
      control_.check();
      VertexSums s;
      Scratch scratch;
      const std::size_t end = std::min(nv_, (block + 1) * kVertexBlock);
      Links links{static_cast<std::uint32_t>(end), {}};
      for (std::size_t v = block * kVertexBlock; v < end; ++v) {
        if (start_[v] == start_[v + 1]) continue;
        ++s.referenced;
        if (!closed_fan(static_cast<std::uint32_t>(v), s, links)) {
          general_vertex(static_cast<std::uint32_t>(v), s, scratch, links);
        }
      }
      vertex_sums_[block] = std::move(s);
      later[block] = std::move(links.later);
    });
    // The edges between blocks, in parallel on the atomic union-find.
    parallel_for(blocks, threads_, [&](int block) {
      control_.check();
      std::int64_t made = 0;
      for (const auto& [v, w] : later[block]) made += components_.unite(v, w) ? 1 : 0;
      vertex_sums_[block].links += made;
    });
  }

  void link(std::uint32_t& root, std::uint32_t v, std::uint32_t w, VertexSums& s, Links& links) const {
    if (w < links.end) {
      s.links += components_.join_alone(root, w) ? 1 : 0;
    } else {
      links.later.push_back({v, w});
    }
  }

  // The fast path; false (and nothing recorded) when v needs the general one.
  bool closed_fan(std::uint32_t v, VertexSums& s, Links& links) const {
    const std::uint32_t begin = start_[v], end = start_[v + 1];
    const int k = static_cast<int>(end - begin);
    if (k > kMaxFastCorners) return false;
    // a is padded with v (never a neighbour of itself) to whole groups of four for match_mask.
    alignas(16) std::array<std::uint32_t, kMaxFastCorners> a, b;
    for (int i = k; i < ((k + 3) & ~3); ++i) a[i] = v;
    for (int i = 0; i < k; ++i) {
      const std::uint32_t corner = corners_[begin + i];
      const Triangle& tri = mesh_.triangles[corner >> 2];
      a[i] = tri[kNext[corner & 3]];
      b[i] = tri[kPrev[corner & 3]];
    }
    // next[i] = the corner j whose a is corner i's b (the next triangle around v); it must be one and only one.
    std::array<std::uint8_t, kMaxFastCorners> next{};
    std::uint32_t hit = 0;
    for (int i = 0; i < k; ++i) {
      const std::uint32_t matches = match_mask(a.data(), k, b[i]);
      if (matches == 0 || (matches & (matches - 1)) != 0 || (hit & matches)) return false;
      hit |= matches;
      next[i] = static_cast<std::uint8_t>(std::countr_zero(matches));
    }
    int length = 1;
    for (int i = next[0]; i != 0; i = next[i]) ++length;
    if (length != k) return false;
    s.add_valence(k);
    // The edges counted at v (those to larger neighbours), gathered without a branch per neighbour.
    std::array<std::uint32_t, kMaxFastCorners> larger;
    int m = 0;
    for (int i = 0; i < k; ++i) {
      larger[m] = a[i];
      m += a[i] > v ? 1 : 0;
    }
    s.edges += m;
    std::uint32_t root = components_.find_alone(v);
    for (int i = 0; i < m; ++i) link(root, v, larger[i], s, links);
    return true;
  }

  struct Incidence {
    std::uint32_t other;
    int direction;  // +1: v -> other, -1: other -> v
    bool operator<(const Incidence& o) const { return other < o.other; }
  };
  struct Scratch {
    std::vector<Incidence> incidences;
    std::vector<std::uint32_t> distinct;
    std::vector<std::uint32_t> link_parent;
  };

  void general_vertex(std::uint32_t v, VertexSums& s, Scratch& scratch, Links& links) const {
    const std::uint32_t begin = start_[v], end = start_[v + 1];
    auto& incidences = scratch.incidences;
    auto& distinct = scratch.distinct;
    auto& link_parent = scratch.link_parent;
    incidences.clear();
    for (std::uint32_t k = begin; k < end; ++k) {
      const Triangle& tri = mesh_.triangles[corners_[k] >> 2];
      const std::uint32_t c = corners_[k] & 3;
      incidences.push_back({tri[kNext[c]], +1});
      incidences.push_back({tri[kPrev[c]], -1});
    }
    std::sort(incidences.begin(), incidences.end());
    distinct.clear();
    bool fan_ok = true;
    std::uint32_t root = components_.find_alone(v);
    for (std::size_t r = 0; r < incidences.size();) {
      std::size_t q = r;
      int out = 0;
      while (q < incidences.size() && incidences[q].other == incidences[r].other) {
        out += incidences[q].direction > 0 ? 1 : 0;
        ++q;
      }
      const auto multiplicity = static_cast<std::int64_t>(q - r);
      const std::uint32_t w = incidences[r].other;
      distinct.push_back(w);
      if (multiplicity > 2) fan_ok = false;
      if (w > v) {
        ++s.edges;
        link(root, v, w, s, links);
        if (multiplicity == 1) ++s.boundary_edges;
        if (multiplicity > 2) ++s.non_manifold_edges;
        if (multiplicity > 2 || (multiplicity == 2 && out != 1)) s.oriented = false;
      }
      r = q;
    }
    s.add_valence(static_cast<int>(distinct.size()));

    // The link of v: its distinct neighbours joined by one edge per triangle. One fan <=> connected link with every
    // neighbour in at most two triangles (a path: half-disk; a cycle: disk).
    if (fan_ok) {
      link_parent.resize(distinct.size());
      std::iota(link_parent.begin(), link_parent.end(), 0u);
      auto link_find = [&](std::uint32_t x) {
        while (link_parent[x] != x) x = link_parent[x] = link_parent[link_parent[x]];
        return x;
      };
      std::size_t parts = distinct.size();
      for (std::uint32_t k = begin; k < end; ++k) {
        const Triangle& tri = mesh_.triangles[corners_[k] >> 2];
        const std::uint32_t c = corners_[k] & 3;
        const auto ia = static_cast<std::uint32_t>(std::lower_bound(distinct.begin(), distinct.end(), tri[kNext[c]]) -
                                                   distinct.begin());
        const auto ib = static_cast<std::uint32_t>(std::lower_bound(distinct.begin(), distinct.end(), tri[kPrev[c]]) -
                                                   distinct.begin());
        const std::uint32_t ra = link_find(ia), rb = link_find(ib);
        if (ra != rb) {
          link_parent[ra] = rb;
          --parts;
        }
      }
      fan_ok = parts == 1;
    }
    s.vertex_manifold = s.vertex_manifold && fan_ok;
  }

  MeshReport report() const {
    MeshReport r;
    TriangleSums t;
    for (const TriangleSums& b : triangle_sums_) t.add(b);
    r.degenerate_triangles = t.degenerate;
    r.triangles_below_angle = t.below_angle;
    r.area = 0.5 * t.area;
    r.volume = t.volume / 6.0;
    auto degrees = [](double signed_square) {
      const double cosine = std::copysign(std::sqrt(std::abs(signed_square)), signed_square);
      return std::acos(std::clamp(cosine, -1.0, 1.0)) * 180.0 / kPi;
    };
    if (t.max_cos >= -1.5) {
      r.min_angle_degrees = degrees(t.max_cos);
      r.max_angle_degrees = degrees(t.min_cos);
    }
    VertexSums v;
    for (const VertexSums& b : vertex_sums_) v.add(b);
    r.boundary_edges = v.boundary_edges;
    r.non_manifold_edges = v.non_manifold_edges;
    r.closed = r.boundary_edges == 0;
    r.edge_manifold = r.non_manifold_edges == 0;
    r.vertex_manifold = v.vertex_manifold && r.edge_manifold;
    r.oriented = v.oriented;
    r.euler_characteristic = v.referenced - v.edges + t.valid;
    r.components = static_cast<int>(v.referenced - v.links);
    r.valence_histogram = std::move(v.histogram);
    if (v.referenced > 0) {
      r.min_valence = v.min_valence;
      r.max_valence = v.max_valence;
    }
    return r;
  }

  const Mesh& mesh_;
  const int threads_;
  const RunControl& control_;
  const bool count_below_;
  const double below_cos_;  // cos |cos| of below_degrees: an angle is below it when its own is larger
  const std::size_t nv_;
  const std::size_t nf_;
  double diag2_ = 0.0;
  std::vector<TriangleSums> triangle_sums_;
  Buffer<std::uint32_t> start_;    // nv_ + 1 offsets into corners_
  Buffer<std::uint32_t> corners_;  // 4 t + c
  std::vector<VertexSums> vertex_sums_;
  UnionFind components_;
  int parts_ = 1;                        // contiguous runs of triangle blocks, each counted and filled by one item
  std::vector<std::size_t> part_begin_;  // parts_ + 1 triangle block indices
  std::optional<RowBuckets> buckets_;    // the corners per vertex, counted and written by the parts
};

}  // namespace

MeshReport check_mesh(const Mesh& mesh) { return check_mesh(mesh, 1); }

MeshReport check_mesh(const Mesh& mesh, int threads, const RunControl& control, double below_degrees) {
  return Checker(mesh, threads, control, below_degrees).run();
}

}  // namespace surfacer
