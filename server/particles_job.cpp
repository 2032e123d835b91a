// Job `particles`: particle frames -> one smooth, watertight mesh per frame (Williams 2008), frames in parallel.
#include <cmath>
#include <limits>

#include "core/util/errors.h"
#include "core/particles/particle_surfacer.h"
#include "server/frames.h"
#include "server/job_types.h"
#include "server/particle_input.h"
#include "server/scene_translate.h"

namespace surfacer::server {
namespace {

class ParticlesRunner final : public JobRunner {
 public:
  ParticlesRunner(std::vector<v1::ParticleFrame> frames, const UploadStore& uploads, ParticleSurfacingOptions options,
                  FrameEncoding encoding, const Limits& limits, int worker_threads)
      : frames_(std::move(frames)),
        uploads_(uploads),
        options_(std::move(options)),
        encoding_(encoding),
        limits_(limits),
        worker_threads_(worker_threads) {}

  std::string kind() const override { return "particles"; }
  int task_count() const override { return static_cast<int>(frames_.size()); }
  int frame_count() const override { return task_count(); }

  void run_task(int index, FrameSink& sink, const RunControl& control) override {
    const std::string path = "spec.particles.frames[" + std::to_string(index) + "]";
    StageTimer timer;
    const ParticleData data = timer.run(
        "decode", [&] { return load_particle_frame(frames_[index], path, uploads_, limits_.max_particles); });
    ParticleSurfacingOptions options = options_;
    // A single frame gets every core; a sequence runs its frames in parallel, one thread each.
    options.threads = frames_.size() == 1 ? worker_threads_ : 1;
    ParticleSurfacingStats stats;
    const Mesh mesh = surface_particles(data.positions, data.radii, options, control, &stats);
    control.check();
    timer.add("distance_field", stats.seconds_distance_field);
    timer.add("polygonize", stats.seconds_polygonize);
    timer.add("laplacian", stats.seconds_laplacian);
    timer.add("build_b", stats.seconds_build_b);
    timer.add("bilaplacian", stats.seconds_bilaplacian);
    timer.add("polish", stats.seconds_polish);
    if (options.erosion) timer.add("erosion", stats.seconds_erosion);
    FrameOutput frame = make_frame(mesh, encoding_, limits_.max_triangles, timer);
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
    sink.emit(index, std::move(frame));
  }

 private:
  std::vector<v1::ParticleFrame> frames_;
  const UploadStore& uploads_;
  ParticleSurfacingOptions options_;
  FrameEncoding encoding_;
  Limits limits_;
  int worker_threads_;
};

template <class T>
void positive_count(const std::string& field, const T& value) {
  if (value < 0) throw InvalidInput(field, field + " (" + std::to_string(value) + ") must be >= 0");
}

}  // namespace

std::unique_ptr<JobRunner> make_particles_runner(const v1::JobSpec& spec, const JobContext& context) {
  const auto& job = spec.particles();
  const std::string path = "spec.particles";
  if (job.frames_size() == 0) {
    throw InvalidInput(path + ".frames", path + ".frames is empty; give at least one particle frame");
  }
  check_frame_count(job.frames_size(), path + ".frames", context.limits);
  ParticleSurfacingOptions options;
  if (job.has_r_inner()) options.r_inner = job.r_inner();
  options.derive_r_inner = job.derive_r_inner();
  if (job.has_r_outer()) options.r_outer = job.r_outer();
  if (job.has_spacing_factor()) options.spacing_factor = job.spacing_factor();
  if (job.has_laplacian_sweeps()) options.laplacian_sweeps = job.laplacian_sweeps();
  if (job.has_bilaplacian_sweeps()) options.bilaplacian_sweeps = job.bilaplacian_sweeps();
  if (job.has_polish_sweeps()) options.polish_sweeps = job.polish_sweeps();
  if (job.has_relaxation()) options.relaxation = job.relaxation();
  if (job.has_erosion()) options.erosion = job.erosion();
  if (job.container().has_box()) options.container_box = to_aabb(job.container().box(), path + ".container.box");
  if (job.container().has_solid()) {
    options.container_solid = field_from_scene(job.container().solid(), path + ".container.solid", context.uploads);
  }
  positive_count(path + ".min_particles_per_component", job.min_particles_per_component());
  options.min_particles_per_component = job.min_particles_per_component();
  options.normals = spec.output().normals();
  try {
    ParticleSurfacer validate(options);  // the constructor checks every option
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    throw InvalidInput(path + "." + e.field(), path + "." + e.what());
  }

  // Every frame is checked now (so bad data fails the submit, not a frame later), and the quantization box is the
  // union of the frames' particles, padded by how far the surface can reach: r_outer (or the largest particle's).
  std::vector<v1::ParticleFrame> frames(job.frames().begin(), job.frames().end());
  Aabb box;
  double max_radius = 0.0;
  for (int i = 0; i < job.frames_size(); ++i) {
    const auto summary = summarize_particle_frame(job.frames(i), path + ".frames[" + std::to_string(i) + "]",
                                                  context.uploads, context.limits.max_particles);
    box = i == 0 ? summary.bounds : Aabb{box.min.cwiseMin(summary.bounds.min), box.max.cwiseMax(summary.bounds.max)};
    max_radius = std::max(max_radius, summary.max_radius);
    if (summary.max_radius == 0.0 && !options.r_inner && !options.derive_r_inner) {
      throw InvalidInput(path + ".r_inner", path + ".r_inner is required: frame " + std::to_string(i) +
                                                " has no per-particle radii; give r_inner (e.g. the simulation's "
                                                "particle radius) or set derive_r_inner");
    }
  }
  box = particle_sequence_box(
      box, max_radius, options.r_inner, options.r_outer,
      [&] {
        return load_particle_frame(job.frames(0), path + ".frames[0]", context.uploads, context.limits.max_particles)
            .positions;
      },
      options.container_box);
  const FrameEncoding encoding = resolve_output(spec.output(), box, "spec.output");
  return std::make_unique<ParticlesRunner>(std::move(frames), context.uploads, std::move(options), encoding,
                                           context.limits, context.worker_threads);
}

}  // namespace surfacer::server
