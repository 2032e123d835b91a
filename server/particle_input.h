// Particle frames of a request (inline or uploaded float32 records) -> positions and radii, validated.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/mesh.h"

namespace surfacer::v1 {
class ParticleFrame;
}

namespace surfacer::server {

class UploadStore;

struct ParticleData {
  std::vector<Vec3> positions;
  std::vector<double> radii;  // empty, or one per particle
  Aabb bounds;                // of the positions (invalid when empty)
};

// Throws InvalidInput naming `path` (e.g. "spec.particles.frames[3]") for malformed data (NaN, a byte count that
// is not a whole number of records, radii count mismatch, negative radius), ResourceLimit naming --max-particles.
ParticleData load_particle_frame(const v1::ParticleFrame& frame, const std::string& path, const UploadStore& uploads,
                                 std::int64_t max_particles);

}  // namespace surfacer::server
