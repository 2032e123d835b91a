// Cap flips, normal-improving flips and needle collapses (core/optimize/cleanup.h).
//
// Sequential: the changes are few and local, and each one changes what its neighbours see. Nothing global is built:
// the flips and collapses go through MeshEditor (core/mesh/mesh_edit.h), whose TriMesh holds only the fans of the
// vertices the candidates reach, and only the candidates (caps, needles, deviating triangles) and the triangles changed
// in a pass are visited. The rules here (midpoint records, field-facing scores, caps, green pairs) are the predicates
// on top of its topological checks.
#include "core/optimize/cleanup.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <unordered_set>

#include "core/mesh/mesh_edit.h"
#include "core/scene/scene.h"

namespace surfacer::optimizer_detail {
namespace {

class Cleaner {
 public:
  Cleaner(std::vector<Vec3>& positions, std::vector<Triangle>& tris, RedGreenHierarchy& hierarchy,
          std::vector<Vec3>& field_normals, const VertexTriangles& adjacency, const Field& field,
          const CleanupOptions& options)
      : positions_(positions),
        tris_(tris),
        hierarchy_(hierarchy),
        field_normals_(field_normals),
        adjacency_(adjacency),
        field_(field),
        options_(options) {
    cap_cos_ = std::cos(options.cap_angle_degrees * 3.14159265358979323846 / 180.0);
  }

  CleanupCounts run(const RunControl& control) {
    std::vector<std::int32_t> candidates;
    for (std::size_t t = 0; t < tris_.size(); ++t) {
      if (problem(static_cast<std::int32_t>(t))) candidates.push_back(static_cast<std::int32_t>(t));
    }
    CleanupCounts counts;
    if (candidates.empty()) return counts;
    editor_.emplace(tris_, adjacency_, positions_.size());
    for (int pass = 0; pass < options_.max_passes && !candidates.empty(); ++pass) {
      control.check();
      touched_.clear();
      for (std::int32_t t : candidates) {
        if (removed(t)) continue;
        if (try_flip(t) || try_deviation_flip(t)) {
          ++counts.flips;
        } else if (try_collapse(t)) {
          ++counts.collapses;
        }
      }
      if (touched_.empty()) break;
      // Next pass: this pass's candidates that are still a problem (their neighbourhood may have changed) and the
      // triangles it changed.
      std::vector<std::int32_t> next;
      for (std::int32_t t : candidates) {
        if (!removed(t) && problem(t)) next.push_back(t);
      }
      for (std::int32_t t : touched_) {
        if (!removed(t) && problem(t)) next.push_back(t);
      }
      std::sort(next.begin(), next.end());
      next.erase(std::unique(next.begin(), next.end()), next.end());
      candidates = std::move(next);
    }
    finish();
    return counts;
  }

 private:
  // --- Geometry ----------------------------------------------------------------------------------------------
  // Cosine of the largest angle of t (opposite its longest edge) and the corner it sits at; 1 when degenerate.
  double largest_cos(const Triangle& t, int& corner) const {
    std::array<double, 3> e2;  // e2[k]: squared length of the edge opposite corner k
    for (int k = 0; k < 3; ++k) e2[k] = (positions_[t[(k + 2) % 3]] - positions_[t[(k + 1) % 3]]).squaredNorm();
    corner = static_cast<int>(std::max_element(e2.begin(), e2.end()) - e2.begin());
    const double a2 = e2[(corner + 1) % 3], b2 = e2[(corner + 2) % 3];
    const double den = 2.0 * std::sqrt(a2 * b2);
    return den > 0.0 ? (a2 + b2 - e2[corner]) / den : 1.0;
  }
  double largest_cos(const Triangle& t) const {
    int corner;
    return largest_cos(t, corner);
  }
  // Index k of the needle edge (t[k], t[k+1]) of t, or -1.
  int needle_edge(const Triangle& t) const {
    std::array<double, 3> len2;
    for (int k = 0; k < 3; ++k) len2[k] = (positions_[t[(k + 1) % 3]] - positions_[t[k]]).squaredNorm();
    const int k = static_cast<int>(std::min_element(len2.begin(), len2.end()) - len2.begin());
    const double r2 = options_.needle_ratio * options_.needle_ratio;
    return len2[k] < r2 * std::min(len2[(k + 1) % 3], len2[(k + 2) % 3]) ? k : -1;
  }
  // |n_T - m_T|² with the field normal at T's centroid (2 for a degenerate triangle).
  double deviation(std::int32_t t) const {
    const Triangle& tri = tris_[t];
    const Vec3 n = (positions_[tri[1]] - positions_[tri[0]]).cross(positions_[tri[2]] - positions_[tri[0]]);
    const double len = n.norm();
    return len <= options_.degenerate_cross ? 2.0 : (n / len - field_normals_[t]).squaredNorm();
  }
  bool problem(std::int32_t t) const {
    return largest_cos(tris_[t]) < cap_cos_ || needle_edge(tris_[t]) >= 0 || deviation(t) > options_.flip_deviation;
  }
  Vec3 field_normal(const Triangle& t) const {
    Vec3 g;
    field_.value_and_gradient((positions_[t[0]] + positions_[t[1]] + positions_[t[2]]) / 3.0, g);
    const double len = g.norm();
    return len > 0.0 ? Vec3(g / len) : Vec3::Zero();
  }
  // n·m(centroid), or -2 for a degenerate triangle.
  double score(const Triangle& t) const {
    const Vec3 n = (positions_[t[1]] - positions_[t[0]]).cross(positions_[t[2]] - positions_[t[0]]);
    const double len = n.norm();
    return len <= options_.degenerate_cross ? -2.0 : n.dot(field_normal(t)) / len;
  }
  double energy(const Triangle& t, const Vec3& m) const {  // A |n - m|²
    const Vec3 n = (positions_[t[1]] - positions_[t[0]]).cross(positions_[t[2]] - positions_[t[0]]);
    const double len = n.norm();
    return len <= options_.degenerate_cross ? 0.0 : 0.5 * len * (n / len - m).squaredNorm();
  }

  bool removed(std::int32_t t) const { return tris_[t][0] == MeshEditor::kNone; }

  // A green pair with a changed child is dissolved (both children become plain triangles).
  void dissolve(std::int32_t t) {
    const std::int32_t g = hierarchy_.green_group[t];
    if (g < 0) return;
    if (group_children_.empty()) {
      group_children_.assign(hierarchy_.green_parents.size(), {-1, -1});
      for (std::size_t i = 0; i < tris_.size(); ++i) {
        const std::int32_t gi = hierarchy_.green_group[i];
        if (gi >= 0) group_children_[gi][group_children_[gi][0] < 0 ? 0 : 1] = static_cast<std::int32_t>(i);
      }
    }
    for (std::int32_t c : group_children_[g]) {
      if (c >= 0) hierarchy_.green_group[c] = -1;
    }
  }

  // --- Flips ---------------------------------------------------------------------------------------------------
  // For t = (x, u, v) rotated so that k is x's corner: the triangle t2 = (v, u, y) across (u, v), when (u, v) has
  // exactly these two consistently oriented triangles, y != x and (x, y) carries no midpoint record. The editor's
  // flip_site (the edge (x, y) is new) is asked last, by the callers, once the cheaper tests pass: it loads the
  // neighbourhood into the TriMesh.
  bool flippable(std::int32_t t, int k, std::int32_t& t2, std::uint32_t& y) const {
    const std::uint32_t x = tris_[t][k], u = tris_[t][(k + 1) % 3], v = tris_[t][(k + 2) % 3];
    const std::optional<MeshEditor::Across> site = editor_->across(static_cast<std::uint32_t>(t), u, v);
    if (!site) return false;
    t2 = static_cast<std::int32_t>(site->triangle);
    y = site->vertex;
    return y != x && hierarchy_.midpoints.count(edge_key(x, y)) == 0;
  }
  bool flip_valid(std::int32_t t, int k) {
    return editor_->flip_site(static_cast<std::uint32_t>(t), tris_[t][(k + 1) % 3], tris_[t][(k + 2) % 3]).has_value();
  }

  // Replaces t = (x, u, v) and t2 = (v, u, y) by (u, y, x) and (y, v, x).
  void apply_flip(std::int32_t t, std::int32_t t2, int k) {
    const std::uint32_t u = tris_[t][(k + 1) % 3], v = tris_[t][(k + 2) % 3];
    dissolve(t);
    dissolve(t2);
    editor_->flip(static_cast<std::uint32_t>(t), u, v);
    field_normals_[t] = field_normal(tris_[t]);
    field_normals_[t2] = field_normal(tris_[t2]);
    touched_.push_back(t);
    touched_.push_back(t2);
  }

  // Cap: flip the edge opposite its largest angle when the pair's largest angle drops.
  bool try_flip(std::int32_t t) {
    int k;
    const double old_cos = largest_cos(tris_[t], k);
    if (!(old_cos < cap_cos_)) return false;
    std::int32_t t2;
    std::uint32_t y;
    if (!flippable(t, k, t2, y)) return false;
    const std::uint32_t x = tris_[t][k], u = tris_[t][(k + 1) % 3], v = tris_[t][(k + 2) % 3];
    const Triangle a{u, y, x}, b{y, v, x};
    if (!(std::min(largest_cos(a), largest_cos(b)) > std::min(old_cos, largest_cos(tris_[t2])))) return false;
    if (score(a) < options_.min_cos || score(b) < options_.min_cos || !flip_valid(t, k)) return false;
    apply_flip(t, t2, k);
    return true;
  }

  // Deviating triangle: flip the edge that lowers A |n - m|² of the pair the most (by at least 1 %), when the new
  // triangles face along the field and are no caps.
  bool try_deviation_flip(std::int32_t t) {
    if (deviation(t) <= options_.flip_deviation) return false;
    double best_gain = 0.0;
    int best = -1;
    std::int32_t best_t2 = -1;
    for (int k = 0; k < 3; ++k) {
      std::int32_t t2;
      std::uint32_t y;
      if (!flippable(t, k, t2, y)) continue;
      const std::uint32_t x = tris_[t][k], u = tris_[t][(k + 1) % 3], v = tris_[t][(k + 2) % 3];
      const Triangle a{u, y, x}, b{y, v, x};
      if (!(std::min(largest_cos(a), largest_cos(b)) > cap_cos_)) continue;
      const double before = energy(tris_[t], field_normals_[t]) + energy(tris_[t2], field_normals_[t2]);
      const double gain = before - energy(a, field_normal(a)) - energy(b, field_normal(b));
      if (!(gain > 0.01 * before) || gain <= best_gain) continue;
      if (score(a) < options_.min_cos || score(b) < options_.min_cos || !flip_valid(t, k)) continue;
      best_gain = gain;
      best = k;
      best_t2 = t2;
    }
    if (best < 0) return false;
    apply_flip(t, best_t2, best);
    return true;
  }

  // --- Collapses -----------------------------------------------------------------------------------------------
  bool try_collapse(std::int32_t t) {
    const int k = needle_edge(tris_[t]);
    if (k < 0) return false;
    const std::uint32_t a = tris_[t][k], b = tris_[t][(k + 1) % 3];
    // The editor's link condition (a and b share exactly the two opposite vertices; not both on the boundary, which
    // would pinch it), then: no new edge (a, y) carries a midpoint record.
    const std::optional<MeshEditor::Across> site = editor_->collapse_site(static_cast<std::uint32_t>(t), a, b);
    if (!site) return false;
    const auto t2 = static_cast<std::int32_t>(site->triangle);
    for (std::uint32_t y : editor_->neighbours(b)) {
      if (y != a && hierarchy_.midpoints.count(edge_key(a, y)) != 0) return false;
    }
    std::vector<std::uint32_t> around = editor_->triangles_around(a);
    const std::vector<std::uint32_t> around_b = editor_->triangles_around(b);
    around.insert(around.end(), around_b.begin(), around_b.end());
    std::sort(around.begin(), around.end());
    around.erase(std::unique(around.begin(), around.end()), around.end());
    std::vector<std::int32_t> changed;
    std::vector<double> floor;
    for (const std::uint32_t uf : around) {
      const auto f = static_cast<std::int32_t>(uf);
      if (f == t || f == t2) continue;
      changed.push_back(f);
      floor.push_back(std::min(options_.min_cos, score(tris_[f])));
    }
    auto renamed = [&](std::int32_t f) {
      Triangle r = tris_[f];
      for (std::uint32_t& w : r) {
        if (w == b) w = a;
      }
      return r;
    };
    // Place a at the midpoint, else at a, else at b: the first where every changed triangle passes the guard test.
    const Vec3 pa = positions_[a];
    bool ok = false;
    for (const Vec3& x : {Vec3(0.5 * (positions_[a] + positions_[b])), Vec3(positions_[a]), Vec3(positions_[b])}) {
      positions_[a] = x;
      ok = true;
      for (std::size_t i = 0; i < changed.size() && ok; ++i) {
        const double s = score(renamed(changed[i]));
        ok = s > -2.0 && s >= floor[i];
      }
      if (ok) break;
    }
    if (!ok) {
      positions_[a] = pa;
      return false;
    }
    for (const std::uint32_t f : around) dissolve(static_cast<std::int32_t>(f));
    editor_->collapse(static_cast<std::uint32_t>(t), a, b);
    for (std::int32_t f : changed) {
      field_normals_[f] = field_normal(tris_[f]);
      touched_.push_back(f);
    }
    dead_.insert(b);
    return true;
  }

  // Drops deleted triangles (keeping order) and the midpoint records that name a collapsed vertex.
  void finish() {
    if (dead_.empty()) return;
    std::size_t out = 0;
    for (std::size_t t = 0; t < tris_.size(); ++t) {
      if (removed(t)) continue;
      tris_[out] = tris_[t];
      field_normals_[out] = field_normals_[t];
      hierarchy_.green_group[out] = hierarchy_.green_group[t];
      ++out;
    }
    tris_.resize(out);
    field_normals_.resize(out);
    hierarchy_.green_group.resize(out);
    for (auto it = hierarchy_.midpoints.begin(); it != hierarchy_.midpoints.end();) {
      const auto lo = static_cast<std::uint32_t>(it->first >> 32);
      const auto hi = static_cast<std::uint32_t>(it->first & 0xffffffffu);
      if (dead_.count(lo) || dead_.count(hi) || dead_.count(it->second)) {
        it = hierarchy_.midpoints.erase(it);
      } else {
        ++it;
      }
    }
  }

  std::vector<Vec3>& positions_;
  std::vector<Triangle>& tris_;
  RedGreenHierarchy& hierarchy_;
  std::vector<Vec3>& field_normals_;
  const VertexTriangles& adjacency_;
  const Field& field_;
  const CleanupOptions& options_;
  double cap_cos_ = -1.0;
  std::optional<MeshEditor> editor_;  // made at the first candidate
  std::vector<std::int32_t> touched_;
  std::unordered_set<std::uint32_t> dead_;
  std::vector<std::array<std::int32_t, 2>> group_children_;
};

}  // namespace

CleanupCounts repair_connectivity(std::vector<Vec3>& positions, std::vector<Triangle>& triangles,
                                  RedGreenHierarchy& hierarchy, std::vector<Vec3>& field_normals,
                                  const VertexTriangles& adjacency, const Field& field, const CleanupOptions& options,
                                  const RunControl& control) {
  Cleaner cleaner(positions, triangles, hierarchy, field_normals, adjacency, field, options);
  return cleaner.run(control);
}

}  // namespace surfacer::optimizer_detail
