#include "wire/particle_frames.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <set>
#include <span>
#include <vector>

#include "core/util/errors.h"
#include "core/util/format.h"
#include "surfacer/v1/surfacer.pb.h"
#include "wire/uploads.h"

namespace surfacer::wire {
namespace {

void check_count(std::size_t count, const std::string& path, std::int64_t max_particles) {
  if (count == 0) throw InvalidInput(path, path + " has no particles; every frame needs at least one");
  if (static_cast<std::int64_t>(count) > max_particles) {
    throw ResourceLimit("max_particles", path + " has " + std::to_string(count) +
                                             " particles, over the server's limit of " + std::to_string(max_particles) +
                                             " per frame; subsample, or start the server with a larger "
                                             "--max-particles");
  }
}

std::size_t attribute_floats(const v1::ParticleFrame& frame, const std::string& path);

// Calls begin(count, has_radius) once, then visit(i, x, y, z, r, attribute_bytes) for every particle (r = 0
// without radii; attribute_bytes: its attributes' float32 values in the frame's order), after checking every value
// but the attributes'.
template <class Begin, class Visit>
void for_each_particle(const v1::ParticleFrame& frame, const std::string& path, const UploadLookup& uploads,
                       std::int64_t max_particles, Begin&& begin, Visit&& visit) {
  auto check = [&](std::size_t i, double x, double y, double z, double r, bool has_radius) {
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) {
      throw InvalidInput(path, path + ": particle " + std::to_string(i) + " has a coordinate that is not finite");
    }
    if (has_radius && !(r > 0.0 && std::isfinite(r))) {
      throw InvalidInput(path + ".radii", path + ": particle " + std::to_string(i) + " has radius " + format_number(r) +
                                              "; radii must be finite and > 0");
    }
  };
  const std::size_t extra = attribute_floats(frame, path);
  if (!frame.upload_id().empty()) {
    if (frame.positions_size() > 0 || frame.radii_size() > 0) {
      throw InvalidInput(path + ".upload_id", path + ": give either inline positions or upload_id, not both");
    }
    const auto blob = uploads.get(frame.upload_id(), path + ".upload_id");
    const bool has_radius = frame.with_radius();
    const std::size_t head = has_radius ? 4 : 3;
    const std::size_t record = (head + extra) * sizeof(float);
    if (blob->bytes.size() % record != 0) {
      throw InvalidInput(path + ".upload_id",
                         path + ".upload_id: the upload has " + std::to_string(blob->bytes.size()) +
                             " bytes, not a whole number of " + std::to_string(record) + "-byte records (float32 " +
                             (has_radius ? "x y z r" : "x y z") +
                             (extra > 0 ? " and " + std::to_string(extra) + " attribute values" : std::string()) +
                             "); check with_radius and attributes");
    }
    const std::size_t count = blob->bytes.size() / record;
    check_count(count, path, max_particles);
    begin(count, has_radius);
    const char* p = blob->bytes.data();
    for (std::size_t i = 0; i < count; ++i, p += record) {
      float v[4] = {0, 0, 0, 0};
      std::memcpy(v, p, head * sizeof(float));
      check(i, v[0], v[1], v[2], v[3], has_radius);
      visit(i, v[0], v[1], v[2], v[3], std::span<const char>(p + head * sizeof(float), extra * sizeof(float)));
    }
    return;
  }
  if (frame.positions_size() % 3 != 0) {
    throw InvalidInput(path + ".positions", path + ".positions has " + std::to_string(frame.positions_size()) +
                                                " numbers, not a multiple of 3 (x, y, z per particle)");
  }
  const std::size_t count = frame.positions_size() / 3;
  check_count(count, path, max_particles);
  const bool has_radius = frame.radii_size() > 0;
  if (has_radius && static_cast<std::size_t>(frame.radii_size()) != count) {
    throw InvalidInput(path + ".radii", path + ".radii has " + std::to_string(frame.radii_size()) + " values for " +
                                            std::to_string(count) + " particles; give one per particle or none");
  }
  for (int a = 0; a < frame.attributes_size(); ++a) {
    const v1::ParticleAttribute& attribute = frame.attributes(a);
    if (static_cast<std::size_t>(attribute.values_size()) != count * static_cast<std::size_t>(attribute.components())) {
      throw InvalidInput(path + ".attributes", path + ": attribute " + attribute.name() + " has " +
                                                   std::to_string(attribute.values_size()) + " values for " +
                                                   std::to_string(count) + " particles of " +
                                                   std::to_string(attribute.components()) + " components");
    }
  }
  begin(count, has_radius);
  std::vector<float> values(extra);
  for (std::size_t i = 0; i < count; ++i) {
    const double x = frame.positions(3 * i), y = frame.positions(3 * i + 1), z = frame.positions(3 * i + 2);
    const double r = has_radius ? frame.radii(i) : 0.0;
    check(i, x, y, z, r, has_radius);
    std::size_t at = 0;
    for (const v1::ParticleAttribute& attribute : frame.attributes()) {
      const std::size_t c = static_cast<std::size_t>(attribute.components());
      for (std::size_t k = 0; k < c; ++k) values[at++] = attribute.values(static_cast<int>(i * c + k));
    }
    visit(i, x, y, z, r,
          std::span<const char>(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(float)));
  }
}

// The floats each particle's attributes add (their components), after checking the names and component counts.
std::size_t attribute_floats(const v1::ParticleFrame& frame, const std::string& path) {
  std::size_t floats = 0;
  std::set<std::string> names;
  for (int a = 0; a < frame.attributes_size(); ++a) {
    const v1::ParticleAttribute& attribute = frame.attributes(a);
    const std::string where = path + ".attributes[" + std::to_string(a) + "]";
    if (attribute.name().empty() || !names.insert(attribute.name()).second) {
      throw InvalidInput(where + ".name", where + ": an attribute needs a name, distinct within the frame (\"" +
                                              attribute.name() + "\")");
    }
    if (attribute.components() < 1 || attribute.components() > Attribute::kMaxComponents) {
      throw InvalidInput(where + ".components", where + " (" + attribute.name() + "): components is " +
                                                    std::to_string(attribute.components()) +
                                                    "; it must be 1 (a scalar) to " +
                                                    std::to_string(Attribute::kMaxComponents));
    }
    floats += static_cast<std::size_t>(attribute.components());
  }
  return floats;
}

}  // namespace

ParticleSummary summarize_particle_frame(const v1::ParticleFrame& frame, const std::string& path,
                                         const UploadLookup& uploads, std::int64_t max_particles) {
  ParticleSummary summary;
  summary.bounds = Aabb::empty();
  for_each_particle(
      frame, path, uploads, max_particles,
      [&](std::size_t count, bool) { summary.count = static_cast<std::int64_t>(count); },
      [&](std::size_t, double x, double y, double z, double r, std::span<const char>) {
        summary.bounds.merge(Vec3(x, y, z));
        summary.max_radius = std::max(summary.max_radius, r);
      });
  return summary;
}

ParticleData load_particle_frame(const v1::ParticleFrame& frame, const std::string& path, const UploadLookup& uploads,
                                 std::int64_t max_particles) {
  ParticleData data;
  for_each_particle(
      frame, path, uploads, max_particles,
      [&](std::size_t count, bool has_radius) {
        data.positions.resize(count);
        if (has_radius) data.radii.resize(count);
        for (const v1::ParticleAttribute& a : frame.attributes()) {
          data.attributes.push_back({a.name(), a.components(), {}});
          data.attributes.back().values.resize(count * static_cast<std::size_t>(a.components()));
        }
      },
      [&](std::size_t i, double x, double y, double z, double r, std::span<const char> attribute_bytes) {
        data.positions[i] = Vec3(x, y, z);
        if (!data.radii.empty()) data.radii[i] = r;
        std::size_t at = 0;
        for (Attribute& a : data.attributes) {
          const std::size_t c = static_cast<std::size_t>(a.components);
          std::memcpy(&a.values[i * c], attribute_bytes.data() + at, c * sizeof(float));
          for (std::size_t k = 0; k < c; ++k) {
            if (!std::isfinite(a.values[i * c + k])) {
              throw InvalidInput(path + ".attributes", path + ": attribute " + a.name + " of particle " +
                                                           std::to_string(i) + " is not finite");
            }
          }
          at += c * sizeof(float);
        }
      });
  return data;
}

std::vector<std::string> interpolated_attributes(const v1::ParticlesJob& job, int index, const std::string& path) {
  const v1::ParticleFrame& frame = job.frames(index);
  std::vector<std::string> names;
  const bool all = job.interpolate_size() == 1 && job.interpolate(0) == "all";
  std::string has;
  for (const v1::ParticleAttribute& a : frame.attributes()) {
    has += (has.empty() ? "" : ", ") + a.name();
    if (all) names.push_back(a.name());
  }
  if (all) return names;
  for (const std::string& name : job.interpolate()) {
    if (name.empty() || std::count(names.begin(), names.end(), name) > 0) {
      throw InvalidInput(path + ".interpolate", path + ".interpolate: \"" + name +
                                                    "\" is empty or given twice; name each attribute once, or "
                                                    "give \"all\"");
    }
    const bool found = std::any_of(frame.attributes().begin(), frame.attributes().end(),
                                   [&](const v1::ParticleAttribute& a) { return a.name() == name; });
    if (!found) {
      throw InvalidInput(path + ".interpolate", path + ".frames[" + std::to_string(index) + "] has no attribute \"" +
                                                    name + "\" to interpolate (it has " + (has.empty() ? "none" : has) +
                                                    ")");
    }
    names.push_back(name);
  }
  return names;
}

}  // namespace surfacer::wire
