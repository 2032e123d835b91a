// Job `particles`: particle frames -> one smooth, watertight mesh per frame (Williams 2008), frames in parallel.
#include "core/particles/attribute_interpolation.h"
#include "core/particles/particle_surfacer.h"
#include "core/util/errors.h"
#include "server/runners/frames.h"
#include "server/runners/runner.h"
#include "wire/job_options.h"
#include "wire/particle_frames.h"

namespace surfacer::server {
namespace {

class ParticlesRunner final : public JobRunner {
 public:
  ParticlesRunner(std::vector<v1::ParticleFrame> frames, std::vector<std::vector<std::string>> interpolate,
                  const wire::UploadLookup& uploads, ParticleSurfacingOptions options, FrameMaker frame_maker,
                  const Limits& limits, int worker_threads)
      : frames_(std::move(frames)),
        interpolate_(std::move(interpolate)),
        uploads_(uploads),
        options_(std::move(options)),
        frame_maker_(std::move(frame_maker)),
        limits_(limits),
        worker_threads_(worker_threads) {}

  std::string kind() const override { return "particles"; }
  int task_count() const override { return static_cast<int>(frames_.size()); }
  int frame_count() const override { return task_count(); }

  void run_task(int index, FrameSink& sink, const RunControl& control) override {
    const std::string path = "spec.particles.frames[" + std::to_string(index) + "]";
    StageTimer timer;
    const wire::ParticleData data = timer.run(
        "decode", [&] { return wire::load_particle_frame(frames_[index], path, uploads_, limits_.max_particles); });
    ParticleSurfacingOptions options = options_;
    // A single frame gets every core; a sequence runs its frames in parallel, one thread each.
    options.threads = frames_.size() == 1 ? worker_threads_ : 1;
    ParticleSurfacingStats stats;
    Mesh mesh = surface_particles(data.positions, data.radii, options, control, &stats);
    control.check();
    timer.add("distance_field", stats.seconds_distance_field);
    timer.add("polygonize", stats.seconds_polygonize);
    timer.add("laplacian", stats.seconds_laplacian);
    timer.add("build_b", stats.seconds_build_b);
    timer.add("bilaplacian", stats.seconds_bilaplacian);
    timer.add("polish", stats.seconds_polish);
    if (options.erosion) timer.add("erosion", stats.seconds_erosion);
    timer.add("cleanup", stats.seconds_cleanup);
    if (!interpolate_[index].empty()) {
      std::vector<Attribute> carried;
      for (const std::string& name : interpolate_[index]) {
        for (const Attribute& a : data.attributes) {
          if (a.name == name) carried.push_back(a);
        }
      }
      timer.run("interpolate", [&] {
        AttributeInterpolationOptions support =
            AttributeInterpolationOptions::particle_support(stats.r_inner, stats.r_outer, data.radii);
        support.threads = options.threads;
        mesh.attributes = interpolate_attributes(data.positions, carried, mesh.vertices, support, control);
      });
    }
    FrameOutput frame = frame_maker_.make(std::move(mesh), timer, control);
    auto& metrics = *frame.stats.mutable_metrics();
    metrics["particles"] = static_cast<double>(stats.particles);
    metrics["particles_used"] = static_cast<double>(stats.particles_used);
    metrics["components_dropped"] = static_cast<double>(stats.components_dropped);
    metrics["r_inner"] = stats.r_inner;
    metrics["r_outer"] = stats.r_outer;
    metrics["spacing"] = stats.spacing;
    metrics["faithful_fraction"] = stats.faithful_after_constrained;
    metrics["faithful_fraction_final"] = stats.faithful_after_polish;
    metrics["max_violation"] = stats.max_violation_after_constrained;
    metrics["max_violation_final"] = stats.max_violation_after_polish;
    metrics["initial_min_valence"] = stats.initial_min_valence;
    metrics["field_evaluations"] = static_cast<double>(stats.field_evaluations);
    metrics["slivers_found"] = static_cast<double>(stats.slivers_found);
    metrics["slivers_left"] = static_cast<double>(stats.slivers_left);
    metrics["cusp_vertices"] = static_cast<double>(stats.cusp_vertices);
    metrics["bubbles_dropped"] = static_cast<double>(stats.bubbles_dropped);
    sink.emit(index, std::move(frame));
  }

 private:
  std::vector<v1::ParticleFrame> frames_;
  std::vector<std::vector<std::string>> interpolate_;  // per frame: the attributes carried onto its vertices
  const wire::UploadLookup& uploads_;
  ParticleSurfacingOptions options_;
  FrameMaker frame_maker_;
  Limits limits_;
  int worker_threads_;
};

}  // namespace

std::unique_ptr<JobRunner> make_particles_runner(const v1::JobSpec& spec, const JobContext& context) {
  const auto& job = spec.particles();
  const std::string path = "spec.particles";
  if (job.frames_size() == 0) {
    throw InvalidInput(path + ".frames", path + ".frames is empty; give at least one particle frame");
  }
  check_frame_count(job.frames_size(), path + ".frames", context.limits);
  if (job.interpolate_size() > 0 && spec.output().encoding() != v1::MESH_ENCODING_PLY) {
    throw InvalidInput("spec.output.encoding",
                       "spec.particles.interpolate: interpolated attributes travel in raw frames only "
                       "(spec.output.encoding MESH_ENCODING_PLY, --encoding raw); Draco and meshopt frames do not "
                       "carry them yet");
  }
  ParticleSurfacingOptions options = wire::particle_options(job, spec.output().normals(), path);
  options.container_solid = wire::container_solid(job, context.uploads, path);

  // Every frame is checked now (so bad data fails the submit, not a frame later), and the quantization box is the
  // union of the frames' particles, padded by how far the surface can reach.
  std::vector<v1::ParticleFrame> frames(job.frames().begin(), job.frames().end());
  std::vector<wire::ParticleSummary> summaries;
  summaries.reserve(frames.size());
  std::vector<std::vector<std::string>> interpolate;
  for (int i = 0; i < job.frames_size(); ++i) {
    interpolate.push_back(wire::interpolated_attributes(job, i, path));
    summaries.push_back(wire::summarize_particle_frame(job.frames(i), path + ".frames[" + std::to_string(i) + "]",
                                                       context.uploads, context.limits.max_particles));
  }
  const Aabb box = wire::particles_job_box(job, summaries, [&] {
    return wire::load_particle_frame(job.frames(0), path + ".frames[0]", context.uploads, context.limits.max_particles)
        .positions;
  });
  const FrameEncoding encoding = wire::frame_encoding(spec.output(), box, "spec.output");
  // The sliver repair also removes triangles that would be degenerate once quantized on the job's grid.
  options.output_grid = encoding.grid();
  return std::make_unique<ParticlesRunner>(
      std::move(frames), std::move(interpolate), context.uploads, std::move(options),
      FrameMaker(encoding, context.limits.max_triangles, context.executor), context.limits, context.worker_threads);
}

}  // namespace surfacer::server
