// Particle frames of a request (inline, or uploaded float32 records) -> positions and radii, validated.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/mesh/mesh.h"

namespace surfacer::v1 {
class ParticleFrame;
}  // namespace surfacer::v1

namespace surfacer::wire {

class UploadLookup;

struct ParticleData {
  std::vector<Vec3> positions;
  std::vector<double> radii;  // empty, or one per particle
};

struct ParticleSummary {
  std::int64_t count = 0;
  Aabb bounds;            // of the positions
  double max_radius = 0;  // 0 when the frame has no radii
};

// Validates a frame and summarizes it without keeping the positions (used at submit time for the job's bounds).
// Throws InvalidInput naming `path` (e.g. "spec.particles.frames[3]") for malformed data (NaN, a byte count that is
// not a whole number of records, a radii count mismatch, a radius <= 0, no particles), ResourceLimit naming
// --max-particles.
ParticleSummary summarize_particle_frame(const v1::ParticleFrame& frame, const std::string& path,
                                         const UploadLookup& uploads, std::int64_t max_particles);

// Decodes a frame (same checks).
ParticleData load_particle_frame(const v1::ParticleFrame& frame, const std::string& path, const UploadLookup& uploads,
                                 std::int64_t max_particles);

}  // namespace surfacer::wire
