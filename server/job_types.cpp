#include "server/job_types.h"

#include "core/errors.h"

namespace surfacer::server {

std::unique_ptr<JobRunner> make_job_runner(const v1::JobSpec& spec, const JobContext& context) {
  switch (spec.kind_case()) {
    case v1::JobSpec::kIsosurface:
      return make_isosurface_runner(spec, context);
    case v1::JobSpec::kParticles:
      return make_particles_runner(spec, context);
    case v1::JobSpec::kOptimize:
      return make_optimize_runner(spec, context);
    case v1::JobSpec::KIND_NOT_SET:
      break;
  }
  throw InvalidInput("spec.kind", "spec has no job kind; set one of: isosurface, particles, optimize, active");
}

}  // namespace surfacer::server
