// Job `active`: a narrow-band potential evolved to track a target (Desbrun-Cani 1998). One task (each frame
// evolves from the previous one); modes coat (particle sequence), morph (scene A -> B) and advect (velocity field).
#include <chrono>
#include <cstring>

#include "core/active/active_surface.h"
#include "core/util/checks.h"
#include "core/util/errors.h"
#include "server/runners/decimation.h"
#include "server/runners/frames.h"
#include "server/runners/runner.h"
#include "wire/job_options.h"
#include "wire/particle_frames.h"
#include "wire/scene.h"
#include "wire/uploads.h"

namespace surfacer::server {
namespace {

class ActiveRunner final : public JobRunner {
 public:
  ActiveRunner(v1::ActiveJob job, const wire::UploadLookup& uploads, ActiveSurfaceOptions options, FrameMaker frames,
               const Limits& limits, int frames_expected, MemoryBudget* memory)
      : job_(std::move(job)),
        uploads_(uploads),
        options_(options),
        frames_(std::move(frames)),
        limits_(limits),
        frames_expected_(frames_expected),
        memory_(memory) {}

  std::string kind() const override { return "active"; }
  int task_count() const override { return 1; }
  int frame_count() const override { return frames_expected_; }

  void resume_from(int, int, std::string state) override { resume_state_ = std::move(state); }

  void run_task(int, FrameSink& sink, const RunControl& job_control) override {
    // Each frame's mesh is held to --max-triangles as it is polygonized; the largest one's memory stays reserved.
    TaskMemory memory(limits_, memory_, "active surface",
                      task_bytes_per_triangle(frames_, TaskMemory::kPolygonizeBytesPerTriangle));
    const RunControl control = memory.control(job_control);
    // After a restart: continue from the last checkpoint (the mode's blob carries its next frame); a blob this build
    // cannot read starts over, and Job::emit drops the frames already stored.
    std::string resume = std::move(resume_state_);
    resume_state_.clear();
    if (!resume.empty()) {
      try {
        run_mode(sink, control, &resume);
        return;
      } catch (const Error& e) {
        if (e.kind() != ErrorKind::kInvalidInput || e.field() != "resume_state") throw;
      }
    }
    run_mode(sink, control, nullptr);
  }

  void run_mode(FrameSink& sink, const RunControl& control, const std::string* resume) {
    ActiveCheckpoints checkpoints;
    checkpoints.resume_state = resume;
    CheckpointPacer pacer;
    checkpoints.save = [&](int next_frame, std::string state) {
      if (pacer.due()) pacer.take([&] { sink.checkpoint(0, next_frame, std::move(state)); });
    };
    auto last = std::chrono::steady_clock::now();
    const ActiveFrameSink emit = [&](ActiveFrame&& frame) {
      const auto now = std::chrono::steady_clock::now();
      StageTimer timer;
      timer.add("evolve", std::chrono::duration<double>(now - last).count());
      // The engine's potential lives on its sparse grid only: the tolerance bound alone (docs/ALGORITHMS.md §5).
      FrameOutput out = decimated_frame(frames_, std::move(frame.mesh), {}, timer, control);
      auto& m = *out.stats.mutable_metrics();
      const ActiveFrameStats& s = frame.stats;
      m["time"] = s.time;
      m["volume"] = s.volume;
      m["area"] = s.area;
      m["active_nodes"] = static_cast<double>(s.active_nodes);
      m["allocated_blocks"] = static_cast<double>(s.allocated_blocks);
      m["substeps"] = s.substeps;
      m["dt"] = s.dt;
      m["max_dfdt"] = s.max_dfdt;
      m["components"] = s.components;
      m["reinitializations"] = s.reinitializations;
      sink.emit(frame.index, std::move(out));
      control.report("evolve", static_cast<double>(frame.index + 1) / std::max(1, frames_expected_));
      last = std::chrono::steady_clock::now();
    };
    const std::string path = "spec.active";
    switch (job_.mode_case()) {
      case v1::ActiveJob::kCoat: {
        const auto& coat = job_.coat();
        std::vector<std::vector<Vec3>> frames;
        frames.reserve(coat.frames_size());
        for (int i = 0; i < coat.frames_size(); ++i) {
          frames.push_back(wire::load_particle_frame(coat.frames(i), path + ".coat.frames[" + std::to_string(i) + "]",
                                                     uploads_, limits_.max_particles)
                               .positions);
        }
        CoatOptions options = wire::coat_options(coat, options_, path);
        options.checkpoints = checkpoints;
        coat_particles(frames, options, options_, emit, control);
        break;
      }
      case v1::ActiveJob::kMorph: {
        const auto& morph = job_.morph();
        const FieldPtr from = wire::field_from_scene(morph.from(), path + ".morph.from", uploads_);
        const FieldPtr to = wire::field_from_scene(morph.to(), path + ".morph.to", uploads_);
        MorphOptions options = wire::morph_options(morph, options_, path);
        options.checkpoints = checkpoints;
        morph_shapes(*from, to, options, options_, emit, control);
        break;
      }
      case v1::ActiveJob::kAdvect: {
        const auto& advect = job_.advect();
        const FieldPtr shape = wire::field_from_scene(advect.shape(), path + ".advect.shape", uploads_);
        AdvectOptions options = wire::advect_options(advect, path);
        options.checkpoints = checkpoints;
        advect_shape(*shape, velocity(advect, path + ".advect"), options, options_, emit, control);
        break;
      }
      case v1::ActiveJob::MODE_NOT_SET:
        break;
    }
  }

  VelocityFn velocity(const v1::ActiveAdvect& advect, const std::string& path) const {
    if (advect.has_grid()) return make_velocity_fn(velocity_grid(advect.grid(), path + ".grid", uploads_));
    const double period = advect.enright().has_period() ? advect.enright().period() : kEnrightPeriod;
    return [period](const Vec3& p, double t) { return enright_velocity(p, t, period); };
  }

  static std::shared_ptr<const VelocityGrid> velocity_grid(const v1::VelocityGrid& g, const std::string& path,
                                                           const wire::UploadLookup& uploads) {
    auto grid = std::make_shared<VelocityGrid>(wire::velocity_grid_geometry(g, path));
    const auto blob = uploads.get(g.upload_id(), path + ".upload_id");
    if (blob->bytes.size() % sizeof(float) != 0) {
      throw InvalidInput(path + ".upload_id", path + ".upload_id: the upload is not a whole number of float32 values");
    }
    grid->values.resize(blob->bytes.size() / sizeof(float));
    std::memcpy(grid->values.data(), blob->bytes.data(), grid->values.size() * sizeof(float));
    with_path(path, [&] { grid->validate(); });
    return grid;
  }

 private:
  v1::ActiveJob job_;
  const wire::UploadLookup& uploads_;
  ActiveSurfaceOptions options_;
  FrameMaker frames_;
  Limits limits_;
  int frames_expected_;
  MemoryBudget* memory_;
  std::string resume_state_;
};

}  // namespace

std::unique_ptr<JobRunner> make_active_runner(const v1::JobSpec& spec, const JobContext& context) {
  const auto& job = spec.active();
  const std::string path = "spec.active";
  ActiveSurfaceOptions options = wire::active_options(job, spec.output().normals(), path);

  // Validate the mode now and find the region the surface can occupy (the frames' quantization box).
  // With bounds, the surface closes just outside the last grid nodes inside them: up to a cell beyond.
  std::optional<Aabb> region;
  if (options.domain) region = options.domain->padded(options.h);
  std::optional<Aabb> initial_bounds;  // of the shape the surface starts from
  // Where the region and the initial shape come from, for a grid too fine for them: the part of the request that
  // reaches furthest from the grid's origin, and the initial shape's.
  std::string widest = path + ".bounds", initial_source = path + ".bounds";
  double reach = -1.0;
  int frames_expected = 1;
  auto add_region = [&](const std::optional<Aabb>& b, double pad, const std::string& source) {
    if (!b || options.domain) return;
    const Aabb padded = b->padded(pad);
    region = region ? merged(*region, padded) : padded;
    const double r = std::max(padded.min.cwiseAbs().maxCoeff(), padded.max.cwiseAbs().maxCoeff());
    if (!(r <= reach)) {
      reach = r;
      widest = source;
    }
  };
  auto set_initial = [&](const std::optional<Aabb>& b, const std::string& source) {
    initial_bounds = b;
    if (!options.domain) initial_source = source;
  };
  switch (job.mode_case()) {
    case v1::ActiveJob::kCoat: {
      const auto& coat = job.coat();
      if (coat.frames_size() == 0) {
        throw InvalidInput(path + ".coat.frames", path + ".coat.frames is empty; give the particle sequence");
      }
      wire::coat_options(coat, options, path);
      for (int i = 0; i < coat.frames_size(); ++i) {
        const std::string frame = path + ".coat.frames[" + std::to_string(i) + "]";
        const auto summary =
            wire::summarize_particle_frame(coat.frames(i), frame, context.uploads, context.limits.max_particles);
        add_region(summary.bounds, coat.kernel_radius() + 4 * options.h, frame);
        if (i == 0) set_initial(summary.bounds.padded(coat.kernel_radius()), frame);
      }
      check_frame_count(coat.frames_size(), path + ".coat.frames", context.limits);
      frames_expected = coat.frames_size();
      break;
    }
    case v1::ActiveJob::kMorph: {
      const auto& morph = job.morph();
      std::string from_unbounded, to_unbounded;
      const FieldPtr from =
          wire::field_from_scene(morph.from(), path + ".morph.from", context.uploads, &from_unbounded);
      const FieldPtr to = wire::field_from_scene(morph.to(), path + ".morph.to", context.uploads, &to_unbounded);
      if (!options.domain && (!from_unbounded.empty() || !to_unbounded.empty())) {
        throw InvalidInput(path + ".bounds", path + ": a morph between unbounded scenes needs " + path + ".bounds: " +
                                                 (from_unbounded.empty() ? to_unbounded : from_unbounded));
      }
      set_initial(from->bounds(), path + ".morph.from");
      add_region(from->bounds(), 4 * options.h, path + ".morph.from");
      add_region(to->bounds(), 4 * options.h, path + ".morph.to");
      const MorphOptions morph_options = wire::morph_options(morph, options, path);
      check_frame_count(morph_options.max_frames, path + ".morph.max_frames", context.limits);
      frames_expected = morph_options.max_frames + 1;
      break;
    }
    case v1::ActiveJob::kAdvect: {
      const auto& advect = job.advect();
      const FieldPtr shape = wire::field_from_scene(advect.shape(), path + ".advect.shape", context.uploads);
      // The initial frame, then `frames` more.
      check_frame_count(std::int64_t{wire::advect_options(advect, path).frames} + 1, path + ".advect.frames",
                        context.limits);
      set_initial(shape->bounds(), path + ".advect.shape");
      add_region(shape->bounds(), 4 * options.h, path + ".advect.shape");
      if (advect.has_grid()) {
        const auto grid = ActiveRunner::velocity_grid(advect.grid(), path + ".advect.grid", context.uploads);
        const Vec3 far = grid->origin + grid->spacing.cwiseProduct(Vec3(grid->nx - 1, grid->ny - 1, grid->nz - 1));
        add_region(Aabb{grid->origin, far}, 4 * options.h, path + ".advect.grid");
      } else {
        if (advect.enright().has_period()) {
          with_path(path + ".advect.enright", [&] { require_positive("period", advect.enright().period()); });
        }
        // The Enright field lives in the unit cube.
        add_region(Aabb{Vec3::Zero(), Vec3::Ones()}, 4 * options.h, path + ".advect.enright");
      }
      frames_expected = advect.frames() + 1;
      break;
    }
    case v1::ActiveJob::MODE_NOT_SET:
      throw InvalidInput(path + ".mode", path + " has no mode; set one of coat, morph, advect");
  }
  if (!region) {
    throw InvalidInput(path + ".bounds", path + ": the shape is unbounded; give " + path + ".bounds");
  }
  try {
    check_grid_reach(initial_bounds, *region, options);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kResourceLimit) throw Error(e.kind(), path + ".bounds", path + ": " + e.what());
    // "h": the region leaves the grid's reach; "domain": the initial shape's box is too many blocks to scan.
    throw Error(e.kind(), path + ".grid_spacing",
                path + ".grid_spacing (" + format_number(options.h) + ") is too fine for " +
                    (e.field() == "h" ? widest : initial_source) + ": " + e.what());
  }
  const FrameEncoding encoding = wire::frame_encoding(spec.output(), *region, "spec.output");
  FrameMaker frames(encoding, context.limits.max_triangles, context.worker_threads);
  options.vertex_margin = frames.vertex_margin();
  return std::make_unique<ActiveRunner>(job, context.uploads, options, std::move(frames), context.limits,
                                        frames_expected, context.memory);
}

}  // namespace surfacer::server
