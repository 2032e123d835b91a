#include "server/particle_input.h"

#include <cmath>
#include <cstring>

#include "core/errors.h"
#include "server/uploads.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::server {
namespace {

void check_count(std::size_t count, const std::string& path, std::int64_t max_particles) {
  if (static_cast<std::int64_t>(count) > max_particles) {
    throw ResourceLimit("max_particles", path + " has " + std::to_string(count) +
                                             " particles, over the server's limit of " +
                                             std::to_string(max_particles) +
                                             " per frame; subsample, or start the server with a larger "
                                             "--max-particles");
  }
}

}  // namespace

ParticleData load_particle_frame(const v1::ParticleFrame& frame, const std::string& path, const UploadStore& uploads,
                                 std::int64_t max_particles) {
  ParticleData data;
  if (!frame.upload_id().empty()) {
    if (frame.positions_size() > 0 || frame.radii_size() > 0) {
      throw InvalidInput(path + ".upload_id", path + ": give either inline positions or upload_id, not both");
    }
    const auto blob = uploads.get(frame.upload_id(), path + ".upload_id");
    const std::size_t record = (frame.with_radius() ? 4 : 3) * sizeof(float);
    if (blob->bytes.size() % record != 0) {
      throw InvalidInput(path + ".upload_id",
                         path + ".upload_id: the upload has " + std::to_string(blob->bytes.size()) +
                             " bytes, not a whole number of " + std::to_string(record) + "-byte records (float32 " +
                             (frame.with_radius() ? "x y z r" : "x y z") + "); check with_radius");
    }
    const std::size_t count = blob->bytes.size() / record;
    check_count(count, path, max_particles);
    data.positions.resize(count);
    if (frame.with_radius()) data.radii.resize(count);
    const char* p = blob->bytes.data();
    for (std::size_t i = 0; i < count; ++i, p += record) {
      float v[4] = {0, 0, 0, 0};
      std::memcpy(v, p, record);
      data.positions[i] = Vec3(v[0], v[1], v[2]);
      if (frame.with_radius()) data.radii[i] = v[3];
    }
  } else {
    if (frame.positions_size() % 3 != 0) {
      throw InvalidInput(path + ".positions", path + ".positions has " + std::to_string(frame.positions_size()) +
                                                  " numbers, not a multiple of 3 (x, y, z per particle)");
    }
    const std::size_t count = frame.positions_size() / 3;
    check_count(count, path, max_particles);
    if (frame.radii_size() != 0 && static_cast<std::size_t>(frame.radii_size()) != count) {
      throw InvalidInput(path + ".radii", path + ".radii has " + std::to_string(frame.radii_size()) +
                                              " values for " + std::to_string(count) +
                                              " particles; give one per particle or none");
    }
    data.positions.resize(count);
    for (std::size_t i = 0; i < count; ++i) {
      data.positions[i] = Vec3(frame.positions(3 * i), frame.positions(3 * i + 1), frame.positions(3 * i + 2));
    }
    data.radii.assign(frame.radii().begin(), frame.radii().end());
  }
  if (data.positions.empty()) {
    throw InvalidInput(path, path + " has no particles; every frame needs at least one");
  }
  data.bounds.min = data.bounds.max = data.positions.front();
  for (std::size_t i = 0; i < data.positions.size(); ++i) {
    const Vec3& x = data.positions[i];
    if (!x.allFinite()) {
      throw InvalidInput(path, path + ": particle " + std::to_string(i) + " has a coordinate that is not finite");
    }
    data.bounds.min = data.bounds.min.cwiseMin(x);
    data.bounds.max = data.bounds.max.cwiseMax(x);
  }
  for (std::size_t i = 0; i < data.radii.size(); ++i) {
    if (!(data.radii[i] > 0.0) || !std::isfinite(data.radii[i])) {
      throw InvalidInput(path + ".radii", path + ": particle " + std::to_string(i) + " has radius " +
                                              std::to_string(data.radii[i]) + "; radii must be finite and > 0");
    }
  }
  return data;
}

}  // namespace surfacer::server
