// The one mesh-editing layer (docs/ALGORITHMS.md §1, CHOICE "One mesh-editing layer"): the shared edge key and
// vertex -> triangle adjacency of the flat-array paths, and MeshEditor, which flips and collapses edges of a flat
// triangle list through an OpenMesh TriMesh of the neighbourhoods it edits (OpenMesh's is_flip_ok / is_collapse_ok
// decide what is valid topologically; the callers' own rules stay small predicates on top). OpenMesh stays in
// mesh_edit.cpp.
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
// edited so far: a vertex is loaded (its whole fan added) when an edit first needs it, from the adjacency given on
// entry, which stays exact for every vertex not loaded because every edit loads the vertices whose fans it changes
// first. A vertex whose fan OpenMesh cannot hold (a non-manifold edge or vertex) is unusable: no edit touches it. The
// flat list is written by the editor only, with the rotations documented per edit; a collapsed triangle becomes
// {kNone, kNone, kNone} in place (the caller compacts). Positions are the caller's: the editor is purely topological.
// Both arguments must outlive the editor; `triangles` may not be resized while it lives.
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

  // Queries answer from the entry adjacency for a vertex not loaded (exact, see above) and from the TriMesh for a
  // loaded one; they load nothing and work at non-manifold vertices too.
  // The live triangles at v, in increasing index order.
  std::vector<std::uint32_t> triangles_around(std::uint32_t v) const;
  // How many triangles v has.
  std::size_t triangle_count(std::uint32_t v) const;
  // v's distinct neighbours, sorted.
  std::vector<std::uint32_t> neighbours(std::uint32_t v) const;
  // Number of triangles on edge (u, w).
  int edge_triangle_count(std::uint32_t u, std::uint32_t w) const;
  // Whether v has an edge with one triangle only (a boundary vertex).
  bool on_boundary(std::uint32_t v) const;
  // The triangle across directed edge (u, v) of live triangle t and its third vertex, when (u, v) has exactly two
  // triangles, the other holding v -> u; else nullopt.
  std::optional<Across> across(std::uint32_t t, std::uint32_t u, std::uint32_t v) const;

  // Edits load the vertices whose fans they change and refuse unusable ones.
  // The triangle across directed edge (u, v) of live triangle t (the one holding v -> u) and its third vertex y, when
  // OpenMesh's is_flip_ok allows flipping (u, v): the edge has two triangles and the new edge (x, y) does not exist
  // (x: t's vertex opposite (u, v)). nullopt when not, or when a vertex of the pair is unusable.
  std::optional<Across> flip_site(std::uint32_t t, std::uint32_t u, std::uint32_t v);
  // Flips (u, v) of t = (u, v, x) (any rotation) with t2 = (v, u, y): writes t = (u, y, x) and t2 = (y, v, x).
  // Precondition: flip_site(t, u, v) returned t2.
  void flip(std::uint32_t t, std::uint32_t u, std::uint32_t v);
  // Undoes flip(t, u, v) when neither triangle changed since: t = old_t and t2 = old_t2 again, as they were.
  void undo_flip(std::uint32_t t, std::uint32_t t2, const Triangle& old_t, const Triangle& old_t2);

  // The other triangle t2 of edge (keep, gone) of live triangle t (either direction) and its third vertex d, when
  // OpenMesh's is_collapse_ok allows collapsing gone into keep: they share no neighbour but the two opposite vertices
  // (the link condition), those differ, and when both are on the boundary the edge is a boundary edge. nullopt when
  // not, or when a vertex of the pair is unusable.
  std::optional<Across> collapse_site(std::uint32_t t, std::uint32_t keep, std::uint32_t gone);
  // Collapses gone into keep: every triangle at gone but t and t2 names keep instead (same rotation), t and t2 become
  // removed. Precondition: collapse_site(t, keep, gone) returned t2.
  void collapse(std::uint32_t t, std::uint32_t keep, std::uint32_t gone);

 private:
  struct Impl;
  std::vector<Triangle>& triangles_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace surfacer
