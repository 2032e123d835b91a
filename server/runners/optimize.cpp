// Job `optimize`: a start mesh evolved toward f = 0 with the field's normals (Ohtake-Belyaev-Pasko 2002). One task;
// a snapshot frame every `snapshot_every` iterations (frame k = k-th snapshot), the result last.
#include <chrono>

#include "core/mesh/mesh_io.h"
#include "core/optimize/mesh_optimizer.h"
#include "core/util/errors.h"
#include "server/runners/decimation.h"
#include "server/runners/frames.h"
#include "server/runners/runner.h"
#include "wire/job_options.h"
#include "wire/scene.h"
#include "wire/uploads.h"

namespace surfacer::server {
namespace {

constexpr double kBoxPadFraction = 0.05;  // of the diagonal: room for vertices moving onto the true surface

// Frames a run can emit: a snapshot every snapshot_every iterations (iteration 0 included) plus the final mesh.
std::int64_t optimize_frame_count(const MeshOptimizerOptions& options) {
  return options.snapshot_every > 0 ? std::int64_t{options.max_iterations} / options.snapshot_every + 2 : 1;
}

MeshFormat sniff_mesh_format(const std::string& bytes) {
  if (bytes.rfind("ply", 0) == 0) return MeshFormat::kPly;
  if (bytes.rfind("DRACO", 0) == 0) return MeshFormat::kDraco;
  if (bytes.rfind("glTF", 0) == 0) return MeshFormat::kGlb;
  if (bytes.rfind("{", 0) == 0) return MeshFormat::kGltf;
  return MeshFormat::kObj;
}

class OptimizeRunner final : public JobRunner {
 public:
  OptimizeRunner(FieldPtr field, std::optional<Mesh> start, PolygonizeGrid start_grid, MeshOptimizerOptions options,
                 FrameMaker frames, const JobContext& context)
      : field_(std::move(field)),
        start_(std::move(start)),
        start_grid_(start_grid),
        options_(options),
        frames_(std::move(frames)),
        threads_(context.worker_threads),
        limits_(context.limits),
        memory_(context.memory) {}

  std::string kind() const override { return "optimize"; }
  int task_count() const override { return 1; }
  int frame_count() const override { return static_cast<int>(optimize_frame_count(options_)); }

  void resume_from(int, int next_frame, std::string state) override {
    resume_frame_ = next_frame;
    resume_state_ = std::move(state);
  }

  void run_task(int, FrameSink& sink, const RunControl& job_control) override {
    // The start mesh's polygonization and every subdivision round are held to --max-triangles as they build, and
    // reserve their memory first.
    TaskMemory memory(limits_, memory_, "optimize",
                      task_bytes_per_triangle(frames_, TaskMemory::kMeshWorkBytesPerTriangle));
    const RunControl control = memory.control(job_control);
    MeshOptimizerOptions options = options_;
    options.threads = threads_;
    StageTimer start_timer;
    // After a restart: continue from the last checkpoint (written after frame resume_frame_ - 1); a blob this
    // server cannot read (another version, corrupted) starts over, and Job::emit drops the frames already stored.
    std::optional<MeshOptimizer> resumed;
    if (!resume_state_.empty()) {
      try {
        resumed.emplace(MeshOptimizer::from_state(*field_, resume_state_, options));
      } catch (const Error&) {
        resumed.reset();
      }
      resume_state_.clear();
    }
    if (!resumed) {
      Mesh start = start_ ? std::move(*start_) : start_timer.run("polygonize", [&] {
        PolygonizeGrid grid = start_grid_;
        grid.threads = threads_;
        memory.reserve_fixed(polygonize_fixed_bytes(grid));
        return polygonize(*field_, grid, control);
      });
      resumed.emplace(*field_, std::move(start), options);
      resume_frame_ = 0;
    }
    start_.reset();
    MeshOptimizer& optimizer = *resumed;
    std::int64_t covered = 0;  // an uploaded or resumed start mesh: its triangles' memory
    reserve_triangles(control, static_cast<std::int64_t>(optimizer.mesh().triangles.size()), covered);
    int frame = resume_frame_;
    CheckpointPacer pacer;
    // A checkpoint is taken right after a frame, so its state is the emitted snapshot's.
    int last_emitted = frame > 0 ? optimizer.stats().iteration : -1;
    auto emit = [&](StageTimer& timer) {
      const auto& stats = optimizer.stats();
      FrameOutput out = decimated_frame(frames_, optimizer.mesh(),
                                        zero_set_rule(*field_, frames_.encoding().decimate.tolerance), timer, control);
      out.stats.set_iteration(stats.iteration);
      auto& m = *out.stats.mutable_metrics();
      m["e_d"] = stats.e_d;
      m["e_n"] = stats.e_n;
      m["max_distance"] = stats.max_distance;
      m["rms_distance"] = stats.rms_distance;
      m["min_angle_degrees"] = stats.min_angle_degrees;
      m["t_flow_on"] = stats.t_flow_on ? 1.0 : 0.0;
      m["limited_moves"] = static_cast<double>(stats.limited_moves);
      m["triangles_added"] = static_cast<double>(stats.triangles_added);
      m["flips"] = static_cast<double>(stats.flips);
      m["collapses"] = static_cast<double>(stats.collapses);
      m["vertices_used"] = static_cast<double>(stats.vertices);
      sink.emit(frame++, std::move(out));
      last_emitted = stats.iteration;
      // Needless after the last frame.
      if (!optimizer.done() && pacer.due()) pacer.take([&] { sink.checkpoint(0, frame, optimizer.save_state()); });
    };
    if (options.snapshot_every > 0 && frame == 0) emit(start_timer);
    StageTimer timer;
    double optimize_seconds = 0.0;
    while (!optimizer.done()) {
      const auto t0 = std::chrono::steady_clock::now();
      optimizer.step(control);
      optimize_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      control.report("optimize",
                     static_cast<double>(optimizer.stats().iteration) / std::max(1, options.max_iterations));
      if (options.snapshot_every > 0 && optimizer.stats().iteration % options.snapshot_every == 0) {
        StageTimer snapshot_timer;
        snapshot_timer.add("optimize", optimize_seconds);
        optimize_seconds = 0.0;
        emit(snapshot_timer);
      }
    }
    if (last_emitted != optimizer.stats().iteration) {
      StageTimer final_timer = options.snapshot_every > 0 ? StageTimer() : start_timer;
      final_timer.add("optimize", optimize_seconds);
      emit(final_timer);
    }
  }

 private:
  FieldPtr field_;
  std::optional<Mesh> start_;
  PolygonizeGrid start_grid_;
  MeshOptimizerOptions options_;
  FrameMaker frames_;
  int threads_;
  Limits limits_;
  MemoryBudget* memory_;
  int resume_frame_ = 0;
  std::string resume_state_;
};

}  // namespace

std::unique_ptr<JobRunner> make_optimize_runner(const v1::JobSpec& spec, const JobContext& context) {
  const auto& job = spec.optimize();
  const std::string path = "spec.optimize";
  if (!job.has_scene()) {
    throw InvalidInput(path + ".scene", path + ".scene is missing; give the field the mesh should fit");
  }
  FieldPtr field = wire::field_from_scene(job.scene(), path + ".scene", context.uploads);
  const MeshOptimizerOptions options = wire::optimizer_options(job, spec.output().normals(), path);
  check_frame_count(optimize_frame_count(options), path + ".snapshot_every", context.limits);
  if (options.triangle_budget && *options.triangle_budget > context.limits.max_triangles) {
    throw ResourceLimit("max_triangles", path + ".triangle_budget (" + std::to_string(*options.triangle_budget) +
                                             ") is over the server's limit of " +
                                             std::to_string(context.limits.max_triangles) +
                                             " triangles; lower it or start the server with a larger --max-triangles");
  }

  // The start mesh: uploaded (parsed now, so a bad file fails the submit) or polygonized by the job.
  std::optional<Mesh> start;
  PolygonizeGrid grid;
  Aabb box;
  if (job.start_case() == v1::OptimizeJob::kMeshUploadId) {
    const auto blob = context.uploads.get(job.mesh_upload_id(), path + ".mesh_upload_id");
    try {
      MeshReadLimits read_limits;
      read_limits.max_triangles = context.limits.max_triangles;
      start = parse_mesh(blob->bytes, sniff_mesh_format(blob->bytes), "upload " + job.mesh_upload_id(), read_limits);
      validate_start_mesh(*start);
      start->attributes.clear();  // the optimizer moves, adds and removes vertices: per-vertex arrays do not carry
    } catch (const Error& e) {
      if (e.kind() == ErrorKind::kResourceLimit) {
        throw ResourceLimit(e.field(), path + ".mesh_upload_id: " + e.what() + "; raise --max-triangles");
      }
      if (e.kind() != ErrorKind::kInvalidInput) throw;
      throw InvalidInput(path + ".mesh_upload_id", path + ".mesh_upload_id: " + e.what());
    }
    if (static_cast<std::int64_t>(start->triangles.size()) > context.limits.max_triangles) {
      throw ResourceLimit("max_triangles", path + ".mesh_upload_id: the start mesh has " +
                                               std::to_string(start->triangles.size()) +
                                               " triangles, over the server's limit; raise --max-triangles");
    }
    box = Aabb::of(start->vertices);
    if (const auto b = field->bounds()) box.merge(*b);
  } else {
    const PolygonizeOptions start_options = wire::start_polygonize_options(job.polygonize(), path + ".polygonize");
    const FieldPtr fields[] = {field};
    grid = with_path(path + ".polygonize", [&] { return resolve_grid(fields, start_options); });
    check_grid_cells(grid, path + ".polygonize", context.limits);
    box = grid.bounds;
  }
  box = box.padded(kBoxPadFraction * box.size().norm());
  const FrameEncoding encoding = wire::frame_encoding(spec.output(), box, "spec.output");
  return std::make_unique<OptimizeRunner>(std::move(field), std::move(start), grid, options,
                                          FrameMaker(encoding, context.limits.max_triangles, context.worker_threads),
                                          context);
}

}  // namespace surfacer::server
