#include "core/mesh/mesh_repair.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <span>
#include <tuple>
#include <vector>

#include "core/mesh/mesh_edit.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr std::uint32_t kDead = MeshEditor::kNone;  // a removed triangle, or no vertex
using GridPoint = std::array<std::uint32_t, 3>;

// A candidate repair of one bad triangle: flip one of its edges, or collapse one onto one of its ends.
struct Move {
  enum class Kind { kFlip, kCollapse } kind = Kind::kFlip;
  int edge = 0;            // edge k = (tri[k], tri[k+1]) of the triangle
  bool keep_first = true;  // collapse: keep tri[k] (else tri[k+1])
  double before = 0.0;     // the worst quality among the triangles the move removes or changes
  double after = 0.0;      // the worst quality among the triangles it makes
  std::array<std::uint32_t, 2> blocked{kDead, kDead};  // vertices the move would take below the valence floor
};

class Repair {
 public:
  Repair(Mesh& mesh, const SliverOptions& options)
      : mesh_(mesh), positions_(mesh.vertices), tris_(mesh.triangles), options_(options) {
    if (options_.grid) {
      snapped_.resize(positions_.size());
      for (std::size_t v = 0; v < positions_.size(); ++v) snapped_[v] = options_.grid->frame_point(positions_[v]);
    }
  }

  // A triangle's smallest angle as its reader sees it; -1 when degenerate on the output grid (worst of all).
  double shown_quality(std::uint32_t t) const { return quality(tris_[t]); }

  bool bad(const Triangle& t) const {
    if (t[0] == kDead) return false;
    if (options_.grid && collinear_on_grid(snapped_[t[0]], snapped_[t[1]], snapped_[t[2]])) return true;  // quality -1
    return !clearly_good(t) && min_angle_degrees(shown(t[0]), shown(t[1]), shown(t[2])) < options_.min_angle_degrees;
  }

  // Repairs triangle t if it is still bad: of the flips of its three edges and the collapses of each edge onto
  // either end, the valid move whose new triangles are best, when they are better than what it replaces. A move
  // blocked only by the valence floor is tried after one flip elsewhere gives the blocking vertex a neighbour more.
  // Records the triangles it changed.
  bool repair(std::uint32_t t, std::vector<std::uint32_t>& changed) {
    if (!bad(tris_[t])) return false;
    if (!editor_) {  // built at the first bad triangle only
      adjacency_ = vertex_triangles(positions_.size(), tris_);
      editor_.emplace(tris_, adjacency_, positions_.size());
    }
    undo_.clear();
    std::vector<Move> moves = candidates(t);
    for (const Move& m : moves) {
      if (m.blocked[0] == kDead && allowed(t, m)) return apply(t, m, changed);
    }
    for (const Move& m : moves) {
      if (!allowed(t, m)) continue;
      const std::size_t mark = undo_.size();
      bool raised = true;
      for (const std::uint32_t v : m.blocked) {
        if (v != kDead && !may_lose(v)) raised = raised && raise_valence(v, t, changed);
      }
      // The flips changed the neighbourhood: evaluate the same move again.
      const std::optional<Move> again = !raised                       ? std::nullopt
                                        : m.kind == Move::Kind::kFlip ? evaluate_flip(t, m.edge)
                                                                      : evaluate_collapse(t, m.edge, m.keep_first);
      if (again && again->blocked[0] == kDead && again->after > again->before && allowed(t, *again)) {
        return apply(t, *again, changed);
      }
      roll_back(mark);  // the raising flips served nothing: the mesh stays as it was
    }
    return options_.place && relocate(t, changed);
  }

 private:
  // Whether the smallest angle is well above min_angle_degrees, without an arctangent: at every corner, |u x v| >
  // tan(min angle) (u . v) with a margin far above rounding (the smallest angle is below 60 degrees, so at its corner
  // u . v > 0); the exact test decides the rest.
  bool clearly_good(const Triangle& t) const {
    const Vec3 a = shown(t[0]), b = shown(t[1]), c = shown(t[2]);
    const Vec3 ab = b - a, ac = c - a, bc = c - b;
    const double cross = ab.cross(ac).norm();
    const double bound = tan_min_angle_ * (1.0 + 1e-9);
    return cross > bound * ab.dot(ac) && cross > -bound * ab.dot(bc) && cross > bound * ac.dot(bc);
  }

  // A triangle's smallest angle in degrees, as its reader sees it (on the output grid when there is one); -1 when it
  // is degenerate on the output grid.
  double quality(const Triangle& t) const {
    if (options_.grid && collinear_on_grid(snapped_[t[0]], snapped_[t[1]], snapped_[t[2]])) return -1.0;
    return min_angle_degrees(shown(t[0]), shown(t[1]), shown(t[2]));
  }
  // Where a reader of the output finds vertex v: its grid point as Draco's decoder gives it when there is an output
  // grid (the angles a frame shows are those of its grid points), else v itself.
  Vec3 shown(std::uint32_t v) const { return options_.grid ? options_.grid->dequantize(snapped_[v]) : positions_[v]; }
  Vec3 normal(const Triangle& t) const {
    return (positions_[t[1]] - positions_[t[0]]).cross(positions_[t[2]] - positions_[t[0]]);
  }
  std::size_t valence(std::uint32_t v) const { return edit().triangle_count(v); }
  // A vertex may lose one neighbour when it stays at or above the floor, or was below it already.
  bool may_lose(std::uint32_t v) const {
    const std::size_t val = valence(v);
    return val < static_cast<std::size_t>(options_.min_valence) ||
           val - 1 >= static_cast<std::size_t>(options_.min_valence);
  }
  // The other triangle of directed edge (a, b) of triangle t (the one holding b -> a), or kDead when there is none
  // or the edge is not manifold.
  std::uint32_t across(std::uint32_t t, std::uint32_t a, std::uint32_t b) const {
    const std::optional<MeshEditor::Across> site = edit().across(t, a, b);
    return site ? site->triangle : kDead;
  }
  std::vector<std::uint32_t> neighbours(std::uint32_t v) const { return edit().neighbours(v); }
  std::vector<std::uint32_t> around(std::uint32_t v) const { return edit().triangles_around(v); }

  // Every valid move for t, improving ones only, best first (ties in a fixed order: deterministic).
  std::vector<Move> candidates(std::uint32_t t) const {
    std::vector<Move> moves;
    for (int k = 0; k < 3; ++k) {
      if (const std::optional<Move> m = evaluate_flip(t, k)) moves.push_back(*m);
      for (const bool keep_first : {true, false}) {
        if (const std::optional<Move> m = evaluate_collapse(t, k, keep_first)) moves.push_back(*m);
      }
    }
    std::erase_if(moves, [](const Move& m) { return !(m.after > m.before); });
    // First the moves that leave no bad triangle, flips before collapses (a flip keeps every vertex); then by quality.
    auto rank = [&](const Move& m) {
      const bool good = m.after >= options_.min_angle_degrees;
      return std::tuple(good, good && m.kind == Move::Kind::kFlip, m.after);
    };
    std::stable_sort(moves.begin(), moves.end(), [&](const Move& a, const Move& b) { return rank(a) > rank(b); });
    return moves;
  }

  // Flip edge k = (u, v) of t = (u, v, x) with t2 = (v, u, y): (u, y, x) and (y, v, x), when edge x-y does not exist
  // yet and both new triangles turn the way the old pair did (the quad is convex seen along its normal).
  std::optional<Move> evaluate_flip(std::uint32_t t, int k) const {
    const Triangle& tri = tris_[t];
    const std::uint32_t u = tri[k], v = tri[(k + 1) % 3], x = tri[(k + 2) % 3];
    const std::optional<MeshEditor::Across> site = edit().across(t, u, v);
    if (!site || site->vertex == x) return std::nullopt;
    const Triangle& other = tris_[site->triangle];
    const std::uint32_t y = site->vertex;
    const Triangle n1{u, y, x}, n2{y, v, x};
    const Vec3 before = normal(tri) + normal(other);
    if (!(normal(n1).dot(before) > 0.0) || !(normal(n2).dot(before) > 0.0)) return std::nullopt;
    const std::vector<std::uint32_t> nx = neighbours(x);  // (x, y) must be new; the editor decides in allowed()
    if (std::binary_search(nx.begin(), nx.end(), y)) return std::nullopt;
    Move m;
    m.kind = Move::Kind::kFlip;
    m.edge = k;
    m.before = std::min(quality(tri), quality(other));
    m.after = std::min(quality(n1), quality(n2));
    int b = 0;
    for (const std::uint32_t w : {u, v}) {
      if (!may_lose(w)) m.blocked[b++] = w;
    }
    return m;
  }

  // Collapse edge k = (a, b) of t = (a, b, c), with t2 = (b, a, d), onto `keep`: when a and b share exactly the
  // neighbours c and d (the link condition: the mesh stays manifold), no triangle around the removed vertex turns
  // over and the merged vertex keeps the valence floor.
  std::optional<Move> evaluate_collapse(std::uint32_t t, int k, bool keep_first) const {
    const Triangle& tri = tris_[t];
    const std::uint32_t a = tri[k], b = tri[(k + 1) % 3], c = tri[(k + 2) % 3];
    const std::uint32_t keep = keep_first ? a : b, gone = keep_first ? b : a;
    const std::optional<MeshEditor::Across> site = edit().across(t, a, b);
    if (!site || site->vertex == c) return std::nullopt;
    const std::uint32_t t2 = site->triangle, d = site->vertex;
    const std::vector<std::uint32_t> na = neighbours(a), nb = neighbours(b);
    // The link condition from the rings at hand; the editor decides in allowed().
    std::vector<std::uint32_t> common;
    std::set_intersection(na.begin(), na.end(), nb.begin(), nb.end(), std::back_inserter(common));
    if (common.size() != 2) return std::nullopt;
    const std::size_t merged = na.size() + nb.size() - 4, floor = static_cast<std::size_t>(options_.min_valence);
    if (merged < floor && std::max(na.size(), nb.size()) >= floor) return std::nullopt;
    Move m;
    m.kind = Move::Kind::kCollapse;
    m.edge = k;
    m.keep_first = keep_first;
    m.before = std::min(quality(tri), quality(tris_[t2]));
    m.after = std::numeric_limits<double>::infinity();
    for (const std::uint32_t s : around(gone)) {
      if (s == t || s == t2) continue;
      Triangle moved = tris_[s];
      for (std::uint32_t& w : moved) {
        if (w == gone) w = keep;
      }
      if (!(normal(moved).dot(normal(tris_[s])) > 0.0)) return std::nullopt;
      m.before = std::min(m.before, quality(tris_[s]));
      m.after = std::min(m.after, quality(moved));
    }
    int blocked = 0;
    for (const std::uint32_t w : {c, d}) {
      if (!may_lose(w)) m.blocked[blocked++] = w;
    }
    return m;
  }

  // Whether the editor allows the move (is_flip_ok, is_collapse_ok), asked only of a move about to be taken or
  // raised for: it loads the neighbourhood into the TriMesh, which costs far more than the evaluation.
  bool allowed(std::uint32_t t, const Move& m) const {
    const Triangle& tri = tris_[t];
    const std::uint32_t a = tri[m.edge], b = tri[(m.edge + 1) % 3];
    if (m.kind == Move::Kind::kFlip) return edit().flip_site(t, a, b).has_value();
    return edit().collapse_site(t, m.keep_first ? a : b, m.keep_first ? b : a).has_value();
  }

  bool apply(std::uint32_t t, const Move& m, std::vector<std::uint32_t>& changed) {
    if (m.kind == Move::Kind::kFlip) {
      apply_flip(t, m.edge, changed);
    } else {
      apply_collapse(t, m.edge, m.keep_first, changed);
    }
    return true;
  }

  void apply_flip(std::uint32_t t, int k, std::vector<std::uint32_t>& changed) {
    const Triangle tri = tris_[t];
    const std::uint32_t u = tri[k], v = tri[(k + 1) % 3];
    const std::uint32_t t2 = across(t, u, v);
    undo_.push_back({t, t2, tris_[t], tris_[t2]});
    edit().flip(t, u, v);
    changed.push_back(t);
    changed.push_back(t2);
    ++flips_;
  }

  // Undoes the flips recorded after `mark`, newest first.
  void roll_back(std::size_t mark) {
    while (undo_.size() > mark) {
      const FlipRecord r = undo_.back();
      undo_.pop_back();
      edit().undo_flip(r.t, r.t2, r.old_t, r.old_t2);
      --flips_;
    }
  }

  void apply_collapse(std::uint32_t t, int k, bool keep_first, std::vector<std::uint32_t>& changed) {
    const Triangle tri = tris_[t];
    const std::uint32_t a = tri[k], b = tri[(k + 1) % 3];
    const std::uint32_t keep = keep_first ? a : b, gone = keep_first ? b : a;
    const std::uint32_t t2 = across(t, a, b);
    for (const std::uint32_t s : around(gone)) {
      if (s != t && s != t2) changed.push_back(s);
    }
    edit().collapse(t, keep, gone);
    dead_vertices_.push_back(gone);
    ++collapses_;
  }

  // Vertex v at p, and its grid point.
  void put(std::uint32_t v, const Vec3& p) {
    positions_[v] = p;
    if (options_.grid) snapped_[v] = options_.grid->frame_point(p);
  }

  // How good a vertex's triangles are, for relocate(): fewer degenerate on the grid first, then a larger smallest
  // angle among the others, then fewer below the angle threshold. The smallest angle comes before the count: a move
  // that takes two triangles above a threshold of 10 degrees may not leave a third at 0.3.
  struct Score {
    int degenerate = 0, bad = 0;
    double worst = std::numeric_limits<double>::infinity();
    bool better_than(const Score& o) const {
      if (degenerate != o.degenerate) return degenerate < o.degenerate;
      if (worst != o.worst) return worst > o.worst;
      return bad < o.bad;
    }
  };
  Score score(std::span<const std::uint32_t> triangles) const {
    Score s;
    for (const std::uint32_t t : triangles) {
      const double q = quality(tris_[t]);
      if (q < 0.0) {
        ++s.degenerate;
        continue;
      }
      s.bad += q < options_.min_angle_degrees ? 1 : 0;
      s.worst = std::min(s.worst, q);
    }
    return s;
  }

  // Moves the vertex of t whose move leaves its triangles best (Score), when that is better than now. Each vertex is
  // proposed at two centroids of its neighbours, projected on its tangent plane (the plane of its area-weighted
  // normal): the plain one, and one weighted by the length of the edge to each neighbour, which a knot of
  // near-coincident vertices does not hold back. Each proposal is placed by options_.place and refused when it turns
  // one of the vertex's triangles away from that normal (a triangle that faced away already may stay so).
  bool relocate(std::uint32_t t, std::vector<std::uint32_t>& changed) {
    std::uint32_t best_vertex = kDead;
    Vec3 best_position = Vec3::Zero();
    std::optional<Score> best;
    for (const std::uint32_t v : tris_[t]) {
      const std::vector<std::uint32_t> fan = around(v);
      Vec3 normal_sum = Vec3::Zero();
      for (const std::uint32_t s : fan) normal_sum += normal(tris_[s]);
      const std::vector<std::uint32_t> ring = neighbours(v);
      if (ring.empty() || !(normal_sum.squaredNorm() > 0.0)) continue;
      const Vec3 n = normal_sum.normalized();
      const Score before = score(fan);
      std::vector<char> facing(fan.size());
      for (std::size_t i = 0; i < fan.size(); ++i) facing[i] = normal(tris_[fan[i]]).dot(n) > 0.0;
      Vec3 plain = Vec3::Zero(), weighted = Vec3::Zero();
      double length = 0.0;
      for (const std::uint32_t w : ring) {
        const double l = (positions_[w] - positions_[v]).norm();
        plain += positions_[w];
        weighted += l * positions_[w];
        length += l;
      }
      plain /= static_cast<double>(ring.size());
      const Vec3 old = positions_[v];
      for (const Vec3& centroid : {plain, length > 0.0 ? Vec3(weighted / length) : plain}) {
        Vec3 proposal = centroid - (centroid - old).dot(n) * n;
        if (!options_.place(v, proposal, n)) continue;
        put(v, proposal);
        bool turned = false;
        for (std::size_t i = 0; i < fan.size(); ++i) {
          turned = turned || (facing[i] && !(normal(tris_[fan[i]]).dot(n) > 0.0));
        }
        const Score after = score(fan);
        put(v, old);
        if (!turned && after.better_than(before) && (!best || after.better_than(*best))) {
          best_vertex = v;
          best_position = proposal;
          best = after;
        }
      }
    }
    if (best_vertex == kDead) return false;
    put(best_vertex, best_position);
    for (const std::uint32_t s : around(best_vertex)) changed.push_back(s);
    ++moves_;
    return true;
  }

  // One flip that gives v a neighbour more: an edge of v's link (opposite v in one of its triangles, neither triangle
  // being t or across an edge of t) turned towards v, when it makes no bad triangle. When that flip would take one of
  // its ends below the floor, that end is raised first the same way, `depth` levels deep.
  bool raise_valence(std::uint32_t v, std::uint32_t t, std::vector<std::uint32_t>& changed, int depth = 2) {
    std::array<std::uint32_t, 4> near{t, kDead, kDead, kDead};
    for (int k = 0; k < 3; ++k) near[k + 1] = across(t, tris_[t][k], tris_[t][(k + 1) % 3]);
    auto is_near = [&](std::uint32_t s) { return std::find(near.begin(), near.end(), s) != near.end(); };
    // v's link edges as (p, q): rebuilt from the adjacency on every attempt, since raising an end changes it.
    auto opposite = [&](std::uint32_t s, std::uint32_t& p, std::uint32_t& q) {
      const Triangle& tri = tris_[s];
      const int k = tri[0] == v ? 1 : tri[1] == v ? 2 : 0;  // edge (tri[k], tri[k+1]) is opposite v
      p = tri[k];
      q = tri[(k + 1) % 3];
      return k;
    };
    for (const std::uint32_t s : around(v)) {
      if (is_near(s)) continue;
      std::uint32_t p = kDead, q = kDead;
      const int k = opposite(s, p, q);
      const std::uint32_t other = across(s, p, q);
      if (other == kDead || is_near(other)) continue;
      std::optional<Move> m = evaluate_flip(s, k);
      if (!m || !(m->after >= options_.min_angle_degrees) || !allowed(s, *m)) continue;
      if (m->blocked[0] != kDead) {
        if (depth == 0) continue;
        bool raised = true;
        for (const std::uint32_t w : m->blocked) {
          if (w != kDead && w != v && !may_lose(w)) raised = raised && raise_valence(w, t, changed, depth - 1);
        }
        // The raises may have changed this triangle: it must still hold v opposite the same edge.
        if (!raised || tris_[s][0] == kDead || std::find(tris_[s].begin(), tris_[s].end(), v) == tris_[s].end()) {
          continue;
        }
        std::uint32_t p2 = kDead, q2 = kDead;
        const int k2 = opposite(s, p2, q2);
        if (p2 != p || q2 != q) continue;
        m = evaluate_flip(s, k2);
        if (!m || m->blocked[0] != kDead || !(m->after >= options_.min_angle_degrees) || !allowed(s, *m)) continue;
      }
      apply_flip(s, k, changed);
      return true;
    }
    return false;
  }

 public:
  // Removes the collapsed vertices and triangles (the others keep their order).
  void compact() {
    if (dead_vertices_.empty()) return;
    std::vector<std::uint32_t> remap(positions_.size(), 0);
    for (const std::uint32_t v : dead_vertices_) remap[v] = kDead;
    std::uint32_t next = 0;
    for (std::size_t v = 0; v < positions_.size(); ++v) {
      if (remap[v] == kDead) continue;
      positions_[next] = positions_[v];
      if (!mesh_.normals.empty()) mesh_.normals[next] = mesh_.normals[v];
      remap[v] = next++;
    }
    positions_.resize(next);
    if (!mesh_.normals.empty()) mesh_.normals.resize(next);
    std::size_t kept = 0;
    for (const Triangle& t : tris_) {
      if (t[0] == kDead) continue;
      tris_[kept++] = Triangle{remap[t[0]], remap[t[1]], remap[t[2]]};
    }
    tris_.resize(kept);
  }

  std::int64_t flips_ = 0, collapses_ = 0, moves_ = 0;

 private:
  Mesh& mesh_;
  std::vector<Vec3>& positions_;
  std::vector<Triangle>& tris_;
  const SliverOptions& options_;
  const double tan_min_angle_ = std::tan(options_.min_angle_degrees * kPi / 180.0);
  VertexTriangles adjacency_;                 // of the triangles on entry, for the editor
  mutable std::optional<MeshEditor> editor_;  // its queries load neighbourhoods: logically const
  MeshEditor& edit() const { return *editor_; }
  std::vector<GridPoint> snapped_;
  std::vector<std::uint32_t> dead_vertices_;
  struct FlipRecord {
    std::uint32_t t, t2;
    Triangle old_t, old_t2;
  };
  std::vector<FlipRecord> undo_;  // flips made to raise a valence, until the move they serve is applied
};

}  // namespace

double min_angle_degrees(const Vec3& a, const Vec3& b, const Vec3& c) {
  const std::array<Vec3, 3> p{a, b, c};
  std::array<double, 3> opposite;  // squared length of the edge opposite corner k
  for (int k = 0; k < 3; ++k) opposite[k] = (p[(k + 2) % 3] - p[(k + 1) % 3]).squaredNorm();
  const int k = static_cast<int>(std::min_element(opposite.begin(), opposite.end()) - opposite.begin());
  const Vec3 u = p[(k + 1) % 3] - p[k], v = p[(k + 2) % 3] - p[k];
  const double cross = u.cross(v).norm();
  if (!(cross > 0.0)) return 0.0;
  return std::atan2(cross, u.dot(v)) * 180.0 / kPi;
}

SliverReport repair_slivers(Mesh& mesh, const SliverOptions& options, const RunControl& control) {
  SliverReport report;
  Repair repair(mesh, options);
  // The first pass scans every triangle (in parallel chunks); later passes only what the previous one changed.
  std::vector<std::uint32_t> candidates;
  {
    const std::size_t n = mesh.triangles.size();
    const int chunks = static_cast<int>(std::min<std::size_t>(64, n / 16384 + 1));
    std::vector<std::vector<std::uint32_t>> found(static_cast<std::size_t>(chunks));
    parallel_for(chunks, resolve_threads(options.threads), [&](int c) {
      const auto [begin, end] = chunk_range(n, chunks, c);
      for (std::size_t t = begin; t < end; ++t) {
        if (repair.bad(mesh.triangles[t])) found[static_cast<std::size_t>(c)].push_back(static_cast<std::uint32_t>(t));
      }
    });
    for (const auto& f : found) candidates.insert(candidates.end(), f.begin(), f.end());
  }
  report.candidates = static_cast<std::int64_t>(candidates.size());
  std::vector<std::uint32_t> still_bad;
  std::vector<std::pair<double, std::uint32_t>> order;
  for (int pass = 0; pass < options.max_passes && !candidates.empty(); ++pass) {
    control.check();
    // Worst first: a move near a triangle can leave it with no move of its own, so the smallest angles choose first.
    // A triangle found bad may have gone since (collapsed by a later repair of the pass that found it).
    order.clear();
    for (const std::uint32_t t : candidates) {
      if (repair.bad(mesh.triangles[t])) order.emplace_back(repair.shown_quality(t), t);
    }
    std::sort(order.begin(), order.end());
    candidates.resize(order.size());
    for (std::size_t i = 0; i < order.size(); ++i) candidates[i] = order[i].second;
    std::vector<std::uint32_t> changed;
    still_bad.clear();
    bool progress = false;
    for (const std::uint32_t t : candidates) {
      if (repair.repair(t, changed)) {
        progress = true;
      } else if (repair.bad(mesh.triangles[t])) {
        still_bad.push_back(t);
      }
    }
    candidates = still_bad;
    for (const std::uint32_t t : changed) {
      if (repair.bad(mesh.triangles[t])) candidates.push_back(t);
    }
    std::sort(candidates.begin(), candidates.end());
    candidates.erase(std::unique(candidates.begin(), candidates.end()), candidates.end());
    if (!progress) break;
  }
  report.remaining = 0;
  for (const std::uint32_t t : candidates) report.remaining += repair.bad(mesh.triangles[t]);
  report.flips = repair.flips_;
  report.collapses = repair.collapses_;
  report.moves = repair.moves_;
  repair.compact();
  return report;
}

}  // namespace surfacer
