// Particle frames of a request (inline, or uploaded float32 records) -> positions and radii, validated.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/mesh/mesh.h"

namespace surfacer::v1 {
class ParticleFrame;
class ParticlesJob;
}  // namespace surfacer::v1

namespace surfacer::wire {

class UploadLookup;

struct ParticleData {
  std::vector<Vec3> positions;
  std::vector<double> radii;          // empty, or one per particle
  std::vector<Attribute> attributes;  // the frame's ParticleAttributes, one element per particle each
};

struct ParticleSummary {
  std::int64_t count = 0;
  Aabb bounds;            // of the positions
  double max_radius = 0;  // 0 when the frame has no radii
};

// Particle frames of a request (positions, radii and attributes) -> core types. Attributes (ParticleAttribute) need a
// non-empty name unique in the frame, 1 to Attribute::kMaxComponents components and finite values, one element per
// particle (inline), and add their components to every upload record.
//
// Validates a frame and summarizes it without keeping the positions (used at submit time for the job's bounds).
// Throws InvalidInput naming `path` (e.g. "spec.particles.frames[3]") for malformed data (NaN, a byte count that is
// not a whole number of records, a radii count mismatch, a radius <= 0, no particles), ResourceLimit naming
// --max-particles.
ParticleSummary summarize_particle_frame(const v1::ParticleFrame& frame, const std::string& path,
                                         const UploadLookup& uploads, std::int64_t max_particles);

// Decodes a frame (same checks).
ParticleData load_particle_frame(const v1::ParticleFrame& frame, const std::string& path, const UploadLookup& uploads,
                                 std::int64_t max_particles);

// The attributes of frame `index` of `job` to interpolate (ParticlesJob.interpolate; "all": every one the frame
// carries), in the order named (the frame's order for "all"). Throws InvalidInput("spec.particles.interpolate") naming
// the frame and the attributes it has when it lacks one, or for an empty name or a name given twice.
std::vector<std::string> interpolated_attributes(const v1::ParticlesJob& job, int index, const std::string& path);

}  // namespace surfacer::wire
