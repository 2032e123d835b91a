// Red–green refinement (core/optimize/refine.h).
//
// Each pass works on the "parent level" mesh: every green pair is first merged back into its parent, whose split
// edge then carries a hanging midpoint (the neighbour across it stays refined). Split edges are the edges of red
// triangles and every edge that carries a midpoint; a triangle with an edge whose halves carry midpoints too (two
// levels finer across it) must be red. Closure marks red every triangle with >= 2 split edges. Then red triangles
// are split 1-to-4, triangles with one split edge are bisected (green), the rest are kept. Red children of a
// triangle next to a two-levels-finer neighbour still see a midpoint on a half edge, so passes repeat (with no new
// requests) until no triangle edge carries a midpoint; each pass lowers the largest level difference by one.
#include "core/optimize/refine.h"

#include <algorithm>
#include <array>

#include "core/mesh/mesh_edit.h"
#include "core/util/triangle_limit.h"

namespace surfacer::optimizer_detail {

namespace {

constexpr std::size_t kCheckMask = (std::size_t{1} << 16) - 1;  // control.check() every 2^16 items

}  // namespace

void RedGreenHierarchy::assign(const RedGreenHierarchy& other, const RunControl& control) {
  control.check();
  green_group = other.green_group;
  green_parents = other.green_parents;
  midpoints.clear();
  midpoints.reserve(other.midpoints.size());
  std::size_t copied = 0;
  for (const auto& entry : other.midpoints) {
    if ((copied++ & kCheckMask) == 0) control.check();
    midpoints.insert(entry);
  }
}

bool refine_red_green(std::vector<Vec3>& vertices, std::vector<Triangle>& triangles, RedGreenHierarchy& hierarchy,
                      const std::vector<std::uint8_t>& requested, const RunControl& control, std::int64_t max_triangles,
                      std::int64_t* reserved) {
  std::int64_t reserved_here = 0;
  std::int64_t& covered = reserved != nullptr ? *reserved : reserved_here;
  const auto tick = [&](std::size_t i) {
    if ((i & kCheckMask) == 0) control.check();
  };
  auto& midpoints = hierarchy.midpoints;
  auto midpoint_of = [&](std::uint32_t a, std::uint32_t b) -> std::int64_t {
    const auto it = midpoints.find(edge_key(a, b));
    return it == midpoints.end() ? -1 : static_cast<std::int64_t>(it->second);
  };
  auto get_or_make_midpoint = [&](std::uint32_t a, std::uint32_t b) -> std::uint32_t {
    const auto [it, inserted] = midpoints.try_emplace(edge_key(a, b), static_cast<std::uint32_t>(vertices.size()));
    if (inserted) vertices.push_back(0.5 * (vertices[a] + vertices[b]));
    return it->second;
  };

  std::vector<std::uint8_t> request = requested;
  request.resize(triangles.size(), 0);
  for (int pass = 0;; ++pass) {
    control.check();
    // 1. Merge green pairs back into their parents.
    std::vector<Triangle> level;
    std::vector<std::uint8_t> red;
    level.reserve(triangles.size());
    red.reserve(triangles.size());
    {
      std::vector<std::int64_t> placed(hierarchy.green_parents.size(), -1);
      for (std::size_t t = 0; t < triangles.size(); ++t) {
        tick(t);
        const std::int32_t g = hierarchy.green_group[t];
        if (g < 0) {
          level.push_back(triangles[t]);
          red.push_back(request[t]);
        } else if (placed[g] < 0) {
          placed[g] = static_cast<std::int64_t>(level.size());
          level.push_back(hierarchy.green_parents[g]);
          red.push_back(request[t]);
        } else {
          red[placed[g]] |= request[t];
        }
      }
    }
    const std::size_t n = level.size();

    // 2. Edges of the parent-level mesh: sort (key, corner) pairs; edge id per corner; triangles per edge.
    std::vector<std::pair<std::uint64_t, std::uint32_t>> corners(3 * n);
    for (std::size_t t = 0; t < n; ++t) {
      tick(t);
      for (int k = 0; k < 3; ++k) {
        corners[3 * t + k] = {edge_key(level[t][k], level[t][(k + 1) % 3]), static_cast<std::uint32_t>(3 * t + k)};
      }
    }
    {
      std::size_t comparisons = 0;  // the sort of 3n corners is the longest step: it checks too
      std::sort(corners.begin(), corners.end(), [&](const auto& a, const auto& b) {
        if ((++comparisons & ((std::size_t{1} << 20) - 1)) == 0) control.check();
        return a < b;
      });
    }
    std::vector<std::uint32_t> corner_edge(3 * n);
    std::vector<std::uint64_t> edge_keys;
    std::vector<std::uint32_t> edge_begin;  // into `corners`
    for (std::size_t i = 0; i < corners.size(); ++i) {
      tick(i);
      if (i == 0 || corners[i].first != corners[i - 1].first) {
        edge_keys.push_back(corners[i].first);
        edge_begin.push_back(static_cast<std::uint32_t>(i));
      }
      corner_edge[corners[i].second] = static_cast<std::uint32_t>(edge_keys.size() - 1);
    }
    edge_begin.push_back(static_cast<std::uint32_t>(corners.size()));
    const std::size_t edges = edge_keys.size();

    std::vector<std::uint8_t> split(edges, 0);
    for (std::size_t e = 0; e < edges; ++e) {
      tick(e);
      const auto a = static_cast<std::uint32_t>(edge_keys[e] >> 32);
      const auto b = static_cast<std::uint32_t>(edge_keys[e] & 0xffffffffu);
      const std::int64_t m = midpoint_of(a, b);
      if (m < 0) continue;
      split[e] = 1;
      const auto mm = static_cast<std::uint32_t>(m);
      if (midpoint_of(a, mm) >= 0 || midpoint_of(mm, b) >= 0) {
        for (std::uint32_t i = edge_begin[e]; i < edge_begin[e + 1]; ++i) red[corners[i].second / 3] = 1;
      }
    }

    // 3. Closure: red triangles split all their edges; a triangle with >= 2 split edges turns red.
    std::vector<std::uint32_t> work;
    auto mark_red = [&](std::size_t t) {
      for (int k = 0; k < 3; ++k) {
        const std::uint32_t e = corner_edge[3 * t + k];
        if (split[e]) continue;
        split[e] = 1;
        for (std::uint32_t i = edge_begin[e]; i < edge_begin[e + 1]; ++i) work.push_back(corners[i].second / 3);
      }
    };
    for (std::size_t t = 0; t < n; ++t) {
      if (red[t]) mark_red(t);
    }
    for (std::size_t t = 0; t < n; ++t) {
      if (!red[t]) work.push_back(static_cast<std::uint32_t>(t));
    }
    for (std::size_t popped = 0; !work.empty(); ++popped) {
      tick(popped);
      const std::uint32_t t = work.back();
      work.pop_back();
      if (red[t]) continue;
      const int count = split[corner_edge[3 * t]] + split[corner_edge[3 * t + 1]] + split[corner_edge[3 * t + 2]];
      if (count >= 2) {
        red[t] = 1;
        mark_red(t);
      }
    }

    // 4. Split, when the result fits: a red triangle makes 4, one with a split edge 2.
    std::int64_t result = 0;
    for (std::size_t t = 0; t < n; ++t) {
      tick(t);
      if (red[t]) {
        result += 4;
      } else {
        const int count = split[corner_edge[3 * t]] + split[corner_edge[3 * t + 1]] + split[corner_edge[3 * t + 2]];
        result += count == 0 ? 1 : 2;
      }
    }
    if (result > max_triangles) return false;
    reserve_triangles(control, result, covered);
    std::vector<Triangle> out;
    std::vector<std::int32_t> out_group;
    std::vector<Triangle> parents;
    out.reserve(n + 3 * static_cast<std::size_t>(std::count(red.begin(), red.end(), 1)) + 16);
    for (std::size_t t = 0; t < n; ++t) {
      tick(t);
      const Triangle& tri = level[t];
      if (red[t]) {
        const std::uint32_t a = tri[0], b = tri[1], c = tri[2];
        const std::uint32_t ab = get_or_make_midpoint(a, b);
        const std::uint32_t bc = get_or_make_midpoint(b, c);
        const std::uint32_t ca = get_or_make_midpoint(c, a);
        for (const Triangle& child :
             {Triangle{a, ab, ca}, Triangle{ab, b, bc}, Triangle{ca, bc, c}, Triangle{ab, bc, ca}}) {
          out.push_back(child);
          out_group.push_back(-1);
        }
        continue;
      }
      int only = -1, count = 0;
      for (int k = 0; k < 3; ++k) {
        if (split[corner_edge[3 * t + k]]) {
          only = k;
          ++count;
        }
      }
      if (count == 0) {
        out.push_back(tri);
        out_group.push_back(-1);
        continue;
      }
      // count == 1 (>= 2 would have turned red): bisect edge (v0, v1) towards the opposite vertex v2.
      const std::uint32_t v0 = tri[only], v1 = tri[(only + 1) % 3], v2 = tri[(only + 2) % 3];
      const std::uint32_t m = get_or_make_midpoint(v0, v1);
      const auto g = static_cast<std::int32_t>(parents.size());
      parents.push_back(tri);
      out.push_back(Triangle{v0, m, v2});
      out.push_back(Triangle{m, v1, v2});
      out_group.push_back(g);
      out_group.push_back(g);
    }
    triangles = std::move(out);
    hierarchy.green_group = std::move(out_group);
    hierarchy.green_parents = std::move(parents);

    // 5. Conforming when no remaining edge carries a midpoint.
    bool conforming = true;
    for (std::size_t t = 0; t < triangles.size(); ++t) {
      tick(t);
      const Triangle& tri = triangles[t];
      for (int k = 0; k < 3 && conforming; ++k) {
        if (midpoint_of(tri[k], tri[(k + 1) % 3]) >= 0) conforming = false;
      }
      if (!conforming) break;
    }
    if (conforming) return true;
    request.assign(triangles.size(), 0);
  }
}

}  // namespace surfacer::optimizer_detail
