#include "wire/particle_frames.h"

#include <cmath>
#include <cstring>
#include <limits>

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

// Calls begin(count, has_radius) once, then visit(i, x, y, z, r) for every particle (r = 0 without radii), after
// checking every value.
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
  if (!frame.upload_id().empty()) {
    if (frame.positions_size() > 0 || frame.radii_size() > 0) {
      throw InvalidInput(path + ".upload_id", path + ": give either inline positions or upload_id, not both");
    }
    const auto blob = uploads.get(frame.upload_id(), path + ".upload_id");
    const bool has_radius = frame.with_radius();
    const std::size_t record = (has_radius ? 4 : 3) * sizeof(float);
    if (blob->bytes.size() % record != 0) {
      throw InvalidInput(path + ".upload_id",
                         path + ".upload_id: the upload has " + std::to_string(blob->bytes.size()) +
                             " bytes, not a whole number of " + std::to_string(record) + "-byte records (float32 " +
                             (has_radius ? "x y z r" : "x y z") + "); check with_radius");
    }
    const std::size_t count = blob->bytes.size() / record;
    check_count(count, path, max_particles);
    begin(count, has_radius);
    const char* p = blob->bytes.data();
    for (std::size_t i = 0; i < count; ++i, p += record) {
      float v[4] = {0, 0, 0, 0};
      std::memcpy(v, p, record);
      check(i, v[0], v[1], v[2], v[3], has_radius);
      visit(i, v[0], v[1], v[2], v[3]);
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
  begin(count, has_radius);
  for (std::size_t i = 0; i < count; ++i) {
    const double x = frame.positions(3 * i), y = frame.positions(3 * i + 1), z = frame.positions(3 * i + 2);
    const double r = has_radius ? frame.radii(i) : 0.0;
    check(i, x, y, z, r, has_radius);
    visit(i, x, y, z, r);
  }
}

}  // namespace

ParticleSummary summarize_particle_frame(const v1::ParticleFrame& frame, const std::string& path,
                                         const UploadLookup& uploads, std::int64_t max_particles) {
  ParticleSummary summary;
  summary.bounds = Aabb::empty();
  for_each_particle(
      frame, path, uploads, max_particles,
      [&](std::size_t count, bool) { summary.count = static_cast<std::int64_t>(count); },
      [&](std::size_t, double x, double y, double z, double r) {
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
      },
      [&](std::size_t i, double x, double y, double z, double r) {
        data.positions[i] = Vec3(x, y, z);
        if (!data.radii.empty()) data.radii[i] = r;
      });
  return data;
}

}  // namespace surfacer::wire
