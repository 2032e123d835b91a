#include "core/mesh/mesh_repair.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <span>
#include <unordered_map>
#include <vector>

#include "core/util/parallel.h"

namespace surfacer {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr std::uint32_t kDead = std::numeric_limits<std::uint32_t>::max();
using GridPoint = std::array<std::uint32_t, 3>;

// Collinear (or repeated) grid points, exactly: coordinates below 2^30, so the cross product fits in 64 bits.
bool degenerate(const GridPoint& a, const GridPoint& b, const GridPoint& c) {
  std::array<std::int64_t, 3> u, v;
  for (int k = 0; k < 3; ++k) {
    u[k] = static_cast<std::int64_t>(b[k]) - static_cast<std::int64_t>(a[k]);
    v[k] = static_cast<std::int64_t>(c[k]) - static_cast<std::int64_t>(a[k]);
  }
  return u[1] * v[2] == u[2] * v[1] && u[2] * v[0] == u[0] * v[2] && u[0] * v[1] == u[1] * v[0];
}

// The vertex -> triangles adjacency: compressed rows built once, and the lists of the vertices a repair changed.
class Adjacency {
 public:
  Adjacency(std::size_t vertices, const std::vector<Triangle>& triangles) : offsets_(vertices + 1, 0) {
    for (const Triangle& t : triangles) {
      for (const std::uint32_t v : t) ++offsets_[v + 1];
    }
    for (std::size_t v = 0; v < vertices; ++v) offsets_[v + 1] += offsets_[v];
    list_.resize(offsets_[vertices]);
    std::vector<std::uint32_t> fill(offsets_.begin(), offsets_.end() - 1);
    for (std::size_t t = 0; t < triangles.size(); ++t) {
      for (const std::uint32_t v : triangles[t]) list_[fill[v]++] = static_cast<std::uint32_t>(t);
    }
  }

  // Valid until the next change of v's list.
  std::span<const std::uint32_t> of(std::uint32_t v) const {
    const auto it = changed_.find(v);
    if (it != changed_.end()) return it->second;
    return std::span<const std::uint32_t>(list_).subspan(offsets_[v], offsets_[v + 1] - offsets_[v]);
  }
  void add(std::uint32_t v, std::uint32_t t) {
    std::vector<std::uint32_t>& l = editable(v);
    l.push_back(t);
  }
  void remove(std::uint32_t v, std::uint32_t t) {
    std::vector<std::uint32_t>& l = editable(v);
    l.erase(std::remove(l.begin(), l.end(), t), l.end());
  }
  void set(std::uint32_t v, std::vector<std::uint32_t> l) { changed_[v] = std::move(l); }

 private:
  std::vector<std::uint32_t>& editable(std::uint32_t v) {
    const auto it = changed_.find(v);
    if (it != changed_.end()) return it->second;
    const std::span<const std::uint32_t> base = of(v);
    return changed_.emplace(v, std::vector<std::uint32_t>(base.begin(), base.end())).first->second;
  }

  std::vector<std::uint32_t> offsets_, list_;
  std::unordered_map<std::uint32_t, std::vector<std::uint32_t>> changed_;
};

class Repair {
 public:
  Repair(Mesh& mesh, const SliverOptions& options)
      : mesh_(mesh), x_(mesh.vertices), tris_(mesh.triangles), o_(options), adj_(x_.size(), tris_) {
    if (o_.grid) {
      snapped_.resize(x_.size());
      for (std::size_t v = 0; v < x_.size(); ++v) snapped_[v] = o_.grid->quantize(x_[v]);
    }
  }

  bool bad(const Triangle& t) const {
    if (t[0] == kDead) return false;
    if (min_angle_degrees(x_[t[0]], x_[t[1]], x_[t[2]]) < o_.min_angle_degrees) return true;
    return o_.grid && degenerate(snapped_[t[0]], snapped_[t[1]], snapped_[t[2]]);
  }

  // Repairs triangle t if it is still bad and some repair is allowed; records the triangles it changed.
  bool repair(std::uint32_t t, std::vector<std::uint32_t>& changed) {
    const Triangle tri = tris_[t];
    if (!bad(tri)) return false;
    // Angles: the largest is opposite the longest edge, the smallest opposite the shortest.
    std::array<double, 3> len2;  // edge k = (tri[k], tri[k+1])
    for (int k = 0; k < 3; ++k) len2[k] = (x_[tri[(k + 1) % 3]] - x_[tri[k]]).squaredNorm();
    const int longest = static_cast<int>(std::max_element(len2.begin(), len2.end()) - len2.begin());
    const int shortest = static_cast<int>(std::min_element(len2.begin(), len2.end()) - len2.begin());
    const std::uint32_t x = tri[(longest + 2) % 3];
    const Vec3 xa = x_[tri[longest]] - x_[x], xb = x_[tri[(longest + 1) % 3]] - x_[x];
    const bool cap = xa.dot(xb) <= 0.0;  // the angle at x is at least 90 degrees
    if (cap && flip(t, longest, changed)) return true;
    return collapse(t, shortest, changed) || (!cap && flip(t, longest, changed));
  }

 private:
  double tri_min_angle(const Triangle& t) const { return min_angle_degrees(x_[t[0]], x_[t[1]], x_[t[2]]); }
  Vec3 normal(const Triangle& t) const { return (x_[t[1]] - x_[t[0]]).cross(x_[t[2]] - x_[t[0]]); }
  bool snapped_degenerate(const Triangle& t) const {
    return o_.grid && degenerate(snapped_[t[0]], snapped_[t[1]], snapped_[t[2]]);
  }
  std::size_t valence(std::uint32_t v) const { return adj_.of(v).size(); }
  // A vertex may lose one neighbour when it stays at or above the floor, or was below it already.
  bool may_lose(std::uint32_t v) const {
    const std::size_t val = valence(v);
    return val < static_cast<std::size_t>(o_.min_valence) || val - 1 >= static_cast<std::size_t>(o_.min_valence);
  }
  // The other triangle of directed edge (a, b) of triangle t (the one holding b -> a), or kDead.
  std::uint32_t across(std::uint32_t t, std::uint32_t a, std::uint32_t b) const {
    std::uint32_t found = kDead;
    int count = 0;
    for (const std::uint32_t s : adj_.of(a)) {
      if (s == t) continue;
      const Triangle& q = tris_[s];
      for (int k = 0; k < 3; ++k) {
        if (q[k] == b && q[(k + 1) % 3] == a) {
          found = s;
          ++count;
        }
      }
      for (int k = 0; k < 3; ++k) {
        if (q[k] == a && q[(k + 1) % 3] == b) ++count;  // a second triangle along a -> b: not manifold here
      }
    }
    return count == 1 ? found : kDead;
  }
  bool has_edge(std::uint32_t a, std::uint32_t b) const {
    for (const std::uint32_t s : adj_.of(a)) {
      const Triangle& q = tris_[s];
      if (q[0] == b || q[1] == b || q[2] == b) return true;
    }
    return false;
  }

  // Flip edge k = (tri[k], tri[k+1]) of t. must_improve: the new pair's smallest angle exceeds the old pair's;
  // otherwise (a flip that makes room for a collapse) neither new triangle may be bad.
  bool flip(std::uint32_t t, int k, std::vector<std::uint32_t>& changed, bool must_improve = true) {
    const Triangle tri = tris_[t];
    const std::uint32_t u = tri[k], v = tri[(k + 1) % 3], x = tri[(k + 2) % 3];
    const std::uint32_t t2 = across(t, u, v);
    if (t2 == kDead) return false;
    const Triangle other = tris_[t2];
    std::uint32_t y = kDead;
    for (const std::uint32_t w : other) {
      if (w != u && w != v) y = w;
    }
    if (y == kDead || y == x || has_edge(x, y)) return false;
    // At the valence floor, an end of the edge may first gain a neighbour elsewhere (not when this flip is itself
    // making room: one level deep).
    if (!may_lose(u) && !(must_improve && raise_valence(u, t, t2, changed))) return false;
    if (!may_lose(v) && !(must_improve && raise_valence(v, t, t2, changed))) return false;
    const Triangle n1{u, y, x}, n2{y, v, x};
    const Vec3 before = normal(tri) + normal(other);
    if (!(normal(n1).dot(before) > 0.0) || !(normal(n2).dot(before) > 0.0)) return false;
    if (snapped_degenerate(n1) || snapped_degenerate(n2)) return false;
    const double new_angle = std::min(tri_min_angle(n1), tri_min_angle(n2));
    if (must_improve ? !(new_angle > std::min(tri_min_angle(tri), tri_min_angle(other)))
                     : !(new_angle >= o_.min_angle_degrees)) {
      return false;
    }
    tris_[t] = n1;
    tris_[t2] = n2;
    adj_.remove(u, t2);
    adj_.remove(v, t);
    adj_.add(x, t2);
    adj_.add(y, t);
    changed.push_back(t);
    changed.push_back(t2);
    ++flips_;
    return true;
  }

  // One flip that gives v a neighbour more: an edge of v's link (opposite v in one of its triangles, neither
  // triangle being t or t2) turned towards v, when no bad triangle results.
  bool raise_valence(std::uint32_t v, std::uint32_t t, std::uint32_t t2, std::vector<std::uint32_t>& changed) {
    const std::span<const std::uint32_t> around = adj_.of(v);
    const std::vector<std::uint32_t> triangles(around.begin(), around.end());
    for (const std::uint32_t s : triangles) {
      if (s == t || s == t2) continue;
      const Triangle& tri = tris_[s];
      const int k = tri[0] == v ? 1 : tri[1] == v ? 2 : 0;  // edge (tri[k], tri[k+1]) is opposite v
      const std::uint32_t other = across(s, tri[k], tri[(k + 1) % 3]);
      if (other == kDead || other == t || other == t2) continue;
      if (flip(s, k, changed, false)) return true;
    }
    return false;
  }

  // Collapse edge k = (tri[k], tri[k+1]) of t onto one of its ends.
  bool collapse(std::uint32_t t, int k, std::vector<std::uint32_t>& changed) {
    const Triangle tri = tris_[t];
    const std::uint32_t a = tri[k], b = tri[(k + 1) % 3], c = tri[(k + 2) % 3];
    const std::uint32_t t2 = across(t, a, b);
    if (t2 == kDead) return false;
    std::uint32_t d = kDead;
    for (const std::uint32_t w : tris_[t2]) {
      if (w != a && w != b) d = w;
    }
    if (d == kDead || d == c) return false;
    // Link condition: a and b share exactly the neighbours c and d.
    auto neighbours = [&](std::uint32_t v) {
      std::vector<std::uint32_t> out;
      for (const std::uint32_t s : adj_.of(v)) {
        for (const std::uint32_t w : tris_[s]) {
          if (w != v) out.push_back(w);
        }
      }
      std::sort(out.begin(), out.end());
      out.erase(std::unique(out.begin(), out.end()), out.end());
      return out;
    };
    const std::vector<std::uint32_t> na = neighbours(a), nb = neighbours(b);
    std::vector<std::uint32_t> common;
    std::set_intersection(na.begin(), na.end(), nb.begin(), nb.end(), std::back_inserter(common));
    if (common.size() != 2) return false;
    if (!may_lose(c) && !raise_valence(c, t, t2, changed)) return false;
    if (!may_lose(d) && !raise_valence(d, t, t2, changed)) return false;
    const double needle = std::min(tri_min_angle(tri), tri_min_angle(tris_[t2]));
    for (const auto& [keep, gone] : {std::pair{a, b}, std::pair{b, a}}) {
      // The merged vertex has the neighbours of both minus the shared two and each other.
      const std::size_t merged = na.size() + nb.size() - 4;
      if (merged < static_cast<std::size_t>(o_.min_valence) &&
          std::max(na.size(), nb.size()) >= static_cast<std::size_t>(o_.min_valence)) {
        return false;
      }
      bool ok = true;
      for (const std::uint32_t s : adj_.of(gone)) {
        if (s == t || s == t2) continue;
        Triangle moved = tris_[s];
        for (std::uint32_t& w : moved) {
          if (w == gone) w = keep;
        }
        const double old_angle = tri_min_angle(tris_[s]);
        if (!(normal(moved).dot(normal(tris_[s])) > 0.0) || snapped_degenerate(moved) ||
            tri_min_angle(moved) < std::min(old_angle, std::max(needle, o_.min_angle_degrees))) {
          ok = false;
          break;
        }
      }
      if (!ok) continue;
      const std::span<const std::uint32_t> keep_now = adj_.of(keep);
      std::vector<std::uint32_t> keep_list(keep_now.begin(), keep_now.end());
      keep_list.erase(std::remove_if(keep_list.begin(), keep_list.end(),
                                     [&](std::uint32_t s) { return s == t || s == t2; }),
                      keep_list.end());
      for (const std::uint32_t s : adj_.of(gone)) {
        if (s == t || s == t2) continue;
        for (std::uint32_t& w : tris_[s]) {
          if (w == gone) w = keep;
        }
        keep_list.push_back(s);
        changed.push_back(s);
      }
      adj_.set(keep, std::move(keep_list));
      adj_.set(gone, {});
      adj_.remove(c, t);
      adj_.remove(d, t2);
      tris_[t] = Triangle{kDead, kDead, kDead};
      tris_[t2] = Triangle{kDead, kDead, kDead};
      dead_vertices_.push_back(gone);
      ++collapses_;
      return true;
    }
    return false;
  }

 public:
  // Removes the collapsed vertices and triangles (the others keep their order).
  void compact() {
    if (dead_vertices_.empty()) return;
    std::vector<std::uint32_t> remap(x_.size(), 0);
    for (const std::uint32_t v : dead_vertices_) remap[v] = kDead;
    std::uint32_t next = 0;
    for (std::size_t v = 0; v < x_.size(); ++v) {
      if (remap[v] == kDead) continue;
      x_[next] = x_[v];
      if (!mesh_.normals.empty()) mesh_.normals[next] = mesh_.normals[v];
      remap[v] = next++;
    }
    x_.resize(next);
    if (!mesh_.normals.empty()) mesh_.normals.resize(next);
    std::size_t kept = 0;
    for (const Triangle& t : tris_) {
      if (t[0] == kDead) continue;
      tris_[kept++] = Triangle{remap[t[0]], remap[t[1]], remap[t[2]]};
    }
    tris_.resize(kept);
  }

  std::int64_t flips_ = 0, collapses_ = 0;

 private:
  Mesh& mesh_;
  std::vector<Vec3>& x_;
  std::vector<Triangle>& tris_;
  const SliverOptions& o_;
  Adjacency adj_;
  std::vector<GridPoint> snapped_;
  std::vector<std::uint32_t> dead_vertices_;
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
      const std::size_t begin = n * static_cast<std::size_t>(c) / static_cast<std::size_t>(chunks);
      const std::size_t end = n * static_cast<std::size_t>(c + 1) / static_cast<std::size_t>(chunks);
      for (std::size_t t = begin; t < end; ++t) {
        if (repair.bad(mesh.triangles[t])) found[static_cast<std::size_t>(c)].push_back(static_cast<std::uint32_t>(t));
      }
    });
    for (const auto& f : found) candidates.insert(candidates.end(), f.begin(), f.end());
  }
  report.candidates = static_cast<std::int64_t>(candidates.size());
  std::vector<std::uint32_t> still_bad;
  for (int pass = 0; pass < options.max_passes && !candidates.empty(); ++pass) {
    control.check();
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
  repair.compact();
  return report;
}

}  // namespace surfacer
