// Job `particles`: particle frames -> one smooth, watertight mesh per frame (Williams 2008), frames in parallel. An
// open sequence (ParticlesJob.open) takes more frames while it runs (docs/ALGORITHMS.md §5, "Open sequences").
#include <deque>
#include <mutex>
#include <span>

#include "core/particles/attribute_interpolation.h"
#include "core/particles/particle_surfacer.h"
#include "core/util/errors.h"
#include "server/runners/decimation.h"
#include "server/runners/frames.h"
#include "server/runners/runner.h"
#include "wire/job_options.h"
#include "wire/particle_frames.h"
#include "wire/scene.h"

namespace surfacer::server {
namespace {

// The memory a frame's particles take while it is surfaced, besides its mesh (TaskMemory::kParticleBytes).
std::int64_t particle_bytes(const wire::ParticleData& data) {
  const auto particles = static_cast<std::int64_t>(data.positions.size());
  std::int64_t bytes = particles * TaskMemory::kParticleBytes;
  if (!data.radii.empty()) bytes += particles * TaskMemory::kWeightedParticleBytes;
  for (const Attribute& a : data.attributes) bytes += static_cast<std::int64_t>(a.values.size() * sizeof(float));
  return bytes;
}

class ParticlesRunner final : public JobRunner {
 public:
  ParticlesRunner(v1::ParticlesJob job, std::vector<std::vector<std::string>> interpolate,
                  const wire::UploadLookup& uploads, ParticleSurfacingOptions options, FrameMaker frame_maker,
                  const Limits& limits, int worker_threads, MemoryBudget* memory, Aabb box)
      : job_(std::move(job)),
        frames_(job_.frames().begin(), job_.frames().end()),
        interpolate_(interpolate.begin(), interpolate.end()),
        uploads_(uploads),
        options_(std::move(options)),
        frame_maker_(std::move(frame_maker)),
        limits_(limits),
        worker_threads_(worker_threads),
        memory_(memory),
        box_(box) {}

  std::string kind() const override { return "particles"; }
  int task_count() const override {
    std::lock_guard lock(mutex_);
    return static_cast<int>(frames_.size());
  }
  int frame_count() const override { return task_count(); }
  bool open() const override { return job_.open(); }

  void check_appended(const google::protobuf::RepeatedPtrField<v1::ParticleFrame>& frames,
                      const std::string& path) const override {
    if (!job_.open()) JobRunner::check_appended(frames, path);
    const int first = task_count();
    check_frame_count(static_cast<std::int64_t>(first) + frames.size(), path, limits_);
    v1::ParticlesJob probe = job_;  // the job's options with the new frames at their indices
    probe.clear_frames();
    for (int i = 0; i < first; ++i) probe.add_frames();
    probe.mutable_frames()->MergeFrom(frames);
    for (int i = 0; i < frames.size(); ++i) {
      const std::string at = path + "[" + std::to_string(i) + "]";
      try {
        wire::interpolated_attributes(probe, first + i, "spec.particles");
        const wire::ParticleSummary summary =
            wire::summarize_particle_frame(frames[i], at, uploads_, limits_.max_particles);
        wire::require_r_inner_frame(probe, static_cast<std::size_t>(first + i), summary.max_radius > 0.0);
        if (!frame_maker_.encoding().grid()) continue;  // lossless frames have no grid to leave
        // The box this frame alone would need (its particles padded by the surface's reach) must lie in the job's.
        const Aabb need = wire::particles_job_box(probe, std::span(&summary, 1), [&] {
          return wire::load_particle_frame(frames[i], at, uploads_, limits_.max_particles).positions;
        });
        if ((need.min.array() < box_.min.array()).any() || (need.max.array() > box_.max.array()).any()) {
          throw InvalidInput("spec.output.quantization_bounds",
                             at + ": its surface can reach outside the job's quantization box (fixed by the first "
                                  "frames of the open sequence); give spec.output.quantization_bounds "
                                  "(--quantization-bounds) covering every frame");
        }
      } catch (const Error& e) {
        if (e.kind() != ErrorKind::kInvalidInput || e.field() == "spec.output.quantization_bounds") throw;
        throw InvalidInput(at, at + ": " + e.what());
      }
    }
  }

  void append(const google::protobuf::RepeatedPtrField<v1::ParticleFrame>& frames) override {
    std::lock_guard lock(mutex_);
    v1::ParticlesJob probe = job_;
    probe.clear_frames();
    for (std::size_t i = 0; i < frames_.size(); ++i) probe.add_frames();
    probe.mutable_frames()->MergeFrom(frames);
    for (int i = 0; i < frames.size(); ++i) {
      interpolate_.push_back(wire::interpolated_attributes(probe, static_cast<int>(frames_.size()), "spec.particles"));
      frames_.push_back(frames[i]);
    }
  }

  void pin(v1::JobSpec& spec) const override {
    if (job_.open() && !spec.output().has_quantization_bounds()) {
      wire::set_bounds(*spec.mutable_output()->mutable_quantization_bounds(), box_);
    }
  }

  void run_task(int index, FrameSink& sink, const RunControl& control) override {
    const std::string path = "spec.particles.frames[" + std::to_string(index) + "]";
    v1::ParticleFrame input;
    std::vector<std::string> interpolate;
    {
      std::lock_guard lock(mutex_);
      input = frames_[index];
      interpolate = interpolate_[index];
    }
    StageTimer timer;
    const wire::ParticleData data =
        timer.run("decode", [&] { return wire::load_particle_frame(input, path, uploads_, limits_.max_particles); });
    ParticleSurfacingOptions options = options_;
    // A single frame gets every core; a sequence (an open one too) runs its frames in parallel, one thread each.
    options.threads = frames_.size() == 1 && !job_.open() ? worker_threads_ : 1;
    ParticleSurfacingStats stats;
    TaskMemory memory(limits_, memory_, "particles frame " + std::to_string(index),
                      task_bytes_per_triangle(frame_maker_, TaskMemory::kMeshWorkBytesPerTriangle));
    memory.reserve_fixed(particle_bytes(data));
    const RunControl task = memory.control(control);
    Mesh mesh = surface_particles(data.positions, data.radii, options, task, &stats);
    control.check();
    timer.add("distance_field", stats.seconds_distance_field);
    timer.add("polygonize", stats.seconds_polygonize);
    timer.add("laplacian", stats.seconds_laplacian);
    timer.add("build_b", stats.seconds_build_b);
    timer.add("bilaplacian", stats.seconds_bilaplacian);
    timer.add("polish", stats.seconds_polish);
    if (options.erosion) timer.add("erosion", stats.seconds_erosion);
    timer.add("cleanup", stats.seconds_cleanup);
    if (!interpolate.empty()) {
      std::vector<Attribute> carried;
      for (const std::string& name : interpolate) {
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
    FrameOutput frame =
        decimated_frame(frame_maker_, std::move(mesh),
                        particle_band_rule(data.positions, data.radii, stats.r_inner, stats.r_outer), timer, task);
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
    metrics["cusp_vertices"] = static_cast<double>(stats.cusp_vertices);
    metrics["bubbles_dropped"] = static_cast<double>(stats.bubbles_dropped);
    sink.emit(index, std::move(frame));
  }

 private:
  const v1::ParticlesJob job_;  // the options and the submitted frames (appended ones are in frames_ only)
  mutable std::mutex mutex_;    // frames_ and interpolate_, which grow in an open sequence
  std::deque<v1::ParticleFrame> frames_;
  std::deque<std::vector<std::string>> interpolate_;  // per frame: the attributes carried onto its vertices
  const wire::UploadLookup& uploads_;
  ParticleSurfacingOptions options_;
  FrameMaker frame_maker_;
  Limits limits_;
  int worker_threads_;
  MemoryBudget* memory_;
  Aabb box_;  // the quantization box
};

// An open sequence's quantization box when the request gives none: the submitted frames' box grown by its own
// extent on every side, so that later frames may move about, and clipped to the container box as the frames' box is
// (docs/ALGORITHMS.md §5, "Open sequences").
Aabb open_sequence_box(const v1::ParticlesJob& job, const Aabb& box) {
  const Vec3 extent = box.max - box.min;
  Aabb grown{box.min - extent, box.max + extent};
  // The frames' box lies inside the container already (particle_sequence_box), so the clipped box still holds it.
  if (job.container().has_box()) grown.intersect(wire::to_aabb(job.container().box(), "spec.particles.container.box"));
  return grown;
}

}  // namespace

std::unique_ptr<JobRunner> make_particles_runner(const v1::JobSpec& spec, const JobContext& context) {
  const auto& job = spec.particles();
  const std::string path = "spec.particles";
  if (job.frames_size() == 0) {
    throw InvalidInput(path + ".frames", path + ".frames is empty; give at least one particle frame");
  }
  check_frame_count(job.frames_size(), path + ".frames", context.limits);
  ParticleSurfacingOptions options = wire::particle_options(job, spec.output().normals(), path);
  options.container_solid = wire::container_solid(job, context.uploads, path);

  // Every frame is checked now (so bad data fails the submit, not a frame later), and the quantization box is the
  // union of the frames' particles, padded by how far the surface can reach.
  std::vector<wire::ParticleSummary> summaries;
  summaries.reserve(job.frames_size());
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
  FrameEncoding encoding =
      wire::frame_encoding(spec.output(), job.open() ? open_sequence_box(job, box) : box, "spec.output");
  // Decimation makes no new triangle with an angle below the job's sliver threshold either, when that is the higher.
  encoding.decimate.min_angle_degrees = std::max(encoding.decimate.min_angle_degrees, options.min_angle_degrees);
  // The sliver repair also removes triangles that would be degenerate once quantized on the job's grid.
  options.output_grid = encoding.grid();
  const Aabb quantization_box = encoding.options.draco.quantization_bounds.value_or(box);
  FrameMaker frames(encoding, context.limits.max_triangles, context.worker_threads);
  if (options.min_angle_degrees > 0.0) frames.count_slivers_below(options.min_angle_degrees);
  return std::make_unique<ParticlesRunner>(job, std::move(interpolate), context.uploads, std::move(options),
                                           std::move(frames), context.limits, context.worker_threads, context.memory,
                                           quantization_box);
}

}  // namespace surfacer::server
