// Fuzz target: scene JSON, the way `surfacer run --scene FILE` reads it (client/job_spec.cpp: protobuf JSON with
// unknown fields rejected) -> wire/scene (validation, the one proto -> core translation) -> core Field ->
// value, gradient, bounds and Lipschitz bound at a few points.
// An input starting with a 0 byte is instead a binary v1.Scene, as a SubmitJob request carries it: mutations then
// reach every double bit pattern (denormals, 1e308) that JSON digits rarely hit.
// Expected failures are surfacer::Error (invalid or over-limit scenes); anything else escaping, a crash, UB or a
// violated property below is a bug.
#include <google/protobuf/stubs/logging.h>
#include <google/protobuf/util/json_util.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "fuzz/fuzz_input.h"
#include "surfacer/v1/scene.pb.h"
#include "wire/scene.h"
#include "wire/uploads.h"

namespace surfacer::fuzz {
namespace {

// Values this large make the arithmetic itself (not the code) lose every digit; properties are checked below it.
constexpr double kSane = 1e6;

bool sane(const Vec3& p) { return p.allFinite() && p.cwiseAbs().maxCoeff() < kSane; }

void probe(const Field& field) {
  std::vector<Vec3> points = {Vec3(0, 0, 0), Vec3(1, 2, 3), Vec3(-0.5, 0.25, 0.75), Vec3(3.5, -7, 11)};
  const std::optional<Aabb> bounds = field.bounds();
  if (bounds && bounds->min.allFinite() && bounds->max.allFinite()) {
    const Vec3 lo = bounds->min, hi = bounds->max;
    points.push_back(0.5 * lo + 0.5 * hi);
    points.push_back(lo);
    points.push_back(hi);
    points.push_back(0.25 * lo + 0.75 * hi);
  }
  const std::optional<double> lipschitz = field.lipschitz_bound();
  if (lipschitz) require(!(*lipschitz < 0.0), "lipschitz_bound() is negative");

  std::vector<double> values;
  for (const Vec3& p : points) {
    if (!p.allFinite()) continue;
    Vec3 gradient(7, 7, 7);
    const double v = field.value(p);
    const double vg = field.value_and_gradient(p, gradient);
    values.push_back(v);
    if (!sane(p) || !std::isfinite(v) || std::abs(v) > kSane) continue;
    // value() and value_and_gradient() evaluate the same function.
    require(std::abs(v - vg) <= 1e-9 * (1.0 + std::abs(v)), "value() and value_and_gradient() differ");
  }
  // Points well outside bounds() are outside the solid (value > 0): bounds() must contain all of {value <= 0}.
  if (bounds && sane(bounds->min) && sane(bounds->max)) {
    const double pad = 1.0 + bounds->size().maxCoeff();
    for (const Vec3& dir : {Vec3(1, 0, 0), Vec3(0, -1, 0), Vec3(0, 0, 1), Vec3(-1, -1, -1)}) {
      const Vec3 corner(dir.x() > 0 ? bounds->max.x() : bounds->min.x(),
                        dir.y() > 0 ? bounds->max.y() : bounds->min.y(),
                        dir.z() > 0 ? bounds->max.z() : bounds->min.z());
      const Vec3 p = corner + pad * dir;
      const double v = field.value(p);
      require(!(v <= 0.0), "value " + std::to_string(v) + " <= 0 outside bounds()");
    }
  }
  // |f(p) - f(q)| <= L |p - q| between the probe points.
  if (lipschitz && std::isfinite(*lipschitz) && *lipschitz < kSane) {
    std::size_t k = 0;
    for (std::size_t i = 0; i < points.size(); ++i) {
      if (!points[i].allFinite()) continue;
      const std::size_t vi = k++;
      std::size_t m = 0;
      for (std::size_t j = 0; j < i; ++j) {
        if (!points[j].allFinite()) continue;
        const std::size_t vj = m++;
        if (!sane(points[i]) || !sane(points[j])) continue;
        const double a = values[vi], b = values[vj];
        if (!std::isfinite(a) || !std::isfinite(b) || std::abs(a) > kSane || std::abs(b) > kSane) continue;
        const double d = (points[i] - points[j]).norm();
        require(std::abs(a - b) <= *lipschitz * d * (1 + 1e-9) + 1e-9 * (1 + std::abs(a) + std::abs(b)),
                "lipschitz_bound() " + std::to_string(*lipschitz) + " is too small");
      }
    }
  }
}

// Uploaded grids: scenes name them "u-grid" (3x3x3 float32 samples of a sphere's distance) or "u-odd" (7 bytes,
// not whole floats); the real store ids are random, so the names are swapped for them before translation.
struct Uploads {
  wire::MemoryUploads store;
  std::string grid_id, odd_id;

  Uploads() {
    auto grid = std::make_shared<wire::UploadBlob>();
    for (int k = 0; k < 3; ++k) {
      for (int j = 0; j < 3; ++j) {
        for (int i = 0; i < 3; ++i) {
          const float d = static_cast<float>(Vec3(i - 1, j - 1, k - 1).norm() - 0.8);
          grid->bytes.append(reinterpret_cast<const char*>(&d), sizeof d);
        }
      }
    }
    grid_id = "u-00000000000000a1";
    store.put(grid_id, grid);
    auto odd = std::make_shared<wire::UploadBlob>();
    odd->bytes = "1234567";
    odd_id = "u-00000000000000a2";
    store.put(odd_id, odd);
  }

  void rename(v1::Node& node) const {
    switch (node.kind_case()) {
      case v1::Node::kUnion:
        for (auto& child : *node.mutable_union_()->mutable_children()) rename(child);
        break;
      case v1::Node::kIntersection:
        for (auto& child : *node.mutable_intersection()->mutable_children()) rename(child);
        break;
      case v1::Node::kDifference:
        for (auto& child : *node.mutable_difference()->mutable_children()) rename(child);
        break;
      case v1::Node::kTransform:
        if (node.transform().has_child()) rename(*node.mutable_transform()->mutable_child());
        break;
      case v1::Node::kGrid:
        if (node.grid().upload_id() == "u-grid") node.mutable_grid()->set_upload_id(grid_id);
        if (node.grid().upload_id() == "u-odd") node.mutable_grid()->set_upload_id(odd_id);
        break;
      default:
        break;
    }
  }
};

}  // namespace
}  // namespace surfacer::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace surfacer;
  // No "invalid UTF-8" log line per input.
  [[maybe_unused]] static auto* const previous_handler = google::protobuf::SetLogHandler(nullptr);
  v1::Scene scene;
  google::protobuf::util::JsonParseOptions options;  // as client/job_spec.cpp: unknown fields are errors
  options.ignore_unknown_fields = false;
  if (size > 0 && data[0] == 0) {
    if (!scene.ParseFromArray(data + 1, static_cast<int>(size - 1))) return 0;
  } else if (!google::protobuf::util::JsonStringToMessage(fuzz::as_view(data, size), &scene, options).ok()) {
    return 0;
  }
  static const fuzz::Uploads uploads;  // any other upload_id must be rejected as unknown
  if (scene.has_root()) uploads.rename(*scene.mutable_root());
  FieldPtr field;
  try {
    field = wire::field_from_scene(scene, "scene", uploads.store);
  } catch (const Error& e) {
    fuzz::require(e.what()[0] != '\0', "an Error without a message");
    return 0;
  }
  fuzz::require(field != nullptr, "field_from_scene returned null");
  fuzz::probe(*field);  // outside the try: evaluating a built field must not throw
  return 0;
}
