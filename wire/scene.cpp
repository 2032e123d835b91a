#include "wire/scene.h"

#include <Eigen/Geometry>
#include <cmath>
#include <cstring>

#include "core/util/checks.h"
#include "core/util/errors.h"
#include "surfacer/v1/scene.pb.h"
#include "wire/enums.h"
#include "wire/protocol.h"
#include "wire/request_limits.h"
#include "wire/uploads.h"

namespace surfacer::wire {
namespace {

using NodeProto = v1::Node;

double or_default(double value, double fallback) { return value == 0.0 ? fallback : value; }

class Translator {
 public:
  Translator(const UploadLookup& uploads, std::string root) : uploads_(uploads), root_(std::move(root)) {}

  FieldPtr node(const NodeProto& n, const std::string& path) {
    if (++depth_ > kMaxSceneDepth) throw InvalidInput(root_, root_ + ": " + scene_too_deep());
    std::string outer_reason = std::move(unbounded_reason_);
    unbounded_reason_.clear();
    FieldPtr result = dispatch(n, path);
    --depth_;
    const auto where = [&] { return path + "." + NodeProto::descriptor()->FindFieldByNumber(n.kind_case())->name(); };
    if (const std::optional<Aabb> b = result->bounds()) {
      // Every argument is within range, but some nodes reach far beyond them (a Blinn kernel of tiny blobbiness).
      const double reach = std::max(b->min.cwiseAbs().maxCoeff(), b->max.cwiseAbs().maxCoeff());
      if (!(reach <= kMaxCoordinate)) {
        throw InvalidInput(where(), where() + ": the node reaches " + format_number(reach) + ", beyond +-" +
                                        format_number(kMaxCoordinate) +
                                        ", the range of coordinates; bring its arguments into a smaller region");
      }
      unbounded_reason_ = std::move(outer_reason);  // an unbounded descendant was bounded here
    } else if (unbounded_reason_.empty()) {
      // No child is unbounded (csg() explains a smooth union's own reach): the node itself is, a plane or gyroid.
      unbounded_reason_ = where() + " is unbounded; intersect it with a bounded solid";
    }
    return result;
  }

  // Why the last node translated is unbounded (empty if it is bounded): the deepest node that made it so.
  const std::string& unbounded_reason() const { return unbounded_reason_; }

 private:
  FieldPtr dispatch(const NodeProto& n, const std::string& path) {
    switch (n.kind_case()) {
      case NodeProto::kSphere: {
        const auto& s = n.sphere();
        return with_path(path + ".sphere", [&] { return make_sphere(to_vec3(s.center()), s.radius()); });
      }
      case NodeProto::kBox: {
        const auto& b = n.box();
        return with_path(path + ".box", [&] { return make_box(to_vec3(b.center()), to_vec3(b.half_size())); });
      }
      case NodeProto::kRoundedBox: {
        const auto& b = n.rounded_box();
        return with_path(path + ".rounded_box",
                         [&] { return make_rounded_box(to_vec3(b.center()), to_vec3(b.half_size()), b.radius()); });
      }
      case NodeProto::kCylinder: {
        const auto& c = n.cylinder();
        return with_path(path + ".cylinder", [&] { return make_cylinder(to_vec3(c.a()), to_vec3(c.b()), c.radius()); });
      }
      case NodeProto::kCone: {
        const auto& c = n.cone();
        return with_path(path + ".cone",
                         [&] { return make_cone(to_vec3(c.a()), to_vec3(c.b()), c.radius_a(), c.radius_b()); });
      }
      case NodeProto::kTorus: {
        const auto& t = n.torus();
        Vec3 axis = to_vec3(t.axis());
        if (axis.isZero()) axis = Vec3::UnitZ();
        return with_path(path + ".torus",
                         [&] { return make_torus(to_vec3(t.center()), axis, t.major_radius(), t.minor_radius()); });
      }
      case NodeProto::kPlane: {
        const auto& p = n.plane();
        return with_path(path + ".plane", [&] { return make_plane(to_vec3(p.normal()), p.offset()); });
      }
      case NodeProto::kCapsule: {
        const auto& c = n.capsule();
        return with_path(path + ".capsule", [&] { return make_capsule(to_vec3(c.a()), to_vec3(c.b()), c.radius()); });
      }
      case NodeProto::kGyroid: {
        const auto& g = n.gyroid();
        return with_path(path + ".gyroid", [&] { return make_gyroid(g.period(), g.thickness()); });
      }
      case NodeProto::kBlobs:
        return blobs(n.blobs(), path + ".blobs");
      case NodeProto::kUnion:
        return csg(CsgOp::kUnion, n.union_(), path + ".union");
      case NodeProto::kIntersection:
        return csg(CsgOp::kIntersection, n.intersection(), path + ".intersection");
      case NodeProto::kDifference:
        return csg(CsgOp::kDifference, n.difference(), path + ".difference");
      case NodeProto::kTransform:
        return transform(n.transform(), path + ".transform");
      case NodeProto::kGrid:
        return grid(n.grid(), path + ".grid");
      case NodeProto::KIND_NOT_SET:
        break;
    }
    throw InvalidInput(path, path +
                                 " is empty; give one of sphere, box, rounded_box, cylinder, cone, torus, "
                                 "plane, capsule, gyroid, blobs, union, intersection, difference, transform, grid");
  }

  FieldPtr blobs(const v1::Blobs& b, const std::string& path) {
    std::vector<PointSkeleton> points;
    points.reserve(b.points_size());
    for (const auto& p : b.points()) {
      points.push_back({to_vec3(p.center()), p.radius(), or_default(p.strength(), 1.0)});
    }
    std::vector<SegmentSkeleton> segments;
    segments.reserve(b.segments_size());
    for (const auto& s : b.segments()) {
      segments.push_back({to_vec3(s.a()), to_vec3(s.b()), s.radius(), or_default(s.strength(), 1.0)});
    }
    BlobOptions options;
    require_known_enum(v1::Kernel_descriptor(), b.kernel(), path + ".kernel");
    options.kernel = b.kernel() == v1::KERNEL_BLINN ? BlobKernel::kBlinn : BlobKernel::kWyvill;
    options.iso = or_default(b.iso(), 0.5);
    options.blobbiness = or_default(b.blobbiness(), 1.0);
    return with_path(path, [&] { return make_blobs(points, segments, options); });
  }

  FieldPtr csg(CsgOp op, const v1::Csg& c, const std::string& path) {
    std::vector<FieldPtr> children;
    children.reserve(c.children_size());
    for (int i = 0; i < c.children_size(); ++i) {
      children.push_back(node(c.children(i), path + ".children[" + std::to_string(i) + "]"));
    }
    CsgOptions options;
    require_known_enum(v1::Blend_descriptor(), c.blend(), path + ".blend");
    switch (c.blend()) {
      case v1::BLEND_RFUNCTION:
        options.blend = CsgBlend::kRFunction;
        break;
      case v1::BLEND_SMOOTH:
        options.blend = CsgBlend::kSmooth;
        break;
      default:
        options.blend = CsgBlend::kMinMax;
        break;
    }
    options.radius = c.radius();
    FieldPtr result = with_path(path, [&] { return make_csg(op, children, options); });
    if (op == CsgOp::kUnion && options.blend == CsgBlend::kSmooth && unbounded_reason_.empty() && !result->bounds()) {
      // Every child is bounded, but the blend reaches below the one that stays nearest its surface far away.
      std::size_t i = 0;
      double limit = children[0]->sublevel_limit();
      for (std::size_t j = 1; j < children.size(); ++j) {
        const double l = children[j]->sublevel_limit();
        if (l < limit) {
          i = j;
          limit = l;
        }
      }
      const NodeProto& child = c.children(static_cast<int>(i));
      unbounded_reason_ = path + " is unbounded: its smooth blend (radius " + format_number(options.radius) +
                          ") lowers the value by up to " + format_number(kSmoothBlendDepth * options.radius) +
                          " per child where children come within the radius of each other, and " + path + ".children[" +
                          std::to_string(i) + "]." +
                          NodeProto::descriptor()->FindFieldByNumber(child.kind_case())->name() + " stays within " +
                          format_number(limit) +
                          " of its surface arbitrarily far away; give a smaller radius, or bounds";
    }
    return result;
  }

  FieldPtr transform(const v1::Transform& t, const std::string& path) {
    if (!t.has_child()) {
      throw InvalidInput(path + ".child", path + ".child is missing; a transform applies to one child node");
    }
    FieldPtr child = node(t.child(), path + ".child");
    Eigen::Matrix3d linear;
    Vec3 translation;
    if (t.matrix_size() > 0) {
      if (t.matrix_size() != 12) {
        throw InvalidInput(path + ".matrix", path + ".matrix has " + std::to_string(t.matrix_size()) +
                                                 " numbers; give 12 (row-major 3x4 [A | t]) or none");
      }
      for (int i = 0; i < 12; ++i) {
        with_path(path, [&] { require_coordinate("matrix[" + std::to_string(i) + "]", t.matrix(i)); });
      }
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) linear(r, c) = t.matrix(4 * r + c);
        translation[r] = t.matrix(4 * r + 3);
      }
    } else {
      const double scale = or_default(t.scale(), 1.0);
      const Vec3 axis = to_vec3(t.rotate_axis());
      with_path(path, [&] {
        require_range("scale", scale, 1.0 / kMaxCoordinate, kMaxCoordinate, "0 or absent means 1");
        require_finite("rotate_axis", axis);
        require_finite("rotate_degrees", t.rotate_degrees());
        require_coordinate("translate", to_vec3(t.translate()));
      });
      Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
      if (t.rotate_degrees() != 0.0) {
        const double largest = axis.cwiseAbs().maxCoeff();  // scaled first: the norm of a huge axis overflows
        if (!(largest > 0.0)) {
          throw InvalidInput(path + ".rotate_axis",
                             path + ".rotate_axis is zero; give the axis to rotate about, e.g. {\"z\": 1}");
        }
        // Whole turns dropped first: sin and cos of a huge angle in radians lose every digit.
        const double degrees = std::fmod(t.rotate_degrees(), 360.0);
        rotation = Eigen::AngleAxisd(degrees * M_PI / 180.0, (axis / largest).normalized()).toRotationMatrix();
      }
      linear = scale * rotation;
      translation = to_vec3(t.translate());
    }
    // The builder names its arguments `linear` / `translation`; the request calls them matrix / scale.
    return with_path(path + "." + (t.matrix_size() > 0 ? "matrix" : "scale"),
                     [&] { return make_transform(child, linear, translation); });
  }

  FieldPtr grid(const v1::SampledGrid& g, const std::string& path) {
    SampledGridDesc desc;
    desc.origin = to_vec3(g.origin());
    desc.spacing = to_vec3(g.spacing());
    desc.nx = g.nx();
    desc.ny = g.ny();
    desc.nz = g.nz();
    desc.potential = g.potential();
    desc.iso = g.iso();
    if (!g.upload_id().empty()) {
      if (g.values_size() > 0) {
        throw InvalidInput(path + ".values", path + ": give either values or upload_id, not both");
      }
      auto blob = uploads_.get(g.upload_id(), path + ".upload_id");
      if (blob->bytes.size() % sizeof(float) != 0) {
        throw InvalidInput(path + ".upload_id", path + ".upload_id: upload has " + std::to_string(blob->bytes.size()) +
                                                    " bytes, not a whole number of float32 values");
      }
      std::vector<float> values(blob->bytes.size() / sizeof(float));
      std::memcpy(values.data(), blob->bytes.data(), values.size() * sizeof(float));
      return with_path(path, [&] { return make_sampled_grid(desc, values); });
    }
    return with_path(
        path, [&] { return make_sampled_grid(desc, std::span<const float>(g.values().data(), g.values_size())); });
  }

  const UploadLookup& uploads_;
  const std::string root_;  // the scene's root node, where a depth error points
  int depth_ = 0;
  std::string unbounded_reason_;
};

}  // namespace

Vec3 to_vec3(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

Aabb to_aabb(const v1::Bounds& bounds, const std::string& path) {
  const Aabb box{to_vec3(bounds.min()), to_vec3(bounds.max())};
  require_box(path, box);
  return box;
}

void set_vec3(v1::Vec3& out, const Vec3& v) {
  out.set_x(v.x());
  out.set_y(v.y());
  out.set_z(v.z());
}

void set_bounds(v1::Bounds& out, const Aabb& box) {
  set_vec3(*out.mutable_min(), box.min);
  set_vec3(*out.mutable_max(), box.max);
}

FieldPtr field_from_scene(const v1::Scene& scene, const std::string& path, const UploadLookup& uploads,
                          std::string* unbounded_reason) {
  if (!scene.has_root()) {
    throw InvalidInput(path + ".root", path +
                                           ".root is missing; a scene needs a root node, e.g. "
                                           "{\"root\": {\"sphere\": {\"radius\": 1}}}");
  }
  Translator translator(uploads, path + ".root");
  FieldPtr field = translator.node(scene.root(), path + ".root");
  if (unbounded_reason) *unbounded_reason = translator.unbounded_reason();
  return field;
}

}  // namespace surfacer::wire
