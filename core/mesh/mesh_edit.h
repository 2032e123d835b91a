// The one mesh-editing layer (docs/ALGORITHMS.md, "Mesh editing"): the shared edge key and vertex -> triangle
// adjacency of the flat-array paths, and MeshEditor, which flips and collapses edges of a flat triangle list through an
// OpenMesh TriMesh of the neighbourhoods it edits (OpenMesh's is_flip_ok / is_collapse_ok decide what is valid
// topologically; the callers' own rules stay small predicates on top). OpenMesh stays in mesh_edit.cpp.
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "core/mesh/mesh.h"

namespace surfacer {

// One key per undirected edge: the sorted vertex pair (smaller id in the high 32 bits).
inline std::uint64_t edge_key(std::uint32_t a, std::uint32_t b) {
  if (a > b) std::swap(a, b);
  return (static_cast<std::uint64_t>(a) << 32) | b;
}

// Vertex -> triangle adjacency in compressed rows: the triangles at vertex v are triangles[offsets[v] ..
// offsets[v + 1]), in increasing index order.
struct VertexTriangles {
  std::vector<std::uint32_t> offsets{0};  // vertex count + 1 entries
  std::vector<std::uint32_t> triangles;

  std::span<const std::uint32_t> of(std::uint32_t v) const {
    return std::span<const std::uint32_t>(triangles).subspan(offsets[v], offsets[v + 1] - offsets[v]);
  }
};

// The adjacency of `triangles` over vertices 0 .. vertex_count - 1 (every index must be below vertex_count).
VertexTriangles vertex_triangles(std::size_t vertex_count, std::span<const Triangle> triangles);

// Edits a flat triangle list in place by edge flips and collapses. The TriMesh behind it holds only the neighbourhoods
// touched so far: a vertex is loaded (its whole fan added) on first use, from the adjacency given on entry, which stays
// exact for every vertex not loaded because every edit loads the vertices whose fans it changes first. A vertex whose
// fan OpenMesh cannot hold (a non-manifold edge or vertex) is unusable: queries on it return nullopt and no edit
// touches it. The flat list is written by the editor only, with the rotations documented per edit; a collapsed
// triangle becomes {kNone, kNone, kNone} in place (the caller compacts). Positions are the caller's: the editor is
// purely topological. Both arguments must outlive the editor; `triangles` may not be resized while it lives.
class MeshEditor {
 public:
  static constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

  // The other triangle of an edge and its vertex opposite the edge.
  struct Across {
    std::uint32_t triangle = kNone;
    std::uint32_t vertex = kNone;
  };

  MeshEditor(std::vector<Triangle>& triangles, const VertexTriangles& adjacency, std::size_t vertex_count);
  ~MeshEditor();
  MeshEditor(const MeshEditor&) = delete;
  MeshEditor& operator=(const MeshEditor&) = delete;

  bool removed(std::uint32_t t) const { return triangles_[t][0] == kNone; }

  // The live triangles at v (any order); nullopt when v is unusable.
  std::optional<std::vector<std::uint32_t>> triangles_around(std::uint32_t v);
  // v's distinct neighbours, sorted; nullopt when v is unusable.
  std::optional<std::vector<std::uint32_t>> neighbours(std::uint32_t v);
  // Number of triangles on edge (u, w) (0, 1 or 2); nullopt when u or w is unusable.
  std::optional<int> edge_triangle_count(std::uint32_t u, std::uint32_t w);
  // Whether v has an edge with one triangle only (a boundary vertex); nullopt when unusable.
  std::optional<bool> on_boundary(std::uint32_t v);

  // The triangle across directed edge (u, v) of live triangle t (the one holding v -> u) and its third vertex y, when
  // OpenMesh's is_flip_ok allows flipping (u, v): the edge has two triangles and the new edge (x, y) does not exist
  // (x: t's vertex opposite (u, v)). nullopt when not, or when a vertex of the pair is unusable.
  std::optional<Across> flip_site(std::uint32_t t, std::uint32_t u, std::uint32_t v);
  // Flips (u, v) of t = (u, v, x) (any rotation) with t2 = (v, u, y): writes t = (u, y, x) and t2 = (y, v, x).
  // Precondition: flip_site(t, u, v) returned t2.
  void flip(std::uint32_t t, std::uint32_t u, std::uint32_t v);

  // The triangle across directed edge (a, b) of live triangle t and its third vertex d, when OpenMesh's
  // is_collapse_ok allows collapsing b into a: a and b share no neighbour but the two opposite vertices (the link
  // condition), those differ, and when a and b are both on the boundary the edge is a boundary edge. nullopt when
  // not, or when a vertex of the pair is unusable.
  std::optional<Across> collapse_site(std::uint32_t t, std::uint32_t a, std::uint32_t b);
  // Collapses b into a: every triangle at b but t and t2 names a instead (same rotation), t and t2 become removed.
  // Precondition: collapse_site(t, a, b) returned t2.
  void collapse(std::uint32_t t, std::uint32_t a, std::uint32_t b);

 private:
  struct Impl;
  std::vector<Triangle>& triangles_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace surfacer
