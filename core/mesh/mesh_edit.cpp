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

  // The site across directed edge (u, v) of t: the face of v -> u and its vertex opposite the edge.
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

std::optional<std::vector<std::uint32_t>> MeshEditor::triangles_around(std::uint32_t v) {
  if (!impl_->load(v)) return std::nullopt;
  std::vector<std::uint32_t> out;
  const TriMesh& m = impl_->mesh;
  for (auto it = m.cvf_iter(TriMesh::VertexHandle(impl_->local_vertex[v])); it.is_valid(); ++it) {
    out.push_back(impl_->global(*it));
  }
  return out;
}

std::optional<std::vector<std::uint32_t>> MeshEditor::neighbours(std::uint32_t v) {
  if (!impl_->load(v)) return std::nullopt;
  std::vector<std::uint32_t> out;
  const TriMesh& m = impl_->mesh;
  for (auto it = m.cvv_iter(TriMesh::VertexHandle(impl_->local_vertex[v])); it.is_valid(); ++it) {
    out.push_back(impl_->global(*it));
  }
  std::sort(out.begin(), out.end());
  return out;
}

std::optional<int> MeshEditor::edge_triangle_count(std::uint32_t u, std::uint32_t w) {
  if (!impl_->load_all({u, w})) return std::nullopt;
  const TriMesh::HalfedgeHandle h = impl_->halfedge(u, w);
  if (!h.is_valid()) return 0;
  const TriMesh& m = impl_->mesh;
  return (m.is_boundary(h) ? 0 : 1) + (m.is_boundary(m.opposite_halfedge_handle(h)) ? 0 : 1);
}

std::optional<bool> MeshEditor::on_boundary(std::uint32_t v) {
  if (!impl_->load(v)) return std::nullopt;
  return impl_->mesh.is_boundary(TriMesh::VertexHandle(impl_->local_vertex[v]));
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

std::optional<MeshEditor::Across> MeshEditor::collapse_site(std::uint32_t t, std::uint32_t a, std::uint32_t b) {
  const Triangle& tri = triangles_[t];
  const std::uint32_t c = tri[0] != a && tri[0] != b ? tri[0] : tri[1] != a && tri[1] != b ? tri[1] : tri[2];
  if (!impl_->load_all({a, b, c})) return std::nullopt;
  TriMesh::HalfedgeHandle ab;
  const std::optional<Across> site = impl_->across(t, a, b, ab);
  if (!site || !impl_->load(site->vertex)) return std::nullopt;
  // OpenMesh collapses a halfedge's from-vertex into its to-vertex: b -> a.
  if (!impl_->mesh.is_collapse_ok(impl_->mesh.opposite_halfedge_handle(ab))) return std::nullopt;
  return site;
}

void MeshEditor::collapse(std::uint32_t t, std::uint32_t a, std::uint32_t b) {
  TriMesh::HalfedgeHandle ab;
  const Across site = *impl_->across(t, a, b, ab);
  TriMesh& m = impl_->mesh;
  for (auto it = m.vf_iter(TriMesh::VertexHandle(impl_->local_vertex[b])); it.is_valid(); ++it) {
    const std::uint32_t f = impl_->global(*it);
    if (f == t || f == site.triangle) continue;
    for (std::uint32_t& w : triangles_[f]) {
      if (w == b) w = a;
    }
  }
  m.collapse(m.opposite_halfedge_handle(ab));
  triangles_[t] = Triangle{kNone, kNone, kNone};
  triangles_[site.triangle] = Triangle{kNone, kNone, kNone};
}

}  // namespace surfacer
