// Job types: each turns its part of a v1::JobSpec into a JobRunner, validating everything at submit time so
// that bad input answers INVALID_ARGUMENT / RESOURCE_EXHAUSTED before any work is queued.
#pragma once

#include <memory>

#include "server/jobs.h"
#include "server/server.h"

namespace surfacer::server {

class UploadStore;

struct JobContext {
  const Limits& limits;
  const UploadStore& uploads;
  int worker_threads = 1;
};

// Throws ResourceLimit naming --max-frames when `count` frames (requested at `field_path`) exceed the limit.
void check_frame_count(std::int64_t count, const std::string& field_path, const Limits& limits);

// Dispatches on spec.kind. Throws surfacer::Error naming the offending field ("spec.isosurface.cells").
std::unique_ptr<JobRunner> make_job_runner(const v1::JobSpec& spec, const JobContext& context);

std::unique_ptr<JobRunner> make_isosurface_runner(const v1::JobSpec& spec, const JobContext& context);
std::unique_ptr<JobRunner> make_particles_runner(const v1::JobSpec& spec, const JobContext& context);
std::unique_ptr<JobRunner> make_optimize_runner(const v1::JobSpec& spec, const JobContext& context);
std::unique_ptr<JobRunner> make_active_runner(const v1::JobSpec& spec, const JobContext& context);

}  // namespace surfacer::server
