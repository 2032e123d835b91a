// Job `optimize`: a start mesh evolved toward f = 0 with the field's normals (Ohtake-Belyaev-Pasko 2002). One task;
// a snapshot frame every `snapshot_every` iterations (frame k = k-th snapshot), the result last.
#include <chrono>
#include <cmath>

#include "core/util/errors.h"
#include "core/mesh/mesh_io.h"
#include "core/optimize/mesh_optimizer.h"
#include "server/frames.h"
#include "server/job_types.h"
#include "server/polygonize.h"
#include "server/scene_translate.h"
#include "server/uploads.h"

namespace surfacer::server {
namespace {

constexpr int kDefaultStartCells = 64;
constexpr double kBoxPadFraction = 0.05;  // of the diagonal: room for vertices moving onto the true surface

MeshFormat sniff_mesh_format(const std::string& bytes) {
  if (bytes.rfind("ply", 0) == 0) return MeshFormat::kPly;
  if (bytes.rfind("DRACO", 0) == 0) return MeshFormat::kDraco;
  return MeshFormat::kObj;
}

class OptimizeRunner final : public JobRunner {
 public:
  OptimizeRunner(FieldPtr field, std::optional<Mesh> start, PolygonizeSettings start_settings,
                 MeshOptimizerOptions options, FrameEncoding encoding, std::int64_t max_triangles, int threads)
      : field_(std::move(field)),
        start_(std::move(start)),
        start_settings_(start_settings),
        options_(options),
        encoding_(encoding),
        max_triangles_(max_triangles),
        threads_(threads) {}

  std::string kind() const override { return "optimize"; }
  int task_count() const override { return 1; }
  int frame_count() const override {
    return options_.snapshot_every > 0 ? options_.max_iterations / options_.snapshot_every + 2 : 1;
  }

  void resume_from(int, int next_frame, std::string state) override {
    resume_frame_ = next_frame;
    resume_state_ = std::move(state);
  }

  void run_task(int, FrameSink& sink, const RunControl& control) override {
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
      Mesh start = start_ ? std::move(*start_)
                          : start_timer.run("polygonize",
                                            [&] { return polygonize(*field_, start_settings_, threads_, control); });
      resumed.emplace(*field_, std::move(start), options);
      resume_frame_ = 0;
    }
    start_.reset();
    MeshOptimizer& optimizer = *resumed;
    int frame = resume_frame_;
    CheckpointPacer pacer;
    // A checkpoint is taken right after a frame, so its state is the emitted snapshot's.
    int last_emitted = frame > 0 ? optimizer.stats().iteration : -1;
    auto emit = [&](StageTimer& timer) {
      const auto& stats = optimizer.stats();
      FrameOutput out = make_frame(optimizer.mesh(), encoding_, max_triangles_, timer);
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
      control.report("optimize", static_cast<double>(optimizer.stats().iteration) / std::max(1, options.max_iterations));
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
  PolygonizeSettings start_settings_;
  MeshOptimizerOptions options_;
  FrameEncoding encoding_;
  std::int64_t max_triangles_;
  int threads_;
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
  FieldPtr field = field_from_scene(job.scene(), path + ".scene", context.uploads);

  MeshOptimizerOptions options;
  if (job.has_d_flow()) options.d_flow = job.d_flow();
  if (job.has_n_flow()) options.n_flow = job.n_flow();
  if (job.has_t_flow()) options.t_flow = job.t_flow();
  if (job.has_c_d()) options.c_d = job.c_d();
  if (job.has_c_n()) options.c_n = job.c_n();
  if (job.has_c_t()) options.c_t = job.c_t();
  if (job.has_step_bound()) options.step_bound = job.step_bound();
  options.modified_flows = job.modified_flows();
  if (job.has_t_flow_iterations()) options.t_flow_iterations = job.t_flow_iterations();
  if (job.has_max_iterations()) options.max_iterations = job.max_iterations();
  if (job.has_tolerance()) options.tolerance = job.tolerance();
  if (job.has_subdivision_threshold()) options.subdivision_threshold = job.subdivision_threshold();
  if (job.has_triangle_budget()) options.triangle_budget = job.triangle_budget();
  if (job.has_snapshot_every()) options.snapshot_every = job.snapshot_every();
  options.normals = spec.output().normals();
  if (options.snapshot_every < 0) {
    throw InvalidInput(path + ".snapshot_every", path + ".snapshot_every (" + std::to_string(options.snapshot_every) +
                                                     ") must be >= 0 (0: only the final mesh)");
  }
  if (options.max_iterations < 0 || options.max_iterations > 1'000'000) {
    throw InvalidInput(path + ".max_iterations", path + ".max_iterations (" + std::to_string(options.max_iterations) +
                                                     ") must be in 0..1000000 (default 200)");
  }
  if (options.triangle_budget && *options.triangle_budget > context.limits.max_triangles) {
    throw ResourceLimit("max_triangles", path + ".triangle_budget (" + std::to_string(*options.triangle_budget) +
                                             ") is over the server's limit of " +
                                             std::to_string(context.limits.max_triangles) +
                                             " triangles; lower it or start the server with a larger --max-triangles");
  }

  // The start mesh: uploaded (parsed now, so a bad file fails the submit) or polygonized by the job.
  std::optional<Mesh> start;
  PolygonizeSettings settings;
  Aabb box;
  if (job.start_case() == v1::OptimizeJob::kMeshUploadId) {
    const auto blob = context.uploads.get(job.mesh_upload_id(), path + ".mesh_upload_id");
    try {
      start = parse_mesh(blob->bytes, sniff_mesh_format(blob->bytes), "upload " + job.mesh_upload_id());
    } catch (const Error& e) {
      if (e.kind() != ErrorKind::kInvalidInput) throw;
      throw InvalidInput(path + ".mesh_upload_id", path + ".mesh_upload_id: " + e.what());
    }
    if (start->triangles.empty()) {
      throw InvalidInput(path + ".mesh_upload_id", path + ".mesh_upload_id: the start mesh has no triangles");
    }
    if (static_cast<std::int64_t>(start->triangles.size()) > context.limits.max_triangles) {
      throw ResourceLimit("max_triangles", path + ".mesh_upload_id: the start mesh has " +
                                               std::to_string(start->triangles.size()) +
                                               " triangles, over the server's limit; raise --max-triangles");
    }
    box.min = box.max = start->vertices.front();
    for (const auto& v : start->vertices) {
      box.min = box.min.cwiseMin(v);
      box.max = box.max.cwiseMax(v);
    }
    if (const auto b = field->bounds()) {
      box.min = box.min.cwiseMin(b->min);
      box.max = box.max.cwiseMax(b->max);
    }
  } else {
    const v1::Polygonize& p = job.polygonize();
    Resolution resolution;
    if (p.resolution_case() == v1::Polygonize::kCells) resolution.cells = p.cells();
    if (p.resolution_case() == v1::Polygonize::kCellSize) resolution.cell_size = p.cell_size();
    // Optimization starts from Marching Cubes unless asked otherwise (the paper's setting).
    const v1::Polygonizer method = p.method() == v1::POLYGONIZER_UNSPECIFIED ? v1::POLYGONIZER_CUBES : p.method();
    settings = resolve_polygonize({field}, p.has_bounds() ? &p.bounds() : nullptr, resolution, kDefaultStartCells,
                                  method, false, context.limits, path + ".polygonize");
    box = settings.bounds;
  }
  const double pad = kBoxPadFraction * box.size().norm();
  box.min.array() -= pad;
  box.max.array() += pad;
  const FrameEncoding encoding = resolve_output(spec.output(), box, "spec.output");
  try {
    // Validates the options (the constructor throws InvalidInput naming the option).
    Mesh probe;
    probe.vertices = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)};
    probe.triangles = {{0, 1, 2}};
    MeshOptimizer validate(*field, std::move(probe), options);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    throw InvalidInput(path + "." + e.field(), path + "." + e.what());
  }
  return std::make_unique<OptimizeRunner>(std::move(field), std::move(start), settings, options, encoding,
                                          context.limits.max_triangles, context.worker_threads);
}

}  // namespace surfacer::server
