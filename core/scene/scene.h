// Implicit scenes: fields built from primitives, skeletal blobs, CSG operations, affine transforms and sampled grids.
//
// Sign convention (docs/ALGORITHMS.md, "Notation"): every Field here is normalized to
//     value < 0 inside, value == 0 on the surface, value > 0 outside.
// Signed-distance nodes are already so; potential nodes (blobs, potential grids: inside where potential > iso) are
// converted as (iso - potential). No algorithm has to guess. Gradients are exact (forward-mode dual numbers or
// analytic derivatives), never finite differences; where a field is not differentiable (CSG seams, trilinear cell
// faces) a one-sided gradient is returned.
//
// Builders validate their arguments and throw surfacer::Error(kInvalidInput) with the argument name as `field`
// (e.g. "radius") and a message saying how to fix it; callers that know the path in a larger document prefix it.
// Coordinates and lengths (centres, end points, radii, sizes, offsets, a transform's reach) must lie within
// +-kMaxCoordinate (core/util/checks.h, 1e12), skeleton strengths too, and a Blinn blobbiness in (0, 100], so that
// no bound, padding or kernel value computed from them overflows.
#pragma once

#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "core/mesh/mesh.h"

namespace surfacer {

class Field {
 public:
  virtual ~Field() = default;
  // Normalized value at p (negative inside).
  virtual double value(const Vec3& p) const = 0;
  // Value and exact gradient at p.
  virtual double value_and_gradient(const Vec3& p, Vec3& gradient) const = 0;
  // A box containing the whole solid {value <= 0}, if the solid is bounded; nullopt for unbounded fields
  // (plane, gyroid, complement-like differences keep their first child's bounds).
  virtual std::optional<Aabb> bounds() const = 0;
  // A box containing {value <= level} for a level >= 0, if that set is bounded. Smooth CSG blends lower the value
  // by up to a quarter of their radius, so they ask their children for the set below that level. The default
  // knows only the solid itself (level <= 0).
  virtual std::optional<Aabb> sublevel_bounds(double level) const { return level <= 0.0 ? bounds() : std::nullopt; }
  // A hint for smooth unions: below this level sublevel_bounds() gives a box (+infinity where the value grows without
  // bound away from the solid, as distances do; a blob's iso, which its value tends to far away; -infinity for a
  // plane). The default: 0 if the solid is bounded.
  virtual double sublevel_limit() const { return bounds() ? 0.0 : -std::numeric_limits<double>::infinity(); }
  // A constant L with |value(p) - value(q)| <= L |p - q| for all p, q, if one is known; nullopt otherwise (the
  // default). Polygonizers use it to skip regions that cannot hold the surface (|value(c)| > L r: no zero within r
  // of c), so it must never be too small; a loose bound only costs speed. Signed distances give 1; CSG and
  // transforms combine their children's bounds; sampled grids and blobs compute one from their data.
  virtual std::optional<double> lipschitz_bound() const { return std::nullopt; }
  // A value with the sign of value(p) (a zero value counting as positive) and any magnitude. Polygonizers need exact
  // values only at the two ends of an edge the surface crosses: where sign_is_cheaper() says so they ask this first
  // and value() only for those ends. The default is value(p).
  virtual double sign_value(const Vec3& p) const { return value(p); }
  virtual bool sign_is_cheaper() const { return false; }
  // True only when every point of `box` is inside (value < 0); false when that is not known, which is always safe.
  // Polygonizers skip the cells whose tetrahedra lie in such a box. Fields that can tell cheaply (a particle field's
  // mask of cubes inside the balls) say so with answers_inside_boxes(); the default answers nothing.
  virtual bool inside_everywhere(const Aabb& box) const {
    (void)box;
    return false;
  }
  virtual bool answers_inside_boxes() const { return false; }
};

using FieldPtr = std::shared_ptr<const Field>;

// The nodes built here answer sublevel_bounds() at every level; their bounds() is level 0.
class SceneField : public Field {
 public:
  std::optional<Aabb> bounds() const final { return sublevel_bounds(0.0); }
  std::optional<Aabb> sublevel_bounds(double level) const override = 0;
};

// --- Primitives (signed distances, exact or a bound where noted) -----------------------------------------------
FieldPtr make_sphere(const Vec3& center, double radius);
FieldPtr make_box(const Vec3& center, const Vec3& half_size);
FieldPtr make_rounded_box(const Vec3& center, const Vec3& half_size, double radius);
FieldPtr make_cylinder(const Vec3& a, const Vec3& b, double radius);                 // capped
FieldPtr make_cone(const Vec3& a, const Vec3& b, double radius_a, double radius_b);  // capped, truncated
FieldPtr make_torus(const Vec3& center, const Vec3& axis, double major_radius, double minor_radius);
FieldPtr make_plane(const Vec3& normal, double offset);  // solid: dot(normal, x) <= offset (normal need not be unit)
FieldPtr make_capsule(const Vec3& a, const Vec3& b, double radius);
FieldPtr make_gyroid(double period, double thickness);  // unbounded sheet, see scene.proto

// --- Skeletal blobs (potentials, summed; inside where sum > iso) -----------------------------------------------
enum class BlobKernel { kWyvill, kBlinn };
struct PointSkeleton {
  Vec3 center = Vec3::Zero();
  double radius = 1.0;
  double strength = 1.0;
};
struct SegmentSkeleton {
  Vec3 a = Vec3::Zero();
  Vec3 b = Vec3::Zero();
  double radius = 1.0;
  double strength = 1.0;
};
struct BlobOptions {
  BlobKernel kernel = BlobKernel::kWyvill;
  double iso = 0.5;
  double blobbiness = 1.0;  // Blinn only
};
FieldPtr make_blobs(std::span<const PointSkeleton> points, std::span<const SegmentSkeleton> segments,
                    const BlobOptions& options);

// --- CSG ----------------------------------------------------------------------------------------------------
enum class CsgOp { kUnion, kIntersection, kDifference };  // difference: first minus all others
enum class CsgBlend {
  kMinMax,     // min/max
  kRFunction,  // Rvachev R0: union f1+f2-sqrt(f1^2+f2^2) in the negative-inside convention, etc.
  kSmooth,     // polynomial smooth min/max with blend radius
};
struct CsgOptions {
  CsgBlend blend = CsgBlend::kMinMax;
  double radius = 0.0;  // kSmooth only, > 0
};
// The smooth blend moves min(a, b) (union) or max(a, b) (intersection) by at most this times its radius. So a smooth
// union of n children goes at most (n - 1) times as far below its lowest child, and is unbounded when a child comes
// that close to its surface arbitrarily far away (blobs, whose value tends to iso there).
inline constexpr double kSmoothBlendDepth = 0.25;
// Requires at least two children.
FieldPtr make_csg(CsgOp op, std::vector<FieldPtr> children, const CsgOptions& options = {});

// --- Transforms ---------------------------------------------------------------------------------------------
// x_world = A x_local + t. The child is evaluated at A^-1 (x - t). With A = s R (uniform scale s, rotation R) the
// value is multiplied by s so distances stay exact; a general A keeps the sign and zero set (not exact distances).
FieldPtr make_transform(FieldPtr child, const Eigen::Matrix3d& linear, const Vec3& translation);

// --- Sampled grid -------------------------------------------------------------------------------------------
struct SampledGridDesc {
  Vec3 origin = Vec3::Zero();
  Vec3 spacing = Vec3::Ones();
  int nx = 0, ny = 0, nz = 0;  // >= 2 each
  bool potential = false;      // true: inside where value > iso
  double iso = 0.0;
};
// values: nx*ny*nz floats, x fastest. Trilinear inside the grid; outside it the value at the nearest grid point
// plus the distance to the grid box (so the solid never leaks out of the sampled region). Copies the values.
FieldPtr make_sampled_grid(const SampledGridDesc& desc, std::span<const float> values);

}  // namespace surfacer
