// Cap flips and needle collapses (core/mesh_optimizer_cleanup.h). Sequential: the changes are few and local, and
// each one changes what its neighbours see.
#include "core/mesh_optimizer_cleanup.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <unordered_map>

#include "core/scene.h"

namespace surfacer::optimizer_detail {
namespace {

constexpr std::int32_t kNone = -1;
constexpr std::int32_t kMany = -2;  // the edge has more than two triangles

std::uint64_t edge_key(std::uint32_t a, std::uint32_t b) {
  if (a > b) std::swap(a, b);
  return (static_cast<std::uint64_t>(a) << 32) | b;
}

// Cosine of the largest angle of triangle (a, b, c) and the corner (0..2) it sits at; 1 for coincident corners.
double largest_angle_cos(const Vec3& a, const Vec3& b, const Vec3& c, int& corner) {
  const std::array<Vec3, 3> p{a, b, c};
  double best = 2.0;
  corner = 0;
  for (int k = 0; k < 3; ++k) {
    const Vec3 u = p[(k + 1) % 3] - p[k];
    const Vec3 w = p[(k + 2) % 3] - p[k];
    const double den = u.norm() * w.norm();
    const double cos_k = den > 0.0 ? u.dot(w) / den : 1.0;
    if (cos_k < best) {
      best = cos_k;
      corner = k;
    }
  }
  return best;
}

class Cleaner {
 public:
  Cleaner(std::vector<Vec3>& p, std::vector<Triangle>& tris, RedGreenHierarchy& h, std::vector<Vec3>& m,
          const Field& field, const CleanupOptions& o)
      : p_(p), tris_(tris), h_(h), m_(m), field_(field), o_(o) {
    cap_cos_ = std::cos(o.cap_angle_degrees * 3.14159265358979323846 / 180.0);
  }

  // True when some triangle is a cap or a needle (cheap scan before building any structure).
  bool needed() const {
    for (std::size_t t = 0; t < tris_.size(); ++t) {
      int k;
      const Triangle& tri = tris_[t];
      if (largest_angle_cos(p_[tri[0]], p_[tri[1]], p_[tri[2]], k) < cap_cos_ || needle_edge(tri) >= 0 ||
          deviation(t) > o_.flip_deviation) {
        return true;
      }
    }
    return false;
  }

  CleanupCounts run(const RunControl& control) {
    build();
    CleanupCounts counts;
    for (int pass = 0; pass < o_.max_passes; ++pass) {
      control.check();
      std::int64_t changed = 0;
      for (std::size_t t = 0; t < tris_.size(); ++t) {
        if (deleted_[t]) continue;
        if (try_flip(static_cast<std::int32_t>(t)) || try_deviation_flip(static_cast<std::int32_t>(t))) {
          ++counts.flips;
          ++changed;
        } else if (try_collapse(static_cast<std::int32_t>(t))) {
          ++counts.collapses;
          ++changed;
        }
      }
      if (changed == 0) break;
    }
    finish();
    return counts;
  }

 private:
  // |n_T - m_T|² with the field normal at T's centroid (2 for a degenerate triangle).
  double deviation(std::size_t t) const {
    const Triangle& tri = tris_[t];
    const Vec3 n = (p_[tri[1]] - p_[tri[0]]).cross(p_[tri[2]] - p_[tri[0]]);
    const double len = n.norm();
    return len <= o_.degenerate_cross ? 2.0 : (n / len - m_[t]).squaredNorm();
  }

  Vec3 field_normal(const Triangle& t) const {
    Vec3 g;
    field_.value_and_gradient((p_[t[0]] + p_[t[1]] + p_[t[2]]) / 3.0, g);
    const double len = g.norm();
    return len > 0.0 ? Vec3(g / len) : Vec3::Zero();
  }

  // Index k of the needle edge (tri[k], tri[k+1]) of t, or -1.
  int needle_edge(const Triangle& t) const {
    std::array<double, 3> len;
    for (int k = 0; k < 3; ++k) len[k] = (p_[t[(k + 1) % 3]] - p_[t[k]]).norm();
    const int k = static_cast<int>(std::min_element(len.begin(), len.end()) - len.begin());
    return len[k] < o_.needle_ratio * std::min(len[(k + 1) % 3], len[(k + 2) % 3]) ? k : -1;
  }

  void build() {
    edges_.reserve(tris_.size() * 2);
    vertex_tris_.assign(p_.size(), {});
    deleted_.assign(tris_.size(), 0);
    dead_.assign(p_.size(), 0);
    for (std::size_t t = 0; t < tris_.size(); ++t) {
      add(static_cast<std::int32_t>(t));
      for (std::uint32_t v : tris_[t]) vertex_tris_[v].push_back(static_cast<std::int32_t>(t));
    }
    group_children_.assign(h_.green_parents.size(), {kNone, kNone});
    for (std::size_t t = 0; t < tris_.size(); ++t) {
      const std::int32_t g = h_.green_group[t];
      if (g >= 0) group_children_[g][group_children_[g][0] == kNone ? 0 : 1] = static_cast<std::int32_t>(t);
    }
  }

  void add(std::int32_t t) {
    for (int k = 0; k < 3; ++k) {
      auto [it, inserted] =
          edges_.try_emplace(edge_key(tris_[t][k], tris_[t][(k + 1) % 3]), std::array<std::int32_t, 2>{kNone, kNone});
      auto& s = it->second;
      if (s[0] == kMany) continue;
      if (s[0] == kNone) {
        s[0] = t;
      } else if (s[1] == kNone) {
        s[1] = t;
      } else {
        s = {kMany, kMany};
      }
    }
  }
  void remove(std::int32_t t) {
    for (int k = 0; k < 3; ++k) {
      const auto it = edges_.find(edge_key(tris_[t][k], tris_[t][(k + 1) % 3]));
      if (it == edges_.end() || it->second[0] == kMany) continue;
      auto& s = it->second;
      if (s[0] == t) s[0] = kNone;
      if (s[1] == t) s[1] = kNone;
      if (s[0] == kNone) std::swap(s[0], s[1]);
      if (s[0] == kNone) edges_.erase(it);
    }
  }
  // The two triangles of edge (a, b), or false when it has another count.
  bool pair_of(std::uint32_t a, std::uint32_t b, std::int32_t& t0, std::int32_t& t1) const {
    const auto it = edges_.find(edge_key(a, b));
    if (it == edges_.end() || it->second[0] < 0 || it->second[1] < 0) return false;
    t0 = it->second[0];
    t1 = it->second[1];
    return true;
  }

  void dissolve(std::int32_t t) {
    const std::int32_t g = h_.green_group[t];
    if (g < 0) return;
    for (std::int32_t c : group_children_[g]) {
      if (c >= 0) h_.green_group[c] = -1;
    }
  }

  // n·m(centroid) / |n|, or -2 for a degenerate triangle.
  double score(const Triangle& t) const {
    const Vec3 n = (p_[t[1]] - p_[t[0]]).cross(p_[t[2]] - p_[t[0]]);
    const double len = n.norm();
    if (len <= o_.degenerate_cross) return -2.0;
    Vec3 g;
    field_.value_and_gradient((p_[t[0]] + p_[t[1]] + p_[t[2]]) / 3.0, g);
    const double gl = g.norm();
    return gl > 0.0 ? n.dot(g) / (len * gl) : 0.0;
  }

  double largest_cos(const Triangle& t) const {
    int k;
    return largest_angle_cos(p_[t[0]], p_[t[1]], p_[t[2]], k);
  }

  static void erase_value(std::vector<std::int32_t>& list, std::int32_t value) {
    list.erase(std::remove(list.begin(), list.end(), value), list.end());
  }

  bool try_flip(std::int32_t t) {
    int k;
    const double old_cos = largest_angle_cos(p_[tris_[t][0]], p_[tris_[t][1]], p_[tris_[t][2]], k);
    if (!(old_cos < cap_cos_)) return false;
    const std::uint32_t x = tris_[t][k], u = tris_[t][(k + 1) % 3], v = tris_[t][(k + 2) % 3];
    std::int32_t s0, s1;
    if (!pair_of(u, v, s0, s1)) return false;
    const std::int32_t t2 = s0 == t ? s1 : s0;
    if (t2 == t || deleted_[t2]) return false;
    int j = 0;
    while (j < 3 && !(tris_[t2][j] == v && tris_[t2][(j + 1) % 3] == u)) ++j;
    if (j == 3) return false;  // not oriented consistently across (u, v)
    const std::uint32_t y = tris_[t2][(j + 2) % 3];
    if (y == x || edges_.count(edge_key(x, y)) != 0 || h_.midpoints.count(edge_key(x, y)) != 0) return false;
    const Triangle a{u, y, x}, b{y, v, x};
    const double new_cos = std::min(largest_cos(a), largest_cos(b));
    if (!(new_cos > std::min(old_cos, largest_cos(tris_[t2])))) return false;
    if (score(a) < o_.min_cos || score(b) < o_.min_cos) return false;
    apply_flip(t, t2, u, v, x, y);
    return true;
  }

  // Replaces t = (x, u, v) and t2 = (v, u, y) by (u, y, x) and (y, v, x).
  void apply_flip(std::int32_t t, std::int32_t t2, std::uint32_t u, std::uint32_t v, std::uint32_t x, std::uint32_t y) {
    dissolve(t);
    dissolve(t2);
    remove(t);
    remove(t2);
    tris_[t] = Triangle{u, y, x};
    tris_[t2] = Triangle{y, v, x};
    add(t);
    add(t2);
    m_[t] = field_normal(tris_[t]);
    m_[t2] = field_normal(tris_[t2]);
    erase_value(vertex_tris_[u], t2);
    erase_value(vertex_tris_[v], t);
    vertex_tris_[x].push_back(t2);
    vertex_tris_[y].push_back(t);
  }

  // A triangle whose normal deviates from the field's by more than flip_deviation: flip the edge of t that lowers
  // Σ A |n - m|² of the pair the most (by at least 1 %), if the new triangles face along the field and are no caps.
  bool try_deviation_flip(std::int32_t t) {
    if (deviation(t) <= o_.flip_deviation) return false;
    auto energy = [&](const Triangle& tri, const Vec3& m) {
      const Vec3 n = (p_[tri[1]] - p_[tri[0]]).cross(p_[tri[2]] - p_[tri[0]]);
      const double len = n.norm();
      return len <= o_.degenerate_cross ? 0.0 : 0.5 * len * (n / len - m).squaredNorm();
    };
    double best_gain = 0.0;
    int best = -1;
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t x = tris_[t][k], u = tris_[t][(k + 1) % 3], v = tris_[t][(k + 2) % 3];
      std::int32_t s0, s1;
      if (!pair_of(u, v, s0, s1)) continue;
      const std::int32_t t2 = s0 == t ? s1 : s0;
      if (t2 == t || deleted_[t2]) continue;
      int j = 0;
      while (j < 3 && !(tris_[t2][j] == v && tris_[t2][(j + 1) % 3] == u)) ++j;
      if (j == 3) continue;
      const std::uint32_t y = tris_[t2][(j + 2) % 3];
      if (y == x || edges_.count(edge_key(x, y)) != 0 || h_.midpoints.count(edge_key(x, y)) != 0) continue;
      const Triangle a{u, y, x}, b{y, v, x};
      if (!(std::min(largest_cos(a), largest_cos(b)) > cap_cos_)) continue;
      const double before = energy(tris_[t], m_[t]) + energy(tris_[t2], m_[t2]);
      const Vec3 ma = field_normal(a), mb = field_normal(b);
      const double after = energy(a, ma) + energy(b, mb);
      const double gain = before - after;
      if (!(gain > 0.01 * before) || gain <= best_gain) continue;
      if (score(a) < o_.min_cos || score(b) < o_.min_cos) continue;
      best_gain = gain;
      best = k;
    }
    if (best < 0) return false;
    const std::uint32_t x = tris_[t][best], u = tris_[t][(best + 1) % 3], v = tris_[t][(best + 2) % 3];
    std::int32_t s0 = kNone, s1 = kNone;
    pair_of(u, v, s0, s1);
    const std::int32_t t2 = s0 == t ? s1 : s0;
    int j = 0;
    while (!(tris_[t2][j] == v && tris_[t2][(j + 1) % 3] == u)) ++j;
    apply_flip(t, t2, u, v, x, tris_[t2][(j + 2) % 3]);
    return true;
  }

  std::vector<std::uint32_t> neighbours(std::uint32_t v) const {
    std::vector<std::uint32_t> out;
    for (std::int32_t t : vertex_tris_[v]) {
      for (std::uint32_t w : tris_[t]) {
        if (w != v) out.push_back(w);
      }
    }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
  }

  bool try_collapse(std::int32_t t) {
    const int k = needle_edge(tris_[t]);
    if (k < 0) return false;
    const std::uint32_t a = tris_[t][k], b = tris_[t][(k + 1) % 3], c = tris_[t][(k + 2) % 3];
    std::int32_t s0, s1;
    if (!pair_of(a, b, s0, s1)) return false;
    const std::int32_t t2 = s0 == t ? s1 : s0;
    if (t2 == t || deleted_[t2]) return false;
    std::uint32_t d = c;
    for (std::uint32_t w : tris_[t2]) {
      if (w != a && w != b) d = w;
    }
    if (d == c) return false;
    // Link condition.
    const std::vector<std::uint32_t> na = neighbours(a), nb = neighbours(b);
    std::vector<std::uint32_t> common;
    std::set_intersection(na.begin(), na.end(), nb.begin(), nb.end(), std::back_inserter(common));
    if (common.size() != 2 || !((common[0] == c && common[1] == d) || (common[0] == d && common[1] == c))) {
      return false;
    }
    // Every edge around a and b has at most two triangles; no new edge (a, y) carries a midpoint record.
    std::vector<std::int32_t> fan = vertex_tris_[a];
    fan.insert(fan.end(), vertex_tris_[b].begin(), vertex_tris_[b].end());
    std::sort(fan.begin(), fan.end());
    fan.erase(std::unique(fan.begin(), fan.end()), fan.end());
    bool a_on_boundary = false, b_on_boundary = false;
    for (std::int32_t f : fan) {
      for (int e = 0; e < 3; ++e) {
        const std::uint32_t u = tris_[f][e], w = tris_[f][(e + 1) % 3];
        const auto it = edges_.find(edge_key(u, w));
        if (it == edges_.end() || it->second[0] == kMany) return false;
        if (it->second[1] == kNone) {
          a_on_boundary = a_on_boundary || u == a || w == a;
          b_on_boundary = b_on_boundary || u == b || w == b;
        }
      }
    }
    // An interior edge between two boundary vertices: collapsing it would pinch the boundary.
    if (a_on_boundary && b_on_boundary) return false;
    for (std::uint32_t y : nb) {
      if (y != a && h_.midpoints.count(edge_key(a, y)) != 0) return false;
    }
    std::vector<std::int32_t> changed;
    std::vector<double> floor;
    for (std::int32_t f : fan) {
      if (f == t || f == t2) continue;
      changed.push_back(f);
      floor.push_back(std::min(o_.min_cos, score(tris_[f])));
    }
    auto renamed = [&](std::int32_t f) {
      Triangle r = tris_[f];
      for (std::uint32_t& w : r) {
        if (w == b) w = a;
      }
      return r;
    };
    const Vec3 pa = p_[a];
    bool ok = false;
    for (const Vec3& x : {Vec3(0.5 * (p_[a] + p_[b])), p_[a], p_[b]}) {
      p_[a] = x;
      ok = true;
      for (std::size_t i = 0; i < changed.size() && ok; ++i) {
        const double s = score(renamed(changed[i]));
        ok = s > -2.0 && s >= floor[i];
      }
      if (ok) break;
    }
    if (!ok) {
      p_[a] = pa;
      return false;
    }
    for (std::int32_t f : fan) {
      dissolve(f);
      remove(f);
    }
    deleted_[t] = deleted_[t2] = 1;
    for (std::int32_t f : changed) {
      tris_[f] = renamed(f);
      add(f);
      m_[f] = field_normal(tris_[f]);
    }
    vertex_tris_[a] = changed;
    vertex_tris_[b].clear();
    erase_value(vertex_tris_[c], t);
    erase_value(vertex_tris_[d], t2);
    dead_[b] = 1;
    return true;
  }

  void finish() {
    std::size_t out = 0;
    for (std::size_t t = 0; t < tris_.size(); ++t) {
      if (deleted_[t]) continue;
      tris_[out] = tris_[t];
      m_[out] = m_[t];
      h_.green_group[out] = h_.green_group[t];
      ++out;
    }
    tris_.resize(out);
    m_.resize(out);
    h_.green_group.resize(out);
    if (std::find(dead_.begin(), dead_.end(), 1) == dead_.end()) return;
    for (auto it = h_.midpoints.begin(); it != h_.midpoints.end();) {
      const auto lo = static_cast<std::uint32_t>(it->first >> 32);
      const auto hi = static_cast<std::uint32_t>(it->first & 0xffffffffu);
      if (dead_[lo] || dead_[hi] || dead_[it->second]) {
        it = h_.midpoints.erase(it);
      } else {
        ++it;
      }
    }
  }

  std::vector<Vec3>& p_;
  std::vector<Triangle>& tris_;
  RedGreenHierarchy& h_;
  std::vector<Vec3>& m_;
  const Field& field_;
  const CleanupOptions& o_;
  double cap_cos_ = -1.0;
  std::unordered_map<std::uint64_t, std::array<std::int32_t, 2>> edges_;
  std::vector<std::vector<std::int32_t>> vertex_tris_;
  std::vector<std::uint8_t> deleted_;
  std::vector<std::uint8_t> dead_;
  std::vector<std::array<std::int32_t, 2>> group_children_;
};

}  // namespace

CleanupCounts repair_connectivity(std::vector<Vec3>& positions, std::vector<Triangle>& triangles,
                                RedGreenHierarchy& hierarchy, std::vector<Vec3>& field_normals, const Field& field,
                                const CleanupOptions& options, const RunControl& control) {
  Cleaner cleaner(positions, triangles, hierarchy, field_normals, field, options);
  if (!cleaner.needed()) return {};
  return cleaner.run(control);
}

}  // namespace surfacer::optimizer_detail
