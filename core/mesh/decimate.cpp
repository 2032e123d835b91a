#include "core/mesh/decimate.h"

#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Tools/Decimater/DecimaterT.hh>
#include <OpenMesh/Tools/Decimater/ModHausdorffT.hh>
#include <OpenMesh/Tools/Decimater/ModNormalFlippingT.hh>
#include <OpenMesh/Tools/Decimater/ModQuadricT.hh>
#include <OpenMesh/Tools/Decimater/Observer.hh>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>

#include "core/particles/spatial_hash.h"
#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "core/util/format.h"

namespace surfacer {
namespace {

struct DoubleTraits : OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3d;
  using Normal = OpenMesh::Vec3d;
};
using DecimationMesh = OpenMesh::TriMesh_ArrayKernelT<DoubleTraits>;

Vec3 to_vec3(const OpenMesh::Vec3d& p) { return {p[0], p[1], p[2]}; }

// The smallest angle of triangle (a, b, c), as its cosine's largest value (cosines decrease with the angle).
double max_cosine(const Vec3& a, const Vec3& b, const Vec3& c) {
  const auto cosine = [](const Vec3& apex, const Vec3& p, const Vec3& q) {
    const Vec3 u = p - apex, v = q - apex;
    const double norms = u.norm() * v.norm();
    return norms > 0.0 ? u.dot(v) / norms : 1.0;
  };
  return std::max({cosine(a, b, c), cosine(b, c, a), cosine(c, a, b)});
}

// Our rules for a collapse v0 -> v1 (binary): every triangle at v0 but the two that vanish, with v0 at p1, keeps its
// angles >= the minimum and its centroid and the midpoint of its new edge (v1, other) acceptable to the engine.
template <class MeshT>
class ModSurfaceRulesT : public OpenMesh::Decimater::ModBaseT<MeshT> {
 public:
  DECIMATING_MODULE(ModSurfaceRulesT, MeshT, SurfaceRules);

  explicit ModSurfaceRulesT(MeshT& mesh) : Base(mesh, true) {}

  void set_rules(double min_angle_degrees, const SurfacePointRule* acceptable) {
    max_cos_ = std::cos(min_angle_degrees * std::numbers::pi / 180.0);
    acceptable_ = acceptable;
  }

  float collapse_priority(const CollapseInfo& ci) override {
    MeshT& mesh = Base::mesh();
    const Vec3 p1 = to_vec3(ci.p1);
    // The faces that stay, with v0 moved to p1: the angles of all first (cheap), then the engine's rule.
    fans_.clear();
    for (auto fh : mesh.vf_range(ci.v0)) {
      if (fh == ci.fl || fh == ci.fr) continue;
      std::array<Vec3, 3> corner;
      int k = 0;
      for (auto vh : mesh.fv_range(fh)) corner[k++] = vh == ci.v0 ? p1 : to_vec3(mesh.point(vh));
      if (max_cosine(corner[0], corner[1], corner[2]) > max_cos_) return Base::ILLEGAL_COLLAPSE;
      fans_.push_back(corner);
    }
    if (acceptable_ && *acceptable_) {
      for (const auto& corner : fans_) {
        if (!(*acceptable_)((corner[0] + corner[1] + corner[2]) / 3.0)) return Base::ILLEGAL_COLLAPSE;
        // The midpoints of the new edges (v1, w); the edge between the other two corners is not new.
        for (const Vec3& w : corner) {
          if (w != p1 && !(*acceptable_)(0.5 * (p1 + w))) return Base::ILLEGAL_COLLAPSE;
        }
      }
    }
    return Base::LEGAL_COLLAPSE;
  }

 private:
  double max_cos_ = 1.0;
  const SurfacePointRule* acceptable_ = nullptr;
  std::vector<std::array<Vec3, 3>> fans_;
};

// Stops the Decimater when the job is cancelled.
class CancelObserver : public OpenMesh::Decimater::Observer {
 public:
  explicit CancelObserver(const RunControl& control) : Observer(kInterval), control_(control) {}
  void notify(std::size_t) override {}
  bool abort() const override { return control_.cancelled(); }

 private:
  static constexpr std::size_t kInterval = 1024;
  const RunControl& control_;
};

}  // namespace

Mesh decimate(const Mesh& mesh, const DecimateOptions& options, const SurfacePointRule& acceptable,
              const RunControl& control, DecimateStats* stats) {
  validate(options);
  const auto start = std::chrono::steady_clock::now();
  DecimateStats local;
  DecimateStats& s = stats ? *stats : local;
  s = {};
  s.vertices_before = mesh.vertices.size();
  s.triangles_before = mesh.triangles.size();
  Mesh out;
  if (options.tolerance == 0.0 || mesh.triangles.empty()) {
    out = mesh;
  } else {
    DecimationMesh om;
    om.reserve(mesh.vertices.size(), 3 * mesh.triangles.size() / 2, mesh.triangles.size());
    for (const Vec3& p : mesh.vertices) om.add_vertex(OpenMesh::Vec3d(p.x(), p.y(), p.z()));
    std::vector<Triangle> refused;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      const Triangle& tri = mesh.triangles[t];
      for (std::uint32_t v : tri) {
        if (v >= mesh.vertices.size()) {
          throw InvalidInput("triangles", "triangle " + std::to_string(t) + " names vertex " + std::to_string(v) +
                                              " of " + std::to_string(mesh.vertices.size()));
        }
      }
      // A face OpenMesh refuses (at a non-manifold edge or vertex) stays as it is, and so do its vertices.
      if (!om.add_face(om.vertex_handle(tri[0]), om.vertex_handle(tri[1]), om.vertex_handle(tri[2])).is_valid()) {
        refused.push_back(tri);
      }
    }
    // Boundary vertices stay: locking them keeps every boundary (and any face OpenMesh refused) exactly as it was.
    om.request_vertex_status();
    om.request_edge_status();
    om.request_face_status();
    for (auto vh : om.vertices()) {
      if (om.is_boundary(vh) || om.is_isolated(vh)) om.status(vh).set_locked(true);
    }
    for (const Triangle& tri : refused) {
      for (std::uint32_t v : tri) om.status(om.vertex_handle(v)).set_locked(true);
    }

    OpenMesh::Decimater::DecimaterT<DecimationMesh> decimater(om);
    OpenMesh::Decimater::ModQuadricT<DecimationMesh>::Handle quadric;
    OpenMesh::Decimater::ModHausdorffT<DecimationMesh>::Handle hausdorff;
    OpenMesh::Decimater::ModNormalFlippingT<DecimationMesh>::Handle normals;
    typename ModSurfaceRulesT<DecimationMesh>::Handle rules;
    om.request_face_normals();
    om.update_face_normals();
    // Binary modules run in the order added and stop at the first refusal: measured fastest in this order.
    decimater.add(quadric);
    decimater.add(normals);
    decimater.add(hausdorff);
    decimater.add(rules);
    // The quadric orders the collapses only; the Hausdorff module bounds the error.
    // The quadric (area-weighted, so not a distance) orders the collapses only; the Hausdorff module bounds the error.
    decimater.module(quadric).unset_max_err();
    decimater.module(hausdorff).set_tolerance(options.tolerance);
    decimater.module(normals).set_max_normal_deviation(DecimateOptions::kMaxNormalDeviationDegrees);
    decimater.module(rules).set_rules(options.min_angle_degrees, &acceptable);
    decimater.initialize();
    CancelObserver observer(control);
    decimater.set_observer(&observer);
    control.report("decimate", 0.0);
    s.collapses = decimater.decimate();
    control.check();

    // Surviving vertices in input order (OpenMesh renumbers only in garbage collection, not called), then the
    // faces, each from its first halfedge on (orientation kept), then the refused ones.
    constexpr std::uint32_t kGone = std::numeric_limits<std::uint32_t>::max();
    std::vector<std::uint32_t> new_index(mesh.vertices.size(), kGone);
    std::vector<std::uint32_t> kept;
    kept.reserve(mesh.vertices.size() - s.collapses);
    for (std::uint32_t v = 0; v < mesh.vertices.size(); ++v) {
      if (om.status(om.vertex_handle(v)).deleted()) continue;
      new_index[v] = static_cast<std::uint32_t>(kept.size());
      kept.push_back(v);
    }
    out.vertices.reserve(kept.size());
    for (std::uint32_t v : kept) out.vertices.push_back(mesh.vertices[v]);
    if (!mesh.normals.empty()) {
      out.normals.reserve(kept.size());
      for (std::uint32_t v : kept) out.normals.push_back(mesh.normals[v]);
    }
    for (const Attribute& a : mesh.attributes) {
      Attribute& b = out.attributes.emplace_back();
      b.name = a.name;
      b.components = a.components;
      b.values.reserve(kept.size() * static_cast<std::size_t>(a.components));
      for (std::uint32_t v : kept) {
        const auto first = a.values.begin() + static_cast<std::ptrdiff_t>(v) * a.components;
        b.values.insert(b.values.end(), first, first + a.components);
      }
    }
    out.triangles.reserve(om.n_faces());
    for (auto fh : om.faces()) {
      if (om.status(fh).deleted()) continue;
      Triangle tri;
      int k = 0;
      for (auto vh : om.fv_range(fh)) tri[k++] = new_index[vh.idx()];
      out.triangles.push_back(tri);
    }
    for (const Triangle& tri : refused) out.triangles.push_back({new_index[tri[0]], new_index[tri[1]], new_index[tri[2]]});
  }
  s.vertices_after = out.vertices.size();
  s.triangles_after = out.triangles.size();
  s.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

SurfacePointRule particle_band_rule(std::span<const Vec3> particles, std::span<const double> radii, double r_inner,
                                    double r_outer) {
  if (particles.empty()) return [](const Vec3&) { return false; };
  const double ratio = r_outer / r_inner;
  double largest_outer = r_outer;
  if (!radii.empty()) {
    largest_outer = 0.0;
    for (double r : radii) largest_outer = std::max(largest_outer, r * ratio);
  }
  auto hash = std::make_shared<SpatialHash>(particles, largest_outer);
  constexpr double kRelative = 1e-9;  // as the surfacer's faithful fraction
  if (radii.empty()) {
    const double inner = r_inner * (1.0 - kRelative), outer = r_outer * (1.0 + kRelative);
    // Two searches that stop at the first particle found: one in the outer ball (most often in x's own cell), none in
    // the inner one.
    return [hash, inner, outer](const Vec3& x) { return hash->any_within(x, outer) && !hash->any_within(x, inner); };
  }
  return [hash, radii, ratio, largest_outer](const Vec3& x) {
    bool inside_outer = false, outside_inner = true;
    hash->for_each_within(x, largest_outer * (1.0 + kRelative), [&](std::uint32_t i, const Vec3&, double d2) {
      const double d = std::sqrt(d2);
      if (d < radii[i] * (1.0 - kRelative)) outside_inner = false;
      if (d <= radii[i] * ratio * (1.0 + kRelative)) inside_outer = true;
    });
    return inside_outer && outside_inner;
  };
}

SurfacePointRule zero_set_rule(const Field& field, double tolerance) {
  return [&field, tolerance](const Vec3& x) {
    Vec3 gradient;
    const double f = std::abs(field.value_and_gradient(x, gradient));
    return f <= tolerance * gradient.norm();
  };
}

}  // namespace surfacer
