// The mesh-editing layer (core/mesh/mesh_edit.h).
//
// The TriMesh grows by whole fans: loading vertex v adds every triangle of its entry fan not added yet (creating local
// vertices for their corners), so a loaded vertex's circulators see its whole neighbourhood. Local vertex and face
// handles map to global ids through flat vectors, filled as they are created; OpenMesh's deleted faces and vertices
// are never garbage-collected (handles stay valid for the editor's life).
#include "core/mesh/mesh_edit.h"

#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <algorithm>
#include <array>

namespace surfacer {
namespace {

struct Traits : OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3d;  // unused (the editor is topological); double as every position in core
};
using TriMesh = OpenMesh::TriMesh_ArrayKernelT<Traits>;

constexpr std::int32_t kAbsent = -1;  // not in the TriMesh yet
constexpr std::int32_t kFailed = -2;  // OpenMesh refused the face (non-manifold there)

}  // namespace

VertexTriangles vertex_triangles(std::size_t vertex_count, std::span<const Triangle> triangles) {
  VertexTriangles a;
  a.offsets.assign(vertex_count + 1, 0);
  for (const Triangle& t : triangles) {
    for (const std::uint32_t v : t) ++a.offsets[v + 1];
  }
  for (std::size_t v = 0; v < vertex_count; ++v) a.offsets[v + 1] += a.offsets[v];
  a.triangles.resize(a.offsets[vertex_count]);
  std::vector<std::uint32_t> fill(a.offsets.begin(), a.offsets.end() - 1);
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    for (const std::uint32_t v : triangles[t]) a.triangles[fill[v]++] = static_cast<std::uint32_t>(t);
  }
  return a;
}

struct MeshEditor::Impl {
  Impl(std::vector<Triangle>& triangles, const VertexTriangles& adjacency, std::size_t vertex_count)
      : tris(triangles), entry(adjacency), local_vertex(vertex_count, kAbsent), local_face(triangles.size(), kAbsent) {
    mesh.request_vertex_status();
    mesh.request_edge_status();
    mesh.request_halfedge_status();
    mesh.request_face_status();
  }

  std::vector<Triangle>& tris;
  const VertexTriangles& entry;
  TriMesh mesh;
  std::vector<std::int32_t> local_vertex;  // global vertex -> TriMesh vertex index, or kAbsent
  std::vector<std::int32_t> local_face;    // global triangle -> TriMesh face index, kAbsent or kFailed
  std::vector<std::uint32_t> global_vertex, global_face;
  std::vector<std::uint8_t> state;  // per TriMesh vertex: kLoose, kLoaded or kUnusable
  static constexpr std::uint8_t kLoose = 0, kLoaded = 1, kUnusable = 2;

  TriMesh::VertexHandle vertex(std::uint32_t v) {
    if (local_vertex[v] == kAbsent) {
      local_vertex[v] = static_cast<std::int32_t>(mesh.n_vertices());
      mesh.add_vertex(TriMesh::Point(0.0, 0.0, 0.0));
      global_vertex.push_back(v);
      state.push_back(kLoose);
    }
    return TriMesh::VertexHandle(local_vertex[v]);
  }

  // Whether OpenMesh can add the face without a complex vertex or edge (checked here so that it prints nothing).
  bool fits(const std::array<TriMesh::VertexHandle, 3>& c) const {
    for (int k = 0; k < 3; ++k) {
      if (c[k] == c[(k + 1) % 3]) return false;
      if (!mesh.is_boundary(c[k])) return false;  // a closed fan already
      const TriMesh::HalfedgeHandle h = mesh.find_halfedge(c[k], c[(k + 1) % 3]);
      if (h.is_valid() && !mesh.is_boundary(h)) return false;  // that side of the edge has its triangle
    }
    return true;
  }

  // Adds v's whole fan; false when a face of it could not be added (v is then unusable).
  bool load(std::uint32_t v) {
    const TriMesh::VertexHandle vh = vertex(v);
    std::uint8_t& s = state[static_cast<std::size_t>(vh.idx())];
    if (s != kLoose) return s == kLoaded;
    bool ok = true;
    for (const std::uint32_t t : entry.of(v)) {
      if (local_face[t] == kFailed) ok = false;
      if (local_face[t] != kAbsent) continue;
      const Triangle& tri = tris[t];
      const std::array<TriMesh::VertexHandle, 3> corners{vertex(tri[0]), vertex(tri[1]), vertex(tri[2])};
      const TriMesh::FaceHandle f =
          fits(corners) ? mesh.add_face(corners[0], corners[1], corners[2]) : TriMesh::FaceHandle();
      if (!f.is_valid()) {
        local_face[t] = kFailed;
        ok = false;
        continue;
      }
      local_face[t] = f.idx();
      global_face.resize(mesh.n_faces(), kNone);
      global_face[static_cast<std::size_t>(f.idx())] = t;
    }
    state[static_cast<std::size_t>(vh.idx())] = ok ? kLoaded : kUnusable;
    return ok;
  }
  bool loaded(std::uint32_t v) const {
    return local_vertex[v] != kAbsent && state[static_cast<std::size_t>(local_vertex[v])] == kLoaded;
  }
  bool load_all(std::initializer_list<std::uint32_t> vs) {
    for (const std::uint32_t v : vs) {
      if (!load(v)) return false;
    }
    return true;
  }

  // The halfedge u -> w, or an invalid handle; u must be loaded.
  TriMesh::HalfedgeHandle halfedge(std::uint32_t u, std::uint32_t w) {
    if (local_vertex[w] == kAbsent) return TriMesh::HalfedgeHandle();
    return mesh.find_halfedge(TriMesh::VertexHandle(local_vertex[u]), TriMesh::VertexHandle(local_vertex[w]));
  }
  std::uint32_t global(TriMesh::VertexHandle vh) const { return global_vertex[static_cast<std::size_t>(vh.idx())]; }
  std::uint32_t global(TriMesh::FaceHandle fh) const { return global_face[static_cast<std::size_t>(fh.idx())]; }

  // The site across directed edge (u, v) of t: the face of v -> u and its vertex opposite the edge. u must be loaded.
  std::optional<Across> across(std::uint32_t t, std::uint32_t u, std::uint32_t v, TriMesh::HalfedgeHandle& uv) {
    uv = halfedge(u, v);
    if (!uv.is_valid() || mesh.face_handle(uv) != TriMesh::FaceHandle(local_face[t])) return std::nullopt;
    const TriMesh::HalfedgeHandle vu = mesh.opposite_halfedge_handle(uv);
    if (mesh.is_boundary(vu)) return std::nullopt;
    return Across{global(mesh.face_handle(vu)), global(mesh.to_vertex_handle(mesh.next_halfedge_handle(vu)))};
  }
};

MeshEditor::MeshEditor(std::vector<Triangle>& triangles, const VertexTriangles& adjacency, std::size_t vertex_count)
    : triangles_(triangles), impl_(std::make_unique<Impl>(triangles, adjacency, vertex_count)) {}

MeshEditor::~MeshEditor() = default;

std::vector<std::uint32_t> MeshEditor::triangles_around(std::uint32_t v) const {
  if (!impl_->loaded(v)) {
    const auto row = impl_->entry.of(v);
    return {row.begin(), row.end()};
  }
  std::vector<std::uint32_t> out;
  const TriMesh& m = impl_->mesh;
  for (auto it = m.cvf_iter(TriMesh::VertexHandle(impl_->local_vertex[v])); it.is_valid(); ++it) {
    out.push_back(impl_->global(*it));
  }
  std::sort(out.begin(), out.end());
  return out;
}

std::size_t MeshEditor::triangle_count(std::uint32_t v) const {
  if (!impl_->loaded(v)) return impl_->entry.of(v).size();
  std::size_t count = 0;
  const TriMesh& m = impl_->mesh;
  for (auto it = m.cvf_iter(TriMesh::VertexHandle(impl_->local_vertex[v])); it.is_valid(); ++it) ++count;
  return count;
}

std::optional<MeshEditor::Across> MeshEditor::across(std::uint32_t t, std::uint32_t u, std::uint32_t v) const {
  if (impl_->loaded(u)) {
    TriMesh::HalfedgeHandle uv;
    return impl_->across(t, u, v, uv);
  }
  // u's entry fan is exact: the triangles on (u, v) other than t, exactly one of them holding v -> u.
  Across found;
  int count = 0;
  for (const std::uint32_t s : impl_->entry.of(u)) {
    if (s == t) continue;
    const Triangle& q = triangles_[s];
    for (int k = 0; k < 3; ++k) {
      if (q[k] == v && q[(k + 1) % 3] == u) {
        found = Across{s, q[(k + 2) % 3]};
        ++count;
      }
      if (q[k] == u && q[(k + 1) % 3] == v) ++count;  // a second triangle along u -> v: not manifold here
    }
  }
  if (count != 1 || found.triangle == kNone) return std::nullopt;
  return found;
}

std::vector<std::uint32_t> MeshEditor::neighbours(std::uint32_t v) const {
  std::vector<std::uint32_t> out;
  if (!impl_->loaded(v)) {
    for (const std::uint32_t s : impl_->entry.of(v)) {
      for (const std::uint32_t w : triangles_[s]) {
        if (w != v) out.push_back(w);
      }
    }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
  }
  const TriMesh& m = impl_->mesh;
  for (auto it = m.cvv_iter(TriMesh::VertexHandle(impl_->local_vertex[v])); it.is_valid(); ++it) {
    out.push_back(impl_->global(*it));
  }
  std::sort(out.begin(), out.end());
  return out;
}

int MeshEditor::edge_triangle_count(std::uint32_t u, std::uint32_t w) const {
  int count = 0;
  for (const std::uint32_t s : triangles_around(u)) {
    const Triangle& q = triangles_[s];
    count += q[0] == w || q[1] == w || q[2] == w;
  }
  return count;
}

bool MeshEditor::on_boundary(std::uint32_t v) const {
  for (const std::uint32_t w : neighbours(v)) {
    if (edge_triangle_count(v, w) == 1) return true;
  }
  return false;
}

std::optional<MeshEditor::Across> MeshEditor::flip_site(std::uint32_t t, std::uint32_t u, std::uint32_t v) {
  const Triangle& tri = triangles_[t];
  const std::uint32_t x = tri[0] != u && tri[0] != v ? tri[0] : tri[1] != u && tri[1] != v ? tri[1] : tri[2];
  if (!impl_->load_all({u, v, x})) return std::nullopt;
  TriMesh::HalfedgeHandle uv;
  const std::optional<Across> site = impl_->across(t, u, v, uv);
  if (!site || !impl_->load(site->vertex)) return std::nullopt;
  if (!impl_->mesh.is_flip_ok(impl_->mesh.edge_handle(uv))) return std::nullopt;
  return site;
}

void MeshEditor::flip(std::uint32_t t, std::uint32_t u, std::uint32_t v) {
  TriMesh::HalfedgeHandle uv;
  const Across site = *impl_->across(t, u, v, uv);
  const Triangle& tri = triangles_[t];
  const std::uint32_t x = tri[0] != u && tri[0] != v ? tri[0] : tri[1] != u && tri[1] != v ? tri[1] : tri[2];
  // OpenMesh's flip keeps each face on its side: t's face keeps u and x, t2's keeps v and y.
  impl_->mesh.flip(impl_->mesh.edge_handle(uv));
  triangles_[t] = Triangle{u, site.vertex, x};
  triangles_[site.triangle] = Triangle{site.vertex, v, x};
}

// Edge (keep, gone) of t in t's direction: (keep, gone) itself when t holds keep -> gone, else (gone, keep).
static std::pair<std::uint32_t, std::uint32_t> directed_in(const Triangle& tri, std::uint32_t keep,
                                                           std::uint32_t gone) {
  for (int k = 0; k < 3; ++k) {
    if (tri[k] == keep && tri[(k + 1) % 3] == gone) return {keep, gone};
  }
  return {gone, keep};
}

void MeshEditor::undo_flip(std::uint32_t t, std::uint32_t t2, const Triangle& old_t, const Triangle& old_t2) {
  // t = (u, y, x), t2 = (y, v, x) after the flip: flipping (y, x) back leaves t's face with y and u, which is old
  // t2's side, so the two triangles trade faces.
  const Triangle now = triangles_[t];
  TriMesh::HalfedgeHandle yx;
  impl_->across(t, now[1], now[2], yx);
  impl_->mesh.flip(impl_->mesh.edge_handle(yx));
  std::int32_t& ft = impl_->local_face[t];
  std::int32_t& ft2 = impl_->local_face[t2];
  std::swap(ft, ft2);
  impl_->global_face[static_cast<std::size_t>(ft)] = t;
  impl_->global_face[static_cast<std::size_t>(ft2)] = t2;
  triangles_[t] = old_t;
  triangles_[t2] = old_t2;
}

std::optional<MeshEditor::Across> MeshEditor::collapse_site(std::uint32_t t, std::uint32_t keep, std::uint32_t gone) {
  const Triangle& tri = triangles_[t];
  const std::uint32_t c = tri[0] != keep && tri[0] != gone   ? tri[0]
                          : tri[1] != keep && tri[1] != gone ? tri[1]
                                                             : tri[2];
  if (!impl_->load_all({keep, gone, c})) return std::nullopt;
  const auto [a, b] = directed_in(tri, keep, gone);
  TriMesh::HalfedgeHandle ab;
  const std::optional<Across> site = impl_->across(t, a, b, ab);
  if (!site || !impl_->load(site->vertex)) return std::nullopt;
  // OpenMesh collapses a halfedge's from-vertex into its to-vertex.
  const TriMesh::HalfedgeHandle h = a == gone ? ab : impl_->mesh.opposite_halfedge_handle(ab);
  if (!impl_->mesh.is_collapse_ok(h)) return std::nullopt;
  return site;
}

void MeshEditor::collapse(std::uint32_t t, std::uint32_t keep, std::uint32_t gone) {
  const auto [a, b] = directed_in(triangles_[t], keep, gone);
  TriMesh::HalfedgeHandle ab;
  const Across site = *impl_->across(t, a, b, ab);
  TriMesh& m = impl_->mesh;
  for (auto it = m.vf_iter(TriMesh::VertexHandle(impl_->local_vertex[gone])); it.is_valid(); ++it) {
    const std::uint32_t f = impl_->global(*it);
    if (f == t || f == site.triangle) continue;
    for (std::uint32_t& w : triangles_[f]) {
      if (w == gone) w = keep;
    }
  }
  m.collapse(a == gone ? ab : m.opposite_halfedge_handle(ab));
  triangles_[t] = Triangle{kNone, kNone, kNone};
  triangles_[site.triangle] = Triangle{kNone, kNone, kNone};
}

}  // namespace surfacer
