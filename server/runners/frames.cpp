#include "server/runners/frames.h"

#include <chrono>
#include <future>
#include <memory>
#include <thread>

#include "core/mesh/frame_codec.h"
#include "core/mesh/grid_cleanup.h"
#include "core/mesh/mesh_codec.h"
#include "core/util/errors.h"

namespace surfacer::server {

double StageTimer::now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

void fill_mesh_check(const MeshReport& r, v1::MeshCheck& out) {
  out.set_closed(r.closed);
  out.set_edge_manifold(r.edge_manifold);
  out.set_vertex_manifold(r.vertex_manifold);
  out.set_oriented(r.oriented);
  out.set_euler_characteristic(r.euler_characteristic);
  out.set_components(r.components);
  out.set_boundary_edges(r.boundary_edges);
  out.set_non_manifold_edges(r.non_manifold_edges);
  out.set_degenerate_triangles(r.degenerate_triangles);
  for (auto v : r.valence_histogram) out.add_valence_histogram(v);
  out.set_min_valence(r.min_valence);
  out.set_max_valence(r.max_valence);
  out.set_min_angle_degrees(r.min_angle_degrees);
  out.set_max_angle_degrees(r.max_angle_degrees);
  out.set_area(r.area);
  out.set_volume(r.volume);
}

FrameMaker::FrameMaker(FrameEncoding encoding, std::int64_t max_triangles, const Executor* executor)
    : encoding_(std::move(encoding)), max_triangles_(max_triangles), executor_(executor), inline_executor_(1) {}

std::future<std::string> FrameMaker::start_own_thread(const Mesh& mesh) const {
  // The thread owns the encoder (which holds its own copy of the mesh) and the promise, so it may outlive the frame.
  auto encoder = std::make_shared<DracoEncoder>(mesh, encoding_.options.draco);
  auto promise = std::make_shared<std::promise<std::string>>();
  std::future<std::string> result = promise->get_future();
  std::thread([encoder, promise] {
    try {
      promise->set_value(encoder->encode());
    } catch (...) {
      promise->set_exception(std::current_exception());
    }
  }).detach();
  return result;
}

double FrameMaker::vertex_margin() const {
  const std::optional<QuantizationGrid> grid = encoding_.grid();
  return grid ? kMarginSteps * grid->step() : 0.0;
}

FrameOutput FrameMaker::make(Mesh mesh, StageTimer& timer, const RunControl& control) const {
  if (static_cast<std::int64_t>(mesh.triangles.size()) > max_triangles_) {
    throw ResourceLimit("max_triangles", "the mesh has " + std::to_string(mesh.triangles.size()) +
                                             " triangles, over the server's limit of " +
                                             std::to_string(max_triangles_) +
                                             "; lower the resolution or start the server with a larger "
                                             "--max-triangles");
  }
  const Executor& executor = executor_ ? *executor_ : inline_executor_;
  const FrameCodecOptions& options = encoding_.options;
  FrameOutput out;
  out.encoding = encoding_.mesh_encoding();
  const std::optional<QuantizationGrid> grid = encoding_.grid();
  StageTimer check_timer, encode_timer;
  GridCleanupReport cleanup;
  if (grid) {
    control.report("grid_cleanup", 0.0);
    GridCleanupOptions cleanup_options;
    cleanup_options.threads = executor.concurrency();
    cleanup = check_timer.run("grid_cleanup", [&] { return clean_on_grid(mesh, *grid, cleanup_options, control); });
  }
  // Every position is put on its grid point, so that the checks (area and volume included) see what a decoder
  // reads and the encoder, quantizing the same points again, reproduces them exactly.
  if (grid) snap_to_grid(mesh.vertices, *grid, executor.concurrency());
  MeshReport report;
  auto check = [&] {
    control.report("check", 0.0);
    report = check_timer.run("check", [&] { return check_mesh(mesh, executor, control); });
  };
  if (options.codec == FrameCodec::kDraco && mesh.triangles.size() > options.max_piece_triangles) {
    // One Draco mesh, on a thread of its own while the checks run on the executor.
    out.bytes = encode_timer.run("encode", [&] {
      std::future<std::string> encoded = start_own_thread(mesh);
      check();
      control.report("encode", 0.0);
      while (encoded.wait_for(std::chrono::milliseconds(10)) != std::future_status::ready) control.check();
      return encoded.get();
    });
  } else {
    // The checks, then the encoding, each on every thread of the executor: run side by side as two items, each
    // would get one thread only, since a pool thread waiting for its items does not run the other item's pieces.
    check();
    control.report("encode", 0.0);
    out.bytes = encode_timer.run("encode", [&] { return encode_frame(mesh, options, executor, control); });
  }
  out.stats.set_vertices(static_cast<std::int64_t>(mesh.vertices.size()));
  out.stats.set_triangles(static_cast<std::int64_t>(mesh.triangles.size()));
  fill_mesh_check(report, *out.stats.mutable_check());
  if (grid) {
    auto& metrics = *out.stats.mutable_metrics();
    metrics["grid_degenerate_found"] = static_cast<double>(cleanup.degenerate_found);
    metrics["grid_coincident_found"] = static_cast<double>(cleanup.coincident_found);
    metrics["grid_nudges"] = static_cast<double>(cleanup.nudges);
    metrics["grid_left"] = static_cast<double>(cleanup.degenerate_left + cleanup.coincident_left);
  }
  auto add_timing = [&](const std::string& stage, double seconds) {
    auto* t = out.stats.add_timings();
    t->set_stage(stage);
    t->set_seconds(seconds);
  };
  for (const StageTimer* t : {&timer, &encode_timer, &check_timer}) {
    for (const auto& [stage, seconds] : t->timings()) add_timing(stage, seconds);
  }
  return out;
}

}  // namespace surfacer::server
