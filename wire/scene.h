// proto Scene -> core Field: the one translation from the wire schema to core's scene builders, and the small
// geometry messages (Vec3, Bounds) both ways.
#pragma once

#include <string>

#include "core/scene/scene.h"

namespace surfacer::v1 {
class Scene;
class Bounds;
class Vec3;
}  // namespace surfacer::v1

namespace surfacer::wire {

class UploadLookup;

// Builds the field of `scene`. `path` names the scene in the request (e.g. "spec.isosurface.scenes[0]") and
// prefixes every error: "spec.isosurface.scenes[0].root.sphere.radius (-1) must be > 0".
// If the field is unbounded and `unbounded_reason` is given, it receives why, naming the node that makes it so:
// "spec.isosurface.scenes[0].root.plane is unbounded; intersect it with a bounded solid".
// Throws surfacer::Error(kInvalidInput).
FieldPtr field_from_scene(const v1::Scene& scene, const std::string& path, const UploadLookup& uploads,
                          std::string* unbounded_reason = nullptr);

Vec3 to_vec3(const v1::Vec3& v);
// Throws InvalidInput naming `path` when a coordinate is not finite or min >= max on some axis.
Aabb to_aabb(const v1::Bounds& bounds, const std::string& path);
void set_vec3(v1::Vec3& out, const Vec3& v);
void set_bounds(v1::Bounds& out, const Aabb& box);

}  // namespace surfacer::wire
